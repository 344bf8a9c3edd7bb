"""An FMU that crashes, hangs or fails does not take the run down with it.

The faulty door of examples/fmu (``build_fmu(..., faults=True)``) misbehaves in its
derivatives and its DoStep for damping values the tests pick (``build.FAULTS``): above
9 N.m.s/rad a segmentation fault, above 8 an endless loop, above 7 an error status.
Sandboxed evaluations (:mod:`evo_door.optim.sandbox`) must score those candidates as
blow-ups, give the others exactly the in-process numbers, cut a hang at the time limit,
replace a dead or stopped child, and leave a run that finishes, resumes after a kill and
gives the same numbers on every executor.
"""

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from evo_door.data.io import write_trials
from evo_door.data.trial import Trial
from evo_door.experiment import Results
from evo_door.models import get_model
from evo_door.optim import sandbox
from evo_door.optim.ga import GASettings, GeneticAlgorithm
from evo_door.optim.problem import Objective, Problem
from evo_door.sim.simulate import simulate
from tests.helpers import door_fmu_builder
from tests.test_cli import cli
from tests.test_executors import _same
from tests.test_experiment import assert_same, comparable

pytest.importorskip("fmpy")
pytestmark = [
    pytest.mark.skipif(shutil.which("cmake") is None, reason="cmake is not installed"),
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux signals"),
]

ROOT = Path(__file__).resolve().parents[1]
build = door_fmu_builder()  # examples/fmu/build.py

#: damping values (N.m.s/rad) of a good candidate and of each fault; friction (N.m) beside
GOOD, OTHER = 0.8, 1.6
CRASH = build.FAULTS["crash"] + 0.5
HANG = build.FAULTS["hang"] + 0.5
ERROR = build.FAULTS["error"] + 0.5
FRICTION = 0.5
#: the time limit of the tests' evaluations (s): a hang costs this much
LIMIT = 2.0
#: a GA small enough to be quick whose 16 candidates, with damping in [0, 10], hold
#: one crash, one hang and one error (found by scoring damping > 7 as a blow-up)
GA = GASettings(population=8, generations=2, seed=3)


@pytest.fixture(autouse=True)
def one_child(monkeypatch):
    """One sandbox child per process, as in an executor's worker (the ``local``
    executor's group of children has a test of its own)."""
    monkeypatch.setattr(sandbox, "CHILDREN", 1)


@pytest.fixture(scope="module")
def fmus(shared_fmus, tmp_path_factory):
    """The faulty door, FMI 2.0 and 3.0 (both interfaces in each; built once per suite
    run), and two trials of it at its start values (damping 0.8: no fault), also in
    ``folder/trials.h5``."""
    folder = tmp_path_factory.mktemp("faulty")
    paths = shared_fmus.many({fmi: shared_fmus.door_job(fmi, faults=True) for fmi in (2, 3)})
    model = get_model(str(paths[2]))
    dt = 1 / 256  # s
    t = np.arange(128) * dt
    trials = []
    for k, peak in enumerate((20.0, 30.0)):  # N: half-sine pushes of 0.15 s
        force = np.where(t < 0.15, peak * np.sin(np.pi * t / 0.15), 0.0)
        r = simulate(model, model.params.defaults, force, dt, theta0=0.0, dtheta0=0.0)
        assert r.ok
        trials.append(
            Trial(t, force, r.theta, r.dtheta, r.ddtheta, trial_id=f"T{k}", theta0=0.0, dtheta0=0.0)
        )
    write_trials(folder / "trials.h5", trials)
    return {"folder": folder, "trials": trials, **paths}


def faulty_problem(fmus, spec: str, time_limit=LIMIT, trials=None) -> Problem:
    """Damping and friction free over ranges that hold every fault, fitted to the
    fixture's trials, or to ``trials``."""
    model = get_model(spec)
    return Problem(
        model,
        ["damping", "friction"],
        [0.0, 0.0],
        [10.0, 2.0],
        model.params.defaults,
        fmus["trials"] if trials is None else trials,
        Objective("ise", 1),
        model_name=spec,
        time_limit=time_limit,
    )


def in_process(problem, X):
    """``problem.evaluate(X)`` without the sandbox (never with a crash or a hang)."""
    problem.sandboxed = False
    try:
        return problem.evaluate(X)
    finally:
        problem.sandboxed = True


