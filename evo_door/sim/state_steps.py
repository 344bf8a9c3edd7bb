"""The steps of the state-vector integrators (compiled): RK4, ROS2 and Dormand-Prince
5(4) on a state vector, the stick-slip law of each contact in the stages, and a
period of fixed steps with nothing located (:func:`plain_period`; the located one is
:func:`evo_door.sim.state_located.period`).

These are :mod:`evo_door.sim.located`'s algorithms written on a vector ``x`` of
``n`` states instead of the pair ``(theta, dtheta)``; :mod:`evo_door.sim.states`
states the contract a model follows and holds the entry points. Every function here
works in place on rows of one scratch array allocated per trial (``W``, :data:`ROWS`
rows of ``n`` floats), so a period allocates nothing, and each is compiled without
numba's runtime (``_nrt=False``, as numba compiles its own allocation-free helpers):
with it, every array handed from one of these functions to the next, and every row of
``W`` taken, was counted in and out of its owner by an atomic increment, which took
more of a cheap model's trial than its right-hand side (``perf`` on the knob of the
examples: numba's ``NRT_incref`` and ``NRT_decref`` above the model's ``sin``). Without
the runtime a function here cannot allocate (numba refuses to compile one that does):
copies between rows are :func:`copy_into` loops, not slice assignments.

The expressions of the explicit stages are those of the one-coordinate steps, written
per component: on a model ``dx = (x[1], accel(x[0], x[1], force, p))`` RK4 and
``dopri5`` give the one-coordinate results bit for bit. ROS2 does not: its linear
systems are solved by LU rather than by Cramer's rule, its Jacobian's ``d x[0]' / d
x[1]`` is a forward difference (1 up to rounding) rather than exactly 1, and it
keeps the whole forward-difference Jacobian (only its positive diagonal dropped)
where the one-coordinate form keeps only non-positive entries (see :func:`jacobian`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from evo_door.sim.located import (
    CREEP,
    DOPRI5,
    GAMMA,
    SEMI_IMPLICIT,
)


def no_runtime(inline: str = "never"):
    """numba's ``njit`` for the functions of the state-vector steps: cached, without the
    GIL and without numba's runtime (the module docstring); ``inline="always"`` to
    inline at numba's level."""
    return njit(cache=True, nogil=True, inline=inline, _nrt=False)  # type: ignore[call-overload]


#: ROS2 drops its Jacobian for a step when det(I - gamma h J) falls below this: a
#: growing mode with gamma h lambda near 1 would make the linear systems near singular.
MIN_DETERMINANT = 0.5

# rows of the per-trial scratch array W
A1, K2, K3, K4, K5, K6, K7, XS, X1, XT, XLO, Y, R, DX, XE = range(15)
#: rows of the scratch array ``W`` (each ``n_states`` floats)
ROWS = 15

# Dormand-Prince 5(4) (the tableau of evo_door.sim.located, per component here)
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


@njit(cache=True, nogil=True)
def workspace(n, n_surfaces, n_contacts):
    """The scratch arrays of one trial: ``W`` (:data:`ROWS` x n), ``G`` (4 x surfaces:
    g0, g1, gx, active), ``JM`` (2 x n x n: the Jacobian and ROS2's matrix), ``piv``
    (n pivots), ``modes`` (one per contact)."""
    return (
        np.empty((ROWS, n)),
        np.empty((4, max(n_surfaces, 1))),
        np.empty((2, n, n)),
        np.empty(n, dtype=np.int64),
        np.empty(n_contacts, dtype=np.int64),
    )


@no_runtime()
def copy_into(dst, src, n):
    """``dst[:n] = src[:n]``, written as a loop: a slice assignment needs numba's
    runtime, which this module's functions run without (the module docstring)."""
    for i in range(n):
        dst[i] = src[i]


