"""A feel against a chosen one, in just-noticeable differences (``evo_door.perception``).

The JND settings, a force-angle curve read from the file ``evo-door curve`` writes, the
perceptual objective (zero on the feel itself, a known value for a known offset), the
haptic model's balance force (conservative: it shifts both strokes alike), and the two
ends of the method it serves: the haptic model holds the bundled door's feel within the
JND, and a feel made from a chosen door is reached by that door's specifications.
"""

import math

import numpy as np
import pytest

from evo_door.errors import UserError
from evo_door.experiment import load_experiment
from evo_door.experiment.runner import ExperimentRun
from evo_door.models import get_model
from evo_door.params import param_vector
from evo_door.perception import (
    JND,
    FeelCurve,
    FeelTarget,
    check_verdict,
    model_curve,
    perceptual_check,
    read_curve_csv,
    verdict_text,
)
from evo_door.sim.simulate import force_angle_curve
from tests.test_cli import cli
from tests.test_input_files import one_line_error

HAPTIC = get_model("haptic")
DOOR = get_model("door")


# -- the settings ------------------------------------------------------------------------
def test_force_jnd_is_a_weber_fraction_above_its_floor():
    jnd = JND(force=0.08, force_floor=0.4)
    assert jnd.force_threshold(10.0) == pytest.approx(0.8)
    assert jnd.force_threshold(-1.0) == pytest.approx(0.4)
    np.testing.assert_allclose(jnd.force_threshold(np.array([-20.0, 0.0])), [1.6, 0.4])
    # inertia and damping floors: the force floor at the reference acceleration and speed
    assert jnd.inertia_threshold(0.0) == pytest.approx(0.4 / jnd.acceleration)
    assert jnd.damping_threshold(10.0) == pytest.approx(jnd.viscosity * 10.0)


@pytest.mark.parametrize(
    "values, message",
    [
        ({"force": 1.5}, "a Weber fraction below 1"),
        ({"force_floor": -1.0}, "must be a number above 0"),
        ({"forse": 0.1}, "unknown setting 'forse'"),
    ],
)
def test_bad_jnd_settings_are_refused(values, message):
    with pytest.raises(UserError, match=message):
        JND.from_mapping(values)


# -- a feel from a file ----------------------------------------------------------------------
@pytest.mark.numerics
def test_a_curve_file_written_by_evo_door_curve_reads_back(tmp_path, capsys):
    path = tmp_path / "feel.csv"
    res = cli(capsys, "curve", "door", "--params", "default", "--out", str(path))
    assert res.returncode == 0, res.stderr
    curve = read_curve_csv(path)
    ref = force_angle_curve(DOOR, DOOR.load_params("default"))
    np.testing.assert_allclose(curve.theta, ref["theta"], rtol=1e-9)
    for d in ("opening", "closing"):
        np.testing.assert_allclose(getattr(curve, d), ref[d], rtol=1e-8, atol=1e-9)


