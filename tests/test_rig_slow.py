"""Slow (quasi-static) rig trials: seeded like the other kinds, their force on the door's
Coulomb curve, and what they determine in a fit (friction and spring, not inertia);
a render log as the chosen feel of the perceptual objective."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evo_door.data import rig
from evo_door.data.preprocess import remove_rate_bias, split_windows
from evo_door.data.trial import Trial
from evo_door.errors import UserError
from evo_door.models import get_model
from evo_door.optim import Objective, Problem, slsqp
from evo_door.optim.identifiability import identifiability
from evo_door.sim.simulate import force_angle_curve

DOOR = get_model("door")
DEG = math.pi / 180.0


def _slow(trials=1, seed=1, rate=256.0, kinds=("slow",)):
    return rig.generate_trials(
        DOOR,
        DOOR.load_params("default"),
        rig.Campaign(users=2, trials=trials, seed=seed, kinds=list(kinds)),
        rig.RigSettings(rate=rate),
        progress=False,
    )


def test_slow_is_a_declared_kind_checked_like_the_others():
    assert (
        "slow" in rig.KINDS and "slow" in DOOR.rig_kinds and "slow" in get_model("haptic").rig_kinds
    )
    assert rig.check_spec({"model": "door", "kinds": ["slow", "impulse"]})["kinds"] == [
        "slow",
        "impulse",
    ]
    with pytest.raises(rig.SpecError, match="unknown trial kind 'slwo'.*slow"):
        rig.check_spec({"model": "door", "kinds": ["slwo"]})


@pytest.mark.slow
def test_a_slow_trial_is_seeded_and_strokes_open_and_back():
    a, b = _slow(seed=4), _slow(seed=4)
    tr = a[0]
    assert np.array_equal(tr.force, b[0].force) and np.array_equal(tr.dtheta, b[0].dtheta)
    assert tr.kind == "slow" and tr.channels == ("theta", "dtheta")
    assert tr.theta0 == pytest.approx(math.pi / 2, abs=0.5 * DEG)  # from closed
    ev = tr.meta["rig"]["events"]
    assert 0.06 < ev["speed_open"] < 0.25 and 0.06 < ev["speed_close"] < 0.25  # rad/s
    assert ev["t_start"] < ev["t_turn"] < ev["t_stop"] < ev["t_release"] < tr.t[-1]
    # opened (pulled, dtheta < 0) to near fully open, then closed (pushed)
    opening = (tr.t > ev["t_start"] + 2.0) & (tr.t < ev["t_turn"])
    closing = (tr.t > ev["t_turn"] + 2.0) & (tr.t < ev["t_stop"])
    assert np.median(tr.dtheta[opening]) < -0.05 and np.median(tr.dtheta[closing]) > 0.05
    angle = split_windows(tr, 0.5)
    lowest = min(w.theta0 for w in angle)
    assert 0.5 * DEG < lowest < 8.0 * DEG  # the stop at 5 deg, a ramp past it


@pytest.mark.slow
@pytest.mark.numerics
def test_the_force_of_a_slow_trial_is_the_doors_coulomb_curve():
    """Quasi-static: away from the latch, the recorded force averaged over 2.5 deg of
    angle is the Coulomb force-angle curve of the door (within 0.35 N of 5-13 N)."""
    (tr,) = _slow(seed=2, rate=512.0)
    tr = remove_rate_bias(tr, "start")
    curve = force_angle_curve(DOOR, DOOR.load_params("default"), n=181)
    angle = np.concatenate([w.theta0 + np.cumsum(np.r_[0.0, w.dtheta[1:]]) * w.dt
                            for w in split_windows(tr, 1.0)])  # fmt: skip
    for direction, moving in (("opening", tr.dtheta < -0.03), ("closing", tr.dtheta > 0.03)):
        sel = moving & (angle > 10 * DEG) & (angle < 75 * DEG)
        ref = np.interp(angle[sel], curve["theta"], curve[direction])
        bins = np.digitize(angle[sel], np.arange(10, 76, 2.5) * DEG)
        diff = [np.mean(tr.force[sel][bins == k] - ref[bins == k]) for k in np.unique(bins)]
        assert len(diff) > 20, direction
        assert np.max(np.abs(diff)) < 0.35, (direction, np.round(diff, 3))


@pytest.mark.slow
@pytest.mark.numerics
def test_slow_trials_pin_friction_and_spring_but_hardly_the_inertia():
    """F_atD and F_load fitted on windows of slow trials come back within 1 %, with
    95 % intervals under 1 %; the door's inertia I_z is far less determined by them
    than by impulse trials (an impulse is an acceleration, a slow stroke is not)."""
    params = DOOR.load_params("default")
    free = ["F_atD", "F_load", "I_z"]
    true = np.array([params[n] for n in free])
    lo, hi = [5.0, 50.0, 0.02], [40.0, 150.0, 0.5]
    ci = {}
    for kind in ("slow", "impulse"):
        trials = [remove_rate_bias(t, "start") for t in _slow(2, 3, 256.0, [kind])]
        if kind == "slow":
            trials = [w for t in trials for w in split_windows(t, 1.0)]
        prob = Problem(DOOR, free, lo, hi, np.array(params.vector), trials, Objective("ise", 1))
        x = slsqp(prob, true * [1.1, 0.93, 1.5]).x
        idf = identifiability(prob, x)
        ci[kind] = dict(zip(free, idf.ci_rel))
        if kind == "slow":
            assert x[:2] == pytest.approx(true[:2], rel=0.01)
            assert idf.verdicts[:2] == ["identifiable", "identifiable"]
            assert max(idf.ci_rel[:2]) < 0.01
    assert ci["slow"]["I_z"] > 3.0 * ci["impulse"]["I_z"]
    assert ci["slow"]["F_atD"] < 0.1 * ci["impulse"]["F_atD"]


def test_windows_start_from_the_measured_state_and_the_inclinometer_anchors_them():
    t = np.arange(400) / 100.0
    theta = np.pi / 2 - 0.2 * t  # leaves the +-10 deg inclinometer after 0.87 s
    trial = Trial(
        t, np.zeros_like(t), theta=np.clip(theta, np.pi / 2 - 10 * DEG, None),
        dtheta=np.full_like(t, -0.2), trial_id="T01", theta0=np.pi / 2,
        sensors={"theta": {"range": [np.pi / 2 - 10 * DEG, np.pi / 2 + 10 * DEG]}},
    )  # fmt: skip
    windows = split_windows(trial, 1.0)
    assert [w.trial_id for w in windows] == ["T01w01", "T01w02", "T01w03", "T01w04"]
    for w in windows:
        assert w.theta0 == pytest.approx(theta[int(round(w.t[0] * 100))], abs=1e-9)
        assert w.dtheta0 == -0.2
    assert len(split_windows(trial, 1.7)) == 2  # the short remainder joins the last
    with pytest.raises(UserError, match="windows: give a length in seconds > 0"):
        split_windows(trial, 0.0)


def test_a_render_log_is_a_chosen_feel_for_the_perceptual_objective(tmp_path):
    """``target: {model: haptic, params: LOG.h5}``: the set the log rendered is the feel
    a door's specification is fitted to, in JND units."""
    from evo_door.experiment import ExperimentRun, load_experiment
    from tests.test_render_check import _model_log, _push

    haptic = get_model("haptic")
    rendered = haptic.load_params("seed_trial", {"friction_closing": 4.0, "friction_opening": 2.5})
    log = _model_log(tmp_path / "session.h5", [(rendered, _push(400))])
    (tmp_path / "exp.yaml").write_text(
        "name: log-feel\nmodel: haptic\nparams: seed_trial\n"
        "target: {model: haptic, params: session.h5}\n"
        "free: {friction_closing: [0.0, 10.0], friction_opening: [0.0, 10.0]}\n"
        "objective: {kind: perceptual}\n"
        "algorithm: {population: 16, generations: 3, seed: 1, polish: slsqp}\n"
    )
    run = ExperimentRun.create(load_experiment(tmp_path / "exp.yaml"), tmp_path / "run.h5").run()
    best = dict(zip(run.setup.free, run.result["best_x"]))
    assert log.exists() and run.setup.feel.curve.source.startswith("haptic")
    assert best["friction_closing"] == pytest.approx(4.0, abs=0.05)
    assert best["friction_opening"] == pytest.approx(2.5, abs=0.05)


