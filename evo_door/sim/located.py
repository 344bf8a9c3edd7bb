"""Integration that locates the model's switching surfaces within the step (compiled).

A door model is smooth almost everywhere, but not everywhere: a latch band begins, a
spring reaches its hold, the door meets a stop, dry friction changes direction or
sticks. A fixed step that crosses one of these in its middle mixes the laws of both
sides in its stages and loses its order: the error of a whole trial is then made at a
handful of crossings, and no sensible step size removes it.

:func:`advance_located` moves the state over one sample period like
:func:`~evo_door.sim.integrators.advance`, and on top of it:

**Switching surfaces.** A model declares them as a compiled function
``switches(theta, dtheta, force, p, g)`` that writes the values ``g[i]`` of its
surfaces (:data:`SWITCHES_SIGNATURE`; a surface is where ``g[i]`` changes sign, for
example ``theta - theta_0`` at the start of a latch band). After every step the
signs are compared with those at its start; where one changed, the crossing is found
by the Illinois method on the step *length* (each trial length a fresh step from the
same start, so every candidate is a step that does not cross), to :data:`LOCATE_TOL`
(1e-7) of the sample period. The step to the last length short of the surface is kept,
the state is moved across it by an Euler step of the bracket's width (at least
``LOCATE_TOL`` of the period, 1e-10 s at 1 kHz; widened fourfold while that does not
cross it, to past 1e-6 of the period at most, so the next step's stages all see the far
side's law), and the period goes on from there. A surface crossed
more than :data:`MAX_EVENTS` times in one period (a chatter) is stepped over for the
rest of it.

**Stick-slip friction.** A model whose dry friction is a sign law, ``-F_c sgn(v)``
with ``sgn(0) = 0`` (``stick_slip``), gets the set-valued Coulomb law that the
renderer solves (:mod:`evo_door.render.friction`): the speed's zero is a surface;
there the door sticks (speed exactly 0.0, angle held) while the other forces stay
within the friction levels, which :func:`rate` reads as the acceleration at a speed of
``+-``:data:`CREEP` (the friction's two sides, nothing else changed). The force is
linear between samples and the acceleration affine in it, so the instant the other
forces break the stick is solved exactly; the door then slips from ``+-CREEP``.

**Adaptive steps** (method ``dopri5``): Dormand and Prince's 5(4) pair, its step
chosen within each sample period from the embedded error estimate against the
tolerance ``tol``: ``|error| <= tol (1 + |x|)`` per component (rad, rad/s). Steps
never exceed ``dt / substeps``; a period's first step is the length the error of the
last period's first step asked for (:func:`advance_located`). ``rk4`` and
``semi_implicit`` keep their fixed steps, with the surfaces located as above.

**Steps over several periods** (``dopri5`` at one substep): where the force is linear
over several periods, one step may cross them (:mod:`evo_door.sim.spans`).

Most periods of a trial need none of the locating: their steps cross nothing and are
accurate at the first try. :func:`smooth_period` takes those steps on their own, with
the same arithmetic as :func:`advance_located` (so the same numbers), and hands the
period to :func:`advance_located` when a step is too coarse or crosses something.

Size: some 650 lines: the steps, the locating and the friction's two sides
share their arithmetic (a smooth period's numbers are :func:`advance_located`'s), so
they stay side by side.
"""

from __future__ import annotations

import math

from numba import njit, types

# the ``method`` codes (plain data, :data:`evo_door.sim_settings.METHODS`)
from evo_door.sim_settings import DOPRI5, SEMI_IMPLICIT

#: Speed (rad/s) at which a stick-slip model's friction is read at rest: its sign is
#: the side of the friction, and it is far too small to move anything else.
CREEP = 1e-200
#: Surface crossings located in one sample period before the rest is stepped over.
MAX_EVENTS = 64
#: Width of a located crossing's bracket, as a fraction of the sample period.
LOCATE_TOL = 1e-7
#: Most Illinois iterations of one location.
LOCATE_ITER = 80
#: Most step-size rejections in one period before a step is taken regardless.
MAX_REJECTS = 400
#: Most steps of one period without an event taken outside the locating loop.
MAX_SMOOTH_STEPS = 256