@pytest.mark.parametrize(
    "text, message",
    [
        ("theta,force\n0,1\n", "missing column(s) direction"),
        (
            "theta,force,direction\n0,1,opening\n1,2,opening\n0,1,closing\n",
            "needs at least 2 closing",
        ),
        ("theta,force,direction\n0,x,opening\n", ":2: expected theta,force,direction"),
        ("theta,force,direction\n0,1,sideways\n", ":2: direction 'sideways'"),
        (
            "theta,force,direction\n0,1,opening\n0,2,opening\n0,1,closing\n1,1,closing\n",
            "two opening rows at one angle",
        ),
    ],
)
def test_a_bad_curve_file_is_one_line_naming_the_line(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(UserError) as info:
        read_curve_csv(path)
    assert message in str(info.value) and "\n" not in str(info.value)


# -- the perceptual objective --------------------------------------------------------------
@pytest.mark.numerics
def test_the_feel_scores_zero_against_itself_and_a_uniform_offset_its_size_in_jnds():
    params = DOOR.load_params("default")
    target = FeelTarget.from_model(DOOR, params)
    p = param_vector(params, DOOR.params)
    assert target.value(DOOR, p) < 1e-9
    # a curve shifted by 2 JND of its own force everywhere (its peaks by as much, at the
    # same angles): scored against it, the door is off by -2 t(F) / t(F + 2 t(F)) JND at
    # each point, between -2.5 (10 % of a pull: -10 N against -8 N) and -5/3 (a push)
    jnd = JND()
    c = target.curve
    shifted = FeelCurve(
        c.theta,
        c.opening + 2 * jnd.force_threshold(c.opening),
        c.closing + 2 * jnd.force_threshold(c.closing),
    )
    bare = FeelTarget(shifted, jnd)
    r = bare.residuals(DOOR, p)
    n = bare.stroke.size
    # per stroke: its points weighted by their share of the angle range, then each
    # point's excess beyond 1 JND times sqrt(10); then each peak's force and angle
    assert r.size == 4 * n + 4
    total = 0.0
    for k in (0, 2):
        weighted, excess = r[k * n : (k + 1) * n], r[(k + 1) * n : (k + 2) * n]
        ratio = weighted / np.sqrt(0.5 * bare.weights)
        # (to the linear interpolation of the curve between its points)
        assert np.all((ratio > -2.5 * 1.001) & (ratio < -5 / 3 * 0.999)), ratio
        np.testing.assert_allclose(excess, -math.sqrt(10.0) * (np.abs(ratio) - 1.0), rtol=1e-12)
        # the stroke's mean square, half of it per stroke: between (5/3)^2 and 2.5^2
        assert 0.5 * (5 / 3) ** 2 * 0.999 < np.sum(weighted**2) < 0.5 * 2.5**2 * 1.001
        total += np.sum(weighted**2) + np.sum(excess**2)
    force_o, angle_o, force_c, angle_c = r[-4:]
    assert -2.5 - 1e-3 < force_o < -5 / 3 + 1e-3 and -2.5 - 1e-3 < force_c < -5 / 3 + 1e-3
    assert abs(angle_o) < 0.05 and abs(angle_c) < 0.05  # the peaks did not move
    assert bare.value(DOOR, p) == pytest.approx(total + np.sum(r[-4:] ** 2), rel=1e-12)


@pytest.mark.numerics
@pytest.mark.parametrize("name", ["door", "haptic"])
def test_the_latch_peaks_searched_coarse_to_fine_are_the_whole_grids(name):
    """The perceptual objective searches each latch peak on every 8th angle of the latch
    zone's grid, then around the best (``stroke_and_peaks``): for doors scattered 30 %
    about the default, the same peak forces and angles, to the bit, as on every angle
    of the grid (``measured_feel``), and the same stroke; for doors scattered 70 %, at
    most one in a hundred differs, by a spike where a catch lets go, under a per cent
    of its force. A plant measured only on a whole grid (a state vector) gets it."""
    from evo_door.perception.target import coulomb_rows, measured_feel, stroke_and_peaks

    model = get_model(name)
    feel = FeelTarget.from_model(DOOR, DOOR.load_params("default"))
    p = model.load_params().vector
    lo, hi = np.asarray(model.params.lower, float), np.asarray(model.params.upper, float)
    rng = np.random.default_rng(11)
    theta = np.concatenate([feel.stroke, feel.latch])
    n = feel.stroke.size
    for spread, allowed in ((0.3, 0), (0.7, 3)):
        Q = coulomb_rows(
            model, np.clip(p * rng.uniform(1 - spread, 1 + spread, (300, p.size)), lo, hi)
        )
        whole = measured_feel(model, Q, theta, np.arange(theta.size) >= n)
        got = stroke_and_peaks(model, Q, feel.stroke, feel.latch)
        differ = 0
        for d in ("opening", "closing"):
            assert np.array_equal(got[d], whole[d][:, :n], equal_nan=True)
            same = got["peaks"][d] == whole["peaks"][d]
            assert np.array_equal(same, got["angles"][d] == whole["angles"][d])
            np.testing.assert_allclose(got["peaks"][d], whole["peaks"][d], rtol=1e-2)
            differ += int((~same).sum())
        assert differ <= allowed, (spread, differ)

    class Whole:  # a plant without hold_forces_at
        plant = type("P", (), {"hold_forces_rows": model.plant.hold_forces_rows})()

    got = stroke_and_peaks(Whole(), Q[:5], feel.stroke, feel.latch)
    for d in ("opening", "closing"):
        assert np.array_equal(got[d], whole[d][:5, :n], equal_nan=True)
        assert np.array_equal(got["peaks"][d], whole["peaks"][d][:5], equal_nan=True)


@pytest.mark.numerics
def test_balance_shifts_both_strokes_alike_and_is_linear_between_its_angles():
    base = {"friction_opening": 3.0, "friction_closing": 2.0, "open_force": 0.0}
    plain = force_angle_curve(HAPTIC, HAPTIC.load_params("seed_trial", base), n=181)
    values = {f"balance_{k}": 2.0 * k - 7.0 for k in range(1, 10)}
    pushed = force_angle_curve(HAPTIC, HAPTIC.load_params("seed_trial", {**base, **values}), n=181)
    theta = np.linspace(0.0, math.pi / 2 - 0.05, 50)
    nodes = np.linspace(0.0, math.pi / 2, 9)
    expected = np.interp(theta, nodes, list(values.values()))
    for d in ("opening", "closing"):
        a = np.interp(theta, plain["theta"], plain[d])
        b = np.interp(theta, pushed["theta"], pushed[d])
        # the door pushes toward closing with B: the hand holds it with -B
        np.testing.assert_allclose(a - b, expected, atol=1e-9)


def test_the_check_names_the_worst_angle_and_the_share_of_the_stroke_beyond():
    th = np.linspace(0.0, 1.5, 301)
    chosen = FeelCurve(th, -10.0 + 0 * th, 3.0 + 0 * th)
    # the closing stroke 2 N off from 0.975 to 1.025 rad: 0.05 rad of the 1.5 rad stroke,
    # 4 JND (the floor, 0.5 N): noticeable, however little of the stroke it spans
    closing = np.where(np.abs(th - 1.0) < 0.026, 5.0, 3.0)
    mech = FeelCurve(th, -10.0 + 0 * th, closing)
    v = check_verdict(perceptual_check(mech, chosen, JND()), JND())
    assert v["opening"]["verdict"] == "within the JND" and v["opening"]["worst_jnd"] == 0.0
    assert v["closing"]["verdict"] == "noticeable" and not v["passes"]
    end = th[th < 1.5 - math.radians(3.0)][-1]  # the stroke ends at the latch zone
    assert v["closing"]["fraction_beyond_jnd"] == pytest.approx(0.05 / end, rel=1e-9)
    assert abs(v["closing"]["worst"]["angle_deg"] - math.degrees(1.0)) < 2.0
    assert v["closing"]["worst"]["difference_N"] == pytest.approx(2.0)
    assert v["closing"]["worst"]["jnd_units"] == pytest.approx(4.0)
    assert v["worst_jnd"] == pytest.approx(4.0) and v["worst"].startswith("closing stroke at ")
    (band,) = v["closing"]["bands_deg"]
    assert math.degrees(0.975) <= band[0] < band[1] <= math.degrees(1.025)


# -- the method's two ends ------------------------------------------------------------------
HAPTIC_STAGE = """
name: haptic-feel
model: haptic
params: seed_trial
target: {model: door, params: default}
free:
  inertia: [0.1, 3.0]
  friction_closing: [0.0, 60.0]
  friction_opening: [0.0, 60.0]
  friction_scale_1: [0.0, 1.0]
  friction_scale_2: [0.0, 1.0]
  friction_scale_3: [0.0, 1.0]
  friction_scale_4: [0.0, 1.0]
  friction_scale_5: [0.0, 1.0]
  friction_scale_6: [0.0, 1.0]
  friction_scale_7: [0.0, 1.0]
  friction_scale_8: [0.0, 1.0]
  viscous_damping: [0.0, 20.0]
  balance_1: [-30.0, 30.0]
  balance_2: [-30.0, 30.0]
  balance_3: [-30.0, 30.0]
  balance_4: [-30.0, 30.0]
  balance_5: [-30.0, 30.0]
  balance_6: [-30.0, 30.0]
  balance_7: [-30.0, 30.0]
  balance_8: [-30.0, 30.0]
  balance_9: [-30.0, 30.0]
  open_force: [10.0, 80.0]
  close_force: [5.0, 80.0]
fixed: {window_slope: 20.0}
objective: {kind: perceptual}
algorithm: {population: 100, generations: 20, seed: 1, polish: slsqp, max_iterations: 60}
"""

#: the second step, as experiments/case_study.yaml's haptic_latch: the latch's geometry
#: and forces, so that the haptic model catches where the door does
LATCH_STAGE = """
name: haptic-latch
model: haptic
params: {values}
target: {{model: door, params: default}}
free:
  open_force: [10.0, 80.0]
  close_force: [5.0, 80.0]
  loose_angle: [0.0, 0.02]
  transition_angle: [0.0, 0.02]
objective: {{kind: perceptual}}
algorithm: {{population: 20, generations: 5, seed: 1, polish: slsqp, scan: 21, max_iterations: 30}}
"""


def _run(tmp_path, text, name="exp.yaml"):
    (tmp_path / name).write_text(text)
    exp = load_experiment(tmp_path / name)
    return ExperimentRun.create(exp, tmp_path / "run.h5").run()


@pytest.fixture(scope="module")
def haptic_check(tmp_path_factory):
    """The check of the haptic model fitted to the bundled door's feel (HAPTIC_STAGE,
    then LATCH_STAGE from its answer)."""
    run = _run(tmp_path_factory.mktemp("haptic"), HAPTIC_STAGE)
    values = run.setup.problem().full(run.result["best_x"])[0]
    inline = (
        "{" + ", ".join(f"{n}: {float(v)!r}" for n, v in zip(HAPTIC.params.names, values)) + "}"
    )
    run = _run(tmp_path_factory.mktemp("latch"), LATCH_STAGE.format(values=inline))
    values = run.setup.problem().full(run.result["best_x"])[0]
    door = model_curve(DOOR, DOOR.load_params("default"))
    return check_verdict(perceptual_check(model_curve(HAPTIC, values), door, JND()), JND())


@pytest.mark.slow
def test_the_haptic_model_holds_the_bundled_doors_feel_within_the_jnd(haptic_check):
    """Every point of both strokes, both latch peaks and their angles."""
    check = haptic_check
    for d in ("opening", "closing"):
        assert check[d]["fraction_beyond_jnd"] == 0.0, (d, check[d])
        assert check[d]["latch_peak"]["jnd_units"] <= 1.0, (d, check[d]["latch_peak"])
        assert check[d]["peak_angle"]["jnd_units"] <= 1.0, (d, check[d]["peak_angle"])
    assert check["passes"], verdict_text(check)


SPEC_STAGE = """
name: spec-feel
model: door
params: default
target: {curve: feel.csv}
free:
  K: [200.0, 800.0]
  F_load: [40.0, 160.0]
  M: [0.3, 3.0]
  I_z: [0.01, 0.5]
  mu: [0.0, 1.5]
  F_atC: [0.0, 100.0]
  F_atD: [0.0, 100.0]
  unlock_force: [10.0, 80.0]
  lock_force: [5.0, 60.0]
algorithm: {population: 60, generations: 10, seed: 1, polish: slsqp, max_iterations: 40}
"""


@pytest.mark.slow
def test_a_feel_made_from_a_door_is_reached_and_its_door_found(tmp_path, capsys):
    chosen = {"K": 340.0, "F_atD": 12.0, "unlock_force": 32.0}
    sets = [x for n, v in chosen.items() for x in ("--set", f"{n}={v}")]
    res = cli(
        capsys, "curve", "door", "--params", "default", *sets, "--out", str(tmp_path / "feel.csv")
    )
    assert res.returncode == 0, res.stderr
    run = _run(tmp_path, SPEC_STAGE)
    truth = DOOR.load_params("default", chosen)
    values = run.setup.problem().full(run.result["best_x"])[0]
    check = check_verdict(
        perceptual_check(model_curve(DOOR, values), read_curve_csv(tmp_path / "feel.csv"), JND()),
        JND(),
    )
    assert check["passes"], check
    ident = run.result["identifiability"]
    assert ident.verdict("M") != "identifiable"  # a static curve has no inertia in it
    called = [n for n in ident.names if ident.verdict(n) == "identifiable"]
    # the latch peaks pin their forces (to +-10-15 % at one JND); the frictions and the
    # spring trade against each other on a static curve
    assert {"unlock_force", "lock_force"} <= set(called), ident.format()
    assert "F_atC" not in called and "F_atD" not in called
    for n in called:
        value = float(run.result["best_x"][ident.names.index(n)])
        assert abs(value / truth[n] - 1) < 0.05, (n, value, truth[n])


# -- bad input ------------------------------------------------------------------------------
BAD = """
name: bad
model: door
params: default
target: {TARGET}
free: {K: [200.0, 800.0]}
objective: {OBJECTIVE}
"""


@pytest.mark.parametrize(
    "target, objective, message",
    [
        ("{curve: feel.csv}", "{kind: ise}", "a curve target has no trials to score"),
        ("{curve: missing.csv}", "{kind: perceptual}", "missing.csv"),
        ("{data: trials.h5}", "{kind: perceptual}", "measured trials are not one"),
        ("{model: haptic, params: seed_trial}", "{kind: ise}", "target.inputs: required key"),
        ("{curve: feel.csv, model: haptic}", "{kind: perceptual}", "not model and curve"),
    ],
)
def test_bad_feel_targets_are_one_line_errors(tmp_path, capsys, target, objective, message):
    (tmp_path / "feel.csv").write_text(
        "theta,force,direction\n0,-10,opening\n1.6,-10,opening\n0,3,closing\n1.6,3,closing\n"
    )
    (tmp_path / "trials.h5").write_bytes(b"")
    text = BAD.replace("{TARGET}", target).replace("{OBJECTIVE}", objective)
    (tmp_path / "bad.yaml").write_text(text)
    res = cli(capsys, "run", str(tmp_path / "bad.yaml"), "--out", str(tmp_path / "r.h5"))
    one_line_error(res, message)


def test_the_chosen_feel_is_kept_in_the_results_file(tmp_path):
    (tmp_path / "feel.csv").write_text(
        "theta,force,direction\n0,-10,opening\n1.6,-12,opening\n0,3,closing\n1.6,2,closing\n"
    )
    text = BAD.replace("{TARGET}", "{curve: feel.csv}").replace(
        "{OBJECTIVE}", "{kind: perceptual}\nalgorithm: {population: 4, generations: 1, seed: 1}"
    )
    run = _run(tmp_path, text)
    again = ExperimentRun.open(tmp_path / "run.h5")
    a, b = run.setup.feel, again.setup.feel
    np.testing.assert_array_equal(a.curve.closing, b.curve.closing)
    assert a.jnd == b.jnd and a.dynamics is None and b.dynamics is None
    x = run.result["best_x"]
    assert run.setup.problem().evaluate(x)[0][0] == again.setup.problem().evaluate(x)[0][0]
