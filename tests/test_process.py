"""The supplier's process (``process:``): kinds declared once, documented defaults, the
table read from experiment and pipeline files with one-line errors, and the draws the
yield is estimated with."""

import math
from pathlib import Path

import numpy as np
import pytest

from evo_door.errors import UserError
from evo_door.experiment.config import load_experiment
from evo_door.experiment.pipeline import load_pipeline
from evo_door.models import get_model
from evo_door.models.haptic_params import PARAMS as HAPTIC
from evo_door.optim.process import NOT_BUILT, Process, format_tolerance, process_for
from evo_door.optim.specification import spec_names
from evo_door.params import Param
from evo_door.params.process import DEFAULTS, DEFAULTS_FILE, KINDS

ROOT = Path(__file__).resolve().parents[1]
CASE_STUDY = ROOT / "experiments" / "case_study.yaml"

#: the defaults the docs promise (docs/experiments.md), per kind: relative fraction or
#: an absolute half-width in rad
PROMISED = {
    "spring_rate": 0.10,
    "spring_preload": 0.10,
    "mass": 0.03,
    "inertia": 0.05,
    "friction_torque": 0.25,
    "friction_coefficient": 0.20,
    "friction_force": 0.30,
    "latch_force": 0.15,
    "latch_angle": 2e-4,
    "section_scale": 0.0,
}

#: a door fitted to a chosen feel (the haptic model's seed set), nothing to read
FEEL = """\
model: door
target: {model: haptic, params: seed_trial}
free: {K: [200.0, 800.0]}
objective: {kind: perceptual}
"""


@pytest.fixture(scope="module")
def door():
    return get_model("door")