#: The W-method's gamma, 1 + 1/sqrt(2): the L-stable ROS2 step of the ``semi_implicit``
#: scheme, of a state-vector step and of a stiff span.
GAMMA = 1.0 + 1.0 / math.sqrt(2.0)

#: Signature of a model's ``switches(theta, dtheta, force, p, g)``: writes its
#: switching functions into ``g``.
SWITCHES_SIGNATURE = types.void(
    types.float64, types.float64, types.float64, types.float64[::1], types.float64[::1]
)
#: The numba type of a ``switches`` function as a kernel argument.
SWITCHES_TYPE = types.FunctionType(SWITCHES_SIGNATURE)


@njit(SWITCHES_SIGNATURE, cache=True, nogil=True)
def no_switches(theta, dtheta, force, p, g):
    """The ``switches`` of a model that declares none."""


@njit(cache=True, nogil=True, inline="always")
def sided(accel, p, theta, dtheta, force, side):
    """``accel`` with the dry friction held on ``side`` (+1 / -1; 0: as it is).

    While a stick-slip door slides one way, the steps' stages must see its friction
    as that slide's, even where a stage's speed overshoots through zero (the slide's
    law extended smoothly, so that the step and its error estimate stay those of a
    smooth problem and the speed's zero is located on it). The friction's two sides
    at a state differ by ``accel(+CREEP) - accel(-CREEP)``: a stage on the wrong side
    gets that difference added.
    """
    a = accel(theta, dtheta, force, p)
    if side == 0 or dtheta * side > 0.0:
        return a
    return other_side(accel, p, theta, dtheta, force, side, a)


@njit(cache=True, nogil=True)
def other_side(accel, p, theta, dtheta, force, side, a):
    """:func:`sided` where the stage's speed is on the wrong side: ``a`` with the
    friction's two sides' difference added (called, not inlined: it is rare)."""
    here = accel(theta, -side * CREEP, force, p) if dtheta != 0.0 else a
    return a - here + accel(theta, side * CREEP, force, p)


# Dormand-Prince 5(4): nodes, stages, 5th-order weights and the error weights b - b*.
_C2, _C3, _C4, _C5 = 1.0 / 5.0, 3.0 / 10.0, 4.0 / 5.0, 8.0 / 9.0
_A21 = 1.0 / 5.0
_A31, _A32 = 3.0 / 40.0, 9.0 / 40.0
_A41, _A42, _A43 = 44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0
_A51, _A52, _A53, _A54 = 19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0
_A61, _A62, _A63 = 9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0
_A64, _A65 = 49.0 / 176.0, -5103.0 / 18656.0
_B1, _B3, _B4, _B5, _B6 = 35.0 / 384.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0
_E1, _E3, _E4 = 71.0 / 57600.0, -71.0 / 16695.0, 71.0 / 1920.0
_E5, _E6, _E7 = -17253.0 / 339200.0, 22.0 / 525.0, -1.0 / 40.0
#: The nodes c2 ... c5 of a step's stages, as fractions of its length.
DOPRI_NODES = (_C2, _C3, _C4, _C5)
# the dense output's fifth coefficient (Hairer, Norsett and Wanner's DOPRI5)
_D1, _D3 = -12715105075.0 / 11282082432.0, 87487479700.0 / 32700410799.0
_D4, _D5 = -10690763975.0 / 1880347072.0, 701980252875.0 / 199316789632.0
_D6, _D7 = -1453857185.0 / 822651844.0, 69997945.0 / 29380423.0


