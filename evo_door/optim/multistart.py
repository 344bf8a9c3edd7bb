"""Scans along each parameter and a polish from several starts: fits with thresholds.

A threshold parameter (the latch's unlock force: a pull below it does not unlock, so
the response does not change with the force until the force crosses it) gives a
fitness with a narrow notch beside a plateau. A GA's best may sit on the plateau,
where SLSQP sees no slope and stops: on the case study's latch stage the unlock force
ended 5 % off for three GA seeds in five, on the same trials. A finer GA only moves the
odds. :func:`scan_and_polish` looks for the notch on purpose, then polishes from the
best few places it found.

The scan
    One parameter at a time, in the problem's order, the others at the best point so
    far: ``points`` values evenly over its search range, evaluated in one batch. A
    notch narrower than the grid's step can hide between two grid values, so each of
    the grid's intervals is ranked by the lowest value the straight lines through its
    neighbours reach inside it (:func:`interval_bounds`: the line down a slope is
    carried on past the last point, the way a Lipschitz bound is). A steep descent that
    ends on a plateau, the notch's sign, ranks first though no grid value shows the
    notch. The ``starts`` best intervals are searched again, each on a grid of
    ``points`` values over it and one step on either side (a zoom of ``(points - 1) /
    3`` a level), ``levels - 1`` times following its best interval. Cost:
    ``points (1 + starts (levels - 1))`` evaluations a parameter (21, 2, 4: 147).
The polish
    The best ``starts`` distinct points met (the start point, every scan's best; two
    are distinct when some parameter differs by more than 1 % of its range)
    are each polished (:func:`evo_door.optim.local.polish`), and the best polish is the
    answer. Like the polish it is never worse than its start point.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from evo_door.optim.local import LocalResult, LocalSettings, polish

#: candidates closer than this (a fraction of every parameter's range) are one start
DISTINCT = 1e-2


@dataclass(frozen=True)
class ScanSettings:
    """The scan before a multi-start polish (module docstring); ``points = 0``: none."""

    points: int = 0
    starts: int = 2
    levels: int = 4

    def __post_init__(self):
        if self.points != 0 and self.points < 3:
            raise ValueError("a scan needs at least 3 points (0: no scan)")
        if self.starts < 1 or self.levels < 1:
            raise ValueError("starts and levels must be at least 1")

    @property
    def enabled(self) -> bool:
        return self.points > 0


def interval_bounds(f) -> np.ndarray:
    """For each interval of a grid's values ``f`` (``len(f) - 1`` of them), the lowest
    value the lines through the neighbouring pairs reach inside it, and its ends.

    Interval ``k`` (between points ``k`` and ``k + 1``) gets the smallest of ``f[k]``,
    ``f[k + 1]``, the line through points ``k - 1, k`` carried to ``k + 1`` and the
    line through ``k + 1, k + 2`` carried back to ``k``. A non-finite value (a blown
    simulation) counts as +inf.

    >>> interval_bounds([4.0, 3.0, 2.0, 0.5, 0.5, 0.5]).round(2).tolist()
    [3.0, 2.0, 0.5, -1.0, 0.5]
    """
    f = np.where(np.isfinite(f), np.asarray(f, dtype=np.float64), np.inf)
    n = f.size
    out = np.minimum(f[:-1], f[1:])
    with np.errstate(invalid="ignore"):
        down = 2.0 * f[1:-1] - f[:-2]  # line through k-1, k at k+1 (k = 1 .. n-2)
        back = 2.0 * f[1:-1] - f[2:]  # line through k+1, k+2 at k (k = 0 .. n-3)
    out[1:] = np.fmin(out[1:], np.where(np.isfinite(down), down, np.inf))
    out[: n - 2] = np.fmin(out[: n - 2], np.where(np.isfinite(back), back, np.inf))
    return out


def _best_intervals(f, count: int) -> list[int]:
    """The ``count`` most promising intervals of ``f`` (lowest bound first)."""
    bounds = interval_bounds(f)
    order = np.argsort(bounds, kind="stable")
    return [int(k) for k in order[:count] if np.isfinite(bounds[k])]


def _grids(problem, x, j: int, spans, points: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """For each ``(lo, hi)`` of ``spans``: ``points`` candidates, ``x`` with parameter
    ``j`` even over ``[lo, hi]``, and their fitness (inf where blown up); all of them
    evaluated in one batch."""
    X = np.repeat(x[None, :], points * len(spans), axis=0)
    X[:, j] = np.concatenate([np.linspace(a, b, points) for a, b in spans])
    f, blown = problem.evaluate(X)
    f = np.where(blown | ~np.isfinite(f), np.inf, f)
    return [
        (X[k * points : (k + 1) * points], f[k * points : (k + 1) * points])
        for k in range(len(spans))
    ]


def scan(problem, x0, settings: ScanSettings) -> tuple[list[tuple[float, np.ndarray]], int]:
    """The scans of the module docstring from ``x0``: ``([(fitness, x), ...], evaluations)``,
    every window's best point, the start point first."""
    x = np.asarray(x0, dtype=np.float64).copy()
    f0 = float(problem.evaluate(x[None, :])[0][0])
    found = [(f0 if np.isfinite(f0) else np.inf, x.copy())]
    evaluations, n = 1, settings.points
    for j in range(problem.n_var):
        lo, hi = float(problem.lower[j]), float(problem.upper[j])
        ((X, f),) = _grids(problem, x, j, [(lo, hi)], n)
        evaluations += n
        found.append((float(f.min()), X[int(np.argmin(f))].copy()))
        # each window: its grid's values of parameter j, their fitness, the interval to zoom
        windows = [(X[:, j], f, k) for k in _best_intervals(f, settings.starts)]
        for _ in range(settings.levels - 1):
            spans = []
            for grid, _, k in windows:
                step = grid[1] - grid[0]
                spans.append((max(lo, grid[k] - step), min(hi, grid[k + 1] + step)))
            zoomed = _grids(problem, x, j, spans, n) if spans else []
            evaluations += n * len(spans)
            windows = []
            for Xw, fw in zoomed:
                i = int(np.argmin(fw))
                found.append((float(fw[i]), Xw[i].copy()))
                windows.append((Xw[:, j], fw, (_best_intervals(fw, 1) or [min(i, n - 2)])[0]))
        x = min(found, key=lambda c: c[0])[1].copy()  # the next parameter scans from here
    return found, evaluations


