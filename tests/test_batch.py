"""``evo-door batch``: sweeps, per-user experiments, a failure that stops nothing,
interrupt and continue; what a worker runs."""

import pickle
import subprocess
import sys
from pathlib import Path

import pytest

from evo_door.cli import main
from evo_door.errors import UserError
from evo_door.experiment import Results, batch, load_experiment, store
from evo_door.experiment.batch import expand_sweeps, plan, split_values
from evo_door.experiment.runner import ExperimentRun
from evo_door.files import ATTRS

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "experiments" / "data" / "default.h5"
USERS = ROOT / "experiments" / "users"


def _tiny(folder: Path, name: str, user: str) -> Path:
    path = folder / f"{name}.yaml"
    path.write_text(
        f"""
model: door
params: default
target: {{data: {DATA}, kinds: [impulse], users: [{user}]}}
free: {{F_load: [80.0, 120.0], M: [0.3, 2.5]}}
objective: {{kind: ise, derivative: 1}}
algorithm: {{population: 8, generations: 2, seed: 1}}
"""
    )
    return path


# -- sweeps ---------------------------------------------------------------------------
def test_comma_lists_make_the_product_of_their_values():
    got = expand_sweeps(["algorithm.seed=1,2", "objective.kind=ise,max_square", "per_trial=false"])
    assert [s for s, _ in got] == [
        "seed1-kindise",
        "seed1-kindmax_square",
        "seed2-kindise",
        "seed2-kindmax_square",
    ]
    assert got[3][1] == ["algorithm.seed=2", "objective.kind=max_square", "per_trial=false"]
    assert expand_sweeps([]) == [("", [])]
    assert expand_sweeps(["free.M=[0.3, 2.5]"]) == [("", ["free.M=[0.3, 2.5]"])]
    assert split_values("[1, 2], {a: 1, b: 2}") == ["[1, 2]", "{a: 1, b: 2}"]


@pytest.mark.parametrize("bad", ["seed", "=3", "algorithm.seed=1,,2"])
def test_a_bad_set_is_a_user_error(bad):
    with pytest.raises(UserError, match="--set"):
        expand_sweeps([bad])


def test_a_plan_names_every_task_and_its_file(tmp_path):
    a = tmp_path / "a" / "exp.yaml"
    b = tmp_path / "b" / "exp.yaml"
    tasks = plan([a, b], ["algorithm.seed=1,2"], tmp_path / "out")
    assert [t["name"] for t in tasks] == ["exp-seed1", "exp-seed2", "exp-seed1-2", "exp-seed2-2"]
    assert len({t["out"] for t in tasks}) == 4
    assert all(Path(t["out"]).is_absolute() and Path(t["path"]).is_absolute() for t in tasks)


# -- per-user experiments ------------------------------------------------------------------
def test_the_bundled_user_experiments_fit_each_users_trials_only():
    fitted = {}
    for user in ("U1", "U2", "U3"):
        exp = load_experiment(USERS / f"{user}.yaml")
        setup = ExperimentRun.new(exp, "unused.h5").setup
        assert {tr.user_id for tr in setup.fit} == {user}
        assert {tr.kind for tr in setup.fit} == {"impulse"}
        fitted[user] = [tr.trial_id for tr in setup.fit]
    assert fitted == {"U1": ["T01", "T07"], "U2": ["T05"], "U3": ["T03", "T09"]}


def test_an_unknown_user_is_a_user_error_naming_the_users(tmp_path):
    exp = load_experiment(_tiny(tmp_path, "x", "U9"))
    with pytest.raises(
        UserError, match=r"x.yaml:4: target.users: no trial of user 'U9'; users: U1, U2, U3"
    ):
        ExperimentRun.new(exp, "unused.h5")
    bad = tmp_path / "bad.yaml"
    bad.write_text(_tiny(tmp_path, "y", "U1").read_text().replace("users: [U1]", "users: {a: 1}"))
    with pytest.raises(UserError, match="target.users: expected a list of user ids"):
        load_experiment(bad)


# -- the command -------------------------------------------------------------------------
def _status(path):
    return store.peek(path)[ATTRS]["status"]


