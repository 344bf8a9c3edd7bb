"""The force at the handle of a model on a state vector, at static equilibrium (compiled).

A model given by ``accel(theta, dtheta, force, p)`` has its quasi-static force in closed
form: ``accel`` is affine in the force, and the force that makes it zero is
``-a(0) / (a(1) - a(0))``. A model on a state vector ``x`` (an elastic cable to the
spring, a second body, a damper's fluid) has states of its own that the handle's
position does not fix. Its quasi-static force is the solution of a static equilibrium:
with the handle held at ``theta`` and moved at the steady speed ``dtheta``, find the
other states ``z`` and the force ``F`` such that

- every other state is at rest, ``dx[i] = 0`` for ``i`` not the handle's position or
  speed (a carriage on its spring, a second body that the first one drags, a damper's
  pressure settled), and
- the handle does not accelerate, ``dx[speed] = 0``.

That is ``m + 1`` equations in ``m + 1`` unknowns (``m`` the other states), solved by
Newton's method with a forward-difference Jacobian and a small LU with partial pivoting.
Along a curve each angle starts from the previous angle's solution (continuation), so a
scan over the stroke follows one branch of the equilibrium. A state that no equation
holds (a body on a slack cable, at rest anywhere) makes the Jacobian singular: a small
diagonal (1e-9 of its largest entry) then keeps that state where it is and solves the
others. A point where Newton does not converge gives NaN (the curve's caller says where).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange, types

from evo_door.sim.states import RHS_TYPE

_vec = types.float64[::1]
_mat = types.float64[:, ::1]

#: Newton iterations per point, and the step's relative size at which a point is solved.
MAX_NEWTON = 60
NEWTON_TOL = 1e-12


@njit(cache=True, nogil=True)
def _residual(rhs, p, x, unknowns, u, speed, dx, r):
    """Write the equilibrium's residual at ``u`` (the other states, then the force)."""
    m = unknowns.shape[0]
    for i in range(m):
        x[unknowns[i]] = u[i]
    rhs(x, u[m], p, dx)
    for i in range(m):
        r[i] = dx[unknowns[i]]
    r[m] = dx[speed]


@njit(cache=True, nogil=True)
def _solve(a, b):
    """Solve ``a y = b`` in place (``b`` becomes ``y``) by LU with partial pivoting;
    False when ``a`` is singular."""
    n = b.shape[0]
    for k in range(n):
        piv = k
        for i in range(k + 1, n):
            if abs(a[i, k]) > abs(a[piv, k]):
                piv = i
        if a[piv, k] == 0.0 or not math.isfinite(a[piv, k]):
            return False
        if piv != k:
            for j in range(n):
                a[k, j], a[piv, j] = a[piv, j], a[k, j]
            b[k], b[piv] = b[piv], b[k]
        for i in range(k + 1, n):
            f = a[i, k] / a[k, k]
            for j in range(k, n):
                a[i, j] -= f * a[k, j]
            b[i] -= f * b[k]
    for k in range(n - 1, -1, -1):
        s = b[k]
        for j in range(k + 1, n):
            s -= a[k, j] * b[j]
        b[k] = s / a[k, k]
    return True


@njit(
    types.void(RHS_TYPE, _vec, _vec, types.float64, _vec, types.int64, types.int64, _vec, _vec),
    cache=True,
    nogil=True,
)
def hold_states(rhs, p, theta, dtheta, x0, position, speed, out, slope):
    """The force (``out``) holding the handle at each ``theta`` (in order, each point
    starting from the last one's solution) while it moves at ``dtheta``, the other states
    at rest; ``x0``: the first guess of the whole state. ``slope`` gets ``d dx[speed] /
    dF`` at each solution (1 / the felt inertia). NaN where Newton does not converge."""
    # long: Newton's loop with its Jacobian by columns; one body, read top to bottom
    n = x0.shape[0]
    m = n - 2
    unknowns = np.empty(m, dtype=np.int64)
    k = 0
    for i in range(n):
        if i != position and i != speed:
            unknowns[k] = i
            k += 1
    x = x0.copy()
    dx = np.empty(n)
    u = np.empty(m + 1)
    for i in range(m):
        u[i] = x0[unknowns[i]]
    u[m] = 0.0
    r = np.empty(m + 1)
    r2 = np.empty(m + 1)
    jac = np.empty((m + 1, m + 1))
    start = u.copy()
    for j in range(theta.shape[0]):
        x[position] = theta[j]
        x[speed] = dtheta
        solved = False
        for _ in range(MAX_NEWTON):
            _residual(rhs, p, x, unknowns, u, speed, dx, r)
            for c in range(m + 1):
                h = 1e-7 * (1.0 + abs(u[c]))
                keep = u[c]
                u[c] = keep + h
                _residual(rhs, p, x, unknowns, u, speed, dx, r2)
                u[c] = keep
                for i in range(m + 1):
                    jac[i, c] = (r2[i] - r[i]) / h
            step = -r
            keep_jac = jac.copy()
            if not _solve(jac, step):
                # a state no equation holds (a body on a slack cable, free to sit
                # anywhere): a small diagonal leaves it where it is, the others solved
                step = -r
                ridge = 1e-9 * (1.0 + np.max(np.abs(keep_jac)))
                for i in range(m + 1):
                    keep_jac[i, i] += ridge
                if not _solve(keep_jac, step):
                    break
            size = 0.0
            for i in range(m + 1):
                u[i] += step[i]
                size = max(size, abs(step[i]) / (1.0 + abs(u[i])))
            if not math.isfinite(size):
                break
            if size < NEWTON_TOL:
                solved = True
                break
        if solved:
            _residual(rhs, p, x, unknowns, u, speed, dx, r)
            base = dx[speed]
            keep = u[m]
            u[m] = keep + 1.0
            _residual(rhs, p, x, unknowns, u, speed, dx, r2)
            slope[j] = dx[speed] - base  # affine in the force: exact
            u[m] = keep
            out[j] = u[m]
            for i in range(m + 1):
                start[i] = u[i]
        else:
            out[j] = math.nan
            slope[j] = math.nan
            for i in range(m + 1):
                u[i] = start[i]  # the next point starts from the last solved one


@njit(
    types.void(RHS_TYPE, _mat, _vec, types.float64, _mat, types.int64, types.int64, _mat, _mat),
    cache=True,
    parallel=True,
)
def hold_states_rows(rhs, P, theta, dtheta, X0, position, speed, out, slope):
    """:func:`hold_states` for every row of ``P`` (from the first guess ``X0[r]``) into
    ``out[r]`` and ``slope[r]``, the rows in parallel: the feel of a population of
    mechanisms (its force-angle curves, its felt inertia) in one call."""
    for r in prange(P.shape[0]):
        hold_states(rhs, P[r], theta, dtheta, X0[r], position, speed, out[r], slope[r])
