"""Steps over several sample periods where the force is linear (compiled).

A ``dopri5`` step within one sample period (:mod:`evo_door.sim.located`) is far more
accurate than the tolerance asks wherever the motion is smooth, and its six right-hand
sides buy nothing a longer step would not. Across a sample where the force, linear
between samples, changes its slope, a step's stages mix two slopes and its error
estimate, made for a smooth problem, no longer measures its error; a measured force
kinks at every sample (its noise). So a step spans periods only where the force is
linear over them (:func:`kink_free`: zero while a door swings free or rests, held,
ramped), and only over :data:`MIN_SPAN` of them at least. :func:`span_step` takes
that step and reads the samples inside it from its dense output (:func:`dense`),
each checked as a step's end is. :func:`evo_door.sim.integrators.try_span` decides
how many periods to try.
"""

from __future__ import annotations

import math

from numba import njit

from evo_door.sim.located import DOPRI_NODES, GAMMA, _crossed, dopri_stages, jacobian

C2, C3, C4, C5 = DOPRI_NODES


@njit(cache=True, nogil=True)
def dense(y0, y1, slope0, slope1, d5, h, u):
    """A component of a ``dopri5`` step's state at the fraction ``u`` of the step.

    Dormand and Prince's continuous extension of order 4, from the component at the
    step's two ends (``y0``, ``y1``), its derivative there (``slope0``, ``slope1``: the
    first and the last stage) and the coefficient ``d5`` of
    :func:`~evo_door.sim.located.dopri_stages`.
    """
    diff = y1 - y0
    c3 = h * slope0 - diff
    c4 = diff - h * slope1 - c3
    v = 1.0 - u
    return y0 + u * (diff + v * (c3 + u * (c4 + v * d5)))


#: Most sample periods one ``dopri5`` step may span (:func:`span_step`).
MAX_SPAN = 16
#: Fewest periods over which the force must be linear (:func:`kink_free`) before a step
#: tries to span them. A measured force's noise, quantised by its converter, makes three
#: samples in a row collinear now and then, by chance: a step across two periods there
#: would move the trial's numbers for nothing.
MIN_SPAN = 4
#: What :func:`span_step` found: the step kept; too coarse; a surface or the speed's zero
#: reached within it (or a state not finite).
SPAN_KEPT, SPAN_COARSE, SPAN_CROSSES = 0, 1, 2
#: A step over several periods is held to this share of the tolerance. Steps within a
#: period, never longer than it, are mostly far more accurate than the tolerance asks;
#: a span spends it whole, and the samples inside it come from an interpolant a
#: little less accurate than the step: at a tenth, a trial's errors stay those of the
#: periods' steps (tests/test_events.py holds them to the reference).
SPAN_TOLERANCE = 0.1


#: A sample where the force's slope changes by at most this share of the force's size
#: counts as no kink: a force linear to its rounding.
KINK_FREE = 1e-12


@njit(cache=True, nogil=True)
def kink_free(force, k, m):
    """How many of the ``m`` sample periods after sample ``k`` a step may span: up to the
    first sample where the force, linear between samples, changes its slope.

    Across such a kink a step's stages mix two slopes and its error estimate, made for a
    smooth problem, no longer measures its error: a measured force kinks at every sample
    (its noise), a force made by a formula at every sample too unless it is held or
    ramped. Where the force is constant (zero, while the door swings free) or linear,
    a longer step integrates exactly what the periods' steps do.
    """
    for j in range(1, m):
        a, b, c = force[k + j - 1], force[k + j], force[k + j + 1]
        if abs(a - 2.0 * b + c) > KINK_FREE * (abs(a) + 2.0 * abs(b) + abs(c)):
            return j
    return m


@njit(cache=True, nogil=True, inline="always")
def span_step(
    accel, switches, p, theta, dtheta, a_start, force, k, m, dt, tol, n_sw, stick, g0, g1,
    th_out, w_out,
):  # fmt: skip
    """One ``dopri5`` step over the ``m`` sample periods after sample ``k``.

    Where the motion is smooth, a step of one period is far more accurate than the
    tolerance asks, and its six right-hand sides buy nothing a longer step would not.
    The force is linear over the whole step (the caller checks it, :func:`kink_free`),
    so its stages read it from the first period's slope; the samples inside the step are
    read from its dense output (:func:`dense`, order 4), each checked as a step's end
    is: no switching function changed sign since the start, and a stick-slip door's
    speed kept its sign.

    ``a_start`` is the acceleration at the start and ``g0`` holds the switching
    functions there. Returns ``(found, err, a_end)`` (:data:`SPAN_KEPT`, ...): when
    kept, ``th_out[1:m + 1]`` and ``w_out[1:m + 1]`` hold the state at samples ``k + 1``
    ... ``k + m``, ``g0`` the switching functions at the end and ``a_end`` is ``accel``
    there (the last stage); otherwise nothing is moved and ``g0`` stands. ``g1``:
    scratch.
    """
    side = 0
    if stick:
        if dtheta == 0.0:
            return SPAN_CROSSES, math.inf, a_start
        side = 1 if dtheta > 0.0 else -1
    h = m * dt
    f0 = force[k]
    slope = (force[k + 1] - f0) / dt  # the same over the whole step (kink_free)
    th1, w1, err, a_end, d_t, d_w = dopri_stages(
        accel, p, theta, dtheta, a_start, h, f0 + slope * (C2 * h), f0 + slope * (C3 * h),
        f0 + slope * (C4 * h), f0 + slope * (C5 * h), force[k + m], SPAN_TOLERANCE * tol, side,
    )  # fmt: skip
    if not (err <= 1.0):
        return SPAN_COARSE, err, a_end
    if not (math.isfinite(th1) and math.isfinite(w1)):
        return SPAN_CROSSES, err, a_end
    found = read_inside(
        switches, p, theta, dtheta, a_start, th1, w1, a_end, d_t, d_w, force, k, m, h, n_sw,
        side, g0, g1, th_out, w_out,
    )  # fmt: skip
    return found, err, a_end


