"""How a fit's residual changes with each free parameter, at the estimate.

The first half of the identifiability check (:mod:`evo_door.optim.identifiability`):
the residual the statistics are computed on, and its Jacobian by finite differences.

Residuals
    ``r`` stacks, over every fitted trial and every *counted* sample (a saturated
    sensor sample does not count), ``sqrt(w_k dt) (y_s[k] - y_h[k])``: model minus
    target on the objective's channel (``d^n theta``), with the trapezoid weights of the
    ISE kernel (``w = 1/2`` at a trial's first and last sample, else 1). So
    ``sum(r^2)`` is the sum over the trials of their ISE (eq. 5.4), the fitness of an
    ISE objective with ``combine: sum`` (``mean`` divides it by the number of trials,
    which changes neither the minimiser nor the standard errors of
    :mod:`evo_door.optim.covariance`). The theory is that of least squares, a sum of
    squares at its minimum. For a **max-square** objective (eq. 5.3) or ``combine:
    max``, which are not sums of squares, the same ISE residuals are used at the given
    ``x``: the numbers then describe the ISE of the same channel linearised there,
    which is the local information the data hold, but ``x`` is not its minimiser (the
    result says so in ``note``).
Sensitivity
    ``J = dr/dx`` by central differences with the step ``h_j = step (hi_j - lo_j)``,
    a fixed fraction of parameter ``j``'s search range (default ``1e-4``): the range is
    what the experiment calls a meaningful variation of the parameter, and unlike
    ``|x_j|`` it is never zero. The responses are smooth in the parameters (fixed-step
    integration, tanh friction laws), so the error is ``O(h^2)`` plus round-off of
    order ``1e-16 / 1e-4``: both far below the statistical spread (the tests compare
    with scipy's ``approx_fprime`` and across steps from 1e-5 to 1e-3). Where ``x_j +-
    2 h_j`` leaves the search range the second-order one-sided difference inward is
    used. ``J`` is evaluated at ``h`` and at ``2 h``; ``step_agreement`` is the largest
    relative change of a column between the two (round-off or a kink shows there).
    Normalised sensitivities, comparable between parameters: ``sensitivity`` is
    ``|| x_j dr/dx_j ||`` (``dr / d ln x``: the residual change for a 100 % change of
    the parameter, linearised) and ``sensitivity_range`` ``|| (hi_j - lo_j) dr/dx_j ||``,
    both in the residual's unit (``rad/s s^0.5`` for ISE on speed); ``cosine`` is the
    cosine between sensitivity columns (``+-1``: the same effect on the response).
"""

from __future__ import annotations

import numpy as np

from evo_door.errors import UserError

#: Finite-difference step, as a fraction of each parameter's search range.
STEP = 1e-4


# -- residuals and their sensitivity ----------------------------------------------------
def sample_weights(pack) -> list[np.ndarray]:
    """Per trial, ``sqrt(w_k dt)`` on counted samples, 0 elsewhere (the ISE kernel's)."""
    out = []
    for j, (a, b) in enumerate(zip(pack.offsets[:-1], pack.offsets[1:])):
        w = np.full(b - a, pack.dt[j])
        w[0] *= 0.5
        w[-1] *= 0.5
        out.append(np.sqrt(np.where(pack.mask[a:b], w, 0.0)))
    return out


def _responses(problem, X) -> tuple[list[np.ndarray], np.ndarray]:
    """Weighted residuals of every row of ``X`` on each fitted trial, and which blew up.

    Returns a list (one per trial) of ``(len(X), n_counted)`` arrays and a boolean
    array, True where a row's simulation of some trial blew up.
    """
    pack = problem.fit
    P = problem.full(X)
    derivative = problem.objective.derivative
    blown = np.zeros(len(P), dtype=bool)
    out = []
    for j, sw in enumerate(sample_weights(pack)):
        a, b = pack.offsets[j], pack.offsets[j + 1]
        sim = problem.trial_runs(X, j)  # an FMU's in its sandbox
        keep = sw > 0.0
        r = (sim[derivative][:, keep] - pack.target[a:b][keep]) * sw[keep]
        blown |= ~sim[3] | ~np.all(np.isfinite(r), axis=1)
        out.append(r)
    return out, blown


