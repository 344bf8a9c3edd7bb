"""Experiment files, runs, results files, resume, and the run / show / runs / resume commands."""

import json
import re

import h5py
import numpy as np
import pytest

from evo_door.data.io import write_trials
from evo_door.errors import UserError
from evo_door.experiment import (
    ExperimentRun,
    Interrupted,
    Results,
    load_experiment,
    resume_run,
    run_experiment,
)
from tests.test_cli import cli
from tests.test_optim import make_trial

OSC = "tests.conftest:OSCILLATOR_MODEL"

EXPERIMENT = f"""\
name: osc
model: {OSC}
target: {{data: trials.h5, trials: all, validate: [v1]}}
fixed: {{theta_eq: 0.0}}
free:
  k: [20, 500]
  c: [0, 10]
  inertia: [0.2, 8]
objective: {{kind: ise, derivative: 1, combine: sum}}
algorithm:
  kind: ga
  population: 16
  generations: 6
  reproduction_ratio: 0.6
  mutation_probability: 0.1
  mutation_amplitude: 0.8
  seed: 1
  polish: slsqp
per_trial: false
"""


@pytest.fixture()
def folder(tmp_path):
    """An experiment file next to a trial file of three fitted and one validation trial."""
    trials = [make_trial(s, 0.75, tid=f"t{s}") for s in (1, 2, 3)] + [make_trial(4, 0.75, tid="v1")]
    write_trials(tmp_path / "trials.h5", trials)
    (tmp_path / "exp.yaml").write_text(EXPERIMENT)
    return tmp_path


def load(folder, text=None, overrides=None):
    if text is not None:
        (folder / "exp.yaml").write_text(text)
    return load_experiment(folder / "exp.yaml", overrides)


# -- validation ------------------------------------------------------------------------
@pytest.mark.parametrize(
    "old, new, message",
    [
        (
            "per_trial: false",
            "per_trail: false",
            "exp.yaml:19: per_trail: unknown key (did you mean 'per_trial' or 'perception'?)",
        ),
        (
            "  mutation_probability: 0.1",
            "  mutaton_probability: 0.1",
            "exp.yaml:15: algorithm.mutaton_probability: unknown key (did you mean 'mutation_probability'",
        ),
        (
            "  c: [0, 10]",
            "  cc: [0, 10]",
            "exp.yaml:7: free.cc: model 'oscillator' has no parameter 'cc' (did you mean 'c'?)",
        ),
        (
            "  k: [20, 500]",
            "  k: [500, 20]",
            "exp.yaml:6: free.k: inverted bounds [500, 20]: lower > upper (did you swap them?)",
        ),
        (
            "  k: [20, 500]",
            "  k: [20, 5e8]",
            "exp.yaml:6: free.k: [20, 5e+08] N/rad leaves the declared range [0, 1e+07] N/rad",
        ),
        (
            "{theta_eq: 0.0}",
            "{theta_eq: 99.0}",
            "exp.yaml:4: fixed.theta_eq: parameter 'theta_eq' = 99 rad is outside its declared range",
        ),
        ("{theta_eq: 0.0}", "{k: 3.0}", "exp.yaml:6: free.k: 'k' is also fixed"),
        (
            "data: trials.h5",
            "data: nowhere.h5",
            "exp.yaml:3: target.data: file not found: nowhere.h5",
        ),
        (
            f"model: {OSC}\n",
            f"model: {OSC}\nparams: nowhere.yaml\n",
            "exp.yaml:3: params: file not found: nowhere.yaml",
        ),
        (
            "validate: [v1]",
            "validate: [v2]",
            "exp.yaml:3: target.validate: ",
        ),
        (
            "kind: ise",
            "kind: ise2",
            "exp.yaml:9: objective.kind: 'ise2' is not one of max_square, ise",
        ),
        (
            "derivative: 1",
            "derivative: 3",
            "exp.yaml:9: objective.derivative: 3 is not one of 0, 1, 2",
        ),
        (
            "reproduction_ratio: 0.6",
            "reproduction_ratio: 60",
            "exp.yaml:14: algorithm.reproduction_ratio: is a fraction in [0, 1]: AMESim's 60 % is 0.6",
        ),
        (
            "population: 16",
            "population: 1",
            "exp.yaml:12: algorithm.population: must be >= 2, got 1",
        ),
        (
            "polish: slsqp",
            "polish: nlpq",
            "exp.yaml:18: algorithm.polish: 'nlpq' is not one of none, slsqp",
        ),
        ("name: osc", "name: osc\nname: again", "exp.yaml:2: duplicate key 'name' (first at"),
        ("free:", "free: [", "exp.yaml:7: not valid YAML"),
        (
            f"model: {OSC}",
            "model: hapic",
            "exp.yaml:2: model: unknown model 'hapic' (did you mean 'haptic' or 'haptic_tanh'?)",
        ),
        (
            "validate: [v1]}",
            "validate: [v1], preprocess: {rate_bias: end}}",
            "exp.yaml:3: target.preprocess.rate_bias: 'end' is not one of none, start, all",
        ),
        (
            "validate: [v1]}",
            "validate: [v1], preprocess: {lowpas: 20}}",
            "exp.yaml:3: target.preprocess.lowpas: unknown key (did you mean 'lowpass'?)",
        ),
        (
            "validate: [v1]}",
            "validate: [v1], preprocess: {lowpass: 0}}",
            "exp.yaml:3: target.preprocess.lowpass: must be > 0, got 0",
        ),
        (
            "validate: [v1]}",
            "validate: [v1], preprocess: {lowpass: 900}}",
            "exp.yaml:3: target.preprocess: trial 't1': low-pass cutoff 900 Hz must lie in",
        ),
    ],
)
def test_invalid_experiment_is_one_line_naming_file_line_key(folder, old, new, message):
    assert old in EXPERIMENT
    text = EXPERIMENT.replace(old, new)
    with pytest.raises(UserError) as info:
        exp = load(folder, text)
        ExperimentRun.create(exp, folder / "r.h5")
    msg = str(info.value)
    assert "\n" not in msg
    assert message in msg, msg