@njit(cache=True, nogil=True, inline="always")
def dopri_step(accel, p, th, w, a1, t, h, f0, slope, tol, side):
    """One Dormand-Prince 5(4) step of length ``h`` from time ``t`` of the period.

    The force is ``f0 + slope * time``; ``a1`` is the acceleration at the start.
    Returns ``(theta, dtheta, err, a_end)``: ``err`` the embedded error estimate over
    the tolerance (a step is good when it is at most 1), ``a_end`` the acceleration
    at the new state (the next step's first stage).
    """
    th_new, w_new, err, a_end, _dt5, _dw5 = dopri_stages(
        accel, p, th, w, a1, h, f0 + slope * (t + _C2 * h), f0 + slope * (t + _C3 * h),
        f0 + slope * (t + _C4 * h), f0 + slope * (t + _C5 * h), f0 + slope * (t + h), tol, side,
    )  # fmt: skip
    return th_new, w_new, err, a_end


@njit(cache=True, nogil=True, inline="always")
def dopri_stages(accel, p, th, w, a1, h, f2, f3, f4, f5, f_end, tol, side):
    """The stages of :func:`dopri_step`, the force at each stage's time given.

    ``f2`` ... ``f5`` are the force at the nodes ``c2`` ... ``c5`` of the step, ``f_end``
    at its end. Returns ``(theta, dtheta, err, a_end, d_theta, d_dtheta)``: the first
    four as :func:`dopri_step`'s, the last two the fifth coefficient of the step's
    dense output (:func:`evo_door.sim.spans.dense`) for each component.
    """
    k1t, k1w = w, a1
    k2t = w + h * _A21 * k1w
    k2w = sided(accel, p, th + h * _A21 * k1t, k2t, f2, side)
    k3t = w + h * (_A31 * k1w + _A32 * k2w)
    k3w = sided(accel, p, th + h * (_A31 * k1t + _A32 * k2t), k3t, f3, side)
    k4t = w + h * (_A41 * k1w + _A42 * k2w + _A43 * k3w)
    k4w = sided(accel, p, th + h * (_A41 * k1t + _A42 * k2t + _A43 * k3t), k4t, f4, side)
    k5t = w + h * (_A51 * k1w + _A52 * k2w + _A53 * k3w + _A54 * k4w)
    k5w = sided(
        accel, p, th + h * (_A51 * k1t + _A52 * k2t + _A53 * k3t + _A54 * k4t), k5t, f5, side
    )
    k6t = w + h * (_A61 * k1w + _A62 * k2w + _A63 * k3w + _A64 * k4w + _A65 * k5w)
    k6w = sided(
        accel,
        p,
        th + h * (_A61 * k1t + _A62 * k2t + _A63 * k3t + _A64 * k4t + _A65 * k5t),
        k6t,
        f_end,
        side,
    )
    th_new = th + h * (_B1 * k1t + _B3 * k3t + _B4 * k4t + _B5 * k5t + _B6 * k6t)
    w_new = w + h * (_B1 * k1w + _B3 * k3w + _B4 * k4w + _B5 * k5w + _B6 * k6w)
    k7t = w_new
    k7w = sided(accel, p, th_new, w_new, f_end, side)
    et = h * (_E1 * k1t + _E3 * k3t + _E4 * k4t + _E5 * k5t + _E6 * k6t + _E7 * k7t)
    ew = h * (_E1 * k1w + _E3 * k3w + _E4 * k4w + _E5 * k5w + _E6 * k6w + _E7 * k7w)
    err = max(abs(et) / (tol * (1.0 + abs(th))), abs(ew) / (tol * (1.0 + abs(w))))
    d_t = h * (_D1 * k1t + _D3 * k3t + _D4 * k4t + _D5 * k5t + _D6 * k6t + _D7 * k7t)
    d_w = h * (_D1 * k1w + _D3 * k3w + _D4 * k4w + _D5 * k5w + _D6 * k6w + _D7 * k7w)
    return th_new, w_new, err, k7w, d_t, d_w


