"""Local gradient refinement with scipy's SLSQP: the analogue of AMESim's NLPQL.

Both NLPQL (Schittkowski) and SLSQP (Kraft) are sequential quadratic programming
methods for smooth problems with bounds. :func:`slsqp` works in normalised
coordinates ``z = (x - lo) / (hi - lo)`` in ``[0, 1]`` and on the objective divided by
its value at the start point, so that scipy's absolute tolerances mean the same for
every problem. The gradient is a forward difference (backward at the upper bound)
whose ``n + 1`` points are evaluated in one batched compiled call. A candidate whose
simulation blows up gets a large finite value (SLSQP cannot digest inf), and the
result is never worse than the start point.

:func:`polish` is what experiments call: SLSQP on the problem's objective, except that
a max-square objective (eq. 5.3) is first smoothed. The maximum over samples is not
differentiable where the maximising sample changes, and SLSQP started on it from a GA
result stalls or crawls (measured on the door, noise-free trials: a parameter left
40 % off). So :func:`polish` first runs SLSQP on the ISE (eq. 5.4) of the same
derivative, which has the same minimiser when the model can match the target exactly
and is smooth, then SLSQP on the max-square objective itself from there; the answer is
the best of the start point and the two stages *in the max-square objective*, so the
polish never makes the experiment's own fitness worse.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

#: Objective given to SLSQP for a blown-up candidate, relative to the start value.
BLOWUP_VALUE = 1.0e6


@dataclass(frozen=True)
class LocalSettings:
    """SLSQP settings: iteration cap, tolerance on the normalised objective, FD step."""

    max_iterations: int = 100
    ftol: float = 1e-12
    step: float = 1e-7


@dataclass
class LocalResult:
    x0: np.ndarray
    fitness0: float
    x: np.ndarray
    fitness: float
    iterations: int
    evaluations: int
    blowups: int
    success: bool
    message: str
    seconds: float

    def as_dict(self) -> dict:
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in vars(self).items()}


def slsqp(problem, x0, settings: LocalSettings | None = None) -> LocalResult:
    """Refine ``x0`` (free-parameter vector inside the bounds) with bounded SLSQP."""
    # long: the objective on the unit cube, its cached finite-difference
    # gradient and the call share one problem's bounds and counts as closures
    from scipy.optimize import minimize  # imported here: a tenth of a second at start-up

    settings = settings or LocalSettings()
    t0 = time.perf_counter()
    lo, hi = problem.lower, problem.upper
    width = hi - lo
    x0 = np.clip(np.asarray(x0, dtype=np.float64), lo, hi)
    counts = {"evaluations": 0, "blowups": 0}

    def to_x(z):
        return np.clip(lo + np.clip(z, 0.0, 1.0) * width, lo, hi)

    def raw(Z):
        X = np.array([to_x(z) for z in Z])
        f, blown = problem.evaluate(X)
        counts["evaluations"] += len(X)
        counts["blowups"] += int(blown.sum())
        return f

    f0 = float(raw(((x0 - lo) / width)[None, :])[0])
    scale = f0 if np.isfinite(f0) and f0 > 0 else 1.0
    cache: dict[bytes, tuple[float, np.ndarray]] = {}

    def value_and_grad(z):
        z = np.clip(np.asarray(z, dtype=np.float64), 0.0, 1.0)
        key = z.tobytes()
        if key not in cache:
            h = settings.step
            Z = np.repeat(z[None, :], len(z) + 1, axis=0)
            signs = np.where(z + h <= 1.0, 1.0, -1.0)
            Z[1:][np.diag_indices(len(z))] += signs * h
            f = raw(Z) / scale
            f = np.where(np.isfinite(f), f, BLOWUP_VALUE)
            grad = (f[1:] - f[0]) / (signs * h)
            cache.clear()
            cache[key] = (float(f[0]), grad)
        return cache[key]

    res = minimize(
        lambda z: value_and_grad(z)[0],
        (x0 - lo) / width,
        jac=lambda z: value_and_grad(z)[1],
        method="SLSQP",
        bounds=[(0.0, 1.0)] * len(x0),
        options={"maxiter": settings.max_iterations, "ftol": settings.ftol},
    )
    x = to_x(res.x)
    f = float(raw(((x - lo) / width)[None, :])[0])
    if not f <= f0:  # never hand back something worse than the start (or a NaN)
        x, f = x0, f0
    return LocalResult(
        x0=x0,
        fitness0=f0,
        x=x,
        fitness=f,
        iterations=int(res.nit),
        evaluations=counts["evaluations"],
        blowups=counts["blowups"],
        success=bool(res.success),
        message=str(res.message),
        seconds=time.perf_counter() - t0,
    )


def polish(problem, x0, settings: LocalSettings | None = None) -> LocalResult:
    """Refine ``x0`` on ``problem``'s objective (see the module docstring for max-square)."""
    from evo_door.optim.problem import Objective

    objective = problem.objective
    if objective.kind != "max_square":
        return slsqp(problem, x0, settings)
    t0 = time.perf_counter()
    smooth = problem.with_objective(Objective("ise", objective.derivative, objective.combine))
    first = slsqp(smooth, x0, settings)
    second = slsqp(problem, first.x, settings)
    x0 = first.x0
    candidates = np.array([x0, first.x, second.x])
    f, blown = problem.evaluate(candidates)
    f = np.where(blown | ~np.isfinite(f), np.inf, f)
    k = int(np.argmin(f))  # ties go to the earlier: the start point, then the ISE stage
    return LocalResult(
        x0=x0,
        fitness0=float(f[0]),
        x=candidates[k].copy(),
        fitness=float(f[k]),
        iterations=first.iterations + second.iterations,
        evaluations=first.evaluations + second.evaluations + len(candidates),
        blowups=first.blowups + second.blowups + int(blown.sum()),
        success=second.success,
        message=(
            f"ise stage: {first.iterations} iterations, {first.message}; max_square "
            f"stage: {second.iterations} iterations, {second.message}; kept "
            + ("the start point", "the ise stage", "the max_square stage")[k]
        ),
        seconds=time.perf_counter() - t0,
    )
