"""Executors: the GA gives the same numbers in this process, on a process pool and on
Dask (a local cluster, and a scheduler with two workers started as processes), also when
a worker is killed mid-generation; bad executor names are one-line user errors."""

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from evo_door.errors import UserError
from evo_door.experiment import load_experiment
from evo_door.experiment.runner import ExperimentRun
from evo_door.optim import executors
from evo_door.optim.executors import ExecutorSpec, open_executor
from evo_door.optim.ga import GASettings, GeneticAlgorithm
from evo_door.optim.problem import Problem

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "experiments" / "data" / "default.h5"

SMALL = f"""
name: small
model: door
params: default
target: {{data: {DATA}, trials: [T03, T05]}}
free: {{F_load: [80.0, 120.0], M: [0.3, 2.5], F_atD: [5.0, 70.0]}}
objective: {{kind: ise, derivative: 1}}
algorithm: {{population: 16, generations: 4, seed: 3}}
"""


def _setup():
    exp = load_experiment(text=SMALL, source="small.yaml")
    return ExperimentRun.new(exp, "unused.h5").setup


def _ga_run(problem):
    return GeneticAlgorithm(GASettings(population=16, generations=4, seed=3)).run(problem)


def _same(a, b):
    """Two GA states are the same run: best, logbook, counts, every generation."""
    assert list(a.best) == list(b.best)
    assert a.best_fitness == b.best_fitness
    assert list(a.logbook) == list(b.logbook)
    assert (a.evaluations, a.blowups) == (b.evaluations, b.blowups)
    assert np.array_equal(np.array(a.history_x), np.array(b.history_x))
    assert np.array_equal(np.array(a.history_f), np.array(b.history_f))


