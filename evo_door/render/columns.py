"""The columns of a log row: what one servo cycle records.

The loop's kernels (:mod:`evo_door.render.kernels`) write a row per cycle; the log
(:mod:`evo_door.render.log`) keeps them, its side file (:mod:`evo_door.render.spill`)
stores them as :data:`ROW_DTYPE`, and the control port hands them to clients. Code
that builds or reads a row names its columns by the indices below, never by number.
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
#: the first of each three-column vector (x, y, z): the handle's position (m) and
#: velocity (m/s), the user's force on it and the force commanded (N)
POSITION = COLUMNS.index("x")
VELOCITY = COLUMNS.index("vx")
USER_FORCE = COLUMNS.index("fx")
COMMAND = COLUMNS.index("cx")
#: the door's angle (rad), its speed (rad/s) and the user's force toward closing (N)
THETA = COLUMNS.index("theta")
DTHETA = COLUMNS.index("dtheta")
FORCE = COLUMNS.index("force")
#: how a row's numbers are stored in memory and in the side file (float64, little-endian)
ROW_DTYPE = np.dtype("<f8")
