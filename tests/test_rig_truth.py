"""The rig's rich truth: it reduces to the door, its effects are the declared ones, CLI.

References are independent of the code under test where they can be: the door model
itself (:func:`evo_door.sim.simulate`), closed-form first-order responses, scipy's
``lsim`` / ``freqs``, and the mechanical energy of a frictionless door.
"""

import json
import math
from dataclasses import asdict, replace
from pathlib import Path

import h5py
import numpy as np
import pytest
from scipy import signal

from evo_door.data import read_trials, rig
from evo_door.data.sensors import GYROSCOPE, LOAD_CELL, SEED_SENSORS, FilteredSensor
from evo_door.errors import UserError
from evo_door.models import get_model
from evo_door.models.door import accel as door_accel
from evo_door.models.door import energy
from evo_door.models.door import truth as truth_module
from evo_door.models.door.truth import (
    OFF,
    TABLE,
    DoorTruth,
    load_truth_params,
    rigid_accel,
    stribeck_factor,
)
from evo_door.models.door_params import GRAVITY
from evo_door.params import param_vector
from evo_door.sim import simulate
from tests.test_cli import cli

# compared against references: run again on a generic CPU in CI (pyproject markers)
pytestmark = pytest.mark.numerics

DT = 1.0 / 1024
REPO = Path(__file__).resolve().parents[1]


def make_truth(door, params, values, substeps=None):
    return DoorTruth(door, params, load_truth_params(None, values), substeps=substeps)


def push(n=700, peak=8.0, start=0.05, length=0.15):
    t = DT * np.arange(n)
    x = (t - start) / length
    return np.where((x > 0) & (x < 1), peak * np.sin(math.pi * np.clip(x, 0, 1)), 0.0)