def test_tiny_population_takes_a_smaller_default_tournament(folder):
    exp = load(folder, overrides=["algorithm.population=2"])
    assert exp.algorithm.ga.population == 2 and exp.algorithm.ga.tournament == 2
    with pytest.raises(
        UserError,
        match=r"^--set algorithm\.tournament=5: algorithm\.tournament: "
        r"must be <= 2, got 5",
    ):
        load(folder, overrides=["algorithm.population=2", "algorithm.tournament=5"])


def test_validate_id_unknown_names_the_file_and_suggests(folder):
    with pytest.raises(
        UserError,
        match=r"target\.validate: .*trials\.h5 has no trial 'v2' "
        r"\(did you mean 'v1'",
    ):
        ExperimentRun.create(load(folder, EXPERIMENT.replace("[v1]", "[v2]")), folder / "r.h5")


def test_missing_channel_is_reported_with_the_objective_line(folder):
    trials = [make_trial(1, 0.5, tid="a")]
    trials[0].ddtheta = None
    write_trials(folder / "trials.h5", trials)
    text = EXPERIMENT.replace("derivative: 1", "derivative: 2").replace(
        "validate: [v1]", "validate: []"
    )
    with pytest.raises(
        UserError, match=r"exp\.yaml:9: objective\.derivative: trial 'a' .* no 'ddtheta'"
    ):
        ExperimentRun.create(load(folder, text), folder / "r.h5")


def test_set_overrides_are_checked_and_located(folder):
    exp = load(folder, overrides=["algorithm.seed=3", "free.k=[30, 400]"])
    assert exp.algorithm.ga.seed == 3 and exp.free["k"] == (30.0, 400.0)
    with pytest.raises(
        UserError,
        match=r"^--set algorithm\.sed=3: algorithm\.sed: unknown key "
        r"\(did you mean 'seed'\?\)",
    ):
        load(folder, overrides=["algorithm.sed=3"])


# -- runs, results, resume ---------------------------------------------------------------
def comparable(path):
    """Every dataset and attribute of a results file except clocks and timings."""
    skip_keys = {"times", "eval_times", "timings"}
    # the checksums cover the clocks too
    skip_attrs = {"created", "updated", "seconds", "jobs_s", "total_s", "_digest"}
    out = {}
    with h5py.File(path, "r") as f:

        def visit(name, obj):
            if any(part in skip_keys for part in name.split("/")):
                return
            for k, v in obj.attrs.items():
                if k not in skip_attrs:
                    out[f"{name}@{k}"] = v
            if isinstance(obj, h5py.Dataset):
                out[name] = obj[()]

        visit("", f)
        f.visititems(visit)
    return out