def test_an_experiment_cuts_slow_trials_into_windows(tmp_path):
    """``preprocess: {windows: S}`` in an experiment file: each slow trial becomes its
    windows, each from its measured state; a length of 0 is a one-line error."""
    from evo_door.data.io import write_trials
    from evo_door.experiment import load_experiment
    from evo_door.experiment.setup import resolve

    trials = _slow(1, 4, 256.0)
    write_trials(tmp_path / "slow.h5", trials)
    text = (
        "model: door\nparams: default\n"
        "target: {data: slow.h5, kinds: [slow], preprocess: {rate_bias: start, windows: WIN}}\n"
        "free: {F_atD: [5.0, 40.0]}\nobjective: {kind: ise}\n"
    )
    (tmp_path / "exp.yaml").write_text(text.replace("WIN", "1.0"))
    setup = resolve(load_experiment(tmp_path / "exp.yaml"))
    expected = sum(len(split_windows(remove_rate_bias(t, "start"), 1.0)) for t in trials)
    assert len(setup.fit) == expected > 2
    assert all("w" in tr.trial_id for tr in setup.fit)
    (tmp_path / "exp.yaml").write_text(text.replace("WIN", "0"))
    with pytest.raises(UserError, match="windows"):
        load_experiment(tmp_path / "exp.yaml")