# -- the default path and the switched-off truth ----------------------------------------
def test_default_rig_run_never_touches_the_truth(tmp_path, capsys, monkeypatch):
    """Without --truth the rig is what it was: the truth's code is never called, and the
    impulse trials equal the bundled default data's (which the latch does not reach)."""

    def boom(*args, **kwargs):
        raise AssertionError("the default rig path went through the rich truth")

    monkeypatch.setattr(truth_module.DoorTruth, "__init__", boom)
    monkeypatch.setattr(FilteredSensor, "respond", boom)
    out = tmp_path / "default.h5"
    res = cli(
        capsys, "rig", "generate", "--model", "door", "--params", "default", "--users", "3",
        "--trials", "1", "--seed", "1", "--out", out,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    (fresh,) = read_trials(out)
    assert "variant" not in fresh.truth and "effects" not in fresh.truth
    with h5py.File(out) as f:
        assert f.attrs["description"] == (
            "virtual rig: model door, params default, 3 users, 1 trials, seed 1"
        )
    bundled = {t.trial_id: t for t in read_trials(REPO / "experiments" / "data" / "default.h5")}
    ref = bundled["T01"]
    assert fresh.kind == ref.kind == "impulse"
    for ch in ("t", "force", "dtheta"):
        np.testing.assert_array_equal(getattr(fresh, ch), getattr(ref, ch))
    assert fresh.sensors == ref.sensors


def test_switched_off_truth_gives_the_model_trials_bit_for_bit(door, default):
    """Stribeck ratio 1, no handle, ideal sensors: the door's own trials, all kinds."""
    campaign = rig.Campaign(users=3, trials=4, seed=2)
    plain = rig.generate_trials(door, default, campaign, progress=False)
    off_truth = rig.make_truth(door, default, "rich", OFF)
    off = rig.generate_trials(door, default, campaign, truth=off_truth, progress=False)
    assert [t.kind for t in off] == ["impulse", "unlock", "impulse", "lock"]
    for a, b in zip(plain, off):
        for ch in ("t", "force", "theta", "dtheta"):
            x, y = getattr(a, ch), getattr(b, ch)
            assert (x is None) == (y is None)
            if x is not None:
                np.testing.assert_array_equal(x, y)
        assert a.sensors == b.sensors
        assert b.truth["params"] == a.truth["params"] and b.truth["model"] == "door"
        assert b.truth["variant"] == "rich"
        assert b.truth["effects"]["params"]["stribeck_ratio"] == 1.0


def test_rich_truth_differs_and_records_its_sensors(door, default):
    (plain,) = rig.generate_trials(
        door, default, rig.Campaign(users=1, trials=1, seed=5), progress=False
    )
    (rich,) = rig.generate_trials(
        door, default, rig.Campaign(users=1, trials=1, seed=5), truth="rich", progress=False
    )
    assert rich.kind == "impulse"
    assert rich.sensors["dtheta"]["bandwidth"] == 40.0 and rich.sensors["dtheta"]["order"] == 1
    assert rich.sensors["force"]["bandwidth"] == 200.0 and rich.sensors["force"]["order"] == 2
    assert rich.truth["effects"]["units"]["handle_play"] == "m"
    assert rich.truth["method"] == "rk4" and rich.truth["substeps"] == 4
    n = min(plain.t.size, rich.t.size)
    assert np.max(np.abs(plain.dtheta[:n] - rich.dtheta[:n])) > math.radians(1.0)


# -- Stribeck friction --------------------------------------------------------------------
def test_stribeck_factor_is_the_declared_curve():
    v = np.array([0.0, 1e-4, 0.003, 0.005, 0.02, 1.0])
    got = np.array([stribeck_factor(x, 0.005, 1.8) for x in v])
    np.testing.assert_allclose(got, 1.0 + 0.8 * np.exp(-((v / 0.005) ** 2)), rtol=1e-14)
    assert got[0] == 1.8 and stribeck_factor(-1e-4, 0.005, 1.8) == got[1]
    assert stribeck_factor(1e-4, 0.005, 1.0) == 1.0


def hold_force(f, p, theta, dtheta):
    """Force at the handle holding the door at ``theta`` moving at ``dtheta`` (accel = 0);
    accel is affine in the force."""
    a0, a1 = f(theta, dtheta, 0.0, p), f(theta, dtheta, 1.0, p)
    return -a0 / (a1 - a0)


def friction_at_handle(f, p, theta, speed):
    """Half the difference of the hold forces closing and opening: spring and gravity
    cancel, friction remains (N at the handle)."""
    return 0.5 * (hold_force(f, p, theta, speed) - hold_force(f, p, theta, -speed))


@pytest.mark.parametrize("deg", [10.0, 40.0, 70.0])
def test_breakaway_is_the_stribeck_ratio_times_coulomb(door, deg):
    """Quasi-static: creeping far below the Stribeck speed (tanh saturated) the door's
    friction at the handle is ``stribeck_ratio`` times the door model's; fast, the same.

    With mu = 0 every friction is a fixed magnitude, so the ratio is exact; the slot's
    friction grows with the normal force that the other frictions load it with, so with
    the default mu the whole door's breakaway exceeds the ratio (checked too).
    """
    theta = math.radians(deg)
    for mu, exact in ((0.0, True), (0.8065, False)):
        p = param_vector(door.load_params("default", {"a": 1e6, "a_rot": 1e5, "mu": mu}))
        values = {"stribeck_ratio": 1.7, "stribeck_speed": 0.1, "stribeck_speed_rot": 10.0}
        pq = np.concatenate([p, param_vector(load_truth_params(None, values), TABLE)])
        creep = 1e-3  # rad/s: slip 3.5e-5 m/s at the pads, a * v >= 35, v / v_s <= 4e-4
        coulomb = friction_at_handle(door_accel, p, theta, creep)
        breakaway = friction_at_handle(rigid_accel, pq, theta, creep)
        assert coulomb > 1.0
        if exact:
            assert breakaway / coulomb == pytest.approx(1.7, rel=1e-6)
        else:
            assert 1.75 < breakaway / coulomb < 3.0
    # well above every Stribeck speed the truth's friction is the Coulomb level
    fast = {"stribeck_ratio": 1.7, "stribeck_speed": 1e-4, "stribeck_speed_rot": 1e-3}
    pq = np.concatenate([p, param_vector(load_truth_params(None, fast), TABLE)])
    assert friction_at_handle(rigid_accel, pq, theta, 1.0) == pytest.approx(
        friction_at_handle(door_accel, p, theta, 1.0), rel=1e-9
    )


# -- the handle: rigid limit, play, energy -------------------------------------------------
def test_a_stiff_handle_without_play_is_the_door(door, default):
    """The handle's mass is taken out of the leaf, so a stiff mount gives the door back
    (the error falls as the mount stiffens)."""
    force = push()
    ref = simulate(door, default, force, DT, theta0=0.3)
    errors = []
    for k, steps in ((1e6, 8), (1e7, 32)):
        stiff = dict(
            OFF, handle_mass=0.2, handle_stiffness=k, handle_damping=2 * math.sqrt(0.2 * k),
            handle_contact_width=1e-6,
        )  # fmt: skip
        tr = make_truth(door, default, stiff, steps)
        out, _, ok = tr.simulate(force, DT, tr.state(0.3, 0.0))
        assert ok
        errors.append(np.max(np.abs(out["dtheta"] - ref.dtheta)))
    assert errors[0] < 1e-3 * np.max(np.abs(ref.dtheta)) * 2 and errors[1] < 0.5 * errors[0]


def test_the_door_feels_nothing_until_the_handle_crosses_its_play(door, default):
    """Handle in the middle of a 4 mm play, a constant 5 N push: the door's motion is
    exactly the unpushed one until the handle (0.1 kg) has crossed 2 mm, which takes
    t* = sqrt(2 * 0.002 / (F / m - g cos(theta))), then it is pushed."""
    values = dict(OFF, handle_mass=0.1, handle_play=0.004)
    tr = make_truth(door, default, values)
    theta0, n, f = 0.5, 60, 5.0
    start = tr.state(theta0, 0.0)
    pushed, _, _ = tr.simulate(np.full(n, f), DT, start)
    free, _, _ = tr.simulate(np.zeros(n), DT, start)
    t_star = math.sqrt(2 * 0.002 / (f / 0.1 - GRAVITY * math.cos(theta0)))
    before = int(0.9 * t_star / DT)
    after = int(math.ceil(1.3 * t_star / DT))
    assert before >= 8
    np.testing.assert_array_equal(pushed["theta"][:before], free["theta"][:before])
    assert np.all(pushed["dtheta"][after:] - free["dtheta"][after:] > 1e-4)


def test_handle_rattle_conserves_energy_without_friction_or_damping(door):
    """Frictionless door, handle free in a 1 mm play with an undamped mount: the
    mechanical energy (door, handle, its gravity and the mount's spring) is constant."""
    frictionless = {n: 0.0 for n in ("T_atO", "T_atA", "T_atB", "mu", "F_atC", "F_atD")}
    params = door.load_params("default", frictionless)
    m, play, k, w = 0.1, 0.001, 3.0e4, 1.0e-4
    free = dict(
        OFF, handle_mass=m, handle_play=play, handle_damping=0.0, handle_stiffness=k,
        handle_contact_width=w,
    )  # fmt: skip
    tr = make_truth(door, params, free)
    out, _, ok = tr.simulate(np.zeros(205), DT, np.array([0.5, 0.3, 0.5, 0.3]))
    assert ok
    L = params["L"]
    x = L * (out["theta_h"] - out["theta"])
    assert np.max(np.abs(x)) > 0.5 * play  # it does hit the mount
    pen = np.maximum(np.abs(x) - 0.5 * play, 0.0)
    spring = np.where(
        pen < w, k * pen**3 / (6 * w), k * w * w / 6 + 0.5 * k * ((pen - 0.5 * w) ** 2 - w * w / 4)
    )
    e = np.array([energy(a, b, tr.pq) for a, b in zip(out["theta"], out["dtheta"])])
    e += 0.5 * m * (L * out["dtheta_h"]) ** 2 + m * GRAVITY * L * np.sin(out["theta_h"]) + spring
    assert np.ptp(e) < 1e-6  # J, of ~0.05 J kinetic


def test_handle_mass_is_taken_out_of_the_door(door, default):
    leaf = truth_module.leaf_params(param_vector(default), 0.1)
    t = door.params
    m, gx, iz = (leaf[t.index(n)] for n in ("M", "G_x", "I_z"))
    assert m == pytest.approx(default["M"] - 0.1)
    # centre of mass and moment of inertia about O of leaf + handle at E are the door's
    assert (m * gx + 0.1 * default["L"]) / default["M"] == pytest.approx(default["G_x"])
    io = default["I_z"] + default["M"] * default["G_x"] ** 2
    assert iz + m * gx**2 + 0.1 * default["L"] ** 2 == pytest.approx(io, rel=1e-12)


# -- sensor dynamics -----------------------------------------------------------------------
def filtered(base, bandwidth, order):
    quiet = replace(base, noise_std=0.0, bias_std=0.0, resolution=0.0)
    return FilteredSensor(**asdict(quiet), bandwidth=bandwidth, order=order)


def test_first_order_step_response_is_the_analytic_one():
    """A sampled step (linear over the first sample, as the rig's signals are) through a
    40 Hz single pole: y(t) = 1 - (exp(-w (t - dt)) - exp(-w t)) / (w dt) for t >= dt."""
    s = filtered(GYROSCOPE, 40.0, 1)
    x = np.ones(200)
    x[0] = 0.0
    y = s.respond(x, DT)
    w = 2 * math.pi * 40.0
    t = DT * np.arange(200)
    exact = 1.0 - (np.exp(-w * (t - DT)) - np.exp(-w * t)) / (w * DT)
    np.testing.assert_allclose(y[1:], exact[1:], atol=1e-12)
    assert y[0] == 0.0


@pytest.mark.parametrize(
    ("base", "bandwidth", "order"), [(LOAD_CELL, 200.0, 2), (GYROSCOPE, 40.0, 1)]
)
def test_sensor_lowpass_matches_scipy_and_its_bandwidth(base, bandwidth, order):
    s = filtered(base, bandwidth, order)
    num, den = s.transfer()
    # the declared bandwidth is the -3 dB point of the analog system
    _, h = signal.freqs(num, den, worN=[2 * math.pi * bandwidth])
    assert abs(h[0]) == pytest.approx(1 / math.sqrt(2), rel=1e-12)
    # the sampled response is the analog one to the linearly interpolated input
    rng = np.random.default_rng(3)
    t = DT * np.arange(600)
    x = np.cumsum(rng.normal(size=t.size))
    x -= x[0]
    _, ref, _ = signal.lsim(signal.lti(num, den), x, t)
    np.testing.assert_allclose(s.respond(x, DT), ref, atol=1e-9 * np.max(np.abs(x)))
    # steady state at the bandwidth: amplitude 1/sqrt(2); far below it: 1. Sampled 64
    # times per period of the bandwidth (at 1024 Hz, a 200 Hz sine drawn through its
    # samples is itself 12 % smaller than the sine: that is the sampling, not the sensor)
    dt = 1.0 / (64 * bandwidth)
    for f, gain in ((bandwidth, 1 / math.sqrt(2)), (bandwidth / 20, 1.0)):
        t = dt * np.arange(int(round(40 / (f * dt))))
        y = s.respond(np.sin(2 * math.pi * f * t), dt)
        # amplitude over the last half (least squares on sin and cos)
        late = t >= 0.5 * t[-1]
        basis = np.column_stack(
            [np.sin(2 * math.pi * f * t[late]), np.cos(2 * math.pi * f * t[late])]
        )
        a, b = np.linalg.lstsq(basis, y[late], rcond=None)[0]
        assert math.hypot(a, b) == pytest.approx(gain, rel=0.01)


def test_sensor_dynamics_are_causal_and_start_at_rest():
    s = filtered(LOAD_CELL, 100.0, 2)
    x = np.full(100, 7.0)
    x[50:] += 3.0
    y = s.respond(x, DT)
    # nothing before the change (the input ramps from sample 49 to 50)
    np.testing.assert_allclose(y[:50], 7.0, rtol=1e-12)
    assert y[60] > 7.5 and y[-1] == pytest.approx(10.0, rel=1e-6)
    ideal = replace(s, bandwidth=0.0)
    assert ideal.respond(x, DT) is x and SEED_SENSORS["force"].respond(x, DT) is x


# -- command line --------------------------------------------------------------------------
def test_cli_rich_truth_is_recorded_in_the_file(tmp_path, capsys):
    out = tmp_path / "rich.h5"
    res = cli(
        capsys, "rig", "generate", "--model", "door", "--params", "default", "--trials", "1",
        "--seed", "3", "--truth", "rich", "--truth-set", "stribeck_ratio=2",
        "--truth-set", "gyroscope_bandwidth=25", "--out", out,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    (trial,) = read_trials(out)
    assert trial.truth["model"] == "door" and trial.truth["params_source"] == "default"
    assert trial.truth["params"]["F_atD"] == get_model("door").load_params("default")["F_atD"]
    effects = trial.truth["effects"]
    assert trial.truth["variant"] == "rich"
    assert effects["params"]["stribeck_ratio"] == 2.0
    assert effects["params"]["handle_mass"] == TABLE["handle_mass"].default
    assert effects["params_source"] == "defaults, changed: gyroscope_bandwidth, stribeck_ratio"
    assert trial.sensors["dtheta"]["bandwidth"] == 25.0
    with h5py.File(out) as f:
        assert "truth rich" in str(f.attrs.get("description", ""))


def test_show_scores_a_fit_of_rich_trials_against_the_door_values(tmp_path, capsys):
    data, run = tmp_path / "rich.h5", tmp_path / "run.h5"
    args = ("--users", "3", "--trials", "3", "--kinds", "impulse", "--seed", "1")
    res = cli(capsys, "rig", "generate", "--model", "door", "--params", "default", *args,
              "--truth", "rich", "--out", data)  # fmt: skip
    assert res.returncode == 0, res.stderr
    res = cli(
        capsys, "run", REPO / "experiments" / "default.yaml", "--out", run, "--quiet",
        "--set", f"target.data={data}", "--set", "target.validate=[]",
        "--set", "algorithm.population=6", "--set", "algorithm.generations=1",
        "--set", "algorithm.polish=none",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    res = cli(capsys, "show", run, "--json")
    assert json.loads(res.stdout)["truth"] == {"F_load": 101.45, "M": 1.232, "F_atD": 18.8}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--truth", "rihc"), "unknown truth 'rihc' (did you mean 'rich'?)"),
        (("--truth-set", "stribeck_ratio=2"), "need the rich truth (--truth rich)"),
        (("--truth", "rich", "--truth-set", "stribeck_ratio=0.5"), "'stribeck_ratio' = 0.5"),
        (("--truth", "rich", "--truth-set", "stribek_ratio=2"), "did you mean 'stribeck_ratio'"),
        (("--truth", "rich", "--truth-set", "stribeck_ratio"), "expected NAME=VALUE"),
        (("--truth", "rich", "--truth-set", "handle_mass=0"), "handle_play needs a handle_mass"),
        (("--truth", "rich", "--truth-set", "handle_mass=1.5"), "not smaller than the door's mass"),
        (("--truth", "rich", "--model", "haptic"), "use --model door"),
    ],
)
def test_bad_truth_values_are_one_line_errors(tmp_path, capsys, args, message):
    out = tmp_path / "never.h5"
    base = ["rig", "generate", "--model", "door", "--trials", "1", "--out", out]
    if "--model" in args:
        base = ["rig", "generate", "--trials", "1", "--out", out]
    res = cli(capsys, *base, *args)
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("evo-door: error: ")
    assert message in res.stderr
    assert not out.exists()


def test_library_errors():
    door = get_model("door")
    params = door.load_params("default")
    with pytest.raises(UserError, match="integrated by rk4"):
        DoorTruth(door, params, load_truth_params(), method="semi_implicit")
    with pytest.raises(UserError, match="order must be 1 or 2"):
        filtered(LOAD_CELL, 100.0, 3)
    with pytest.raises(UserError, match="bandwidth must be"):
        filtered(LOAD_CELL, -1.0, 2)
    with pytest.raises(UserError, match="sample period"):
        filtered(LOAD_CELL, 100.0, 2).respond(np.ones(4), 0.0)
