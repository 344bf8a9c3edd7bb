"""Dry friction of 20 N rendered in the servo loop: the implicit law holds and releases.

A SimDevice at 2500 Hz (40 N s/m damping, which the tanh law's explicitly sampled end
stops need to pass the passivity check; 0.05 N sensor noise) renders
the seed_trial set with both friction levels at 20 N and a hand that pushes the
handle along the door's tangent: 0.5 N, then 15 N (below the level: must hold), then
25 N (above: must slide). The model's tanh at friction_slope 1000 s/rad (velocity
scale 0.3 mm/s, explicit bound 2 m v_s / T = 6 N) rings instead.
"""

from __future__ import annotations

import numpy as np
import pytest

from evo_door.cli import main
from evo_door.files import open_h5, read_attrs
from evo_door.models import get_model
from evo_door.render import friction as fr
from evo_door.render.columns import DTHETA, THETA
from evo_door.render.device import ForceScript, SimDevice
from evo_door.render.kernels import compute_command_implicit
from evo_door.render.loop import ServoLoop

# compared against references: run again on a generic CPU in CI (pyproject markers)
pytestmark = pytest.mark.numerics

RATE = 2500.0
SLOPE = 1000.0  # s/rad
SEGMENTS = ((0.5, 0.2), (15.0, 0.4), (25.0, 0.3))  # (N toward closing, s)


@pytest.fixture(scope="module")
def twenty_newton():
    base = get_model("haptic").load_params("seed_trial")
    return base.replace(
        {"friction_closing": 20.0, "friction_opening": 20.0, "friction_slope": SLOPE}
    )


def _push(params, friction=None):
    """dtheta (rad/s) and theta (rad) at every cycle, per segment (first 40 ms cut)."""
    dev = SimDevice(ForceScript("push", 0.8, SEGMENTS), seed=3, damping=40.0)
    kwargs = {} if friction is None else {"friction": friction}
    loop = ServoLoop(dev, params, RATE, log_rate=RATE, **kwargs)
    loop.run(sum(d for _, d in SEGMENTS))
    a = loop.log.array()
    out, start = [], 0
    for _, duration in SEGMENTS:
        n = int(round(duration * RATE))
        out.append((a[start + 100 : start + n, 13], a[start + 100 : start + n, 12]))
        start += n
    return loop, out


def test_the_stability_bound_of_the_tanh_law_is_below_the_level(twenty_newton):
    m = twenty_newton["inertia"] / twenty_newton["radius"]  # 4 kg
    v_s = twenty_newton["radius"] / SLOPE
    assert fr.tanh_stability_limit(m, v_s, 1.0 / RATE) == pytest.approx(6.0)


def test_implicit_friction_holds_at_15_newton_and_releases_at_25(twenty_newton):
    loop, ((v0, th0), (v15, th15), (v25, th25)) = _push(twenty_newton)  # the default law
    assert loop.statistics["friction"] == "implicit"
    for v, th in ((v0, th0), (v15, th15)):
        # still: only the sensor noise's jitter (0.05 N on 4 kg), no drift, no reversals
        assert np.abs(v).max() < 2e-4  # rad/s (the tanh law creeps at ~1e-3)
        assert abs(th[-1] - th[0]) < 1e-5  # rad
        assert fr.sign_changes(v, eps=1e-4) == 0
    # 25 N against 20 N: slides toward closing, never reverses, speeds up
    assert v25.min() > 0.0
    assert v25[-1] > 0.1  # rad/s
    assert th25[-1] - th25[0] > 0.02  # rad
    assert fr.sign_changes(v25 - v25.mean(), eps=1e-4) < 5


def test_tanh_friction_at_the_same_level_rings_and_does_not_decay(twenty_newton):
    loop, ((v0, _), (v15, th15), _) = _push(twenty_newton, "tanh")
    assert loop.statistics["friction"] == "tanh"
    # a light touch (0.5 N): a buzz through zero at half the loop rate
    assert fr.sign_changes(v0, eps=1e-4) > 100
    # under 15 N: creeps (cannot hold) and oscillates about its creep speed
    swing = v15 - v15.mean()
    assert fr.sign_changes(swing, eps=1e-4) > 200
    half = len(swing) // 2
    assert np.ptp(swing[half:]) > 0.5 * np.ptp(swing[:half]) > 1e-3  # not decaying
    assert th15[-1] - th15[0] > 1e-4  # rad


def test_implicit_friction_never_reverses_a_sliding_handle():
    """One cycle, any level: the step it implies stops the handle at most, never past."""
    p = get_model("haptic").load_params("seed_trial")
    rng = np.random.default_rng(7)
    from evo_door.models.haptic import PARAMS, on_path
    from evo_door.params import param_vector

    out, row = np.zeros(3), np.zeros(15)
    m, T = 4.0, 1.0 / RATE
    for level in (5.0, 20.0, 80.0):
        vec = param_vector(p.replace({"friction_closing": level, "friction_opening": level}))
        free = vec.copy()
        free[PARAMS.index("friction_closing")] = 0.0
        free[PARAMS.index("friction_opening")] = 0.0
        for _ in range(200):
            theta = rng.uniform(0.2, 1.2)
            pos = np.array(on_path(theta, p["radius"]))
            e_t = np.array([0.0, np.cos(theta), -np.sin(theta)])
            v_t = rng.uniform(-0.5, 0.5)
            vel = v_t * e_t
            user = rng.uniform(-40.0, 40.0) * e_t
            compute_command_implicit(pos, vel, user, vec, free, m, T, 0.0, 200.0, out, row)
            f_total = (out + user) @ e_t
            v_next = v_t + T * f_total / m
            assert v_next * v_t >= -1e-12 or abs(user @ e_t) > level  # no reversal by friction