def assert_same(a, b):
    assert a.keys() == b.keys()
    for k in a:
        va, vb = a[k], b[k]
        if isinstance(va, np.ndarray):
            assert va.dtype == vb.dtype and va.shape == vb.shape, k
            assert va.tobytes() == vb.tobytes(), k  # bit for bit
        else:
            assert va == vb, k


def test_run_writes_everything_and_same_seed_gives_same_file(folder):
    exp = load(folder)
    a = run_experiment(exp, folder / "a.h5")
    b = run_experiment(load(folder), folder / "b.h5")
    assert_same(comparable(a.path), comparable(b.path))
    res = Results(a.path)
    s = res.summary()
    assert s["status"] == "complete" and set(s["best"]) == {"k", "c", "inertia"}
    assert set(s["fit_errors"]) == {"t1", "t2", "t3"} and set(s["validation_errors"]) == {"v1"}
    assert s["validation_errors"]["v1"] < 1e-6  # same true parameters: validation fits too
    for key in ("numpy", "scipy", "numba", "deap", "h5py", "evo_door", "python"):
        assert key in s["versions"]
    with h5py.File(a.path) as f:
        assert f["experiment/text"][()].decode() == EXPERIMENT
        assert json.loads(f["experiment/resolved"][()])["algorithm"]["population"] == 16
        assert f["jobs/0/ga/population"].shape == (7, 16, 3)
        assert f["jobs/0/ga/fitness"].shape == (7, 16)
        assert f["jobs/0/ga/rng_states"].shape[0] == 7
        assert list(f["jobs/0/ga/logbook/gen"][()]) == list(range(7))
        assert f["jobs/0/ga/hof_x"].shape[1] == 3
        assert f["response/0/model"].shape == f["response/0/target"].shape
        assert f.attrs["seed"] == 1
        t = f["timings"].attrs
        local_evals = f["jobs/0/local"].attrs["evaluations"]
        assert t["evaluations"] == f["jobs/0/ga/logbook/evals"][()].sum() + local_evals
        assert 0 < t["ga_evaluation_s"] < t["total_s"] and 0 < t["local_s"] < t["total_s"]
        assert t["evaluations_per_s"] == pytest.approx(t["ga_evaluations"] / t["ga_evaluation_s"])
        assert t["local_evaluations"] == local_evals
        assert f["jobs/0/ga/times"].shape == (7,) and np.all(f["jobs/0/ga/times"][()] > 0)
        assert f["versions"].attrs["numba"] and f["versions"].attrs["cpus"] >= 1
    np.testing.assert_allclose(
        [s["best"][n] for n in ("k", "c", "inertia")], [100, 2, 1.5], rtol=1e-3
    )


def test_kill_after_three_generations_then_resume_is_bitwise_identical(folder):
    whole = run_experiment(load(folder), folder / "whole.h5")

    def kill_after_three(run, job):
        if job.ga is not None and job.ga.generation == 3:
            raise Interrupted()

    with pytest.raises(Interrupted):
        run_experiment(load(folder), folder / "cut.h5", on_checkpoint=kill_after_three)
    cut = Results(folder / "cut.h5")  # readable right after the kill
    assert cut.attrs["status"] == "running" and cut.attrs["generations_done"] == [3]
    assert not list(folder.glob(".*tmp*"))
    assert len(cut.best()) == 3 and cut.progress() == "3/6 gen"
    resumed = resume_run(folder / "cut.h5")
    assert resumed.status == "complete"
    assert_same(comparable(whole.path), comparable(folder / "cut.h5"))