@no_runtime()
def stage_rate(rhs, p, x, force, contacts, modes, dx, y, r):
    """``dx = rhs(x)`` with each contact's law applied (``modes[j]``: 0 stuck, +-1 the
    side it slides on). A stuck contact's speed has rate 0; a sliding one's friction is
    held on its side where the stage's speed overshot through zero (as
    :func:`evo_door.sim.located.sided`: its two sides differ by its rate at
    ``+-CREEP``). ``y`` and ``r`` are scratch rows."""
    rhs(x, force, p, dx)
    for j in range(contacts.shape[0]):
        k = contacts[j]
        side = modes[j]
        if side == 0:
            dx[k] = 0.0
        elif x[k] * side <= 0.0:
            copy_into(y, x, y.shape[0])
            here = dx[k]
            if x[k] != 0.0:
                y[k] = -side * CREEP
                rhs(y, force, p, r)
                here = r[k]
            y[k] = side * CREEP
            rhs(y, force, p, r)
            dx[k] = dx[k] - here + r[k]


@no_runtime(inline="always")
def side_rate(rhs, p, x, force, k, side, y, r):
    """The rate of contact speed ``x[k]`` at rest, read on ``side`` (+1 / -1) of its
    friction: the rhs at ``x[k] = side * CREEP``."""
    copy_into(y, x, y.shape[0])
    y[k] = side * CREEP
    rhs(y, force, p, r)
    return r[k]


@no_runtime()
def sample_rate(rhs, p, x, force, contacts, dx, y, r):
    """The state's rate at a sample instant, a contact at rest given the stick-slip
    rate (:func:`evo_door.sim.located.rate`): 0 while its friction holds the other
    forces, else its rate on the side it slips to."""
    rhs(x, force, p, dx)
    for j in range(contacts.shape[0]):
        k = contacts[j]
        if x[k] != 0.0:
            continue
        forward = side_rate(rhs, p, x, force, k, 1.0, y, r)
        if forward > 0.0:
            dx[k] = forward
            continue
        backward = side_rate(rhs, p, x, force, k, -1.0, y, r)
        dx[k] = backward if backward < 0.0 else 0.0


@no_runtime(inline="always")
def set_modes(x, contacts, modes):
    """Each contact's mode from its speed: 0 at rest (stuck), else its sign."""
    for j in range(contacts.shape[0]):
        v = x[contacts[j]]
        modes[j] = 1 if v > 0.0 else (-1 if v < 0.0 else 0)


@no_runtime()
def surfaces(rhs, switches, p, x, force, n_sw, contacts, modes, g, y, r):
    """All switching values into ``g``: the model's ``n_sw``, then one per contact:
    a sliding contact's speed, a stuck one's ``min(-forward, backward)`` (its rates
    at ``+-CREEP``), negative once the other forces beat the friction."""
    switches(x, force, p, g)
    for j in range(contacts.shape[0]):
        k = contacts[j]
        if modes[j] != 0:
            g[n_sw + j] = x[k]
        else:
            forward = side_rate(rhs, p, x, force, k, 1.0, y, r)
            backward = side_rate(rhs, p, x, force, k, -1.0, y, r)
            g[n_sw + j] = min(-forward, backward)