@njit(cache=True, nogil=True, inline="always")
def read_inside(
    switches, p, theta, dtheta, a_start, th1, w1, a_end, d_t, d_w, force, k, m, h, n_sw, side,
    g0, g1, th_out, w_out,
):  # fmt: skip
    """The samples inside a step over ``m`` periods from sample ``k``, and its end, into
    ``th_out[1:m + 1]`` and ``w_out[1:m + 1]``: read from the step's dense output
    (:func:`dense`, with the fifth coefficients ``d_t`` and ``d_w``), each checked as a
    step's end is: no switching function changed sign since the start (``g0``), and where
    ``side`` is not 0 (a stick-slip door sliding that way) the speed kept its sign.
    Returns :data:`SPAN_KEPT` (``g0`` then holds the switching functions at the end) or
    :data:`SPAN_CROSSES`. ``g1``: scratch."""
    for j in range(1, m + 1):
        th_j, w_j = th1, w1
        if j < m:
            u = j / m
            th_j = dense(theta, th1, dtheta, w1, d_t, h, u)
            w_j = dense(dtheta, w1, a_start, a_end, d_w, h, u)
        if side != 0 and not (w_j * side > 0.0):
            return SPAN_CROSSES
        switches(th_j, w_j, force[k + j], p, g1)
        for i in range(n_sw):
            if _crossed(g0[i], g1[i]):
                return SPAN_CROSSES
        th_out[j] = th_j
        w_out[j] = w_j
    for i in range(n_sw):
        g0[i] = g1[i]
    return SPAN_KEPT


#: How far past ``dopri5``'s stability limit a step over several periods must be asked
#: to go before :func:`stiff_span_step` is tried instead: ``h |d ddtheta / d dtheta|``,
#: where an explicit step's error is its instability (the boundary of ``dopri5``'s
#: stability region on the negative real axis lies near 3.3).
STIFF_LIMIT = 3.0


@njit(cache=True, nogil=True)
def stiffness(accel, p, theta, dtheta, force, a_start):
    """The stabilising part of the Jacobian row of ``ddtheta`` at the state, ``(a_t,
    a_w)`` (:func:`~evo_door.sim.located.jacobian`, two calls of ``accel``): called, not
    inlined, as it is taken only where a step over several periods was refused."""
    return jacobian(accel, p, theta, dtheta, force, a_start)


@njit(cache=True, nogil=True, inline="always")
def stiff_span_step(
    accel, switches, p, theta, dtheta, a_start, force, k, m, dt, tol, n_sw, g0, g1,
    th_out, w_out, a_t, a_w,
):  # fmt: skip
    """One ROS2 step (L-stable, linearly implicit) over the ``m`` sample periods after
    sample ``k``, where the force is constant over them, with the Jacobian row
    ``(a_t, a_w)`` taken at the start (:func:`stiffness`).

    Where a door creeps against a steep friction (the regularised Coulomb friction's
    slope near zero speed), ``dopri5``'s steps are held to a few periods by their
    stability, not their accuracy: the motion is slow and smooth, and an L-stable step
    spans as many periods as its error allows. Its error is estimated against the
    linearly implicit Euler step of the same stages (first order): ``h (k1 + k2) / 2``,
    held to :data:`SPAN_TOLERANCE` of the tolerance as a ``dopri5`` span's is. The
    samples inside the step come from the cubic Hermite interpolant of its ends
    (:func:`dense` with no fifth coefficient), each checked as :func:`span_step` checks
    them. The force being constant, the problem is autonomous over the step and ROS2
    keeps its second order. Returns what :func:`span_step` returns (not for a model
    whose dry friction is a sign law: the caller tries it for smooth frictions only).
    """
    h = m * dt
    f = force[k]
    gh = GAMMA * h
    # M = I - gamma h J = [[1, -gh], [-gh a_t, 1 - gh a_w]]; a_t, a_w <= 0: det >= 1
    m21 = -gh * a_t
    m22 = 1.0 - gh * a_w
    det = m22 + gh * m21
    k1t = (m22 * dtheta + gh * a_start) / det
    k1w = (-m21 * dtheta + a_start) / det
    r1 = dtheta + h * k1w - 2.0 * k1t
    r2 = accel(theta + h * k1t, dtheta + h * k1w, f, p) - 2.0 * k1w
    k2t = (m22 * r1 + gh * r2) / det
    k2w = (-m21 * r1 + r2) / det
    th1 = theta + h * (1.5 * k1t + 0.5 * k2t)
    w1 = dtheta + h * (1.5 * k1w + 0.5 * k2w)
    et = 0.5 * h * (k1t + k2t)
    ew = 0.5 * h * (k1w + k2w)
    stol = SPAN_TOLERANCE * tol
    err = max(abs(et) / (stol * (1.0 + abs(theta))), abs(ew) / (stol * (1.0 + abs(dtheta))))
    if not (err <= 1.0):
        return SPAN_COARSE, err, a_start
    if not (math.isfinite(th1) and math.isfinite(w1)):
        return SPAN_CROSSES, err, a_start
    a_end = accel(th1, w1, f, p)
    found = read_inside(
        switches, p, theta, dtheta, a_start, th1, w1, a_end, 0.0, 0.0, force, k, m, h, n_sw, 0,
        g0, g1, th_out, w_out,
    )  # fmt: skip
    return found, err, a_end
