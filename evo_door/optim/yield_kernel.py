"""The specification's centring objective, compiled (:mod:`evo_door.optim.tolerance`).

Its own module so that reading a results file (which knows the specification's types
from :mod:`.tolerance`) does not import numba: the centring imports it when it runs.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types


@njit(types.float64[::1](types.float64[:, ::1], types.float64[::1]), cache=True, nogil=True)
def worst_shifted(D, v):
    """Each door's worst margin (JND) when its margins are ``D[i] + v``: ``max |D[i] + v|``
    row by row, what ``np.max(np.abs(v + D), axis=1)`` gives (the same sums, NaN
    kept), without the two arrays of the size of ``D`` it makes: the centring's
    objective, evaluated a few hundred times on 400 doors x some 700 margins."""
    out = np.empty(D.shape[0])
    for i in range(D.shape[0]):
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