def test_kill_after_the_last_job_before_the_final_write_then_resume(folder):
    """Every job is done but /best and /response are not written yet: resume finishes them."""
    whole = run_experiment(load(folder), folder / "whole.h5")

    def kill_when_done(run, job):
        if job.done:
            raise Interrupted()

    with pytest.raises(Interrupted):
        run_experiment(load(folder), folder / "cut.h5", on_checkpoint=kill_when_done)
    cut = Results(folder / "cut.h5")
    assert not cut.complete and "best" not in cut.tree
    # a temporary left by a writer killed mid-write is cleaned up on resume
    stale = folder / ".cut.h5.tmp-999999"
    stale.write_bytes(b"half an HDF5 file")
    resumed = resume_run(folder / "cut.h5")
    assert resumed.status == "complete" and not stale.exists()
    assert Results(folder / "cut.h5").complete
    assert_same(comparable(whole.path), comparable(folder / "cut.h5"))


def _counted_run(folder, name, every, monkeypatch, stop_at=None):
    """A run of the folder's experiment with checkpoints ``every`` seconds apart; the
    number of writes. ``stop_at``: Ctrl-C in the first evaluation of that generation."""
    from evo_door.experiment import runner
    from evo_door.optim.problem import Problem

    writes = []
    write = runner.write_checkpoint
    monkeypatch.setattr(runner, "write_checkpoint", lambda *a: writes.append(1) or write(*a))
    run = ExperimentRun.create(load(folder), folder / name)
    run.checkpoint_every = every
    if stop_at is not None:
        calls = []
        evaluate = Problem.evaluate

        def interrupted(self, X):
            calls.append(1)
            if len(calls) == stop_at + 1:  # generation 0 is one population's evaluation
                raise KeyboardInterrupt
            return evaluate(self, X)

        monkeypatch.setattr(Problem, "evaluate", interrupted)
    try:
        run.run()
    finally:
        monkeypatch.undo()
    return len(writes)


def test_checkpoints_spaced_in_time_give_the_same_file(folder, monkeypatch):
    """A GA's generations are written at most every ``checkpoint_every`` seconds: none
    of the seven here (0 to 6), only the file's start, the end of its job and the final
    write; the same file."""
    every = _counted_run(folder, "every.h5", 0.0, monkeypatch)
    spaced = _counted_run(folder, "spaced.h5", 1e9, monkeypatch)
    assert every == 1 + 7 + 2 and spaced == 3
    assert_same(comparable(folder / "every.h5"), comparable(folder / "spaced.h5"))


def test_ctrl_c_between_checkpoints_writes_the_last_finished_generation(folder, monkeypatch):
    whole = run_experiment(load(folder), folder / "whole.h5")
    with pytest.raises(KeyboardInterrupt):
        _counted_run(folder, "cut.h5", 1e9, monkeypatch, stop_at=4)
    cut = Results(folder / "cut.h5")
    assert cut.attrs["status"] == "running" and cut.attrs["generations_done"] == [3]
    assert resume_run(folder / "cut.h5").status == "complete"
    assert_same(comparable(whole.path), comparable(folder / "cut.h5"))


def test_per_trial_fits_give_a_min_max_table(folder):
    text = EXPERIMENT.replace("per_trial: false", "per_trial: true").replace(
        "generations: 6", "generations: 3"
    )

    def kill_in_second_fit(run, job):
        if job.name == "t2" and job.ga is not None and job.ga.generation == 1 and not job.done:
            raise Interrupted()

    whole = run_experiment(load(folder, text), folder / "whole.h5")
    with pytest.raises(Interrupted):
        run_experiment(load(folder, text), folder / "cut.h5", on_checkpoint=kill_in_second_fit)
    resume_run(folder / "cut.h5")
    assert_same(comparable(whole.path), comparable(folder / "cut.h5"))
    s = Results(whole.path).summary()
    assert set(s["per_trial_fits"]) == {"t1", "t2", "t3"}
    for name, row in s["table"].items():
        values = [fit[name] for fit in s["per_trial_fits"].values()]
        assert row["min"] == min(values) and row["max"] == max(values)
    assert s["table"]["k"]["min"] == pytest.approx(100, rel=1e-2)
    assert s["table"]["k"]["max"] == pytest.approx(100, rel=1e-2)


