"""Estimates on a bound of their search range: one tolerance, one test.

An estimate within :data:`BOUND_TOLERANCE` of its search range from a bound was stopped
by the bound, not by the data. The run writes which estimates did (``best/@at_bound``),
the views flag them and the identifiability check notes them: all three ask here, so
that they cannot disagree.
"""

from __future__ import annotations

import math

#: an estimate this close to a bound (as a fraction of its search range) was decided
#: by the bound, not by the data
BOUND_TOLERANCE = 1e-3


def bound_hits(names, x, lower, upper, tolerance: float = BOUND_TOLERANCE) -> dict[str, str]:
    """The estimates that sit on a bound of their search range: name -> ``"lower"|"upper"``.

    An estimate within ``tolerance`` (0.1 %) of the range ``hi - lo`` from a bound was
    stopped by the bound: the data would have taken it further, so the value says
    more about the range in ``free:`` than about the product.

    >>> bound_hits(["k", "c", "m"], [500.0, 2.0, 0.2004], [20, 0, 0.2], [500, 10, 8])
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