def distinct_starts(found, count: int, width) -> list[np.ndarray]:
    """The ``count`` best of ``found`` (``(fitness, x)`` pairs), no two within
    :data:`DISTINCT` of the range ``width`` in every parameter."""
    starts: list[np.ndarray] = []
    for _, x in sorted(found, key=lambda c: c[0]):
        if all(np.any(np.abs(x - s) > DISTINCT * width) for s in starts):
            starts.append(x)
        if len(starts) == count:
            break
    return starts


def scan_and_polish(
    problem, x0, settings: ScanSettings, local: LocalSettings | None = None
) -> LocalResult:
    """Scan from ``x0``, polish from the best distinct points, keep the best polish.

    The result reads as one polish from ``x0`` (``x0``, ``fitness0``: the start), with
    the scans' evaluations counted in and what was done in ``message``.
    """
    t0 = time.perf_counter()
    x0 = np.clip(np.asarray(x0, dtype=np.float64), problem.lower, problem.upper)
    found, scanned = scan(problem, x0, settings)
    starts = distinct_starts(found, settings.starts, problem.upper - problem.lower)
    runs = [polish(problem, s, local) for s in starts]
    k = int(np.argmin([r.fitness if np.isfinite(r.fitness) else np.inf for r in runs]))
    best = runs[k]
    fitness0 = found[0][0]
    x, f = (best.x, best.fitness) if best.fitness <= fitness0 else (x0, fitness0)
    return LocalResult(
        x0=x0,
        fitness0=float(fitness0),
        x=np.array(x, dtype=np.float64),
        fitness=float(f),
        iterations=sum(r.iterations for r in runs),
        evaluations=scanned + sum(r.evaluations for r in runs),
        blowups=sum(r.blowups for r in runs),
        success=best.success,
        message=(
            f"scan: {scanned} evaluations (points {settings.points}, levels "
            f"{settings.levels}, starts {settings.starts}); polished from "
            f"{len(runs)} starts (fitness "
            + ", ".join(f"{r.fitness0:.4g} -> {r.fitness:.4g}" for r in runs)
            + f"), kept start {k + 1}: {best.message}"
        ),
        seconds=time.perf_counter() - t0,
    )