def test_render_cli_takes_the_friction_law_and_logs_it(tmp_path, capsys):
    args = ["render", "--params", "seed_trial", "--device", "sim", "--user", "hold"]
    for law in ("tanh", "implicit"):
        log = tmp_path / f"{law}.h5"  # a render log is replaced only with --force
        # implicit: the default; tanh samples the end stops explicitly: damping needed
        extra = ["--friction", law, "--device-damping", "40"] if law == "tanh" else []
        assert main([*args, "--duration", "0.2", *extra, "--log", str(log)]) == 0
        with open_h5(log) as f:
            render = read_attrs(f["render"])
        assert render["statistics"]["friction"] == law
        assert any(e["kind"] == "friction" and law in e["message"] for e in render["events"])
    with pytest.raises(SystemExit):
        main([*args, "--duration", "0.2", "--friction", "coulomb"])


# -- stiff springs: the end stops and the latch ---------------------------------------
def _free_door(stop_stiffness):
    """seed_trial with nothing but the end stop's spring along the tangent: no
    friction, no damping, no latch; the stop undamped (a pure spring)."""
    zero = ("stop_damping", "close_force", "open_force", "seat_force", "gasket_stiffness")
    zero += ("friction_closing", "friction_opening", "viscous_damping", "transition_damping")
    base = get_model("haptic").load_params("seed_trial")
    return base.replace({**dict.fromkeys(zero, 0.0), "stop_stiffness": stop_stiffness})


def _rebound(params, implicit, device_damping=0.0):
    """Speed ratio out / in of the door thrown against the closed stop (no hand on it).

    A SimDevice without damping or friction of its own, driven cycle by cycle by the
    loop's kernels: a 20 N push for 50 ms from 1.53 rad, then nothing."""
    from evo_door.models.haptic import PARAMS
    from evo_door.params import param_vector
    from evo_door.render.kernels import compute_command

    m = params["inertia"] / params["radius"]
    dev = SimDevice(
        ForceScript("throw", 1.53, ((20.0, 0.05),)), mass=m, damping=device_damping, coulomb=0.0
    )
    p = param_vector(params, PARAMS)
    out, row = np.zeros(3), np.zeros(15)
    w = np.zeros(2500)
    theta = np.zeros(2500)
    for i in range(w.size):
        pos, vel, f = dev.read()
        if implicit:
            compute_command_implicit(pos, vel, f, p, p, m, 1 / RATE, dev.damping, 200.0, out, row)
        else:
            compute_command(pos, vel, f, p, 200.0, out, row)
        dev.command(out)
        dev.step(1 / RATE)
        theta[i], w[i] = row[THETA], row[DTHETA]
    hit = int(np.flatnonzero(theta > np.pi / 2)[0])
    assert w[hit - 1] > 0.5 and theta[hit + 400] < np.pi / 2  # it came in fast, bounced out
    return -w[hit + 200 : hit + 400].min() / w[hit - 1]


@pytest.mark.parametrize("stiffness", [2.0e4, 1.0e5])  # N/rad: seed_trial's, the bound
def test_an_undamped_stop_rendered_implicitly_never_returns_more_than_it_took(stiffness):
    """Passivity where it shows: with no damping anywhere, the explicitly sampled stop
    (K T / 2 = 13-67 N s/m of energy leak) throws the door back faster than it came;
    the step solved implicitly returns it slower, at either stiffness."""
    door = _free_door(stiffness)
    assert _rebound(door, implicit=True) < 0.97
    assert _rebound(door, implicit=False) > 1.02


def test_the_latch_at_the_seeds_stiffness_holds_then_releases_without_ringing():
    """seed_trial's latch (2000 N/rad; the seed's own was 1000) made a pure spring
    (latch_damping 0): a hand pulling 10 N, half the unlock force, holds the door in
    the unlock band, still; 25 N pulls it through, opening without a reversal."""
    params = get_model("haptic").load_params("seed_trial").replace({"latch_damping": 0.0})
    segments = ((-10.0, 0.6), (-25.0, 0.4))
    dev = SimDevice(ForceScript("pull", np.pi / 2 - params["loose_angle"], segments), seed=4)
    loop = ServoLoop(dev, params, RATE, log_rate=RATE)
    loop.run(1.0)
    a = loop.log.array()
    theta, w = a[:, THETA], a[:, DTHETA]
    band = np.pi / 2 - params["loose_angle"] - params["open_force"] / params["latch_stiffness"]
    held = w[1000:1500]  # 0.4-0.6 s
    assert np.all(theta[:1500] > band)  # never left the band under 10 N
    assert np.abs(held).max() < 1e-3  # rad/s: still
    released = w[1510:]
    assert theta[-1] < band - 0.1  # through the latch and opening
    assert released.max() < 1e-3  # toward opening all along, no reversal