def test_a_finished_job_is_written_once_then_copied_unchanged(folder, monkeypatch):
    """A results file is rewritten whole at every checkpoint; a finished job never
    changes, so after the checkpoint that first holds it finished, its group is copied
    from the file (as the trials are): its tree is built once, and the file ends with
    every job as the run holds it (the same as a run that builds every job anew)."""
    from evo_door.experiment import store

    text = EXPERIMENT.replace("per_trial: false", "per_trial: true").replace(
        "generations: 6", "generations: 3"
    )
    built = []
    job_tree = store.job_tree
    monkeypatch.setattr(
        store,
        "job_tree",
        lambda job, free=(): built.append((job.name, job.done)) or job_tree(job, free),
    )
    run = run_experiment(load(folder, text), folder / "kept.h5")
    finished = [name for name, done in built if done]
    assert sorted(finished) == ["t1", "t2", "t3"]  # each finished job's tree built once
    assert sum(not done for _, done in built) > 0  # jobs under way: built at each write
    monkeypatch.setattr(store, "run_tree", _without_keep(store.run_tree))
    again = run_experiment(load(folder, text), folder / "built.h5")
    assert_same(comparable(run.path), comparable(again.path))
    with h5py.File(folder / "kept.h5", "r") as f:
        assert all(f["jobs"][k].attrs["done"] for k in f["jobs"])


def _without_keep(run_tree):
    """``store.run_tree`` with nothing copied from the previous file."""
    return lambda run, trials_on_disk, jobs_on_disk=frozenset(): run_tree(run, False)


def test_nlpql_alone_from_a_start_point(folder):
    text = EXPERIMENT.replace("kind: ga", "kind: nlpql").replace("polish: slsqp", "polish: none")
    text = text.replace("per_trial: false", "per_trial: false\n").rstrip() + "\n"
    exp = load(folder, text, overrides=["algorithm.start={k: 120, c: 1.0, inertia: 1.8}"])
    run = run_experiment(exp, folder / "n.h5")
    best = Results(run.path).best()
    np.testing.assert_allclose([best["k"], best["c"], best["inertia"]], [100, 2, 1.5], rtol=1e-3)
    assert run.jobs[0].ga is None and run.jobs[0].local.x0.tolist() == [120.0, 1.0, 1.8]


def test_model_target_from_a_force_file(tmp_path):
    t = np.arange(1024) / 1024.0
    np.savetxt(
        tmp_path / "push.csv",
        np.column_stack([t, 10 * np.sin(6 * t)]),
        delimiter=",",
        header="t,force",
        comments="",
    )
    (tmp_path / "m.yaml").write_text(f"""\
model: {OSC}
target: {{model: {OSC}, params: {{k: 150, c: 3, inertia: 1.2}}, inputs: push.csv, theta0: 0.05}}
free: {{k: [10, 400], c: [0, 10]}}
fixed: {{inertia: 1.2}}
objective: {{kind: max_square, derivative: 0}}
algorithm: {{population: 12, generations: 2, polish: slsqp}}
""")
    run = run_experiment(load_experiment(tmp_path / "m.yaml"), tmp_path / "m.h5")
    best = Results(run.path).best()
    assert best["k"] == pytest.approx(150, rel=1e-3) and best["c"] == pytest.approx(3, rel=1e-2)
    assert run.setup.fit[0].truth["params"]["k"] == 150


