"""The Python API (evo_door.api, docs/api.md): one validation with the files, the same
results as a file's run, typed results, one-line errors for bad input.

The walk-through itself is run by tests/test_api_doc.py.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

import evo_door
from evo_door.api.build import to_tree
from evo_door.errors import UserError
from evo_door.experiment import load_experiment

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "experiments" / "data" / "default.h5"
MAIN_JOB = ROOT / "experiments" / "default.yaml"
QUICK = ["algorithm.population=20", "algorithm.generations=3", "algorithm.polish=none"]

#: What may differ between the same run made from Python and from a YAML file of the
#: same text, each for its reason. Everything else, every dataset and every attribute,
#: must be equal.
NOT_COMPARED = {
    "/@created": "a timestamp",
    "/@updated": "a timestamp",
    "experiment@source": "a path: the YAML file's, or <python>",
    "jobs/0@seconds": "timing",
    "jobs/0/ga/times": "timing",
    "jobs/0/ga/eval_times": "timing",
    "best/identifiability@seconds": "timing",
    "jobs/0/identifiability@seconds": "timing",
    "timings@*": "timing (every attribute of the group)",
    "*@_digest": "each group's checksum, over the timestamps and timings above too",
}
#: And from the bundled main job with --set assignments, also how it was given.
NOT_COMPARED_MAIN_JOB = {
    **NOT_COMPARED,
    "experiment/text": "the file's own text (its comments), or the YAML of the arguments",
    "experiment@overrides": "the file's --set assignments",
}


def _quick_python_main_job(description: str) -> evo_door.Experiment:
    """The main job with QUICK's settings, written in Python."""
    return evo_door.Experiment(
        name="default",
        description=description,
        model="door",
        params="default",
        target=evo_door.trial_file(
            DATA, kinds=["impulse"], validate=["T09"], preprocess={"rate_bias": "start"}
        ),
        free={"F_load": [80.0, 120.0], "M": [0.3, 2.5], "F_atD": [5.0, 70.0]},
        objective={"kind": "ise", "derivative": 1, "combine": "sum"},
        algorithm={
            "kind": "ga",
            "population": 20,
            "generations": 3,
            "reproduction_ratio": 0.6,
            "mutation_probability": 0.1,
            "mutation_amplitude": 0.8,
            "seed": 1,
            "polish": "none",
        },
    )


def _contents(path: Path) -> dict[str, object]:
    """Every attribute (``group@name``) and dataset (``group/name``) of a file."""
    out: dict[str, object] = {}

    def visit(name: str, obj) -> None:
        for key, value in obj.attrs.items():
            out[f"{name}@{key}"] = value
        if isinstance(obj, h5py.Dataset):
            out[name] = obj[()]

    with h5py.File(path, "r") as f:
        visit("/", f)
        f.visititems(visit)
    return out


def _excluded(key: str, patterns) -> bool:
    for pattern in patterns:
        if pattern.startswith("*@") and key.endswith(pattern[1:]):
            return True
        if pattern.endswith("@*") and key.startswith(pattern[:-1]):
            return True
        if key == pattern:
            return True
    return False


def _equal(a, b) -> bool:
    if isinstance(a, (bytes, str)) or isinstance(b, (bytes, str)):
        return a == b
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind in "fc" and b.dtype.kind in "fc":
        return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=True))
    return a.shape == b.shape and bool(np.array_equal(a, b))