def write(folder: Path, text: str, name="exp.yaml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


def one_line_error(path: Path) -> str:
    with pytest.raises(UserError) as info:
        load_experiment(path)
    message = str(info.value)
    assert "\n" not in message
    return message


# -- declared once, as data --------------------------------------------------------------
def test_every_built_door_specification_has_a_kind_and_sensations_have_none(door):
    spec = [p for p in door.params if p.group == "specification"]
    assert spec and all(p.process in KINDS for p in spec), [p.name for p in spec if not p.process]
    assert not [p.name for p in door.params if p.group != "specification" and p.process]
    assert not [p.name for p in HAPTIC if p.process]
    kinds = {p.name: p.process for p in spec}
    assert kinds["K"] == kinds["latch_open_stiffness"] == "spring_rate"
    assert (
        kinds["latch_open_hold"] == "latch_angle" and kinds["friction_scale_3"] == "section_scale"
    )


def test_defaults_file_is_the_documented_table_and_ships_with_the_package():
    assert set(DEFAULTS) == set(PROMISED)
    for kind, value in PROMISED.items():
        d = DEFAULTS[kind]
        assert d.value == pytest.approx(value), kind
        assert d.relative == (kind != "latch_angle"), kind
        assert d.distribution == "normal" and d.source, kind
    assert DEFAULTS["latch_angle"].unit == "rad"
    assert "project's choice" in DEFAULTS["mass"].source
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert f'"params/{DEFAULTS_FILE.name}"' in pyproject  # package data of a wheel


def test_param_refuses_an_unknown_kind_and_a_unit_its_kind_cannot_take():
    with pytest.raises(ValueError, match="'sprng_rate' not in .*did you mean 'spring_rate'"):
        Param("k", "N/m", 1.0, 0.0, 2.0, "specification", "a spring", process="sprng_rate")
    with pytest.raises(ValueError, match="in deg: process 'latch_angle' gives .* in rad"):
        Param("a", "deg", 1.0, 0.0, 2.0, "specification", "an angle", process="latch_angle")


# -- the defaults on the case study --------------------------------------------------------
def test_case_study_specification_takes_each_kinds_default(door):
    stage = load_pipeline(CASE_STUDY).stage("specification").experiment
    names = spec_names(door, stage.free)
    proc = process_for(door, names, stage.resolved()["process"])
    nominal = {p.name: p.default for p in door.params}
    t = dict(zip(proc.names, proc.half_widths(nominal)))
    assert t["K"] == pytest.approx(0.10 * 400.64)
    assert t["F_load"] == pytest.approx(0.10 * 101.45)
    assert t["M"] == pytest.approx(0.03 * 1.232)
    assert t["I_z"] == pytest.approx(0.05 * 0.1275)
    assert t["T_atA"] == pytest.approx(0.25 * 0.00904)
    assert t["mu"] == pytest.approx(0.20 * 0.8065)
    assert t["F_atD"] == pytest.approx(0.30 * 18.8)
    assert t["unlock_force"] == pytest.approx(0.15 * 40.0)
    assert t["latch_open_hold"] == pytest.approx(2e-4)  # absolute, whatever the value
    assert t["friction_scale_1"] == 0.0
    assert set(proc.distribution) == {"normal"}
    assert all(s.startswith("default: ") for s in proc.source)
    # the stage fitted to the door's feel with the haptic model: nothing built
    haptic = load_pipeline(CASE_STUDY).stage("haptic").experiment
    assert haptic.resolved()["process"] == {"entries": {}}
    assert "process" not in load_pipeline(CASE_STUDY).stage("physical").experiment.resolved()


def test_a_row_without_a_kind_has_no_tolerance_and_cannot_be_given_one(door):
    proc = process_for(door, ["L", "K"], None)
    assert proc.source[0] == NOT_BUILT and proc.half_widths([0.6, 400.0])[0] == 0.0
    with pytest.raises(UserError, match="process: L: not a built quantity"):
        process_for(door, ["K"], {"entries": {"L": {"tolerance": "1 %"}}})
    with pytest.raises(UserError, match="no parameter 'F_lod' \\(did you mean 'F_load'"):
        process_for(door, ["K"], {"F_lod": "1 %"})


# -- half-widths and draws --------------------------------------------------------------
def test_relative_and_absolute_entries_give_their_half_widths(door):
    table = {"K": {"tolerance": "5 %"}, "F_load": {"tolerance": 2.0}, "mu": "20 %"}
    proc = process_for(door, ["K", "F_load", "mu"], table)
    assert list(proc.relative) == [True, False, True]
    np.testing.assert_allclose(proc.half_widths([-400.0, 100.0, 0.5]), [20.0, 2.0, 0.1])
    out = proc.as_dict([400.0, 100.0, 0.5])
    assert out["K"] == {
        "half_width": pytest.approx(20.0),
        "tolerance": "5 %",
        "distribution": "normal",
        "source": "given",
    }
    assert out["F_load"]["tolerance"] == 2.0


def test_sample_has_the_stated_spread_and_the_same_seed_gives_the_same_draws():
    proc = Process(
        ["a", "b", "c"],
        np.array([True, False, False]),
        np.array([0.1, 0.3, 0.0]),
        ["normal", "uniform", "normal"],
        ["x", "y", "z"],
    )
    nominal = np.array([50.0, 1.0, 7.0])
    d = proc.sample(nominal, 20000, np.random.default_rng(5))
    assert d.shape == (20000, 3)
    assert np.std(d[:, 0], ddof=1) == pytest.approx(5.0 / 3.0, rel=0.02)
    assert np.all(np.abs(d[:, 1]) <= 0.3) and np.abs(d[:, 1]).max() > 0.29
    assert np.std(d[:, 1], ddof=1) == pytest.approx(0.3 / math.sqrt(3.0), rel=0.02)
    assert np.all(d[:, 2] == 0.0)
    again = proc.sample(nominal, 20000, np.random.default_rng(5))
    np.testing.assert_array_equal(d, again)
    # the documented order: one draw of the generator per column, in names order
    rng = np.random.default_rng(5)
    np.testing.assert_allclose(d[:, 0], rng.standard_normal(20000) * 5.0 / 3.0, rtol=1e-12)
    np.testing.assert_allclose(d[:, 1], rng.uniform(-1.0, 1.0, 20000) * 0.3, rtol=1e-12)
    assert not np.array_equal(d, proc.sample(nominal, 20000, np.random.default_rng(6)))


def test_format_tolerance_for_people():
    assert format_tolerance("10 %") == "+-10 %"
    assert format_tolerance(0.0002, "rad") == "+-0.0002 rad"
    assert format_tolerance("+-2.5%") == "+-2.5 %"


# -- process: in experiment files ----------------------------------------------------------
def test_experiment_table_forms_kinds_and_sources(tmp_path):
    path = write(
        tmp_path,
        FEEL
        + """\
process:
  K: "5 %"
  F_load: 2.0
  mu: {tolerance: "20 %", distribution: uniform, source: the supplier's letter}
  kinds: {friction_force: "20 %", spring_rate: "8 %"}
""",
    )
    entries = load_experiment(path).resolved()["process"]["entries"]
    assert entries["K"] == {
        "tolerance": "5 %",
        "distribution": "normal",
        "source": f"set in {path}:6",
    }  # a name wins over its kind
    assert entries["F_load"]["tolerance"] == 2.0
    assert entries["mu"]["distribution"] == "uniform"
    assert entries["mu"]["source"] == f"the supplier's letter (set in {path}:8)"
    assert entries["F_atC"]["tolerance"] == entries["F_atD"]["tolerance"] == "20 %"
    assert entries["latch_open_stiffness"]["tolerance"] == "8 %"
    assert entries["M"]["source"].startswith("default: mass")


@pytest.mark.parametrize(
    "process, line, message",
    [
        (
            "{F_lod: '5 %'}",
            5,
            "process.F_lod: model 'door' has no parameter 'F_lod' (did you mean 'F_load'",
        ),
        ("{L: '5 %'}", 5, "process.L: 'L' (geometry) is not built by a supplier"),
        ("{K: -1.0}", 5, "process.K: a tolerance cannot be negative, got -1"),
        ("{K: .nan}", 5, "process.K: a tolerance must be a finite number, got nan"),
        ("{K: [1, 2]}", 5, "process.K: expected a percentage ('10 %') or a half-width"),
        ("{K: '5 percent'}", 5, "process.K: expected a percentage ('10 %') or a half-width"),
        ("{K: '100 %'}", 5, "process.K: a relative tolerance must be below 100 %"),
        ("{K: '-5 %'}", 5, "process.K: a tolerance cannot be negative"),
        (
            "\n  K: {tolerance: '5 %', distribution: gauss}",
            6,
            "process.K.distribution: 'gauss' is not one of normal, uniform",
        ),
        ("\n  K: {distribution: normal}", 6, "process.K.tolerance: required key missing"),
        ("\n  kinds: {spring: '5 %'}", 6, "process.kinds.spring: unknown kind (did you mean"),
        ("[K, '5 %']", 5, "process: expected a mapping name: tolerance"),
        ("missing.yaml", 5, "process: file not found: missing.yaml"),
    ],
)
def test_bad_process_is_one_line_naming_the_file_and_line(tmp_path, process, line, message):
    path = write(tmp_path, FEEL + f"process: {process}\n")
    error = one_line_error(path)
    assert error.startswith(f"{path}:{line}: "), error
    assert message in error, error


def test_process_file_next_to_the_experiment(tmp_path, monkeypatch):
    folder = tmp_path / "exp"
    folder.mkdir()
    write(folder, "# what the supplier wrote\nprocess:\n  K: '4 %'\n  mu: 0.1\n", "tol.yaml")
    path = write(folder, FEEL + "process: tol.yaml\n")
    monkeypatch.chdir(tmp_path)  # found next to the experiment, not in the current folder
    entries = load_experiment(path).resolved()["process"]["entries"]
    assert entries["K"]["tolerance"] == "4 %" and entries["mu"]["tolerance"] == 0.1
    assert entries["K"]["source"] == f"set in {folder / 'tol.yaml'}:3"
    # a bad entry in it names its own file and line
    write(folder, "K: '4 %'\nmu: -0.1\n", "tol.yaml")
    assert one_line_error(path).startswith(f"{folder / 'tol.yaml'}:2: process.mu: ")
    # a file that holds no mapping
    write(folder, "- K\n- 4 %\n", "tol.yaml")
    error = one_line_error(path)
    assert error.startswith(f"{folder / 'tol.yaml'}:1: process: a process file is a mapping")


def test_process_on_an_experiment_not_fitted_to_a_feel_is_refused(tmp_path):
    (tmp_path / "trials.h5").write_bytes(b"")  # only its existence is checked here
    path = write(
        tmp_path,
        """\
model: door
target: {data: trials.h5}
free: {K: [200.0, 800.0]}
objective: {kind: ise}
process: {K: '5 %'}
""",
    )
    error = one_line_error(path)
    assert error.startswith(f"{path}:5: process: ") and "perceptual" in error, error


# -- process: in pipelines --------------------------------------------------------------
PIPELINE = """\
name: tol
process: {K: '5 %', M: '2 %', kinds: {friction_force: '10 %'}}
stages:
  feel:
    model: haptic
    params: seed_trial
    target: {model: door, params: default}
    free: {inertia: [0.1, 3.0]}
    objective: {kind: perceptual}
  spec:
    model: door
    target: {model: haptic, params: seed_trial}
    free: {K: [200.0, 800.0]}
    objective: {kind: perceptual}
    process: {K: '7 %', kinds: {mass: '4 %'}}
  plain:
    model: door
    target: {model: haptic, params: seed_trial}
    free: {K: [200.0, 800.0]}
    objective: {kind: perceptual}
"""


def test_pipeline_table_merges_with_a_stages_own(tmp_path):
    pipe = load_pipeline(write(tmp_path, PIPELINE, "pipe.yaml"))
    spec = pipe.stage("spec").experiment.resolved()["process"]["entries"]
    plain = pipe.stage("plain").experiment.resolved()["process"]["entries"]
    assert spec["K"]["tolerance"] == "7 %" and plain["K"]["tolerance"] == "5 %"
    assert spec["M"]["tolerance"] == "4 %" and plain["M"]["tolerance"] == "2 %"  # stage wins
    assert spec["F_atD"]["tolerance"] == plain["F_atD"]["tolerance"] == "10 %"
    assert plain["K"]["source"] == f"set in {tmp_path / 'pipe.yaml'}:2"
    assert spec["I_z"]["source"].startswith("default: ")
    assert pipe.stage("feel").experiment.resolved()["process"] == {"entries": {}}


def test_pipeline_table_errors_name_the_pipeline_line_and_need_a_stage_to_take_it(tmp_path):
    bad = PIPELINE.replace("M: '2 %'", "M: '2 %', T_at0: 0.01")
    path = write(tmp_path, bad, "pipe.yaml")
    with pytest.raises(UserError, match=f"^{path}:2: process.T_at0: .*did you mean 'T_atO'"):
        load_pipeline(path)
    none = PIPELINE.split("  spec:")[0]
    path = write(tmp_path, none, "none.yaml")
    with pytest.raises(UserError, match=f"^{path}:2: process: .* no stage is one"):
        load_pipeline(path)


def test_docs_table_of_defaults_is_the_data_and_the_declaration(door):
    """docs/experiments.md's table says each kind's default and parameters as they are."""
    text = (ROOT / "docs" / "experiments.md").read_text()
    head = text.index("| kind | parameters (`door`) | default |")
    rows = text[head:].split("\n\n")[0].splitlines()[2:]
    documented = {}
    for row in rows:
        kind, names, default = (c.strip(" `") for c in row.split("|")[1:4])
        documented[kind] = (names, default)
    assert set(documented) == set(KINDS)
    for kind, (names, default) in documented.items():
        d = DEFAULTS[kind]
        assert default == format_tolerance(d.tolerance, d.unit), kind
        declared = [p.name for p in door.params if p.process == kind]
        if kind == "section_scale":
            assert names == "friction_scale_1` .. `_8" and len(declared) == 8
        else:
            assert names.split("`, `") == declared, kind