# -- the commands, run in-process (tests.test_cli.cli) -----------------------------------
@pytest.mark.slow
def test_cli_run_show_runs_resume_and_errors(folder, capsys):
    out = folder / "results" / "a.h5"
    res = cli(
        capsys,
        "run",
        folder / "exp.yaml",
        "--out",
        out,
        "--set",
        "algorithm.seed=3",
        "--set",
        "algorithm.generations=3",
        "--progress",
    )
    assert res.returncode == 0, res.stderr
    # the bar: generation count, best and mean fitness, evaluation rate
    lines = res.stderr.replace("\r", "\n").splitlines()
    assert any(
        re.search(r"osc: 100%.* 3/3 .*best [0-9.e+-]+ +mean [0-9.e+-]+ +[0-9,]+ evals/s", line)
        for line in lines
    ), res.stderr
    assert re.search(
        r"osc: SLSQP from fitness [0-9.e+-]+ \.\.\. [0-9.e+-]+ \(\d+ evaluations", res.stderr
    ), res.stderr
    assert "best" in res.stdout
    # not a terminal and no --progress: no bar; --quiet: nothing at all
    plain = cli(
        capsys,
        "run",
        str(folder / "exp.yaml"),
        "--out",
        str(folder / "b.h5"),
        "--set",
        "algorithm.generations=1",
    )
    assert plain.returncode == 0 and plain.stderr == "" and "best" in plain.stdout
    quiet = cli(
        capsys,
        "run",
        str(folder / "exp.yaml"),
        "--out",
        str(folder / "c.h5"),
        "--set",
        "algorithm.generations=1",
        "--quiet",
        "--progress",
    )
    assert quiet.returncode == 0 and quiet.stderr == "" and quiet.stdout == ""
    shown = cli(capsys, "show", str(out), "--json", "--plot", str(folder / "fit.png"))
    assert shown.returncode == 0, shown.stderr
    doc = json.loads(shown.stdout)
    assert doc["seed"] == 3 and doc["algorithm"]["generations"] == 3
    assert set(doc["best"]) == {"k", "c", "inertia"}
    assert all(isinstance(v, float) for v in doc["best"].values())
    assert (folder / "fit.png").stat().st_size > 10000
    # an interrupted run listed, then resumed from the command line
    with pytest.raises(Interrupted):
        run_experiment(
            load(folder),
            folder / "results" / "cut.h5",
            on_checkpoint=lambda run, job: (
                (_ for _ in ()).throw(Interrupted())
                if job.ga is not None and job.ga.generation == 2
                else None
            ),
        )
    listed = cli(capsys, "runs", str(folder / "results"))
    assert listed.returncode == 0, listed.stderr
    rows = {line.split()[0]: line for line in listed.stdout.split("\n\n")[0].splitlines()[2:]}
    # killed in-process, no process holds the file: interrupted, not "running"
    assert (
        "complete" in rows["a.h5"]
        and "interrupted" in rows["cut.h5"]
        and "2/6 gen" in rows["cut.h5"]
    )
    from evo_door.cli import main

    assert main(["run", str(folder / "exp.yaml"), "--out", str(folder / "results" / "cut.h5")]) == 2
    resumed = cli(capsys, "resume", str(folder / "results" / "cut.h5"), "--quiet")
    assert resumed.returncode == 0, resumed.stderr
    assert Results(folder / "results" / "cut.h5").complete
    assert main(["resume", str(folder / "results" / "cut.h5")]) == 0  # complete: nothing to do


def test_cli_bad_yaml_exits_2_with_one_line(folder, capsys, monkeypatch):
    monkeypatch.chdir(folder)  # where a run without --out would write results/
    (folder / "bad.yaml").write_text(EXPERIMENT.replace("kind: ise", "kind: maxsquare"))
    res = cli(capsys, "run", str(folder / "bad.yaml"))
    assert res.returncode == 2, res.stderr
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr
    assert (
        "bad.yaml:9: objective.kind: 'maxsquare' is not one of max_square, ise, perceptual "
        "(did you mean 'max_square'?)"
    ) in res.stderr
    assert not (folder / "results").exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["run", "{folder}/missing.yaml"], "missing.yaml: experiment file not found"),
        (["show", "{folder}/trials.h5"], "not an evo-door results file"),
        (["resume", "{folder}/nothing.h5"], "nothing.h5: results file not found"),
        (["runs", "{folder}/nowhere"], "nowhere: no such folder"),
        (
            ["run", "{folder}/exp.yaml", "--set", "algorithm.polsh=slsqp"],
            "--set algorithm.polsh=slsqp: algorithm.polsh: unknown key (did you mean 'polish'?)",
        ),
        (["run", "{folder}/exp.yaml", "--out", "{folder}/r.txt"], "results files are HDF5"),
    ],
)
def test_commands_reject_bad_input_with_one_line(folder, capsys, args, message):
    from evo_door.cli import main

    assert main([a.format(folder=folder) for a in args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err


def test_bad_rig_specification_in_inputs_names_file_line_key(tmp_path):
    (tmp_path / "r.yaml").write_text(f"""\
model: {OSC}
target:
  model: {OSC}
  inputs: {{model: {OSC}, trials: 1, user: 2}}
free: {{k: [10, 400]}}
""")
    # refused as the file is read, before any trial is made, as config's other keys are
    with pytest.raises(UserError) as info:
        load_experiment(tmp_path / "r.yaml")
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(
        f"{tmp_path / 'r.yaml'}:4: target.inputs.user: unknown key (did you mean 'users'"
    ), msg
