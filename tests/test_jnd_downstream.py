"""Measured JNDs used downstream: JND files and tables of Weber fractions in an
experiment's ``perception:`` and in ``report --jnd-file``, their sources in ``show`` and
the report, the errors, and the perceptual objective and tolerances that follow them.

The JND files are made here as ``evo-door jnd`` makes them on the simulated device: a
:class:`JndSession` answered by a :class:`SimParticipant` of a chosen Weber fraction,
written with :func:`write_jnd_file`. The feel pair is a door whose opening force
differs from the chosen feel's by about 2.2 N at about 9 N (a quarter): noticeable with
a force JND of 5-7 %, within one of 45-55 %.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from evo_door.errors import UserError
from evo_door.experiment import Results, load_experiment, run_experiment
from evo_door.perception.jnd_file import read_jnd_file, write_jnd_file
from evo_door.perception.procedures import JndSession, SimParticipant, run_simulated
from evo_door.reporting.report import pipeline_settings
from tests.test_cli import cli

#: the simulated participants' Weber fractions of force: one below the feel pair's
#: difference, one above it
SMALL, LARGE = 0.05, 0.45

#: a run fitted to the chosen feel that cannot reach it (the vertical friction at C only)
RUN = """\
name: {name}
model: door
params: default
target: {{curve: feel.csv}}
free: {{F_atC: [0, 2]}}
algorithm: {{population: 8, generations: 2, seed: 1, polish: none}}
"""


def _jnd_file(path, weber, param="friction_closing", unit="N", reference=10.0, **kw):
    """A JND session answered by a simulated participant, written as ``evo-door jnd``
    writes it; ``status`` and ``trials`` as given."""
    trials = kw.get("trials", 80)
    session = JndSession(param, unit, reference, "staircase", trials, seed=3, upper=100.0)
    participant = SimParticipant(weber, seed=4)
    fit = run_simulated(session, participant)
    write_jnd_file(
        path,
        session,
        fit,
        status=kw.get("status", "complete"),
        participant=participant.describe(),
        device="sim",
        model="haptic",
        reference_params={param: reference},
        settings={"trials": trials},
        seed=3,
        created="2026-11-26T12:00:00",
        wall_s=0.0,
        versions={},
    )
    return path


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """The chosen feel, JND files (force small and large, viscosity, a stopped session,
    an angle), and a run fitted to the feel with the default JNDs."""
    from evo_door.commands.curve import curve_csv
    from evo_door.models import get_model
    from evo_door.sim.simulate import force_angle_curve

    w = tmp_path_factory.mktemp("jnd")
    door = get_model("door")
    feel = door.load_params("default", {"K": 350.0, "F_atD": 12.0})
    (w / "feel.csv").write_text(curve_csv(force_angle_curve(door, feel)))
    (w / "jnd").mkdir()
    _jnd_file(w / "jnd" / "small.h5", SMALL)
    _jnd_file(w / "jnd" / "large.h5", LARGE)
    _jnd_file(w / "jnd" / "visc.h5", 0.3, "viscous_damping", "N s/rad", 2.0)
    _jnd_file(w / "jnd" / "stopped.h5", SMALL, status="stopped", trials=20)
    _jnd_file(w / "jnd" / "angle.h5", 0.1, "latch_loose_angle", "rad", 0.01)
    (w / "plain.yaml").write_text(RUN.format(name="plain"))
    run_experiment(load_experiment(w / "plain.yaml"), out=w / "plain.h5")
    return w


def _weber(lab, name) -> float:
    return read_jnd_file(lab / "jnd" / f"{name}.h5").fit.weber


@pytest.mark.numerics
def test_the_feel_pair_lies_between_the_two_measured_jnds(lab):
    # independent of the check's code: the worst relative difference of the opening
    # stroke, from the run's stored curves with plain numpy, against both estimates
    small, large = _weber(lab, "small"), _weber(lab, "large")
    assert 0.6 * SMALL < small < 1.5 * SMALL and 0.6 * LARGE < large < 1.5 * LARGE
    fc = Results(lab / "plain.h5").record.perceptual_check
    theta = fc.chosen.theta
    mech = np.interp(theta, fc.mechanism.theta, fc.mechanism.opening)
    chosen = fc.chosen.opening
    big = np.abs(chosen) > 2.0  # where the 1 N floor below does not decide
    rel = np.abs(mech - chosen)[big] / np.abs(chosen)[big]
    assert np.mean(rel > small) > 0.5  # most of the stroke beyond the small JND
    assert rel.max() < large  # none of it beyond the large one


@pytest.mark.numerics
@pytest.mark.slow
def test_report_jnd_file_changes_the_verdict(lab, tmp_path, capsys):
    verdicts = {}
    for name in ("small", "large"):
        ran = cli(
            capsys,
            "report",
            lab / "plain.h5",
            "--force-floor",
            "1",
            "--jnd-file",
            lab / "jnd" / f"{name}.h5",
            "--out",
            tmp_path / name,
        )
        assert ran.returncode == 0, ran.stderr
        page = (tmp_path / name / "report.html").read_text()
        verdicts[name] = "differs noticeably" in page, "feels like the chosen feel" in page
        # the JNDs used, with the file's participant, trials and interval
        assert "JNDs used" in page and f"{name}.h5: friction_closing at 10 N" in page
        assert f"sim:{SMALL if name == 'small' else LARGE:g}" in page and "80 trials" in page
        assert "changed for this report (--force-floor 1 N)" in page
        assert "default, from the literature" in page  # the settings nobody measured
    assert verdicts == {"small": (True, False), "large": (False, True)}
    # the library call judges alike, and several files combine
    both = pipeline_settings(
        lab / "plain.h5", None, None, 1.0, [lab / "jnd" / "large.h5", lab / "jnd" / "visc.h5"]
    ).check()
    fc = Results(lab / "plain.h5").record.perceptual_check
    jnd = both.apply(fc.jnd)
    assert jnd.force == pytest.approx(_weber(lab, "large"))
    assert jnd.viscosity == pytest.approx(_weber(lab, "visc"))
    assert jnd.inertia == fc.jnd.inertia and jnd.force_floor == 1.0
    assert fc.judged(jnd)["passes"] and not fc.judged()["passes"]


def _run(lab, name: str, perception: str):
    (lab / f"{name}.yaml").write_text(RUN.format(name=name) + perception)
    return run_experiment(load_experiment(lab / f"{name}.yaml"), out=lab / f"{name}.h5").path


@pytest.mark.numerics
@pytest.mark.slow
def test_perception_files_change_the_runs_own_verdict_and_say_where_from(lab, capsys):
    shown = {}
    for name in ("small", "large"):
        path = _run(
            lab,
            f"exp-{name}",
            f"perception:\n  force_floor: 1.0\n  files: [jnd/{name}.h5]\n"
            '  viscosity: {weber: 0.3, source: "lab study 2026-11, 12 participants"}\n',
        )
        ran = cli(capsys, "show", path, "--json")
        assert ran.returncode == 0, ran.stderr
        shown[name] = json.loads(ran.stdout)
    assert not shown["small"]["perceptual_check"]["passes"]
    assert shown["large"]["perceptual_check"]["passes"]
    for name, s in shown.items():
        jnds = s["jnds"]
        assert jnds["force"]["value"] == pytest.approx(_weber(lab, name))
        assert s["perceptual_check"]["jnd"]["force"] == jnds["force"]["value"]
        src = jnds["force"]["source"]
        assert src.startswith(f"{name}.h5: friction_closing") and "80 trials" in src
        assert "[" in src and "sim:" in src  # the interval and the participant
        assert jnds["force_floor"] == {
            "value": 1.0,
            "unit": "N",
            "source": f"set in {lab / f'exp-{name}.yaml'}:8",
        }
        assert jnds["viscosity"]["value"] == 0.3
        assert jnds["viscosity"]["source"].startswith("lab study 2026-11, 12 participants")
        assert "literature" in jnds["inertia"]["source"]
    # the text form too, with units
    text = cli(capsys, "show", lab / "exp-small.h5").stdout
    assert "JNDs used:" in text
    assert re.search(r"force_floor +1 N", text) and re.search(r"viscosity +30 %", text)


def _load(lab, perception: str):
    (lab / "bad.yaml").write_text(RUN.format(name="bad") + perception)
    return load_experiment(lab / "bad.yaml")


@pytest.mark.parametrize(
    "perception, message",
    [
        ("perception: {files: [plain.h5]}", "bad.yaml:7: perception.files[0]: "),
        ("perception: {files: [jnd/stopped.h5]}", "the session is stopped"),
        ("perception: {files: [jnd/angle.h5]}", "latch_loose_angle is in rad"),
        ("perception: {files: [jnd/none.h5]}", "file not found: jnd/none.h5"),
        ("perception: {files: 3}", "expected a list of JND files"),
        ("perception:\n  viscosity: {weber: 1.5}", "bad.yaml:8: perception.viscosity.weber: 1.5"),
        ("perception:\n  viscosity: {weber: 0.3, by: me}", "perception.viscosity: expected {weber"),
        ("perception:\n  force_floor: {weber: 0.3}", "sets a Weber fraction"),
        (
            "perception:\n  force: {weber: 0.3, source: x}\n  files: [jnd/small.h5]",
            "small.h5 measures the force JND, which perception.force sets too (at ",
        ),
        (
            "perception:\n  force: 0.2\n  files: [jnd/small.h5]",
            "give it once",
        ),
    ],
)
def test_bad_measured_jnds_are_one_line_naming_the_line(lab, perception, message):
    with pytest.raises(UserError) as err:
        _load(lab, perception)
    text = str(err.value)
    assert message in text and "\n" not in text and "bad.yaml:" in text
    if "plain.h5" in perception:
        assert "not a JND file" in text


def test_report_refuses_jnd_and_jnd_file_on_one_setting(lab, capsys):
    both = cli(
        capsys, "report", lab / "plain.h5", "--jnd", "0.2", "--jnd-file", lab / "jnd/small.h5"
    )
    assert both.returncode == 2 and "both set the force JND" in both.stderr
    assert len(both.stderr.strip().splitlines()) == 1
    # a file on another setting goes with --jnd
    ok = pipeline_settings(lab / "plain.h5", None, 0.2, None, [lab / "jnd/visc.h5"]).check()
    assert ok.jnd == 0.2 and [k for k, _, _ in ok.measured] == ["viscosity"]
    wrong = cli(capsys, "report", lab / "plain.h5", "--jnd-file", lab / "plain.h5")
    assert wrong.returncode == 2 and "not a JND file" in wrong.stderr


def test_a_pipelines_files_reach_its_stages_and_a_stages_own_setting_wins(lab):
    from evo_door.experiment.pipeline import load_pipeline

    stage = "\n".join("    " + line for line in RUN.format(name="s").splitlines())
    (lab / "pipe.yaml").write_text(
        "name: p\nperception: {files: [jnd/small.h5, jnd/large.h5]}\nstages:\n"
        f"  a:\n{stage}\n  b:\n{stage}\n    perception: {{force: 0.2}}\n"
    )
    a, b = (s.experiment for s in load_pipeline(lab / "pipe.yaml").stages)
    # two files on one setting: the geometric mean, both sessions named
    mean = np.sqrt(_weber(lab, "small") * _weber(lab, "large"))
    assert a.jnd().force == pytest.approx(mean)
    assert a.jnd_sources()["force"].startswith("geometric mean of 2: small.h5")
    assert b.jnd().force == 0.2 and b.jnd_sources()["force"].startswith("set in ")
    assert a.resolved()["perception_sources"] == a.jnd_sources()


@pytest.mark.numerics
@pytest.mark.slow
def test_the_objective_and_the_tolerances_follow_the_file(lab):
    # a door target (its curve and its felt dynamics): the perceptual objective, the
    # chosen feel's JND and the specification's yield all take the measured settings
    from evo_door.experiment.run_specification import stage_specification
    from evo_door.experiment.setup import resolve

    body = (
        "model: door\nparams: default\ntarget: {model: door, params: default}\n"
        "objective: {kind: perceptual}\nfree: {F_atD: [0, 60]}\n"
        "algorithm: {population: 8, generations: 2, seed: 1}\n"
    )
    setups = {}
    for name, perception in (
        ("default", ""),
        ("small", "perception: {files: [jnd/small.h5]}\n"),
        ("large", "perception: {files: [jnd/large.h5, jnd/visc.h5]}\n"),
    ):
        (lab / f"obj-{name}.yaml").write_text(body + perception)
        setups[name] = resolve(load_experiment(lab / f"obj-{name}.yaml"))
    assert setups["small"].feel.jnd.force == pytest.approx(_weber(lab, "small"))
    assert setups["large"].feel.jnd.viscosity == pytest.approx(_weber(lab, "visc"))
    model = setups["default"].model
    base = np.asarray(setups["default"].base, dtype=np.float64)
    off = base.copy()
    off[model.params.index("F_atD")] *= 1.3
    value = {k: s.feel.value(model, off) for k, s in setups.items()}
    assert value["small"] > value["default"] > value["large"] > 0.0
    yields = {}
    for k in ("small", "large"):
        spec = stage_specification(setups[k], {}, base)  # the kinds' default process
        # (the door against its own feel: only the chosen curve's resolution, its points
        # within 1e-3 of its force range, a tenth of a JND at the 0.5 N floor)
        assert spec is not None and spec.nominal_margin < 0.2
        yields[k] = spec.yield_.estimate
    # the same doors, built to the same process: a participant who tells less apart
    # accepts more of them
    assert yields["large"] > yields["small"] + 0.2, yields
