"""Local gradient refinement with scipy's SLSQP: the analogue of AMESim's NLPQL.

Both NLPQL (Schittkowski) and SLSQP (Kraft) are sequential quadratic programming
methods for smooth problems with bounds. :func:`slsqp` works in normalised
coordinates ``z = (x - lo) / (hi - lo)`` in ``[0, 1]`` and on the objective divided by
its value at the start point, so that scipy's absolute tolerances mean the same for
every problem. The gradient is a forward difference (backward at the upper bound)
whose ``n + 1`` points are evaluated in one batched compiled call. A candidate whose
simulation blows up gets a large finite value (SLSQP cannot digest inf), and the
result is never worse than the start point.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

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

    res = minimize(lambda z: value_and_grad(z)[0], (x0 - lo) / width,
                   jac=lambda z: value_and_grad(z)[1], method="SLSQP",
                   bounds=[(0.0, 1.0)] * len(x0),
                   options={"maxiter": settings.max_iterations, "ftol": settings.ftol})
    x = to_x(res.x)
    f = float(raw(((x - lo) / width)[None, :])[0])
    if not f <= f0:  # never hand back something worse than the start (or a NaN)
        x, f = x0, f0
    return LocalResult(x0=x0, fitness0=f0, x=x, fitness=f, iterations=int(res.nit),
                       evaluations=counts["evaluations"], blowups=counts["blowups"],
                       success=bool(res.success), message=str(res.message),
                       seconds=time.perf_counter() - t0)
