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

from evo_door.sim.located import DOPRI_NODES, _crossed, dopri_stages

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
    for j in range(1, m + 1):
        th_j, w_j = th1, w1
        if j < m:
            u = j / m
            th_j = dense(theta, th1, dtheta, w1, d_t, h, u)
            w_j = dense(dtheta, w1, a_start, a_end, d_w, h, u)
        if stick and not (w_j * side > 0.0):
            return SPAN_CROSSES, err, a_end
        switches(th_j, w_j, force[k + j], p, g1)
        for i in range(n_sw):
            if _crossed(g0[i], g1[i]):
                return SPAN_CROSSES, err, a_end
        th_out[j] = th_j
        w_out[j] = w_j
    for i in range(n_sw):
        g0[i] = g1[i]
    return SPAN_KEPT, err, a_end
