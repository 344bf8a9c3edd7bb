"""Compiled helpers of the seed's blocks (:mod:`evo_door.models.blocks.seed`)."""

from __future__ import annotations

import math

from numba import njit

from evo_door.models.door.latch import latch_angles

_CLOSED = 0.5 * math.pi


@njit(cache=True, nogil=True)
def latch_switch(
    j, theta, dtheta, unlock, lock, loose, k_open, k_close, open_hold, close_hold,
    seat, damping, sharpness, wall_k, wall_c,
):  # fmt: skip
    """The latch's switching function ``j`` (0..6) at ``theta`` in the door's frame
    (closed at pi/2): the wall's contact and where its damper would pull (0, 1), the
    free play's end, the seat's rise, the catch's rise, the lock ramp's foot and its
    rise (2..6): the door's :func:`~evo_door.models.door.switches` 2..8. A function
    that does not apply is 1."""
    pen = theta - _CLOSED
    if j == 0:
        return pen
    if j == 1:
        return wall_k * pen + wall_c * dtheta if pen > 0.0 else 1.0
    if unlock <= 0.0 and lock <= 0.0:
        return 1.0
    theta_0, _theta_1, theta_3 = latch_angles(
        unlock, lock, loose, k_open, k_close, open_hold, close_hold
    )
    if j == 2:
        return theta - theta_0
    if j == 3:
        return theta - theta_0 - seat / k_open if unlock > 0.0 else 1.0
    if j == 4:
        return theta - (theta_0 - unlock / k_open)
    if j == 5:
        return theta - theta_3
    return theta - theta_3 - lock / k_close
