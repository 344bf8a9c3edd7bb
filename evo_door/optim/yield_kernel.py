"""The specification's centring objective, compiled (:mod:`evo_door.optim.tolerance`).

Its own module so that reading a results file (which knows the specification's types
from :mod:`.tolerance`) does not import numba: the centring imports it when it runs.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange, types


@njit(types.float64[::1](types.float64[:, ::1], types.float64[::1]), cache=True, parallel=True)
def worst_shifted(D, v):
    """Each door's worst margin (JND) when its margins are ``D[i] + v``: ``max |D[i] + v|``
    row by row, what ``np.max(np.abs(v + D), axis=1)`` gives (the same sums, NaN
    kept), without the two arrays of the size of ``D`` it makes: the centring's
    objective, evaluated a few hundred times on 400 doors x some 700 margins (the
    doors across threads)."""
    out = np.empty(D.shape[0])
    for i in prange(D.shape[0]):
        worst = 0.0
        for j in range(D.shape[1]):
            m = abs(v[j] + D[i, j])
            if m != m:  # NaN: numpy's max is NaN
                worst = m
                break
            if m > worst:
                worst = m
        out[i] = worst
    return out


@njit(
    types.boolean[::1](types.float64[:, ::1], types.float64[::1], types.float64[::1]),
    cache=True,
    nogil=True,
)
def rows_within(M, a, b):
    """Whether each door passes when its margins (JND) are ``M[i] - a[i] b``: every one
    within +-1, what ``np.all(np.abs(M - np.outer(a, b)) <= 1, axis=1)`` gives (the same
    products and differences; NaN fails), without the arrays of the size of ``M`` it
    makes and stopping at a door's first failing margin: the check of thousands of doors
    on some 2000 margins each, and of each specification moved over the sample."""
    out = np.empty(M.shape[0], dtype=np.bool_)
    for i in range(M.shape[0]):
        ok = True
        for j in range(M.shape[1]):
            if not (abs(M[i, j] - a[i] * b[j]) <= 1.0):
                ok = False
                break
        out[i] = ok
    return out