def residuals(problem, x) -> list[np.ndarray]:
    """Weighted residuals of ``x`` on each fitted trial (see the module docstring).

    The sum of their squares is the ISE (eq. 5.4) summed over the trials.
    """
    x = check_estimate(problem, x)
    r, blown = _responses(problem, x[None, :])
    if blown[0]:
        raise UserError("the model blows up at the estimate: no identifiability to compute")
    return [rj[0] for rj in r]


def _stencils(x, lo, hi, h):
    """Per parameter: offsets (in steps) and weights of a derivative of step ``h``.

    Central ``(f(+1) - f(-1)) / 2`` where ``x +- 2 h`` stays in range, else the
    second-order one-sided difference inward, ``(-3 f(0) + 4 f(1) - f(2)) / 2``.
    """
    out = []
    for v, a, b, s in zip(x, lo, hi, h):
        if v - 2.0 * s >= a and v + 2.0 * s <= b:
            out.append(((-1.0, 1.0), (-0.5, 0.5)))
        else:
            d = 1.0 if v - 2.0 * s < a else -1.0
            out.append(((0.0, d, 2.0 * d), (-1.5 * d, 2.0 * d, -0.5 * d)))
    return out


def jacobians(problem, x, steps=(STEP,)) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """Residual at ``x`` and its Jacobian for each relative step in ``steps``.

    Returns ``(r, [J for each step], blown)``: ``r`` of length N (every trial's counted
    samples, stacked), each ``J`` (N, p) in residual unit per parameter unit, ``blown``
    (p,) True where a finite-difference point blew up (that column is NaN).
    """
    x = check_estimate(problem, x)
    width = problem.upper - problem.lower
    rows = [x]
    plan = []  # per step, per parameter: (row indices, weights, h)
    for step in steps:
        h = float(step) * width
        per = []
        for j, (offsets, weights) in enumerate(_stencils(x, problem.lower, problem.upper, h)):
            idx = []
            for o in offsets:
                if o == 0.0:
                    idx.append(0)
                    continue
                xi = x.copy()
                xi[j] = x[j] + o * h[j]
                idx.append(len(rows))
                rows.append(np.clip(xi, problem.lower, problem.upper))
            per.append((idx, np.array(weights), h[j]))
        plan.append(per)
    # the estimate first, alone (:func:`residuals` refuses it where it blows up): the
    # stencil's points are then not run at all (an FMU that crashes there would cost a
    # new sandbox child per point and trial)
    r0 = np.concatenate(residuals(problem, x))
    parts, blown_rows = _responses(problem, np.array(rows[1:]))
    blown_rows = np.concatenate([[False], blown_rows])
    R = np.vstack([r0, np.concatenate(parts, axis=1)])  # (rows, N)
    blown = np.zeros(len(x), dtype=bool)
    out = []
    for per in plan:
        J = np.empty((R.shape[1], len(x)))
        for j, (idx, weights, hj) in enumerate(per):
            if blown_rows[idx].any():
                blown[j] = True
                J[:, j] = np.nan
            else:
                J[:, j] = weights @ R[idx] / hj
        out.append(J)
    return r0, out, blown


def check_estimate(problem, x) -> np.ndarray:
    """``x`` as a float vector, checked: one value per free parameter, finite, in range."""
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    if x.shape != (problem.n_var,):
        raise UserError(f"the estimate needs {problem.n_var} values ({', '.join(problem.free)})")
    if not np.all(np.isfinite(x)):
        raise UserError("the estimate has a non-finite value")
    outside = (x < problem.lower) | (x > problem.upper)
    if outside.any():
        j = int(np.flatnonzero(outside)[0])
        raise UserError(
            f"the estimate {problem.free[j]} = {x[j]:g} is outside its search range "
            f"[{problem.lower[j]:g}, {problem.upper[j]:g}]"
        )
    return x