def running(pid: int) -> bool:
    """The process exists and is not a zombie waiting for whoever adopted it."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


def rows(*damping):
    return np.array([[d, FRICTION] for d in damping])


def test_the_faults_are_a_build_option_that_adds_nothing_without_it(fmus):
    args = (2, "tuned", ("me", "cs"))
    plain = build.c_sources(*args)
    assert "DOOR_FAULT" not in plain["door_variables.h"]
    header = build.c_sources(*args, faults=True)["door_variables.h"]
    for kind, damping in build.FAULTS.items():
        assert f"#define DOOR_FAULT_{kind.upper()}_ABOVE {damping!r}" in header
    assert build.token(*args, faults=True) != build.token(*args)
    assert b"faulty on purpose: a test fixture" in build.model_description(*args, faults=True)
    assert b"faulty" not in build.model_description(*args)
    assert "faulty on purpose" in get_model(str(fmus[3])).title


# -- Problem.evaluate ---------------------------------------------------------------
@pytest.mark.slow
def test_a_group_of_children_splits_a_batch_and_gives_the_single_childs_numbers(fmus, monkeypatch):
    monkeypatch.setattr(sandbox, "CHILDREN", 2)
    problem = faulty_problem(fmus, f"{fmus[2]}:me")
    X = rows(GOOD, OTHER, CRASH, GOOD + 0.1, 0.3, 1.2)
    f, blown = problem.evaluate(X)
    group = sandbox.current()
    assert isinstance(group, sandbox.SandboxGroup) and len(set(group.pids)) == 2
    assert group.lost == {"crashed": 1, "timed out": 0}  # the crash cost its part only
    assert list(blown) == [False, False, True, False, False, False]
    ok = ~blown
    ref_f, _ = in_process(problem, X[ok])
    assert f[ok].tobytes() == ref_f.tobytes()  # bit for bit, whichever child ran it


@pytest.mark.slow
@pytest.mark.parametrize("fmi, interface", [(2, "me"), (3, "cs")])
def test_faulty_candidates_are_blown_and_the_others_exactly_as_in_process(
    fmus, fmi, interface, capfd
):
    problem = faulty_problem(fmus, f"{fmus[fmi]}:{interface}")
    assert problem.sandboxed
    X = rows(GOOD, CRASH, OTHER, HANG, ERROR, GOOD + 0.1)
    f, blown = problem.evaluate(X)
    assert list(blown) == [False, True, False, True, True, False]
    assert np.all(np.isinf(f[blown])) and np.all(np.isfinite(f[~blown]))
    good = ~blown | (X[:, 0] == ERROR)  # an error status is safe to meet in process
    ref_f, ref_blown = in_process(problem, X[good])
    assert f[good].tobytes() == ref_f.tobytes()  # bit for bit
    assert list(ref_blown) == list(blown[good])
    box = sandbox.sandbox_for(problem, problem.time_limit)
    assert box.lost == {"crashed": 1, "timed out": 1}
    assert box.starts == 3  # the first child, and one after the crash and the hang
    err = capfd.readouterr().err
    assert err.count("evo-door: warning:") == 1
    assert "a candidate's evaluation crashed (SIGSEGV) (time limit 2 s)" in err

    if interface == "cs":
        return  # the timing below is the sandbox's, not the interface's
    # a hang costs the time limit, and no more: the child is replaced when needed
    t0 = time.perf_counter()
    f2, blown2 = problem.evaluate(rows(GOOD, HANG))
    took = time.perf_counter() - t0
    assert list(blown2) == [False, True] and f2[0] == f[0]
    assert LIMIT <= took < LIMIT + 1.0, f"{took:.2f} s"
    assert box.lost["timed out"] == 2
    assert capfd.readouterr().err.count("evo-door: warning:") == 0  # said once


@pytest.mark.slow
def test_a_stopped_child_is_a_hang_and_is_replaced(fmus):
    problem = faulty_problem(fmus, str(fmus[2]), time_limit=1.0)
    ref, _ = problem.evaluate(rows(GOOD, OTHER))
    box = sandbox.sandbox_for(problem, problem.time_limit)
    stopped, folder = box.pid, Path(box.folder)
    assert list(folder.iterdir())  # the child extracted the FMU in the sandbox's folder
    os.kill(stopped, signal.SIGSTOP)
    t0 = time.perf_counter()
    f, blown = problem.evaluate(rows(GOOD, OTHER))
    took = time.perf_counter() - t0
    assert list(blown) == [True, False] and f[1] == ref[1]
    assert box.lost == {"crashed": 0, "timed out": 1}
    assert box.pid != stopped and box.starts == 2
    with pytest.raises(ProcessLookupError):  # killed and reaped, not left stopped
        os.kill(stopped, 0)
    assert not folder.exists()  # what it extracted went with it
    assert took < 1.0 + box.start_seconds + 1.0, f"{took:.2f} s"


@pytest.mark.slow
def test_an_evaluation_cut_short_here_leaves_no_answer_for_the_next(fmus):
    """Ctrl-C in the parent while the child works: the child's answers to the rest of
    that batch must not be taken for those of the next batch."""
    problem = faulty_problem(fmus, str(fmus[2]), time_limit=60.0)
    ref, _ = problem.evaluate(rows(GOOD, OTHER))
    box = sandbox.sandbox_for(problem, problem.time_limit)

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGALRM, interrupt)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.3)
        with pytest.raises(KeyboardInterrupt):
            problem.evaluate(rows(HANG, GOOD, OTHER))
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert box.proc is None  # the child was stopped, not left in its loop
    f, blown = problem.evaluate(rows(OTHER, GOOD))
    assert not blown.any() and list(f) == [ref[1], ref[0]]
    assert box.starts == 2 and box.lost == {"crashed": 0, "timed out": 0}


ORPHAN = """\
import sys
import numpy as np
from evo_door.models import get_model
from evo_door.optim import sandbox
from evo_door.optim.problem import Objective, Problem
from evo_door.data.io import read_trials