@pytest.mark.parametrize("form", ["its own YAML", "the main job's file with --set"])
def test_a_run_from_python_stores_what_the_same_run_from_yaml_stores(form, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    main_job = evo_door.Experiment.from_yaml(MAIN_JOB, QUICK)
    from_python = _quick_python_main_job(main_job.config.description)
    if form == "its own YAML":  # the YAML the Python experiment says it is, as a file
        (tmp_path / "quick.yaml").write_text(from_python.yaml)
        from_file, patterns = evo_door.Experiment.from_yaml("quick.yaml"), NOT_COMPARED
    else:
        from_file, patterns = main_job, NOT_COMPARED_MAIN_JOB
    assert from_python.config.resolved() == from_file.config.resolved()
    a = from_python.run("python.h5")
    b = from_file.run("yaml.h5")
    left, right = _contents(a.path), _contents(b.path)
    assert sorted(left) == sorted(right)
    compared = [k for k in left if not _excluded(k, patterns)]
    differ = [k for k in compared if not _equal(left[k], right[k])]
    assert not differ, f"differ: {differ}"
    # the comparison is not vacuous: the answer, the populations, the configuration
    assert {"best/x", "jobs/0/ga/population", "experiment/resolved"} <= set(compared)
    # and no exclusion is stale: each one matches something the files hold
    assert all(any(_excluded(k, [p]) for k in left) for p in patterns)
    assert a.estimates == b.estimates and a.identifiability == b.identifiability
    assert a.config == b.config


def test_a_run_reads_back_typed_with_units_checks_and_its_table(tmp_path, monkeypatch):
    """What Experiment.run returns is the file read back: the same as evo_door.load,
    and the same numbers as the results' reader (Results) every command uses."""
    from evo_door.experiment.results import Results

    monkeypatch.chdir(tmp_path)
    exp = evo_door.Experiment.from_yaml(MAIN_JOB, QUICK)
    run = exp.run(tmp_path / "r.h5")
    res = Results(run.path)
    assert run.path == tmp_path / "r.h5" and run.status == "complete" and run.stage is None
    assert list(run.estimates) == ["F_load", "M", "F_atD"]
    m = run.estimates["M"]
    assert (m.name, m.unit, m.lower, m.upper) == ("M", "kg", 0.3, 2.5)
    assert m.value == res.best()["M"] and m.truth == pytest.approx(1.232)
    assert str(m) == f"M = {m.value:.4g} kg"
    assert run.fitness == res.fitness() and run.fitness_unit == "(rad/s)^2 s"
    ident = res.identifiability().as_dict()
    for name, row in run.identifiability.items():
        assert row.verdict == ident[name]["verdict"] and row.se == ident[name]["se"]
        low, high = row.interval
        assert (high - low) / 2 == pytest.approx(ident[name]["ci_half"], rel=1e-12)
        assert low < run.estimates[name].value < high
    assert run.checks.not_identifiable == tuple(
        n for n, v in ident.items() if v["verdict"] == "not identifiable"
    )
    assert run.checks.integration_recorded and run.checks.feel_passes is None
    assert run.checks.ok == (not run.checks.not_identifiable and not run.checks.at_bound)
    assert math.isfinite(run.checks.mismatch)
    assert run.spec is not None
    rows = {r.name: r for r in run.spec.rows}
    assert rows["M"].value == m.value and rows["M"].status == "estimated"
    assert list(run.validation_errors) == ["T09"]
    again = evo_door.load(run.path)
    assert again.estimates == run.estimates and again.checks == run.checks
    with pytest.raises(UserError, match=r"complete run; give another out, or overwrite=True to"):
        exp.run(run.path)


def test_python_and_yaml_share_one_validation_and_its_messages(tmp_path):
    """Each mistake made in a file and in Python gives one message, the file's naming
    its line and Python's the argument."""
    base = {"model": "door", "target": {"data": str(DATA)}, "free": {"M": [0.3, 2.5]}}
    mistakes = [
        {"free": {"Mx": [0.3, 2.5]}},
        {"free": {"M": [2.5, 0.3]}},
        {"free": {"M": [0.3, "x"]}},
        {"free": "M"},
        {"fixed": {"M": 1.0}},
        {"algorithm": {"populaton": 20}},
        {"algorithm": {"population": "many"}},
        {"objective": {"kind": "ies"}},
        {"per_trial": "yes"},
        {"target": {"data": str(DATA), "kinds": "impulse", "curve": "x.csv"}},
        {"target": 42},
        {"model": "dor"},
        {"simulation": {"substeps": 0}},
        {"modle": "door"},
    ]
    for mistake in mistakes:
        given = {**base, **mistake}
        with pytest.raises(UserError) as from_python:
            evo_door.Experiment(**given)
        with pytest.raises(UserError) as from_file:
            load_experiment(text=yaml.safe_dump(given), source="e.yaml", base_dir=tmp_path)
        py, yml = str(from_python.value), str(from_file.value)
        assert re.match(r"Experiment\((\w+=)?\.\.\.\): ", py), py
        assert re.match(r"e\.yaml:\d+: ", yml), yml
        where = r"Experiment\((\w+=)?\.\.\.\)|e\.yaml:\d+"
        assert re.sub(where, "WHERE", py) == re.sub(where, "WHERE", yml)
        assert "\n" not in py


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (
            {"modle": "door"},
            "Experiment(modle=...): modle: unknown key (did you mean 'model' or 'pooled'?)",
        ),
        ({"model": None}, "Experiment(...): model: required key missing"),
        ({"free": None}, "Experiment(...): free: required key missing"),
        ({"target": None}, "Experiment(...): target: required key missing"),
        (
            {"free": {"Mx": (0.5, 3.0)}},
            "Experiment(free=...): free.Mx: model 'door' has no parameter 'Mx' (did you mean 'M'?)",
        ),
        ({"free": {"M": {0.5, 3.0}}}, "Experiment(free=...): free.M: expected [lower, upper]"),
        ({"free": {("M",): [0.5, 3.0]}}, "Experiment(free=...): mapping keys must be plain names"),
        ({"model": 3}, "Experiment(model=...): model: expected a text value, got 3"),
        ({"algorithm": [20, 3]}, "Experiment(algorithm=...): algorithm: expected a mapping"),
        ({"per_trial": 1}, "Experiment(per_trial=...): per_trial: expected true or false, got 1"),
        (
            {"target": evo_door.trial_file("none.h5")},
            "Experiment(target=...): target.data: file not found: none.h5",
        ),
        ({"name": object()}, "Experiment(name=...): name: expected a text value, got <object"),
    ],
)
def test_bad_input_from_python_is_one_line(arguments, message, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    base = {"model": "door", "target": evo_door.trial_file(DATA), "free": {"M": [0.5, 3.0]}}
    with pytest.raises(UserError) as caught:
        evo_door.Experiment(**{**base, **arguments})
    text = str(caught.value)
    assert text.startswith(message), text
    assert "\n" not in text


def test_numpy_tuples_and_paths_are_taken_as_the_values_they_hold():
    base = evo_door.Experiment(
        model="door", target={"data": str(DATA)}, free={"M": [0.5, 3.0]}, fixed={"K": 400.0}
    )
    same = evo_door.Experiment(
        model="door",
        target=evo_door.trial_file(DATA),
        free={"M": np.array([0.5, 3.0])},
        fixed={"K": np.float32(400.0)},
        algorithm={"seed": np.int64(1)},
    )
    tupled = evo_door.Experiment(
        model="door", target=evo_door.trial_file(DATA), free={"M": (0.5, 3)}, fixed={"K": 400}
    )
    assert same.config.resolved() == base.config.resolved() == tupled.config.resolved()
    tree = to_tree({"a": (1, np.float64(2.5)), "b": Path("x.h5")}, "here")
    assert tree == {"a": [1, 2.5], "b": "x.h5"} and tree.where("a") == "here"
    assert type(tree["a"][1]) is float


def test_a_stage_with_from_runs_only_in_a_pipeline(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exp = evo_door.Experiment(
        model="door", params={"from": "physical"}, target=evo_door.trial_file(DATA),
        free={"M": [0.5, 3.0]},
    )  # fmt: skip
    with pytest.raises(UserError, match=r"^Experiment\(params=\.\.\.\): \{from: physical\}"):
        exp.run("x.h5")
    assert not (tmp_path / "x.h5").exists()


def test_a_pipeline_from_python_is_checked_like_its_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    stage = {"model": "door", "target": {"data": str(DATA)}, "free": {"M": [0.5, 3.0]}}
    with pytest.raises(UserError) as caught:
        evo_door.Pipeline(stages={"a": stage, "b": {**stage, "params": {"from": "c"}}})
    assert str(caught.value) == (
        "Pipeline(stages['b'].params=...): from: 'c' is not a stage of this pipeline; stages: a, b"
    )
    with pytest.raises(UserError, match=r"^Pipeline\(stage=\.\.\.\): stage: unknown key"):
        evo_door.Pipeline(stage={"a": stage})
    with pytest.raises(UserError, match=r"^Pipeline\(\.\.\.\): stages: required key missing"):
        evo_door.Pipeline(name="x")
    with pytest.raises(UserError, match=r"^Pipeline\(stages\['a'\].frees=\.\.\.\): frees: unknown"):
        evo_door.Pipeline(stages={"a": {**stage, "frees": {}}})
    with pytest.raises(
        UserError, match=r"^Pipeline\(stages\['a'\].free=\.\.\.\): free.M: expected"
    ):
        evo_door.Pipeline(stages={"a": {**stage, "free": {"M": {0.5, 3.0}}}})  # not JSON
    with pytest.raises(UserError, match=r"^Pipeline\(stages=\.\.\.\): stages: expected a mapping"):
        evo_door.Pipeline(stages=["a"])
    pipe = evo_door.Pipeline(
        stages={"a": evo_door.Experiment(**stage), "b": MAIN_JOB, "c": {**stage}}
    )
    assert pipe.stages == ["a", "b", "c"]
    assert pipe.config.stage("b").experiment.free == load_experiment(MAIN_JOB).free
    assert yaml.safe_load(pipe.yaml)["stages"]["b"] == str(MAIN_JOB)


def test_load_refuses_what_is_not_a_results_file_in_one_line(tmp_path):
    bad = tmp_path / "x.h5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(UserError) as caught:
        evo_door.load(bad)
    assert str(caught.value).startswith(str(bad)) and "\n" not in str(caught.value)
    with pytest.raises(UserError, match="file not found|No such file|does not exist"):
        evo_door.load(tmp_path / "none.h5")


def test_the_files_and_outputs_of_python_calls_are_checked_in_python_s_words(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    case_study = ROOT / "experiments" / "case_study.yaml"
    cases = [
        (lambda: evo_door.load(123), "load(path=...): expected a results file's path"),
        (
            lambda: evo_door.Experiment.from_yaml(case_study),
            f"{case_study}: a pipeline (it has stages): evo_door.Pipeline.from_yaml reads it",
        ),
        (
            lambda: evo_door.Pipeline.from_yaml(MAIN_JOB),
            f"{MAIN_JOB}: an experiment: evo_door.Experiment.from_yaml reads it",
        ),
        (lambda: evo_door.Experiment.from_yaml(3), "Experiment.from_yaml(path=...): expected"),
        (lambda: evo_door.Experiment.from_yaml(MAIN_JOB, 3), "from_yaml(overrides=...): expected"),
        (
            lambda: evo_door.Experiment.from_yaml(MAIN_JOB).run(out=3),
            "Experiment.run(out=...): expected the results file's path (.h5), got 3",
        ),
        (lambda: evo_door.Experiment.from_yaml(MAIN_JOB).run(out="r.txt"), "r.txt: results files"),
    ]
    for call, message in cases:
        with pytest.raises(UserError) as caught:
            call()
        assert str(caught.value).startswith(message), str(caught.value)
    # one override as a text is one assignment
    assert evo_door.Experiment.from_yaml(MAIN_JOB, "algorithm.seed=3").config.algorithm.ga.seed == 3
    # an existing results file is replaced only with overwrite=True (said so, not --force)
    exp = evo_door.Experiment.from_yaml(MAIN_JOB, QUICK)
    (tmp_path / "done.h5").write_bytes(b"mine")
    with pytest.raises(UserError, match="is not an evo-door results file; .* give another out$"):
        exp.run("done.h5", overwrite=True)
    assert (tmp_path / "done.h5").read_bytes() == b"mine"


def test_an_interrupted_run_reads_with_its_best_so_far(tmp_path):
    """A file an older version left interrupted: the estimates are the GA's best so far,
    with their units; nothing that needs a finished answer is made up."""
    import shutil

    from evo_door.experiment.results import Results

    path = tmp_path / "old.h5"
    shutil.copy(ROOT / "tests" / "data" / "run-0.1-interrupted.h5", path)
    run = evo_door.load(path)
    assert run.status == "interrupted" and run.spec is None and run.identifiability == {}
    assert run.values() == Results(path).best()
    assert [e.unit for e in run.estimates.values()] == ["N", "kg", "N"]
    assert not run.checks.integration_recorded and run.fit_errors == {}


def test_checks_that_need_the_data_name_the_argument_too(tmp_path, monkeypatch):
    """Trial ids are checked when the data is read (at run), named like the rest."""
    monkeypatch.chdir(tmp_path)
    exp = evo_door.Experiment(
        model="door",
        target=evo_door.trial_file(DATA, kinds=["impulse"], validate=["T99"]),
        free={"M": [0.5, 3.0]},
    )
    with pytest.raises(UserError) as caught:
        exp.run("v.h5")
    assert str(caught.value).startswith(
        f"Experiment(target=...): target.validate: {DATA} has no trial 'T99' (did you mean 'T09'?)"
    )
    assert not (tmp_path / "v.h5").exists()