@njit(cache=True, nogil=True, inline="always")
def rk4_step(accel, p, theta, dtheta, a_start, f0, f1, h, side):
    """One RK4 step of length ``h`` with the force going linearly from f0 to f1.

    ``a_start`` is ``accel(theta, dtheta, f0, p)``, which the caller already has;
    ``side`` holds a sliding door's friction (:func:`sided`; 0 for none).
    """
    fm = 0.5 * (f0 + f1)
    k1t = dtheta
    k1w = a_start
    k2t = dtheta + 0.5 * h * k1w
    k2w = sided(accel, p, theta + 0.5 * h * k1t, k2t, fm, side)
    k3t = dtheta + 0.5 * h * k2w
    k3w = sided(accel, p, theta + 0.5 * h * k2t, k3t, fm, side)
    k4t = dtheta + h * k3w
    k4w = sided(accel, p, theta + h * k3t, k4t, f1, side)
    theta_new = theta + h / 6.0 * (k1t + 2.0 * k2t + 2.0 * k3t + k4t)
    dtheta_new = dtheta + h / 6.0 * (k1w + 2.0 * k2w + 2.0 * k3w + k4w)
    return theta_new, dtheta_new


@njit(cache=True, nogil=True, inline="always")
def jacobian(accel, p, theta, dtheta, force, a_start):
    """Stabilising part of (d ddtheta / d theta, d ddtheta / d dtheta), forward differences.

    ``a_start`` is ``accel(theta, dtheta, force, p)``. A W-method keeps its order with
    any Jacobian approximation, so one-sided differences (two calls instead of four)
    are enough. Only the stabilising part is treated implicitly: a snap (a latch apex,
    negative damping) gives a_t > 0 or a_w > 0, with which det(I - gamma h J) can pass
    through zero and the step explodes; with a_t, a_w <= 0 the determinant is >= 1.
    """
    et = 1e-7 * (1.0 + abs(theta))
    ew = 1e-7 * (1.0 + abs(dtheta))
    a_t = (accel(theta + et, dtheta, force, p) - a_start) / et
    a_w = (accel(theta, dtheta + ew, force, p) - a_start) / ew
    return min(a_t, 0.0), min(a_w, 0.0)


@njit(cache=True, nogil=True, inline="always")
def ros2_step(accel, p, theta, dtheta, a_start, f1, h, a_t, a_w, side):
    """One ROS2 step; (a_t, a_w) is the (possibly frozen) Jacobian row of ddtheta.

    ``a_start`` is ``accel`` at the start of the step; ``side`` as in
    :func:`rk4_step`. With x = (theta, dtheta) and
    J = [[0, 1], [a_t, a_w]]:
    (I - gamma h J) k1 = f(t, x);  (I - gamma h J) k2 = f(t + h, x + h k1) - 2 k1;
    x_new = x + h (3 k1 + k2) / 2.
    """
    gh = GAMMA * h
    # M = I - gamma h J = [[1, -gh], [-gh a_t, 1 - gh a_w]]
    m12 = -gh
    m21 = -gh * a_t
    m22 = 1.0 - gh * a_w
    det = m22 - m12 * m21
    r1 = dtheta
    r2 = a_start
    k1t = (m22 * r1 - m12 * r2) / det
    k1w = (-m21 * r1 + r2) / det
    theta1 = theta + h * k1t
    dtheta1 = dtheta + h * k1w
    r1 = dtheta1 - 2.0 * k1t
    r2 = sided(accel, p, theta1, dtheta1, f1, side) - 2.0 * k1w
    k2t = (m22 * r1 - m12 * r2) / det
    k2w = (-m21 * r1 + r2) / det
    return theta + h * (1.5 * k1t + 0.5 * k2t), dtheta + h * (1.5 * k1w + 0.5 * k2w)


@njit(cache=True, nogil=True, inline="always")
def fixed_step(accel, p, th, w, a1, t, h, f0, slope, method, a_t, a_w, side):
    """One RK4 or ROS2 step of length ``h`` from time ``t`` of the period."""
    if method == SEMI_IMPLICIT:
        return ros2_step(accel, p, th, w, a1, f0 + slope * (t + h), h, a_t, a_w, side)
    return rk4_step(accel, p, th, w, a1, f0 + slope * t, f0 + slope * (t + h), h, side)