model = get_model({fmu!r})
problem = Problem(model, ["damping"], [0.0], [10.0], model.params.defaults,
                  read_trials({trials!r}), Objective("ise", 1), model_name={fmu!r},
                  time_limit=600.0)
problem.evaluate(np.array([[{good!r}]]))
print(sandbox.current().pid, flush=True)
problem.evaluate(np.array([[{hang!r}]]))  # never returns: killed meanwhile
"""


@pytest.mark.slow
def test_a_run_killed_while_its_child_hangs_leaves_no_endless_loop_behind(fmus):
    script = ORPHAN.format(
        fmu=str(fmus[2]), trials=str(fmus["folder"] / "trials.h5"), good=GOOD, hang=HANG
    )
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script], cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True
    )
    try:
        child = int(proc.stdout.readline())
        time.sleep(0.3)  # into the loop
        assert running(child)
    finally:
        proc.kill()
        proc.wait()
        proc.stdout.close()
    deadline = time.monotonic() + 5.0
    while running(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not running(child), f"the sandbox child {child} still runs its endless loop"


def test_an_error_status_is_a_blow_up_in_process(fmus):
    for spec in (str(fmus[2]), f"{fmus[3]}:cs"):
        problem = faulty_problem(fmus, spec)
        problem.sandboxed = False
        f, blown = problem.evaluate(rows(GOOD, ERROR, GOOD))
        assert list(blown) == [False, True, False], spec
        assert f[1] == np.inf and f[0] == f[2]  # the instance recovers from the error
        assert np.isfinite(f[0])
    assert f[0] < 1e-3  # co-simulation holds the force over a sample: not quite the trials
    assert in_process(faulty_problem(fmus, str(fmus[2])), rows(GOOD))[0][0] == 0.0


def test_a_python_error_in_the_child_is_raised_here_as_in_process(fmus):
    problem = faulty_problem(fmus, str(fmus[2]))
    problem.fit.force = problem.fit.force[:-1]  # the trials no longer add up: IndexError
    with pytest.raises(Exception) as here:
        in_process(problem, rows(GOOD))
    with pytest.raises(type(here.value)):
        problem.evaluate(rows(GOOD))
    box = sandbox.sandbox_for(problem, problem.time_limit)
    assert box.lost == {"crashed": 0, "timed out": 0}


def test_the_analysis_of_an_answer_runs_the_fmu_contained(fmus):
    """Per-trial errors, validation errors, stored responses and identifiability (what
    a run computes of its answer after the search) run the FMU in the sandbox too: a
    crash there marks the result, never this process (which would die with it)."""
    from evo_door.experiment.answer_checks import identifiability_of

    # one trial: a crash costs a new child per trial run
    problem = faulty_problem(fmus, str(fmus[2]), trials=fmus["trials"][:1])
    good, crash = np.array([GOOD, FRICTION]), np.array([CRASH, FRICTION])
    err, ok = problem.trial_errors(rows(GOOD, CRASH, HANG, GOOD))
    assert ok[0].all() and ok[3].all() and not ok[1:3].any()
    assert np.isinf(err[1:3]).all() and np.array_equal(err[0], err[3])
    problem.sandboxed = False
    assert np.array_equal(problem.trial_errors(rows(GOOD))[0][0], err[0])  # the same numbers
    problem.sandboxed = True
    box = sandbox.current()
    assert box.lost == {"crashed": 1, "timed out": 1}
    lost = problem.responses(crash)
    assert [r.ok for r in lost] == [False] and np.isnan(lost[0].theta).all()
    kept = problem.responses(good)
    assert all(r.ok for r in kept) and np.allclose(kept[0].theta, fmus["trials"][0].theta)
    assert box.lost["crashed"] == 2  # the search's and the responses'
    # the model blows up there: no answer, found on the estimate alone (the 8 points of
    # its finite differences would each cost a new child)
    assert identifiability_of(problem, crash) is None
    assert box.lost["crashed"] == 3
    assert identifiability_of(problem, good) is not None
    assert sandbox.current() is box  # the search's sandbox served the analysis


# -- runs ---------------------------------------------------------------------------
def experiment(fmus) -> str:
    return textwrap.dedent(f"""\
        name: faulty
        model: {fmus[2]}
        target: {{data: {fmus["folder"] / "trials.h5"}, trials: all}}
        free: {{damping: [0.0, 10.0], friction: [0.0, 2.0]}}
        objective: {{kind: ise, derivative: 1}}
        algorithm: {{population: {GA.population}, generations: {GA.generations}, seed: {GA.seed}}}
        """)


@pytest.mark.slow
def test_identical_results_on_every_executor(fmus):
    pytest.importorskip("distributed")
    from evo_door.optim.executors import open_executor

    problem = faulty_problem(fmus, str(fmus[2]), time_limit=1.0)  # pickled to the workers
    local = GeneticAlgorithm(GA).run(problem)
    assert local.blowups >= 3
    for name in ("processes:2", "dask:2"):
        with open_executor(name) as ex, ex.bind(problem) as remote:
            _same(local, GeneticAlgorithm(GA).run(remote))


KILLED_RUN = """\
import os, signal, sys
from evo_door.experiment.runner import ExperimentRun
from evo_door.optim import sandbox

