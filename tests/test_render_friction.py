"""Stable dry friction and stiff springs for rendering (evo_door.render.friction)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from evo_door.errors import UserError
from evo_door.models import haptic
from evo_door.params import param_vector
from evo_door.render import friction as fr

# compared against references: run again on a generic CPU in CI (pyproject markers)
pytestmark = pytest.mark.numerics

T = 1.0 / fr.DEFAULT_RATE  # s, the HapticMaster's servo period
M = 4.0  # kg, the seed's virtual mass (inertia 1.2 kg m / radius 0.3 m)


def run(profile, f_c, law, slope=0.0, v0=0.0, delay=0, mass=M, period=T):
    return fr.simulate_friction(
        np.asarray(profile, dtype=float), mass, period, f_c, slope, law, v0, delay
    )


# -- the implicit law ---------------------------------------------------------------
def test_implicit_holds_a_push_below_the_level_exactly_still():
    x, v, f = run(fr.force_profile([(15.0, 0.5)], T), 20.0, fr.LAW_IMPLICIT)
    assert np.all(v == 0.0) and np.all(x == 0.0)
    np.testing.assert_allclose(f, -15.0, rtol=1e-14)  # friction cancels the push


def test_implicit_releases_a_push_above_the_level_with_the_net_force():
    n = 1000
    x, v, f = run(np.full(n, 25.0), 20.0, fr.LAW_IMPLICIT)
    accel = np.diff(v) / T
    np.testing.assert_allclose(accel, (25.0 - 20.0) / M, rtol=1e-9)
    np.testing.assert_allclose(f, -20.0, rtol=0, atol=0)
    # position of the symplectic update: x_n = a T^2 n (n + 1) / 2
    np.testing.assert_allclose(x[-1], 1.25 * T * T * n * (n + 1) / 2, rtol=1e-9)


def test_implicit_push_hold_release_has_no_oscillation_and_ends_at_rest():
    # break away at 25 N, ease to 15 N (slows down, sticks), let go
    profile = fr.force_profile([(0.0, 0.1), (25.0, 0.3), (15.0, 0.3), (0.0, 0.3)], T)
    x, v, f = run(profile, 20.0, fr.LAW_IMPLICIT)
    assert fr.sign_changes(v) == 0
    assert v.max() > 0.3  # it did slide (1.25 m/s^2 for 0.3 s = 0.375 m/s)
    # after the 15 N phase began it decelerates at 5/4 m/s^2 and sticks in 0.3 s
    n_stick = int(round(0.4 / T)) + int(math.ceil(0.375 / 1.25 / T)) + 2
    assert np.all(v[n_stick:] == 0.0)
    assert np.all(x[n_stick:] == x[-1])


def test_implicit_never_reverses_the_motion_random_states():
    """The friction never pushes the velocity through zero, and never exceeds F_c."""
    rng = np.random.default_rng(14)
    for _ in range(2000):
        m, per = rng.uniform(0.05, 20.0), rng.uniform(1e-4, 1e-2)
        f_fwd, f_bwd = rng.uniform(0.0, 200.0, size=2)
        v, force = rng.normal(0, 1.0), rng.normal(0, 50.0)
        v_next, f = fr.implicit_coulomb_step(v, force, m, per, f_fwd, f_bwd)
        v_free = v + per * force / m
        assert -f_fwd <= f <= f_bwd
        assert v_next == 0.0 or np.sign(v_next) == np.sign(v_free)
        assert abs(v_next) <= abs(v_free)
        np.testing.assert_allclose(v_next, v_free + per * f / m, rtol=1e-12, atol=1e-12)
        if v_next != 0.0:  # sliding: the full level against the motion
            assert f == (-f_fwd if v_next > 0 else f_bwd)
        assert fr.implicit_coulomb(v, force, m, per, f_fwd, f_bwd) == pytest.approx(f, rel=1e-12)


def test_implicit_asymmetric_levels():
    # at rest, 2 N forward friction and 1 N backward: a 1.5 N push sticks one way only
    v, f = fr.implicit_coulomb_step(0.0, 1.5, M, T, 2.0, 1.0)
    assert v == 0.0 and f == pytest.approx(-1.5)
    v, f = fr.implicit_coulomb_step(0.0, -1.5, M, T, 2.0, 1.0)
    assert v < 0.0 and f == 1.0


def test_implicit_stops_a_moving_mass_in_the_predicted_number_of_steps():
    v0 = 0.5
    x, v, f = run(np.zeros(2000), 20.0, fr.LAW_IMPLICIT, v0=v0)
    kinetic = 0.5 * M * v**2
    assert np.all(np.diff(kinetic) <= 0.0)
    steps = int(np.argmax(v == 0.0))
    assert steps == math.ceil(v0 * M / (20.0 * T))


# -- the explicit tanh law --------------------------------------------------------
def test_tanh_friction_is_the_haptic_models_dry_friction():
    p = param_vector(haptic.MODEL.load_params("seed_trial"), haptic.PARAMS)
    for name in ("viscous_damping", "open_force", "close_force", "gasket_stiffness"):
        p[haptic.PARAMS.index(name)] = 0.0
    p[haptic.FRICTION_OPENING] = p[haptic.FRICTION_CLOSING] = 20.0
    radius, slope = p[haptic.RADIUS], p[haptic.FRICTION_SLOPE]
    for dtheta in (-0.3, -0.004, -1e-4, 0.0, 2e-3, 0.05, 1.0):
        expected = haptic.tangential_force(0.8, dtheta, p)
        got = fr.tanh_friction(radius * dtheta, 20.0, slope / radius)
        assert got == pytest.approx(expected, rel=1e-12, abs=1e-12)


def _tail_amplitude(v, n=400):
    return float(np.abs(v[-n:]).max())


@pytest.mark.parametrize("ratio", [0.9, 0.97])
def test_tanh_is_stable_below_the_limit(ratio):
    v_s = 0.001
    f_c = ratio * fr.tanh_stability_limit(M, v_s, T)
    x, v, f = run(np.zeros(3000), f_c, fr.LAW_TANH, slope=1.0 / v_s, v0=0.01)
    assert _tail_amplitude(v) < 1e-9


@pytest.mark.parametrize("ratio", [1.03, 1.2, 2.0])
def test_tanh_rings_above_the_limit_on_the_predicted_cycle(ratio):
    """Above 2 m v_s / T: a period-2 buzz at +-v_s u, 2 u = k tanh(u), that never decays.

    The onset is the linear bound exactly (the rest state's one-step gain is
    1 - k); 3 % above it the cycle is already 0.3 v_s and measured to 1e-6.
    """
    v_s = 0.001
    limit = fr.tanh_stability_limit(M, v_s, T)
    f_c = ratio * limit
    x, v, f = run(np.zeros(6000), f_c, fr.LAW_TANH, slope=1.0 / v_s, v0=1e-6)
    tail = v[-400:]
    assert fr.sign_changes(tail) == len(tail) - 1  # reverses every sample
    k = T * f_c / (M * v_s)
    u = brentq(lambda s: k * math.tanh(s) - 2.0 * s, 1e-9, k)  # independent root
    assert fr.limit_cycle_amplitude(k) == pytest.approx(u, rel=1e-9)
    np.testing.assert_allclose(np.abs(tail), v_s * u, rtol=1e-6)
    # not decaying: the second half of the tail as large as the first
    assert np.abs(tail[200:]).min() >= 0.999 * np.abs(tail[:200]).max()


def test_tanh_onset_with_a_one_step_delay_is_half():
    v_s = 0.001
    limit = fr.tanh_stability_limit(M, v_s, T, delay=1)
    assert limit == pytest.approx(0.5 * fr.tanh_stability_limit(M, v_s, T))
    _, v_lo, _ = run(np.zeros(4000), 0.95 * limit, fr.LAW_TANH, 1.0 / v_s, 1e-4, delay=1)
    _, v_hi, _ = run(np.zeros(4000), 1.05 * limit, fr.LAW_TANH, 1.0 / v_s, 1e-4, delay=1)
    assert _tail_amplitude(v_lo) < 1e-9
    assert _tail_amplitude(v_hi) > 0.1 * v_s  # sustained (grew from 1e-4 / 10 of v_s)
    assert fr.sign_changes(v_hi[-400:]) > 100


def test_seed_limit_and_20_newton_hold_and_release_where_tanh_buzzes():
    """The seed's set: 60 N at 2500 Hz, 12 N at 1 kHz with a one-cycle delay.

    At 1 kHz with one cycle of delay (an H3D-style haptics thread) the seed's tanh
    buzzes at 20 N; the implicit law holds 15 N still and releases at 25 N.
    """
    terms = fr.device_friction_terms(haptic.MODEL.load_params("seed_trial"))
    assert terms["mass"] == pytest.approx(4.0)
    assert terms["velocity_scale"] == pytest.approx(0.3 / 100.0)
    m, v_s = terms["mass"], terms["velocity_scale"]
    assert fr.tanh_stability_limit(m, v_s, T) == pytest.approx(60.0)
    period = 1e-3
    assert fr.tanh_stability_limit(m, v_s, period, delay=1) == pytest.approx(12.0)

    profile = fr.force_profile([(15.0, 0.5), (25.0, 0.2), (0.0, 0.5)], period)
    n_hold = int(round(0.5 / period))
    _, v_tanh, _ = run(profile, 20.0, fr.LAW_TANH, 1.0 / v_s, delay=1, period=period)
    _, v_imp, _ = run(profile, 20.0, fr.LAW_IMPLICIT, period=period)
    # implicit: still while held, slides at 5 N / 4 kg, stops without a reversal
    assert np.all(v_imp[: n_hold + 1] == 0.0)
    assert np.diff(v_imp[n_hold : n_hold + 150]) / period == pytest.approx(1.25, rel=1e-9)
    assert fr.sign_changes(v_imp) == 0 and v_imp[-1] == 0.0
    # tanh: never at rest after release; with the delay it buzzes on a 6-sample
    # cycle (loop rate / 6, 167 Hz here), ~2 v_s peak, not decaying
    tail = v_tanh[-300:]
    assert fr.sign_changes(tail) >= 90
    assert np.abs(tail[150:]).max() >= 0.99 * np.abs(tail[:150]).max() > 1.5 * v_s


# -- stiff springs (the latch) ------------------------------------------------------
def test_seed_latch_spring_is_far_inside_the_explicit_bound():
    terms = fr.device_friction_terms(haptic.MODEL.load_params("seed_trial"))
    k, c = terms["latch_stiffness"], terms["latch_damping"]
    assert k == pytest.approx(2000.0 / 0.3)
    limit = fr.spring_stability_limit(M, T, c)
    assert limit > 1e4 * k  # the virtual mass's update is not what limits the latch
    x, v = fr.simulate_spring(5000, M, T, k, c, 1e-3, False)
    energy = 0.5 * k * x**2 + 0.5 * M * v**2
    assert energy[-1] < 1e-3 * energy[0]


@pytest.mark.parametrize("damping", [0.0, 2000.0])
def test_spring_explicit_onset_matches_the_bound_and_implicit_is_stable(damping):
    limit = fr.spring_stability_limit(M, T, damping)
    x_lo, _ = fr.simulate_spring(2000, M, T, 0.98 * limit, damping, 1e-3, False)
    x_hi, _ = fr.simulate_spring(2000, M, T, 1.02 * limit, damping, 1e-3, False)
    assert np.abs(x_lo).max() < 0.1  # bounded (within 100 x the start)
    assert np.abs(x_hi[-1]) > 1e6
    for k in (1.02 * limit, 100.0 * limit):
        x, v = fr.simulate_spring(2000, M, T, k, damping, 1e-3, True)
        energy = 0.5 * k * x**2 + 0.5 * M * v**2
        assert np.all(np.diff(energy) <= 1e-12 * energy[0])


def test_implicit_spring_step_solves_the_backward_euler_system():
    k, c, x0, v0 = 5e7, 300.0, 2e-3, 0.0
    x, v = fr.simulate_spring(1, M, T, k, c, x0, True)
    # m (v1 - v0) / T = -k x1 - c v1,  x1 = x0 + T v1
    a = np.array([[M / T + c, k], [-T, 1.0]])
    b = np.array([M * v0 / T, x0])
    v1, x1 = np.linalg.solve(a, b)
    assert v[1] == pytest.approx(v1, rel=1e-12)
    assert x[1] == pytest.approx(x1, rel=1e-12)


# -- bad input ------------------------------------------------------------------------
def test_bad_input_raises_user_errors():
    with pytest.raises(UserError, match="positive"):
        fr.tanh_stability_limit(0.0, 0.003, T)
    with pytest.raises(UserError, match="delay"):
        fr.tanh_stability_limit(4.0, 0.003, T, delay=2)
    with pytest.raises(UserError, match="positive"):
        fr.spring_stability_limit(4.0, -1.0)
    with pytest.raises(UserError, match="durations"):
        fr.force_profile([(1.0, -0.1)], T)
    assert fr.limit_cycle_amplitude(2.0) == 0.0


# -- on the simulated device (R1's SimDevice behind the Device interface) ----------------
def _host_friction_run(law, f_c=20.0, v_s=0.3 / 400.0, seconds=3.0):
    """Host loop at 2500 Hz rendering only dry friction on a SimDevice under "open".

    The device renders its 4 kg natively, with no friction or damping of its own and
    no sensor noise; the virtual user's hand (a spring to a moving target, up to
    80 N) pulls the handle; the host commands the friction each cycle.
    """
    from evo_door.render.device import SimDevice

    device = SimDevice("open", mass=M, damping=0.0, coulomb=0.0, noise=0.0)
    device.start()
    out = np.zeros(3)
    n = int(seconds / T)
    vel_log, user_log = np.zeros((n, 3)), np.zeros((n, 3))
    try:
        for i in range(n):
            _, vel, user = device.read()
            if law == fr.LAW_IMPLICIT:
                fr.implicit_coulomb3(vel, user, M, T, f_c, out)
            else:
                speed = math.sqrt(float(vel @ vel))
                out[:] = 0.0 if speed == 0.0 else -f_c * math.tanh(speed / v_s) * vel / speed
            device.command(out)
            device.step(T)
            vel_log[i], user_log[i] = vel, user
    finally:
        device.stop()
    direction = vel_log.sum(axis=0) / np.linalg.norm(vel_log.sum(axis=0))
    return vel_log @ direction, np.linalg.norm(user_log, axis=1)


def test_sim_device_20_newton_friction_holds_and_releases_where_tanh_buzzes():
    """friction_slope 400 s/rad (v_s 0.75 mm/s): the tanh bound at 2500 Hz is 15 N."""
    assert fr.tanh_stability_limit(M, 0.3 / 400.0, T) == pytest.approx(15.0)
    v_imp, user_imp = _host_friction_run(fr.LAW_IMPLICIT)
    v_tanh, user_tanh = _host_friction_run(fr.LAW_TANH)
    tail = slice(-int(0.3 / T), None)
    # implicit: slides (the hand pulls past 20 N), never reverses, and ends held
    # still while the hand still pulls with ~19 N (< 20 N); residue is rounding
    assert np.abs(v_imp).max() > 0.1
    assert fr.sign_changes(v_imp, eps=1e-9) == 0
    assert np.all(user_imp[tail] > 15.0) and np.all(user_imp[tail] < 20.0)
    assert np.abs(v_imp[tail]).max() < 1e-15
    # tanh: buzzes (hundreds of reversals while the hand is below the level) and
    # cannot hold: it creeps at > v_s under the same sub-20 N pull
    assert fr.sign_changes(v_tanh, eps=1e-6) > 300
    assert np.all(user_tanh[tail] < 20.0)
    assert np.abs(v_tanh[tail]).min() > 0.3 / 400.0


def test_tanh_cannot_hold_a_push_below_its_level_it_creeps():
    v_s = 0.003  # the seed's 0.3 m / 100 s/rad, stable at 2500 Hz (bound 60 N)
    _, v, f = run(np.full(5000, 15.0), 20.0, fr.LAW_TANH, slope=1.0 / v_s)
    assert v[-1] == pytest.approx(v_s * math.atanh(15.0 / 20.0), rel=1e-9)
    _, v, _ = run(np.full(5000, 15.0), 20.0, fr.LAW_IMPLICIT)
    assert v[-1] == 0.0