@njit(cache=True, nogil=True, inline="always")
def trial_step(accel, p, th, w, a1, t, h, f0, slope, method, tol, a_t, a_w, side):
    """One step of ``method`` of length ``h`` from time ``t`` of the period:
    ``(theta, dtheta, err, a_end)``, ``err`` and ``a_end`` as :func:`dopri_step`
    gives them (0 for the fixed steps: no estimate, no first stage to reuse)."""
    if method == DOPRI5:
        return dopri_step(accel, p, th, w, a1, t, h, f0, slope, tol, side)
    th1, w1 = fixed_step(accel, p, th, w, a1, t, h, f0, slope, method, a_t, a_w, side)
    return th1, w1, 0.0, 0.0


@njit(cache=True, nogil=True, inline="always")
def rate(accel, p, theta, dtheta, force, stick):
    """The acceleration (rad/s^2) at a state, with a stuck door's 0.

    For a stick-slip model at rest (``dtheta`` exactly 0.0): 0 while the friction
    holds the other forces, else the acceleration of the side it slips to.
    """
    if stick and dtheta == 0.0:
        return stuck_rate(accel, p, theta, force)
    return accel(theta, dtheta, force, p)


@njit(cache=True, nogil=True)
def stuck_rate(accel, p, theta, force):
    """:func:`rate` of a stick-slip model at rest (called, not inlined)."""
    forward = accel(theta, CREEP, force, p)
    if forward > 0.0:
        return forward
    backward = accel(theta, -CREEP, force, p)
    if backward < 0.0:
        return backward
    return 0.0


@njit(cache=True, nogil=True)
def _crossed(a, b):
    """True when ``a`` and ``b`` lie on two sides of zero (0 counts as positive)."""
    return (a < 0.0) != (b < 0.0)


@njit(cache=True, nogil=True)
def _first_crossing(g0, g1, n, w0, w1, stick, active):
    """Index of the crossing with the smallest linear estimate of its time, -1 if none;
    ``n`` stands for the speed's zero (stick-slip)."""
    best = -1
    best_u = 2.0
    for i in range(n):
        if active[i] != 0.0 and _crossed(g0[i], g1[i]):
            u = g0[i] / (g0[i] - g1[i])
            if u < best_u:
                best, best_u = i, u
    if stick and w0 != 0.0 and _crossed(w0, w1):
        u = w0 / (w0 - w1)
        if u < best_u:
            best = n
    return best


@njit(cache=True, nogil=True)
def next_length(h, h_want, err, h_max):
    """The length of the ``dopri5`` step after a kept one of length ``h`` and error
    ``err`` (over the tolerance): grown or cut as the error says, at most ``h_max``.

    ``h_want`` is the length the kept step was asked to have: longer where the period's
    end cut it short. A step cut so is no measure of the next one's length, so where
    its error lets the step grow, the next one is at least the length asked.
    """
    grow = 5.0 if err < 1e-4 else 0.9 * err**-0.2
    nxt = h * min(5.0, grow)
    if h < h_want and nxt >= h:
        nxt = max(nxt, h_want)
    return min(h_max, nxt)


