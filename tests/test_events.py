"""Event-heavy trials: the compiled integrators against an independent reference.

Each trial makes the integrators cross what :mod:`evo_door.sim.located` locates: the
latch's band edges, the stops, the speed's zero of stick-slip friction. The default
``simulate`` (each model's own method and settings) is held to
:func:`tests.reference.converged`, which solves the same model with scipy, segment by
segment between the same surfaces (issue 26's targets: 1e-2 rad/s, 1e-4 rad), and to
what physics says exactly: a door held by its friction does not move at all, it breaks
away at the instant the force reaches the friction level, and a stop never gives
energy back.
"""

import functools
import math

import numpy as np
import pytest
from numba import njit, types

from evo_door.models import get_model
from evo_door.models.door import energy
from evo_door.models.door.latch import latch_angles
from evo_door.models.haptic import latch_angles_of
from evo_door.sim import simulate
from evo_door.sim.integrators import (
    ACCEL_TYPE,
    integrate_compiled,
    kernel_form,
    scratch,
    try_span,
)
from evo_door.sim.located import SWITCHES_TYPE, advance_located, rate
from evo_door.sim.simulate import param_vector
from evo_door.sim.spans import MAX_SPAN, MIN_SPAN
from evo_door.sim_settings import DOPRI5, METHODS, tolerance_of
from tests.reference import converged

# compared against references: run again on a generic CPU in CI (pyproject markers)
pytestmark = pytest.mark.numerics

DT = 1.0 / 1024.0
CLOSED = 0.5 * math.pi
#: issue 26's targets for the default integrators on event-heavy trials
SPEED_TARGET = 1e-2  # rad/s
ANGLE_TARGET = 1e-4  # rad
PRESETS = {"haptic": "seed_trial", "door": "default"}


def times(seconds):
    return np.arange(int(round(seconds / DT))) * DT


def latch_band(name, ps):
    """``(lowest, highest)`` angle (rad) of the latch's bands: lock ramp's foot, catch."""
    if name == "haptic":
        a = latch_angles_of(ps)
        return a["theta_3"], a["theta_0"]
    theta_0, _apex, theta_3 = _door_latch(ps)
    return theta_3, theta_0


def apex(name, ps):
    """The angle (rad) where the latch lets an opening door go."""
    return latch_angles_of(ps)["theta_1"] if name == "haptic" else _door_latch(ps)[1]


def _door_latch(ps):
    names = ("unlock_force", "lock_force", "latch_loose_angle", "latch_open_stiffness")
    names += ("latch_close_stiffness", "latch_open_hold", "latch_close_hold")
    return latch_angles(*(ps[n] for n in names))


def pull(level, seconds=1.5):
    """A hand that pulls toward opening: up to ``level`` (N) over 0.4 s, holds it, lets
    go over 0.1 s from 0.8 s."""
    t = times(seconds)
    rise = np.clip((t - 0.1) / 0.4, 0.0, 1.0)
    fall = np.clip((t - 0.8) / 0.1, 0.0, 1.0)
    return -level * 0.25 * (1.0 - np.cos(np.pi * rise)) * (1.0 + np.cos(np.pi * fall))


# (amplitude N, period s, bias N) of the swing through the latch; at rest 0.2 s first
SWING = {"haptic": (25.0, 0.25, 5.0), "door": (60.0, 0.2, 10.0)}
# (mean N, amplitude N, frequency Hz) of the slow force about the friction levels,
# at 0.8 rad: the haptic door's levels are +1.5 / -1.0 N, the door's about +2.7 / -10.7
SLOW = {"haptic": (0.25, 1.6, 0.5), "door": (-4.0, 7.2, 0.5)}
# (theta0 rad, dtheta0 rad/s) of the throws, free of any hand
THROWN = {
    ("haptic", "open stop"): (0.2, -2.5),
    ("haptic", "closed wall"): (1.3, 3.0),
    ("door", "open stop"): (0.15, -4.0),
    ("door", "closed wall"): (1.2, 3.5),
}


def unlock_threshold(model, ps, theta0, rel=1e-3):
    """The least ``pull`` level (N) that unlocks the door, by bisection on ``simulate``
    (to ``rel``); where the trials below and above it are placed."""
    edge = apex(model.name, ps) - 0.01

    def opens(level):
        return simulate(model, ps, pull(level), DT, theta0=theta0).theta.min() < edge

    lo, hi = 1.0, 200.0
    assert not opens(lo) and opens(hi)
    while hi - lo > rel * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if opens(mid) else (mid, hi)
    return hi


