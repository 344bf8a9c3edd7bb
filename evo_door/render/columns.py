"""The columns of a log row: what one servo cycle records.

The loop's kernels (:mod:`evo_door.render.kernels`) write a row per cycle; the log
(:mod:`evo_door.render.log`) keeps them, its side file (:mod:`evo_door.render.spill`)
stores them as :data:`ROW_DTYPE`, and the control port hands them to clients.
"""

from __future__ import annotations

import numpy as np

#: columns of a log row
COLUMNS = (
    "x",
    "y",
    "z",
    "vx",
    "vy",
    "vz",
    "fx",
    "fy",
    "fz",
    "cx",
    "cy",
    "cz",
    "theta",
    "dtheta",
    "force",
)
N_COLUMNS = len(COLUMNS)
#: how a row's numbers are stored in memory and in the side file (float64, little-endian)
ROW_DTYPE = np.dtype("<f8")