class KillOnce(Problem):
    """A problem whose worker SIGKILLs itself in the middle of a chunk, once: after
    ``armed`` exists (the parent's hook creates it after generation 1) and before
    ``killed`` does."""

    def __init__(self, *args, folder, **kwargs):
        super().__init__(*args, **kwargs)
        self.armed = str(Path(folder) / "armed")
        self.killed = str(Path(folder) / "killed")

    def evaluate(self, X):
        if os.path.exists(self.armed) and not os.path.exists(self.killed):
            try:
                fd = os.open(self.killed, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:  # the other worker was first
                pass
            else:
                os.write(fd, str(os.getpid()).encode())
                os.close(fd)
                os.kill(os.getpid(), signal.SIGKILL)
        return super().evaluate(X)


def _kill_once_problem(setup, folder):
    return KillOnce(
        setup.model,
        setup.free,
        setup.lower,
        setup.upper,
        setup.base,
        setup.fit,
        setup.objective,
        method=setup.method,
        substeps=setup.substeps,
        model_name=setup.model_name,
        folder=folder,
    )


class Arm:
    """GA hook: after generation ``k``, arm the :class:`KillOnce` problem."""

    def __init__(self, problem, k=1):
        self.problem, self.k = problem, k

    def after_generation(self, state):
        if state.generation == self.k:
            Path(self.problem.armed).touch()


# -- names --------------------------------------------------------------------------
@pytest.mark.parametrize(
    "text",
    ["thread", "Dask", "processes:0", "dask:x", "processes:", "tcp://host", "tcp://h:99999", ""],
)
def test_bad_executor_names_are_one_line_user_errors(text):
    with pytest.raises(UserError) as err:
        ExecutorSpec.parse(text)
    assert "\n" not in str(err.value)
    assert "executor" in str(err.value)


def test_executor_names_parse():
    assert ExecutorSpec.parse(" dask ").kind == "dask"
    assert ExecutorSpec.parse("processes:3").workers == 3
    spec = ExecutorSpec.parse("tcp://127.0.0.1:8786")
    assert (spec.kind, spec.address) == ("scheduler", "tcp://127.0.0.1:8786")
    assert "did you mean 'processes'" in _message(lambda: ExecutorSpec.parse("process"))


def _message(fn):
    with pytest.raises(UserError) as err:
        fn()
    return str(err.value)


def test_the_experiment_key_and_the_flag_are_checked(tmp_path, capsys):
    from evo_door.cli import main

    bad = SMALL + "executor: dusk\n"
    msg = _message(lambda: load_experiment(text=bad, source="small.yaml"))
    assert msg.startswith("small.yaml:9: executor: 'dusk' is unknown (did you mean 'dask'?)")
    exp = load_experiment(text=SMALL + "executor: processes:2\n", source="small.yaml")
    assert exp.executor == "processes:2"
    assert "executor" not in exp.resolved()  # provenance, not part of the result
    path = tmp_path / "small.yaml"
    path.write_text(SMALL)
    assert main(["run", str(path), "--executor", "gpu", "--out", str(tmp_path / "r.h5")]) == 2
    assert "evo-door: error: executor 'gpu' is unknown" in capsys.readouterr().err
    assert not (tmp_path / "r.h5").exists()


def test_an_address_where_nothing_listens_is_refused_before_a_file_is_written(tmp_path, capsys):
    from evo_door.cli import main

    path = tmp_path / "small.yaml"
    path.write_text(SMALL)
    out = tmp_path / "r.h5"
    port = _free_port()  # nothing listens there
    assert main(["run", str(path), "--executor", f"tcp://127.0.0.1:{port}", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"executor tcp://127.0.0.1:{port}: no Dask scheduler answers there" in err
    assert err.count("\n") == 1 and not out.exists()


def test_dask_missing_names_the_fix(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed fails
    msg = _message(lambda: open_executor("dask").__enter__())
    assert "pip install 'evo-door[dask]'" in msg


@pytest.mark.slow  # importing distributed takes seconds
def test_an_unreachable_scheduler_is_a_user_error(monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setattr(executors, "CONNECT_TIMEOUT", 1.0)
    port = _free_port()  # nothing listens there
    msg = _message(lambda: open_executor(f"tcp://127.0.0.1:{port}").__enter__())
    assert "no Dask scheduler answers" in msg and "\n" not in msg


def test_a_problem_pickles_with_its_model_by_name():
    import pickle

    problem = _setup().problem()
    problem.model_name = "door"
    back = pickle.loads(pickle.dumps(problem))
    assert back.model is problem.model  # the registered model, not a recompiled copy
    X = (problem.lower + problem.upper)[None, :] / 2
    assert np.array_equal(back.evaluate(X)[0], problem.evaluate(X)[0])


def test_chunks_cover_the_candidates_in_order():
    ex = executors.LocalExecutor(ExecutorSpec.parse("local"))
    ex.slots = 3
    X = np.arange(22.0).reshape(11, 2)
    chunks = ex._split(X)
    assert len(chunks) == 6
    assert np.array_equal(np.concatenate(chunks), X)
    f, b = ex._join([(c[:, 0], c[:, 1] > 10) for c in chunks], 11)
    assert np.array_equal(f, X[:, 0]) and np.array_equal(b, X[:, 1] > 10)


# -- the same numbers everywhere -----------------------------------------------------
@pytest.fixture(scope="module")
def pool():
    """A pool of two worker processes, started once for the tests of this module
    (starting one costs seconds)."""
    with open_executor("processes:2") as ex:
        yield ex


@pytest.mark.slow
def test_a_run_is_identical_on_local_processes_and_dask(tmp_path, pool):
    pytest.importorskip("distributed")
    exp = load_experiment(text=SMALL, source="small.yaml")
    runs = {}
    for name in ("local", "processes:2", "dask:2"):
        run = ExperimentRun.create(exp, tmp_path / f"{name.replace(':', '')}.h5")
        runs[name] = run.run(executor=pool if name == pool.name else name)
    ref = runs["local"].jobs[0].ga
    for name, run in runs.items():
        _same(ref, run.jobs[0].ga)
        assert np.array_equal(run.result["best_x"], runs["local"].result["best_x"])
        from evo_door.experiment import store
        from evo_door.files import ATTRS

        assert store.peek(run.path)[ATTRS]["executor"] == name


@pytest.mark.slow
def test_a_run_interrupted_locally_resumes_on_a_pool_to_the_same_end(tmp_path, pool):
    from evo_door.experiment import Interrupted, store
    from evo_door.files import ATTRS

    exp = load_experiment(text=SMALL, source="small.yaml")
    whole = ExperimentRun.create(exp, tmp_path / "whole.h5").run()

    def stop(run, job):
        if job.ga is not None and job.ga.generation == 2:
            raise Interrupted

    with pytest.raises(Interrupted):
        ExperimentRun.create(exp, tmp_path / "cut.h5").run(on_checkpoint=stop)
    assert store.peek(tmp_path / "cut.h5")[ATTRS]["executor"] == "local"
    resumed = ExperimentRun.open(tmp_path / "cut.h5").run(executor=pool)
    _same(whole.jobs[0].ga, resumed.jobs[0].ga)
    assert store.peek(tmp_path / "cut.h5")[ATTRS]["executor"] == "processes:2"


@pytest.mark.slow
def test_a_pool_worker_killed_mid_generation_changes_nothing(tmp_path, pool):
    setup = _setup()
    reference = _ga_run(setup.problem())
    problem = _kill_once_problem(setup, tmp_path)
    restarts = pool.restarts
    with pool.bind(problem) as remote:
        state = GeneticAlgorithm(GASettings(population=16, generations=4, seed=3)).run(
            remote, hooks=[Arm(problem)]
        )
    assert pool.restarts == restarts + 1  # the pool broke once and was replaced
    assert Path(problem.killed).exists()
    _same(reference, state)


# -- a real scheduler and two workers, as processes ------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def scheduler(tmp_path):
    """``tcp://127.0.0.1:PORT``: ``dask scheduler`` and ``dask worker --nworkers 2``
    started as processes (this test's modules importable by the workers)."""
    distributed = pytest.importorskip("distributed")
    port = _free_port()
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    )
    common = dict(cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    address = f"tcp://127.0.0.1:{port}"
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1"]
            + ["--port", str(port), "--no-dashboard"],
            start_new_session=True,
            **common,
        )
    ]
    try:
        procs.append(
            subprocess.Popen(
                [sys.executable, "-m", "distributed.cli.dask_worker", address]
                + ["--nworkers", "2", "--nthreads", "1", "--host", "127.0.0.1"]
                + ["--no-dashboard", "--death-timeout", "60"],
                start_new_session=True,
                **common,
            )
        )
        with distributed.Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=90)
        yield address
    finally:
        for proc in reversed(procs):  # the worker first, then the scheduler
            try:
                os.killpg(proc.pid, signal.SIGTERM)
                proc.wait(timeout=20)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=20)


@pytest.mark.slow
def test_a_dask_worker_killed_mid_generation_changes_nothing(scheduler, tmp_path):
    setup = _setup()
    reference = _ga_run(setup.problem())
    problem = _kill_once_problem(setup, tmp_path)
    t0 = time.perf_counter()
    with open_executor(scheduler) as ex:
        assert ex.slots == 2 and ex.cluster is None
        with ex.bind(problem) as remote:
            state = GeneticAlgorithm(GASettings(population=16, generations=4, seed=3)).run(
                remote, hooks=[Arm(problem)]
            )
    assert Path(problem.killed).exists()  # a worker died in generation 2
    _same(reference, state)
    assert time.perf_counter() - t0 < 60
    # somebody else's cluster: still there after the run
    import distributed

    with distributed.Client(scheduler, timeout=10) as client:
        assert client.scheduler_info()["address"] == scheduler


@pytest.mark.slow
def test_a_pipeline_shares_one_executor_across_stages(tmp_path, pool):
    from evo_door.data.io import write_trials
    from evo_door.experiment import Results
    from evo_door.experiment.pipeline import PipelineRun, load_pipeline
    from tests.test_optim import make_trial
    from tests.test_pipeline import PIPELINE

    trials = [make_trial(s, 0.75, tid=f"t{s}") for s in (1, 2, 3)] + [make_trial(4, 0.75, tid="v1")]
    write_trials(tmp_path / "trials.h5", trials)
    # the file's executor for every stage; the stages' model is an import path
    (tmp_path / "pipe.yaml").write_text("executor: processes:2\n" + PIPELINE)
    pipe = load_pipeline(tmp_path / "pipe.yaml")
    assert pipe.executor == "processes:2"
    local = PipelineRun.create(pipe, tmp_path / "local.h5").run(executor="local")
    on_pool = PipelineRun.create(pipe, tmp_path / "pool.h5").run(executor=pool)
    for stage in ("first", "second"):
        a, b = Results(local.path, stage), Results(on_pool.path, stage)
        assert a.best() == b.best()
        assert [j["ga"]["fitness"].tolist() for j in a.jobs()] == [
            j["ga"]["fitness"].tolist() for j in b.jobs()
        ]
        assert (a.attrs["executor"], b.attrs["executor"]) == ("local", "processes:2")
    from evo_door.experiment import store

    assert store.pipeline_attrs(on_pool.path)["executor"] == "processes:2"
    # the file's executor when no other is given: started for the run
    again = PipelineRun.create(pipe, tmp_path / "again.h5")
    again.release()
    assert again.executor == "processes:2"


def _wait_for_ctrl_c(folder):
    """A batch's task that waits for Ctrl-C: it says it started, and what stopped it."""
    try:  # "started" inside the try: a Ctrl-C right after it is still caught
        Path(folder, "started").touch()
        time.sleep(60)
    except KeyboardInterrupt:
        Path(folder, "interrupted").touch()
        return "interrupted"
    return "slept"


@pytest.mark.slow  # a spawned worker imports the package
def test_interrupt_passes_ctrl_c_to_the_pools_workers(tmp_path):
    """``interrupt`` reaches the workers the pool started (a batch's Ctrl-C lets their
    runs stop at a checkpoint) and leaves no worker behind."""
    import threading

    with open_executor("processes:1") as ex:
        answers = []
        feeder = threading.Thread(
            target=lambda: answers.extend(ex.imap(_wait_for_ctrl_c, [tmp_path]))
        )
        feeder.start()
        deadline = time.monotonic() + 60
        while not (tmp_path / "started").exists():
            assert time.monotonic() < deadline, "the worker never started the task"
            time.sleep(0.05)
        workers = ex.workers()
        assert len(workers) == 1
        ex.interrupt()
        feeder.join(timeout=30)
    assert (tmp_path / "interrupted").exists()
    assert answers == [(0, "interrupted", None)]
    assert not any(w.is_alive() for w in workers)


@pytest.mark.parametrize(
    ("value", "reason"),
    [
        ("dusk", "'dusk' is unknown (did you mean 'dask'?)"),
        ("processes:0", "'processes:0': the number of workers after ':' must be a whole"),
        ('""', "expected a name, got ''"),
    ],
)
def test_the_experiment_key_says_the_reason_once(value, reason):
    """The key's error is built from the error's fields, not by cutting its text: a
    name that is not a name at all said "executor: executor: ..." when it was."""
    msg = _message(lambda: load_experiment(text=SMALL + f"executor: {value}\n", source="s.yaml"))
    assert msg.startswith(f"s.yaml:9: executor: {reason}")
    assert msg.count("executor") == 1
    with pytest.raises(executors.ExecutorNameError) as err:
        ExecutorSpec.parse(value.strip('"'))
    assert err.value.reason.startswith(reason)


@pytest.mark.slow  # a spawned worker imports the package
def test_interrupt_reaches_workers_spawned_while_ctrl_c_was_ignored(tmp_path):
    """A worker inherits an ignored SIGINT from its parent across exec (a parent that
    ignored Ctrl-C while it started the pool: a test runner, a shell's background job);
    the pool's workers take Ctrl-C back, so that ``interrupt`` still reaches them."""
    import signal

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        test_interrupt_passes_ctrl_c_to_the_pools_workers(tmp_path)
    finally:
        signal.signal(signal.SIGINT, previous)