def scenario(model, ps, kind):
    """``(force, theta0, dtheta0)`` of one event-heavy trial."""
    rest = CLOSED if model.name == "door" else latch_angles_of(ps)["theta_0"]
    if kind == "latch swing":
        amplitude, period, bias = SWING[model.name]
        t = times(1.5)
        force = np.where(t < 0.2, 0.0, bias - amplitude * np.sin(2 * np.pi * (t - 0.2) / period))
        return force, rest, 0.0
    if kind == "slow stick-slip":
        mean, amplitude, hz = SLOW[model.name]
        return mean + amplitude * np.sin(2 * np.pi * hz * times(3.0)), 0.8, 0.0
    if kind in ("open stop", "closed wall"):
        theta0, dtheta0 = THROWN[(model.name, kind)]
        return np.zeros(times(1.5).size), theta0, dtheta0
    factor = {"pull below unlock": 0.98, "pull above unlock": 1.02}[kind]
    return pull(factor * unlock_threshold(model, ps, rest)), rest, 0.0


def crossings(theta, lo, hi):
    """How many times ``theta`` goes from below ``lo`` to above ``hi`` or back."""
    side = np.where(theta < lo, -1, np.where(theta > hi, 1, 0))
    side = side[side != 0]
    return int(np.count_nonzero(np.diff(side)))


def exercised(name, ps, kind, theta, dtheta):
    """What the trial must show on the reference, or it tests nothing (a message if
    it does not)."""
    lo, hi = latch_band(name, ps)
    if kind == "latch swing":
        n = crossings(theta, lo - 0.002, hi)
        return None if n >= 6 else f"crosses the latch bands {n} times"
    if kind == "slow stick-slip":
        both = dtheta.max() > 0.05 and dtheta.min() < -0.05
        rest = np.count_nonzero(np.abs(dtheta) < 1e-3) > 100
        return None if both and rest else "does not slip both ways and rest between"
    if kind == "open stop":
        return None if theta.min() < -1e-3 else f"reaches {theta.min():.4f} rad only"
    if kind == "closed wall":
        return None if theta.max() > CLOSED + 2e-4 else f"reaches {theta.max():.4f} rad only"
    opened = theta.min() < apex(name, ps) - 0.01
    if opened != (kind == "pull above unlock"):
        return f"{'opens' if opened else 'stays latched'} (lowest {theta.min():.4f} rad)"
    return None


KINDS = (
    "latch swing",
    "slow stick-slip",
    "open stop",
    "closed wall",
    "pull below unlock",
    "pull above unlock",
)
#: (speed rad/s, angle rad) asserted per trial where the error measured (in the comment:
#: 2-core AMD EPYC, numba 0.68, 2026-11-26) is below a tenth of the issue's targets: at
#: least 5 times the measurement, 1e-8 at the least; else the targets
BOUNDS = {
    ("haptic", "latch swing"): (2e-3, 1e-5),  # 2.0e-4 rad/s, 1.7e-6 rad
    ("haptic", "slow stick-slip"): (1e-8, 1e-8),  # 1.3e-16 rad/s, 9.2e-11 rad
    ("haptic", "open stop"): (2e-5, 5e-8),  # 2.5e-6 rad/s, 9.8e-9 rad
    ("haptic", "closed wall"): (2e-4, 5e-5),  # 3.2e-5 rad/s, 6.6e-6 rad
    ("haptic", "pull below unlock"): (1e-4, 2e-6),  # 1.1e-5 rad/s, 2.9e-7 rad
    ("haptic", "pull above unlock"): (1e-5, 5e-8),  # 1.7e-6 rad/s, 6.5e-9 rad
    ("door", "slow stick-slip"): (2e-5, 1e-8),  # 2.4e-6 rad/s, 1.7e-9 rad
    ("door", "pull below unlock"): (5e-3, 1e-5),  # 6.2e-4 rad/s, 1.6e-6 rad
    # measured beyond the targets (RK4 x 2, the door's default), kept at the targets:
    # latch swing 1.5 rad/s, 2.7e-3 rad; open stop 5.7e-2 rad/s, 4.5e-4 rad; closed
    # wall 6.8e-2 rad/s, 2.8e-4 rad; pull above unlock 6.7e-2 rad/s, 1.7e-4 rad
}


