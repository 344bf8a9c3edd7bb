"""Estimates on a bound of their search range: one tolerance, one test.

An estimate within :data:`BOUND_TOLERANCE` of its search range from a bound was stopped
by the bound, not by the data. The run writes which estimates did (``best/@at_bound``),
the views flag them and the identifiability check calls them ``not identifiable``
(whatever their curvature says: the local theory assumes an interior optimum, and the
data would have taken the estimate further): all three ask here, so that they cannot
disagree.

Why 1 %: an estimate the data put inside the range but the bound pulled on (a GA and a
polish that stop a hair inside it, 29.96 N against a 30 N bound on a 0..30 N range) is
as much the bound's as one exactly on it; a thousandth of the range let such estimates
pass as interior ones. A genuine interior optimum within 1 % of a bound is reported
too, which costs a widened range and a second run, not a wrong specification.
"""

from __future__ import annotations

import math

#: an estimate this close to a bound (as a fraction of its search range) was decided
#: by the bound, not by the data
BOUND_TOLERANCE = 1e-2


def bound_hits(names, x, lower, upper, tolerance: float = BOUND_TOLERANCE) -> dict[str, str]:
    """The estimates that sit on a bound of their search range: name -> ``"lower"|"upper"``.

    An estimate within ``tolerance`` (1 %) of the range ``hi - lo`` from a bound was
    stopped by the bound: the data would have taken it further, so the value says
    more about the range in ``free:`` than about the product.

    >>> bound_hits(["k", "c", "m"], [497.0, 2.0, 0.26], [20, 0, 0.2], [500, 10, 8])
    {'k': 'upper', 'm': 'lower'}
    """
    out = {}
    for name, v, lo, hi in zip(names, x, lower, upper):
        v, lo, hi = float(v), float(lo), float(hi)
        if not math.isfinite(v):
            continue
        slack = tolerance * (hi - lo)
        if abs(v - lo) <= slack:
            out[name] = "lower"
        elif abs(hi - v) <= slack:
            out[name] = "upper"
    return out


def bound_side(x: float, lower: float, upper: float, tolerance: float = BOUND_TOLERANCE) -> str:
    """``"lower"``, ``"upper"`` or ``""``: which bound one estimate sits on (:func:`bound_hits`).

    >>> bound_side(29.96, 0.0, 30.0), bound_side(15.0, 0.0, 30.0)
    ('upper', '')
    """
    return bound_hits(["x"], [x], [lower], [upper], tolerance).get("x", "")