@njit(cache=True, nogil=True, inline="always")
def smooth_period(
    accel, switches, p, theta, dtheta, f0, f1, a_start, g_ready, dt, substeps, method, tol,
    n_sw, stick, g0, g1, h0,
):  # fmt: skip
    """A sample period whose steps cross nothing and are all accurate at the first try.

    Most periods of a trial are. There :func:`advance_located` takes its steps one after
    the other and checks each end's switching functions, and this does the same, with
    the same arithmetic (so the same numbers) and nothing else: no locating, no retry,
    no bookkeeping for them, which cost about as much as a ``dopri5`` step's six
    right-hand sides. The first step is ``h0`` long, and ``h_next`` is returned, as by
    :func:`advance_located`. Returns ``(ok, theta, dtheta, a_end, a_ok, h_next)``.
    When not ``ok`` (a step too coarse, a surface or the speed's zero reached, not
    finite, a stuck door), nothing is moved, ``g0`` holds the switching functions at the
    period's start, and the period is :func:`advance_located`'s from its start, with
    ``h_next`` as its ``h0``: ``h0``, or, where the first step only was too coarse, that
    step cut as its error asks (what :func:`advance_located` would do first).
    ``g1``: scratch.
    """
    # long: advance_located's step loop without its cases 1, 3 and 4, kept line for line
    # alike so that the two give the same numbers (tests/test_events.py checks it)
    slope = (f1 - f0) / dt
    h_max = dt / substeps
    h = min(h0, h_max)
    t = 0.0
    if not g_ready:
        switches(theta, dtheta, f0, p, g0)
    a_t = 0.0
    a_w = 0.0
    if method == SEMI_IMPLICIT:
        a_t, a_w = jacobian(accel, p, theta, dtheta, f0, a_start)
    th, w = theta, dtheta
    a1 = a_start
    fresh = True
    a_ok = False
    h_next = -1.0
    for _ in range(MAX_SMOOTH_STEPS):
        if not dt - t > LOCATE_TOL * dt:
            for i in range(n_sw):
                g0[i] = g1[i]
            return True, th, w, a1, a_ok, h_next if h_next > 0.0 else h_max
        if stick and w == 0.0:
            break
        side = 0
        if stick:
            side = 1 if w > 0.0 else -1
        h_want = h
        h = min(max(h, LOCATE_TOL * dt), dt - t)
        if not fresh:
            a1 = accel(th, w, f0 + slope * t, p)
        th1, w1, err, a_end = trial_step(
            accel, p, th, w, a1, t, h, f0, slope, method, tol, a_t, a_w, side
        )
        good = err <= 1.0 and math.isfinite(th1) and math.isfinite(w1)
        # the first step only too coarse: where it crosses nothing, advance_located
        # would cut it as the error says; it starts with the cut step instead
        first_cut = t == 0.0 and math.isfinite(err) and h > LOCATE_TOL * dt
        if not (good or first_cut):
            break
        switches(th1, w1, f0 + slope * (t + h), p, g1)
        # (a sign kept since the period's start is the sign at this step's start)
        crossed = stick and _crossed(w, w1)
        for i in range(n_sw):
            crossed = crossed or _crossed(g0[i], g1[i])
        if crossed:
            break
        if not good:
            return False, theta, dtheta, a_start, False, h * max(0.2, 0.9 * err**-0.2)
        th, w = th1, w1
        t += h
        fresh = False
        a_ok = False
        if method == DOPRI5:
            h = next_length(h, h_want, err, h_max)
            if h_next < 0.0:
                h_next = h
            a1 = a_end
            fresh = True
            a_ok = side == 0 or w1 * side > 0.0
    return False, theta, dtheta, a_start, False, h0