@pytest.mark.slow
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("name", ["haptic", "door"])
def test_default_simulate_against_reference(name, kind):
    """The model's own method and settings within the bounds of :data:`BOUNDS` (the
    issue's targets at most) of the converged reference, on a trial that does cross
    what it is named after (:func:`exercised`, read on the reference)."""
    model = get_model(name)
    ps = model.load_params(PRESETS[name])
    force, theta0, dtheta0 = scenario(model, ps, kind)
    speed_bound, angle_bound = BOUNDS.get((name, kind), (SPEED_TARGET, ANGLE_TARGET))
    r = simulate(model, ps, force, DT, theta0=theta0, dtheta0=dtheta0)
    theta, dtheta = converged(
        model.accel,
        param_vector(ps),
        force,
        DT,
        theta0,
        dtheta0,
        bound=min(speed_bound, angle_bound),
        stick=model.stick_slip,
        switches=model.switches,
        n_switches=model.n_switches,
    )
    problem = exercised(name, ps, kind, theta, dtheta)
    assert problem is None, f"{name}, {kind}: the trial {problem}"
    err_speed = np.abs(r.dtheta - dtheta).max()
    err_angle = np.abs(r.theta - theta).max()
    print(
        f"{name} {kind}: max |dtheta error| {err_speed:.2e} rad/s, |theta error| {err_angle:.2e} rad"
    )
    assert r.ok
    assert err_speed <= speed_bound, f"{name}, {kind}: dtheta error {err_speed:.2e} rad/s"
    assert err_angle <= angle_bound, f"{name}, {kind}: theta error {err_angle:.2e} rad"


# -- physics: stick, break-away, no energy from a stop -------------------------------------
@pytest.fixture(scope="module")
def haptic():
    return get_model("haptic")


def test_a_door_held_by_its_friction_does_not_move_at_all(haptic, seed_trial):
    """Mid-stroke (no spring, no latch), a force that stays within the friction levels
    (-1.0 N opening, +1.5 N closing) moves nothing: speed and acceleration exactly 0.0,
    the angle exactly where it started, at every sample."""
    t = times(2.0)
    force = 0.25 + 1.0 * np.sin(2 * np.pi * 1.3 * t)  # -0.75 .. 1.25 N
    r = simulate(haptic, seed_trial, force, DT, theta0=0.8)
    assert r.ok
    assert np.all(r.dtheta == 0.0) and np.all(r.ddtheta == 0.0)
    assert np.all(r.theta == 0.8)


def slip_from_rest(rate, inertia, damping, tau):
    """Speed (rad/s) and angle moved (rad) a time ``tau`` (s) after the break-away, under
    a force ``rate`` (N/s) beyond the friction level: ``I w' = rate tau - c w``, w(0) = 0."""
    x = damping * tau / inertia
    lag = -np.expm1(-x) * inertia / damping  # (I / c) (1 - exp(-c tau / I))
    speed = rate / damping * (tau - lag)
    angle = rate / damping * (0.5 * tau**2 - inertia / damping * (tau - lag))
    return speed, angle


@pytest.mark.parametrize("direction", [1.0, -1.0], ids=["closing", "opening"])
def test_break_away_at_the_instant_the_force_reaches_the_friction_level(
    haptic, seed_trial, direction
):
    """A force ramp from 0: the door holds exactly until the force equals the friction
    level, at t* = level / rate, between samples 300 and 301; the first sample after it
    shows the analytic slip (the force less the friction drives inertia and viscous
    damping), and so do the 200 samples after it."""
    level = seed_trial["friction_closing" if direction > 0 else "friction_opening"]
    inertia, damping = seed_trial["inertia"], seed_trial["viscous_damping"]
    t_star = 300.4 * DT
    rate = level / t_star  # N/s
    t = times(0.6)
    r = simulate(haptic, seed_trial, direction * rate * t, DT, theta0=0.8)
    held = t <= t_star
    assert np.count_nonzero(held) == 301
    assert np.all(r.dtheta[held] == 0.0) and np.all(r.theta[held] == 0.8)
    after = slice(301, 501)
    speed, angle = slip_from_rest(rate, inertia, damping, t[after] - t_star)
    assert r.dtheta[301] == pytest.approx(direction * speed[0], rel=1e-9)
    assert np.abs(r.dtheta[after] - direction * speed).max() <= 1e-12
    assert np.abs(r.theta[after] - 0.8 - direction * angle).max() <= 1e-12


@pytest.mark.parametrize("kind", ["open stop", "closed wall"])
def test_a_stop_bounce_gives_no_energy_back(door, default, kind):
    """The door thrown against a stop, no hand: its mechanical energy (kinetic, gravity,
    spring, latch, stop) never rises from one sample to the next, through the contact
    and after it (the stop and the wall only push, and dissipate); round-off allowed."""
    force, theta0, dtheta0 = scenario(door, default, kind)
    r = simulate(door, default, force, DT, theta0=theta0, dtheta0=dtheta0)
    assert r.ok
    contact = (r.theta < 0.0) | (r.theta > CLOSED)
    assert np.count_nonzero(contact) >= 3, "the door does not reach the stop"
    p = param_vector(default)
    e = np.array([energy(a, b, p) for a, b in zip(r.theta, r.dtheta)])
    rise = np.diff(e)
    worst = int(rise.argmax())
    assert rise[worst] <= 1e-12, f"energy rises by {rise[worst]:.2e} J at sample {worst}"
    assert e[-1] < e[0] - 0.1