@pytest.mark.slow
def test_batch_runs_each_experiment_to_its_file_and_reports_the_failure(tmp_path, capsys):
    exps = [
        _tiny(tmp_path, "one", "U1"),
        _tiny(tmp_path, "bad", "U9"),
        _tiny(tmp_path, "two", "U3"),
    ]
    out = tmp_path / "out"
    code = main(["batch", *map(str, exps), "--out", str(out), "--set", "algorithm.seed=1,2"])
    printed = capsys.readouterr().out
    assert code == 1
    for name in ("one-seed1", "one-seed2", "two-seed1", "two-seed2"):
        res = Results(out / f"{name}.h5")
        assert res.complete and "best" in res.tree
        assert res.fitness() > 0
    assert not list(out.glob("bad*.h5"))
    assert "bad-seed1   failed" in printed
    assert "bad-seed1: " in printed and "no trial of user 'U9'; users: U1, U2, U3" in printed
    assert "(rad/s)^2 s" in printed and "F_load = " in printed and " N, M = " in printed
    assert "6 experiment(s), 2 failed" in printed
    # the seeds differ, and each file says which it had
    assert Results(out / "one-seed1.h5").config["algorithm"]["seed"] == 1
    assert Results(out / "one-seed2.h5").config["algorithm"]["seed"] == 2

    # the same batch again on the same folder reads the finished ones back
    before = (out / "one-seed1.h5").stat().st_mtime_ns
    assert main(["batch", *map(str, exps), "--out", str(out), "--set", "algorithm.seed=1,2"]) == 1
    assert (out / "one-seed1.h5").stat().st_mtime_ns == before
    assert capsys.readouterr().out.count(" complete ") == 4


def test_an_interrupted_batch_says_what_did_not_finish_and_continues(tmp_path, capsys, monkeypatch):
    exps = [_tiny(tmp_path, "one", "U1"), _tiny(tmp_path, "two", "U3")]
    out = tmp_path / "out"
    real = batch.run_task

    def stop_at_two(task):
        if task["name"] == "two":
            raise KeyboardInterrupt
        return real(task)

    monkeypatch.setattr(batch, "run_task", stop_at_two)
    assert main(["batch", *map(str, exps), "--out", str(out)]) == 130
    captured = capsys.readouterr()
    assert "interrupted; not finished: two" in captured.err
    assert _status(out / "one.h5") == "complete"
    monkeypatch.setattr(batch, "run_task", real)
    assert main(["batch", *map(str, exps), "--out", str(out)]) == 0
    assert _status(out / "two.h5") == "complete"


def test_what_a_worker_runs_imports_no_command_line(tmp_path, monkeypatch):
    """The function the batch ships to its workers, unpickled in a fresh interpreter as
    a worker does, imports the experiment layer and below, never the command line
    (which imports every command)."""
    from evo_door.optim import executors

    shipped, real_open = [], executors.open_executor

    def spy(spec):
        executor = real_open(spec)
        real_imap = executor.imap

        def imap(fn, items):
            shipped.append(pickle.dumps(fn))
            return real_imap(fn, items)

        executor.imap = imap
        return executor

    monkeypatch.setattr(executors, "open_executor", spy)
    exp = _tiny(tmp_path, "one", "U1")
    assert main(["batch", str(exp), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    probe = (
        "import pickle, sys\n"
        f"fn = pickle.loads({shipped[0]!r})\n"
        "print(fn.__module__, sorted(m for m in sys.modules if m.split('.')[:2] in "
        "(['evo_door', 'commands'], ['evo_door', 'cli'])))"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split(" ", 1) == ["evo_door.experiment.batch", "[]\n"]


@pytest.mark.slow
@pytest.mark.parametrize("executor", ["processes:2", "dask:2"])
def test_batch_on_worker_processes(tmp_path, capsys, executor):
    if executor.startswith("dask"):
        pytest.importorskip("distributed")
    exps = [
        _tiny(tmp_path, "one", "U1"),
        _tiny(tmp_path, "bad", "U9"),
        _tiny(tmp_path, "two", "U2"),
    ]
    out = tmp_path / "out"
    assert main(["batch", *map(str, exps), "--out", str(out), "--executor", executor]) == 1
    printed = capsys.readouterr().out
    assert f"on executor {executor}" in printed
    assert "bad: " in printed and "target.users: no trial of user 'U9'" in printed
    for name in ("one", "two"):
        assert Results(out / f"{name}.h5").complete
    assert not (out / "bad.h5").exists()