# Not inlined: compiled once, for the first-class function types the kernels pass
# (integrate_compiled, the objective kernels), which keeps compiling the workbench's
# kernels to about a quarter of what inlining it into each of them took.
@njit(cache=True, nogil=True)
def advance_located(
    accel,
    switches,
    p,
    theta,
    dtheta,
    f0,
    f1,
    a_start,
    g_ready,
    dt,
    substeps,
    method,
    tol,
    n_sw,
    stick,
    g0,
    g1,
    gx,
    active,
    h0,
):
    """Move ``(theta, dtheta)`` over one sample period ``dt``, surfaces located.

    The force goes linearly from ``f0`` to ``f1``. ``switches`` writes the model's
    ``n_sw`` switching functions; ``stick`` says its dry friction is a sign law (the
    module docstring). ``g0``, ``g1``, ``gx`` are scratch arrays of at least ``n_sw``
    floats, ``active`` one more (1.0 for a surface still located this period).

    Nothing a period has is computed again by the next: ``a_start`` is the acceleration
    at the start (``accel``'s, as :func:`rate` gives it unless the door is stuck), and
    with ``g_ready`` ``g0`` holds the switching functions there; on return ``g0`` holds
    them at the end. The first step is ``h0`` long (at most ``dt / substeps``).
    Returns ``(theta, dtheta, a_end, a_ok, h_next)``: ``a_end`` is ``accel`` at the
    end, from the last step's last stage, where ``a_ok`` (else compute it); ``h_next``
    the next period's ``h0``: for ``dopri5`` the length the error of the period's first
    kept step asks for next, where that step starts the period; else (after an event,
    and always for the fixed steps) ``dt / substeps``. A measured force kinks at every sample, and a door resting on
    its stiff stop answers each kink with a transient that the first step of every
    period must follow: the first step of one period is the best guess for the next
    one's, where a whole period's step is refused (and costs a step) at each.
    """
    # long: one loop over the period's steps, in four cases read top to bottom (a
    # stuck door; the step; a crossing located; the move across it); they share the
    # period's clock, step length and scratch arrays
    slope = (f1 - f0) / dt
    h_max = dt / substeps
    h = min(h0, h_max)
    t = 0.0
    for i in range(n_sw):
        active[i] = 1.0
    events = 0
    rejects = 0
    a1 = a_start
    fresh = True  # a1 holds the acceleration at the current state
    a_ok = False  # ... and it is the last step's last stage, at the current state
    g_fresh = True  # g0 holds the switching functions at the current state and time
    h_next = -1.0  # the length after the period's first step (see the docstring)
    a_t = 0.0
    a_w = 0.0
    if method == SEMI_IMPLICIT:
        a_base = accel(theta, dtheta, f0, p) if stick and dtheta == 0.0 else a_start
        a_t, a_w = jacobian(accel, p, theta, dtheta, f0, a_base)
    if not g_ready:
        switches(theta, dtheta, f0, p, g0)
    while dt - t > LOCATE_TOL * dt:
        force = f0 + slope * t
        # 1. a stuck door: held until the other forces beat the friction
        if stick and dtheta == 0.0:
            fresh = False
            a_ok = False
            forward = accel(theta, CREEP, force, p)
            backward = accel(theta, -CREEP, force, p)
            if forward > 0.0:
                dtheta = CREEP
            elif backward < 0.0:
                dtheta = -CREEP
            else:
                # accel is affine in the force and the force linear in time: exact
                forward_end = accel(theta, CREEP, f1, p)
                backward_end = accel(theta, -CREEP, f1, p)
                free = dt
                if forward_end > 0.0:
                    free = min(free, t + (dt - t) * (-forward) / (forward_end - forward))
                if backward_end < 0.0:
                    free = min(free, t + (dt - t) * (-backward) / (backward_end - backward))
                if free >= dt:  # held to the end, where the friction still holds: rate 0
                    switches(theta, 0.0, f1, p, g0)
                    return theta, 0.0, 0.0, True, h_next if h_next > 0.0 else h_max
                t = max(free, t + LOCATE_TOL * dt)
                g_fresh = False
                continue
            switches(theta, dtheta, force, p, g0)
            g_fresh = True
        # 2. the step (a sliding door's friction held on its side: see sided)
        side = 0
        if stick:
            side = 1 if dtheta > 0.0 else (-1 if dtheta < 0.0 else 0)
        h_want = h
        h = min(max(h, LOCATE_TOL * dt), dt - t)  # never a step of nothing
        if not fresh:
            a1 = accel(theta, dtheta, force, p)
        fresh = False
        a_ok = False
        th1, w1, err, a_end = trial_step(
            accel, p, theta, dtheta, a1, t, h, f0, slope, method, tol, a_t, a_w, side
        )
        # a step too coarse is cut, unless it crosses a surface: then the crossing is
        # located first (a step across a jump is never accurate, however short)
        coarse = not (err <= 1.0) and rejects < MAX_REJECTS and h > LOCATE_TOL * dt
        switches(th1, w1, f0 + slope * (t + h), p, g1)
        c = -1
        if events < MAX_EVENTS and math.isfinite(th1) and math.isfinite(w1):
            c = _first_crossing(g0, g1, n_sw, dtheta, w1, stick, active)
        if coarse:
            shorter = h * (max(0.2, 0.9 * err**-0.2) if math.isfinite(err) else 0.2)
            if c >= 0:  # locate now if the crossing lies within the accurate length
                v0 = dtheta if c == n_sw else g0[c]
                v1 = w1 if c == n_sw else g1[c]
                if v0 / (v0 - v1) * h <= shorter:
                    shorter = h
            if shorter < h:
                rejects += 1
                h = shorter
                fresh = True  # the same start: a1 stands
                continue
        if c < 0:
            theta, dtheta = th1, w1
            from_start = t == 0.0
            t += h
            for i in range(n_sw):
                g0[i] = g1[i]
            g_fresh = True
            if method == DOPRI5:
                h = next_length(h, h_want, err, h_max)
                if h_next < 0.0:  # the period's first step: from its start, or after an event
                    h_next = h if from_start else h_max
                a1 = a_end  # first same as last: the next step's first stage
                fresh = True
                a_ok = side == 0 or w1 * side > 0.0  # sided gave accel's own value
            continue
        # 3. a crossing: the longest step short of it, by Illinois on the length
        events += 1
        lo, hi = 0.0, h
        while True:
            v_lo = dtheta if c == n_sw else g0[c]
            v_hi = w1 if c == n_sw else g1[c]
            last = 0  # the bracket's end that moved last (Illinois)
            th_lo, w_lo, err_lo = theta, dtheta, 0.0
            for _ in range(LOCATE_ITER):
                if hi - lo <= LOCATE_TOL * dt:
                    break
                s = (lo * v_hi - hi * v_lo) / (v_hi - v_lo)
                if v_hi == 0.0:  # hi lies on the surface: try just short of it
                    s = hi - 0.5 * LOCATE_TOL * dt
                if not (lo < s < hi):
                    s = 0.5 * (lo + hi)
                th_s, w_s, err_s, _a = trial_step(
                    accel, p, theta, dtheta, a1, t, s, f0, slope, method, tol, a_t, a_w, side
                )
                switches(th_s, w_s, f0 + slope * (t + s), p, gx)
                v = w_s if c == n_sw else gx[c]
                if _crossed(v, v_lo):
                    hi, v_hi = s, v
                    if last == 1:
                        v_lo *= 0.5
                    last = 1
                else:
                    lo, v_lo, th_lo, w_lo, err_lo = s, v, th_s, w_s, err_s
                    if last == -1:
                        v_hi *= 0.5
                    last = -1
            # a surface crossed before the located one takes its place
            switches(th_lo, w_lo, f0 + slope * (t + lo), p, gx)
            earlier = _first_crossing(g0, gx, n_sw, dtheta, w_lo, stick, active)
            if earlier < 0 or lo <= 0.0:
                break
            c = earlier
            hi = lo
            lo = 0.0
            th1, w1 = th_lo, w_lo
            for i in range(n_sw):
                g1[i] = gx[i]
        if not (err_lo <= 1.0) and rejects < MAX_REJECTS:
            # the step to the surface is too coarse: a shorter one, and locate again
            rejects += 1
            h = lo * (max(0.2, 0.9 * err_lo**-0.2) if math.isfinite(err_lo) else 0.2)
            continue
        # 4. keep the step to the surface, then cross it
        theta, dtheta = th_lo, w_lo
        t += lo
        if c == n_sw:
            dtheta = 0.0  # the speed's zero: stick, or slip the other way (case 1)
            switches(theta, dtheta, f0 + slope * t, p, g0)
            g_fresh = True
            continue
        width = max(hi - lo, LOCATE_TOL * dt)
        before = g0[c]
        for _ in range(12):
            force = f0 + slope * t
            a_now = accel(theta, dtheta, force, p)
            th_x = theta + width * dtheta
            w_x = dtheta + width * a_now
            switches(th_x, w_x, force + slope * width, p, gx)
            if _crossed(gx[c], before) or width > 1e-6 * dt:
                if stick and _crossed(w_x, dtheta) and dtheta != 0.0:
                    w_x = 0.0
                theta, dtheta = th_x, w_x
                t += width
                break
            width *= 4.0
        switches(theta, dtheta, f0 + slope * min(t, dt), p, g0)
        g_fresh = True
        if not _crossed(g0[c], before):
            active[c] = 0.0  # grazes it: step over it for the rest of the period
    if not g_fresh:
        switches(theta, dtheta, f1, p, g0)
    return theta, dtheta, a1, a_ok, h_next if h_next > 0.0 else h_max