sandbox.DEFAULT_TIME_LIMIT = {limit!r}
write = ExperimentRun.checkpoint

def checkpoint_and_die(run):
    write(run)
    if any(job.ga is not None for job in run.jobs):  # the first checkpoint of the GA
        child = sandbox.current().pid
        open({pid_file!r}, "w").write(str(child))
        os.kill(os.getpid(), signal.SIGKILL)

ExperimentRun.checkpoint = checkpoint_and_die
from evo_door.cli import main
sys.exit(main(["run", {exp!r}, "--out", {out!r}]))
"""


@pytest.mark.slow
def test_a_run_on_the_faulty_fmu_finishes_and_resumes_after_a_kill_to_the_same_end(
    fmus, tmp_path, capsys, monkeypatch
):
    # the experiment file has no time limit yet: the default, shortened
    monkeypatch.setattr(sandbox, "DEFAULT_TIME_LIMIT", LIMIT)
    exp = tmp_path / "exp.yaml"
    exp.write_text(experiment(fmus))
    whole = tmp_path / "whole.h5"
    ran = cli(capsys, "run", exp, "--out", whole)
    assert ran.returncode == 0, ran.stderr
    assert ran.stderr.count("evo-door: warning:") == 1
    summary = Results(whole).summary()
    assert summary["status"] == "complete"
    # three faults (crash, hang, error) and what else blew up in the GA's search
    assert summary["blowups"] >= 3
    assert 0.0 <= summary["best"]["damping"] <= build.FAULTS["error"]
    shown = cli(capsys, "show", whole)
    assert f"{summary['evaluations']} evaluations, {summary['blowups']} blow-ups" in shown.stdout

    # the same run, SIGKILLed right after its first checkpoint, then resumed
    cut, pid_file = tmp_path / "cut.h5", tmp_path / "child.pid"
    script = KILLED_RUN.format(limit=LIMIT, pid_file=str(pid_file), exp=str(exp), out=str(cut))
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    )
    done = subprocess.run(
        [sys.executable, "-c", script],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == -signal.SIGKILL, done.stderr
    assert Results(cut).attrs["status"] == "running"
    # the sandbox's child went with its parent
    child = int(pid_file.read_text())
    deadline = time.monotonic() + 5.0
    while running(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not running(child), f"the killed run's sandbox child {child} is still running"

    resumed = cli(capsys, "resume", cut)
    assert resumed.returncode == 0, resumed.stderr
    assert Results(cut).summary()["status"] == "complete"
    assert_same(comparable(whole), comparable(cut))