def _located_only(
    accel, switches, p, force, dt, theta0, dtheta0, substeps, method, tol, n_sw, stick, th, w
):  # fmt: skip
    """Every period by :func:`advance_located` (the integrators' shortcut for periods
    without events left out), where the integrators do not step over several periods
    (``try_span``, which runs as theirs): the angle and speed at each sample into ``th``
    and ``w``."""
    g = np.empty((4, max(n_sw, 1)))
    theta, dtheta = theta0, dtheta0
    a_now = rate(accel, p, theta, dtheta, force[0], stick)
    th[0], w[0] = theta, dtheta
    spans = method == DOPRI5 and substeps == 1
    th_s, w_s = np.empty(MAX_SPAN + 1), np.empty(MAX_SPAN + 1)
    span, wait, patience, stiff = MIN_SPAN, 0, 1, False
    h_max = dt / substeps
    h0 = h_max
    switches(theta, dtheta, force[0], p, g[0])
    n = force.shape[0]
    # the switching functions are ready at each period's start; a bool numba cannot
    # see as the constant True, so that advance_located runs as the integrators
    # compiled it (a literal True compiled a copy of it for this loop: some 5 s)
    ready = n > 0
    k = 0
    while k < n - 1:
        m = 0
        if spans:
            m, a_end, span, wait, patience, stiff = try_span(
                accel, switches, p, theta, dtheta, a_now, force, k, n, dt, tol, n_sw, stick,
                g[0], g[1], span, wait, patience, stiff, th_s, w_s,
            )  # fmt: skip
        if m > 0:
            for j in range(1, m + 1):  # a loop: a slice assignment compiles numba's
                th[k + j] = th_s[j]  # shape-mismatch error and its message (some 2 s)
                w[k + j] = w_s[j]
            theta, dtheta, a_now = th_s[m], w_s[m], a_end
            h0 = h_max
            k += m
            continue
        theta, dtheta, a_end, a_ok, h0 = advance_located(
            accel, switches, p, theta, dtheta, force[k], force[k + 1], a_now, ready, dt,
            substeps, method, tol, n_sw, stick, g[0], g[1], g[2], g[3], h0,
        )  # fmt: skip
        a_now = a_end if a_ok else rate(accel, p, theta, dtheta, force[k + 1], stick)
        th[k + 1], w[k + 1] = theta, dtheta
        k += 1


@functools.cache
def _located_only_kernel():
    """:func:`_located_only` compiled (once for every model: its functions are typed
    first-class functions) or loaded from numba's cache, when a test first asks for it.
    Not at import: both workers of ``pytest -n 2`` import this file, and with an empty
    cache each compiled it, where one of them runs the tests."""
    signature = types.void(
        ACCEL_TYPE, SWITCHES_TYPE, types.float64[::1], types.float64[::1], types.float64,
        types.float64, types.float64, types.int64, types.int64, types.float64, types.int64,
        types.boolean, types.float64[::1], types.float64[::1],
    )  # fmt: skip
    return njit(signature, cache=True)(_located_only)


@pytest.mark.parametrize(
    "method, substeps", [("default", 1), ("dopri5", 2), ("rk4", 2), ("semi_implicit", 2)]
)
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("name", ["haptic", "door"])
def test_a_period_without_events_has_the_located_steps_numbers(name, kind, method, substeps):
    """Where a period's steps meet no surface and are accurate at the first try, the
    integrators take them without the locating loop (``smooth_period``): the same
    arithmetic, so every sample equals the located integration's bit for bit, on trials
    that cross latch bands, stops and the speed's zero; with each model's method at one
    substep (its steps over several periods, where the force allows them, the same in
    both), and with dopri5 and the fixed-step methods at two."""
    model = get_model(name)
    ps = model.load_params(PRESETS[name])
    force, theta0, dtheta0 = scenario(model, ps, kind)
    form = kernel_form(model.accel, len(param_vector(ps)))
    q = form.vector(param_vector(ps))
    code = METHODS[model.method if method == "default" else method]
    tol = tolerance_of(model)
    n_sw, stick = model.n_switches, model.stick_slip
    out = [np.empty(force.size) for _ in range(3)]
    args = (q, force, DT, substeps, theta0, dtheta0, code, tol, n_sw, stick)
    assert integrate_compiled(form.accel, model.switches, *args, *out, True, *scratch(n_sw))
    th, w = np.empty(force.size), np.empty(force.size)
    _located_only_kernel()(
        form.accel, model.switches, q, force, DT, theta0, dtheta0, substeps, code, tol, n_sw,
        stick, th, w,
    )  # fmt: skip
    np.testing.assert_array_equal(out[0], th)
    np.testing.assert_array_equal(out[1], w)