@no_runtime(inline="always")
def rk4_step(rhs, p, x, a1, f0, f1, h, contacts, modes, W, out):
    """One RK4 step of length ``h`` (force linear from f0 to f1); ``a1`` the rate at
    ``x``; the new state into ``out``."""
    xs, k2, k3, k4, y, r = W[XS], W[K2], W[K3], W[K4], W[Y], W[R]
    n = x.shape[0]
    fm = 0.5 * (f0 + f1)
    for i in range(n):
        xs[i] = x[i] + 0.5 * h * a1[i]
    stage_rate(rhs, p, xs, fm, contacts, modes, k2, y, r)
    for i in range(n):
        xs[i] = x[i] + 0.5 * h * k2[i]
    stage_rate(rhs, p, xs, fm, contacts, modes, k3, y, r)
    for i in range(n):
        xs[i] = x[i] + h * k3[i]
    stage_rate(rhs, p, xs, f1, contacts, modes, k4, y, r)
    for i in range(n):
        out[i] = x[i] + h / 6.0 * (a1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@no_runtime(inline="always")
def dopri_step(rhs, p, x, a1, t, h, f0, slope, tol, contacts, modes, W, out):
    """One Dormand-Prince 5(4) step of length ``h`` from time ``t`` of the period (force
    ``f0 + slope * time``); the new state into ``out``, its rate (the next step's first
    stage) into ``W[K7]``. Returns the error estimate over the tolerance,
    ``max_i |err_i| / (tol (1 + |x_i|))`` (a good step: at most 1)."""
    xs, k2, k3, k4, k5, k6, k7 = W[XS], W[K2], W[K3], W[K4], W[K5], W[K6], W[K7]
    y, r = W[Y], W[R]
    n = x.shape[0]
    for i in range(n):
        xs[i] = x[i] + h * _A21 * a1[i]
    stage_rate(rhs, p, xs, f0 + slope * (t + _C2 * h), contacts, modes, k2, y, r)
    for i in range(n):
        xs[i] = x[i] + h * (_A31 * a1[i] + _A32 * k2[i])
    stage_rate(rhs, p, xs, f0 + slope * (t + _C3 * h), contacts, modes, k3, y, r)
    for i in range(n):
        xs[i] = x[i] + h * (_A41 * a1[i] + _A42 * k2[i] + _A43 * k3[i])
    stage_rate(rhs, p, xs, f0 + slope * (t + _C4 * h), contacts, modes, k4, y, r)
    for i in range(n):
        xs[i] = x[i] + h * (_A51 * a1[i] + _A52 * k2[i] + _A53 * k3[i] + _A54 * k4[i])
    stage_rate(rhs, p, xs, f0 + slope * (t + _C5 * h), contacts, modes, k5, y, r)
    for i in range(n):
        xs[i] = x[i] + h * (
            _A61 * a1[i] + _A62 * k2[i] + _A63 * k3[i] + _A64 * k4[i] + _A65 * k5[i]
        )
    stage_rate(rhs, p, xs, f0 + slope * (t + h), contacts, modes, k6, y, r)
    for i in range(n):
        out[i] = x[i] + h * (_B1 * a1[i] + _B3 * k3[i] + _B4 * k4[i] + _B5 * k5[i] + _B6 * k6[i])
    stage_rate(rhs, p, out, f0 + slope * (t + h), contacts, modes, k7, y, r)
    err = 0.0
    for i in range(n):
        e = h * (_E1 * a1[i] + _E3 * k3[i] + _E4 * k4[i] + _E5 * k5[i] + _E6 * k6[i] + _E7 * k7[i])
        err = max(err, abs(e) / (tol * (1.0 + abs(x[i]))))
    if not math.isfinite(err):
        err = math.inf
    return err


@no_runtime(inline="always")
def jacobian(rhs, p, x, force, J, a0, y, r):
    """Forward-difference Jacobian ``J[i, j] = d rhs_i / d x_j`` at ``x`` (steps
    ``1e-7 (1 + |x_j|)``, as the one-coordinate form), its positive diagonal entries
    set to 0: a state that feeds its own growth (negative damping) is left to the
    explicit part, as the one-coordinate form does with ``a_w > 0``."""
    n = x.shape[0]
    rhs(x, force, p, a0)
    for j in range(n):
        e = 1e-7 * (1.0 + abs(x[j]))
        copy_into(y, x, y.shape[0])
        y[j] = x[j] + e
        rhs(y, force, p, r)
        for i in range(n):
            J[i, j] = (r[i] - a0[i]) / e
    for i in range(n):
        J[i, i] = min(J[i, i], 0.0)


@no_runtime(inline="always")
def lu_factor(M, piv):
    """LU factorisation of ``M`` in place, partial pivoting (``piv`` the row swaps);
    returns the determinant."""
    n = M.shape[0]
    det = 1.0
    for c in range(n):
        best = c
        for i in range(c + 1, n):
            if abs(M[i, c]) > abs(M[best, c]):
                best = i
        piv[c] = best
        if best != c:
            det = -det
            for j in range(n):
                M[c, j], M[best, j] = M[best, j], M[c, j]
        d = M[c, c]
        det *= d
        if d == 0.0:
            continue
        for i in range(c + 1, n):
            m = M[i, c] / d
            M[i, c] = m
            for j in range(c + 1, n):
                M[i, j] -= m * M[c, j]
    return det


@no_runtime(inline="always")
def lu_solve(M, piv, b):
    """Solve ``M z = b`` in place in ``b`` with the factors of :func:`lu_factor`."""
    n = M.shape[0]
    for c in range(n):
        k = piv[c]
        if k != c:
            b[c], b[k] = b[k], b[c]
        for i in range(c + 1, n):
            b[i] -= M[i, c] * b[c]
    for i in range(n - 1, -1, -1):
        s = b[i]
        for j in range(i + 1, n):
            s -= M[i, j] * b[j]
        b[i] = s / M[i, i]


@no_runtime(inline="always")
def ros2_step(rhs, p, x, a1, f1, h, contacts, modes, JM, piv, W, out):
    """One ROS2 step (the Jacobian ``JM[0]`` frozen over the period); the new state
    into ``out``. ``(I - gamma h J) k1 = f(x)``, ``(I - gamma h J) k2 = f(x + h k1) -
    2 k1``, ``x_new = x + h (3 k1 + k2) / 2``; a stuck contact's row is the identity
    (its speed stays exactly 0)."""
    J, M = JM[0], JM[1]
    k1, k2, xs, y, r = W[K2], W[K3], W[XS], W[Y], W[R]
    n = x.shape[0]
    gh = GAMMA * h
    for i in range(n):
        for j in range(n):
            M[i, j] = -gh * J[i, j]
        M[i, i] += 1.0
    for j in range(contacts.shape[0]):
        if modes[j] == 0:
            k = contacts[j]
            for i in range(n):
                M[k, i] = 0.0
            M[k, k] = 1.0
    implicit = lu_factor(M, piv) >= MIN_DETERMINANT
    copy_into(k1, a1, k1.shape[0])
    if implicit:
        lu_solve(M, piv, k1)
    for i in range(n):
        xs[i] = x[i] + h * k1[i]
    stage_rate(rhs, p, xs, f1, contacts, modes, k2, y, r)
    for i in range(n):
        k2[i] = k2[i] - 2.0 * k1[i]
    if implicit:
        lu_solve(M, piv, k2)
    for i in range(n):
        out[i] = x[i] + h * (1.5 * k1[i] + 0.5 * k2[i])


@no_runtime()
def trial_step(rhs, p, x, a1, t, h, f0, slope, method, tol, contacts, modes, JM, piv, W, out):
    """One step of ``method`` of length ``h`` from time ``t`` of the period into
    ``out``; returns dopri5's error estimate (0 for the fixed steps)."""
    if method == DOPRI5:
        return dopri_step(rhs, p, x, a1, t, h, f0, slope, tol, contacts, modes, W, out)
    if method == SEMI_IMPLICIT:
        ros2_step(rhs, p, x, a1, f0 + slope * (t + h), h, contacts, modes, JM, piv, W, out)
    else:
        rk4_step(rhs, p, x, a1, f0 + slope * t, f0 + slope * (t + h), h, contacts, modes, W, out)
    return 0.0


@no_runtime(inline="always")
def plain_period(rhs, p, x, f0, f1, a_start, dt, substeps, method, contacts, modes, JM, piv, W):
    """A period in ``substeps`` fixed steps, nothing located (a model without surfaces
    or contacts, RK4 or ROS2: :func:`evo_door.sim.integrators.advance`); ``a_start``
    the rate at the period's start."""
    h = dt / substeps
    df = (f1 - f0) / substeps
    a1, x1 = W[A1], W[X1]
    copy_into(a1, a_start, a1.shape[0])
    if method == SEMI_IMPLICIT:
        jacobian(rhs, p, x, f0, JM[0], W[DX], W[Y], W[R])
    for s in range(substeps):
        if s > 0:
            rhs(x, f0 + s * df, p, a1)
        if method == SEMI_IMPLICIT:
            ros2_step(rhs, p, x, a1, f0 + (s + 1) * df, h, contacts, modes, JM, piv, W, x1)
        else:
            rk4_step(rhs, p, x, a1, f0 + s * df, f0 + (s + 1) * df, h, contacts, modes, W, x1)
        copy_into(x, x1, x.shape[0])
