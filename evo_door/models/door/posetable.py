"""The chain's pose on a fine angle grid: a cubic Hermite table, built once per geometry.

Everything :func:`~evo_door.models.door.kinematics.pose` returns depends on theta and
the five fully-open geometry lengths only. A trial evaluates the door's right-hand side
some 40 000 times, each time with a cos, a sin, a square root, two atan2 and the cos
and sin of the plate's rotation; the table replaces them with a cubic Hermite
interpolant, a handful of multiply-adds.

Tabulated, at ``TABLE_INTERVALS + 1`` equally spaced angles over
[``TABLE_LO``, ``TABLE_HI``] (the stroke with a margin for the stop and the wall), are
eight quantities, each with its **exact** derivative (:func:`pose_rates`, second
derivatives of the chain in closed form):

====  ==========================================  ==============================
slot  quantity                                    derivative
====  ==========================================  ==============================
0     cos theta                                   -sin theta
1     sin theta                                   cos theta
2     h_y = y_B - y_A (plate's height A -> B)     h_y' = dy_B/dtheta - L_OA cos
3     dy_B/dtheta                                 d2y_B/dtheta2
4     dphi/dtheta                                 d2phi/dtheta2
5     q_x = x_C - x_B                             -dphi/dtheta q_y
6     q_y = y_C - y_B                             dphi/dtheta q_x
7     phi                                         dphi/dtheta
====  ==========================================  ==============================

and the rest of the pose follows by the same arithmetic as the closed form
(:func:`table_pose`). Each interval holds its cubic per quantity in power form, so
a lookup is three multiply-adds per quantity (:func:`build_pose_table`). With exact
slopes the interpolant is C1 and its error is
``h^4 / 384 max |f''''|``: 1e-12 of the quantities' size on the default grid
(``tests/test_door_fast.py``). The velocity ratios are tabulated as values (with
their exact slopes), not differentiated from the positions, so they are as accurate
as the positions and continuous with their derivative.

A table is only as good as its geometry is smooth: near a dead centre of the chain
(``h_y`` -> 0, outside the stroke of any sane geometry) the closed form itself is
singular. :func:`build_pose_table` therefore checks the interpolant against the closed
form at the middle of every interval, where a cubic Hermite's error is largest, and
reports it; the caller uses the closed form when the table is off by more than
:data:`TABLE_TOLERANCE` (``evo_door.models.door.prepare``).
"""

from __future__ import annotations

import math

from numba import njit

from evo_door.models.door.kinematics import Pose, pose

#: Lowest angle of the table (rad): a margin below fully open for the stop's
#: penetration.
TABLE_LO = -0.25
#: Highest angle of the table (rad): a margin above closed for the wall.
TABLE_HI = 0.5 * math.pi + 0.25
#: Intervals of the grid (h = 8.1e-3 rad).
TABLE_INTERVALS = 256
#: Quantities per node (see the module docstring).
N_QUANTITIES = 8
#: Floats per interval: each quantity's cubic in power form, ``c0 + t (c1 + t (c2 +
#: t c3))`` with ``t`` in [0, 1] across the interval (:func:`build_pose_table`).
NODE = 4 * N_QUANTITIES
#: Floats of a whole table.
TABLE_SIZE = TABLE_INTERVALS * NODE
#: Largest error (m for lengths, rad for angles, m/rad and 1 for ratios, per unit of
#: the geometry's size ``l_AB + l_BC``) the mid-interval check accepts.
TABLE_TOLERANCE = 1e-9


@njit(cache=True, nogil=True)
def pose_rates(theta, L_OA, L_Bx, L_By, L_Cx, L_Cy, out):
    """The eight tabulated quantities and their exact derivatives at ``theta``.

    Fills ``out[2 j]`` with quantity ``j`` and ``out[2 j + 1]`` with its d/dtheta (the
    module docstring's table). The values are those of
    :func:`~evo_door.models.door.kinematics.pose`; the derivatives of the velocity
    ratios are the chain's second derivatives:

    ``h_x = L_Bx - L_OA cos``, ``h_x' = L_OA sin``, ``h_x'' = L_OA cos``;
    ``h_y^2 + h_x^2 = l_AB^2`` gives ``h_y' = -h_x h_x' / h_y`` and
    ``h_y'' = -(h_x'^2 + h_x h_x'' + h_y'^2) / h_y``; ``phi' = (h_x h_y' - h_y h_x') /
    l_AB^2`` gives ``phi'' = (h_x h_y'' - h_y h_x'') / l_AB^2``.
    """
    k = pose(theta, L_OA, L_Bx, L_By, L_Cx, L_Cy)
    c = math.cos(theta)
    s = math.sin(theta)
    l2 = (L_Bx - L_OA) ** 2 + L_By * L_By
    hx = k.ABx
    hy = k.ABy
    dhx = L_OA * s
    ddhx = L_OA * c
    dhy = k.dBy - k.dAy
    ddhy = -(dhx * dhx + hx * ddhx + dhy * dhy) / hy
    qx = k.Cx - k.Bx
    qy = k.Cy - k.By
    out[0] = c
    out[1] = -s
    out[2] = s
    out[3] = c
    out[4] = hy
    out[5] = dhy
    out[6] = k.dBy
    out[7] = -L_OA * s + ddhy
    out[8] = k.dphi
    out[9] = (hx * ddhy - hy * ddhx) / l2
    out[10] = qx
    out[11] = -k.dphi * qy
    out[12] = qy
    out[13] = k.dphi * qx
    out[14] = k.phi
    out[15] = k.dphi


@njit(cache=True, nogil=True, inline="always")
def _interval(theta, start):
    """The interval's first float in ``q`` and the position ``t`` in [0, 1] across it."""
    u = (theta - TABLE_LO) * (TABLE_INTERVALS / (TABLE_HI - TABLE_LO))
    i = int(u)
    if i >= TABLE_INTERVALS:
        i = TABLE_INTERVALS - 1
    return start + i * NODE, u - i


@njit(cache=True, nogil=True, inline="always")
def _value(q, base, j, t):
    a = base + 4 * j
    return q[a] + t * (q[a + 1] + t * (q[a + 2] + t * q[a + 3]))


@njit(cache=True, nogil=True)
def table_pose(theta, L_OA, L_Bx, q, start):
    """The :data:`~evo_door.models.door.kinematics.Pose` at ``theta`` from the table.

    ``q[start:start + TABLE_SIZE]`` is a table of :func:`build_pose_table` for this
    geometry; ``theta`` must lie in [TABLE_LO, TABLE_HI] (the caller falls back to the
    closed form outside).
    """
    return table_pose_trig(theta, L_OA, L_Bx, q, start)[0]


@njit(cache=True, nogil=True, inline="always")
def table_pose_trig(theta, L_OA, L_Bx, q, start):
    """``(pose, cos theta, sin theta)`` from the table (see :func:`table_pose`).

    The door's gravity needs cos and sin of theta: they come with the pose.
    """
    base, t = _interval(theta, start)
    c = _value(q, base, 0, t)
    s = _value(q, base, 1, t)
    hy = _value(q, base, 2, t)
    dby = _value(q, base, 3, t)
    dphi = _value(q, base, 4, t)
    qx = _value(q, base, 5, t)
    qy = _value(q, base, 6, t)
    phi = _value(q, base, 7, t)
    ax = L_OA * c
    ay = L_OA * s
    by = ay + hy
    k = Pose(
        ax, ay, -ay, ax, L_Bx, by, dby, L_Bx - ax, hy, phi, dphi, L_Bx + qx, by + qy,
        -dphi * qy, dby + dphi * qx,
    )  # fmt: skip
    return k, c, s


@njit(cache=True, nogil=True)
def build_pose_table(L_OA, L_Bx, L_By, L_Cx, L_Cy, q, start, scratch):
    """Fill ``q[start:start + TABLE_SIZE]`` for this geometry; return the check's error.

    ``scratch`` is a float64 array of at least ``NODE`` values. Each interval holds,
    per quantity, the power-form coefficients of the cubic Hermite interpolant between
    its two nodes (values ``y0``, ``y1`` and slopes times h ``m0``, ``m1``):
    ``y0``, ``m0``, ``3 (y1 - y0) - 2 m0 - m1``, ``2 (y0 - y1) + m0 + m1``, so that a
    lookup is three multiply-adds per quantity. The returned number is
    the largest difference, at the middle of every interval, between the interpolant
    and the closed form over the quantities that carry a length (h_y, q_x, q_y, in
    units of the geometry's size ``l_AB + l_BC``) and the angles and ratios (phi,
    dy_B/dtheta per that size, dphi/dtheta); it is ``inf`` if the closed form is not
    finite somewhere on the grid (a geometry through a dead centre).
    """
    h = (TABLE_HI - TABLE_LO) / TABLE_INTERVALS
    left = 0  # scratch[left:left + 2 N_QUANTITIES]: the interval's left node
    right = 2 * N_QUANTITIES
    pose_rates(TABLE_LO, L_OA, L_Bx, L_By, L_Cx, L_Cy, scratch[left:right])
    for i in range(TABLE_INTERVALS):
        pose_rates(TABLE_LO + (i + 1) * h, L_OA, L_Bx, L_By, L_Cx, L_Cy, scratch[right:])
        a = start + i * NODE
        for j in range(N_QUANTITIES):
            y0 = scratch[left + 2 * j]
            m0 = h * scratch[left + 2 * j + 1]
            y1 = scratch[right + 2 * j]
            m1 = h * scratch[right + 2 * j + 1]
            q[a + 4 * j] = y0
            q[a + 4 * j + 1] = m0
            q[a + 4 * j + 2] = 3.0 * (y1 - y0) - 2.0 * m0 - m1
            q[a + 4 * j + 3] = 2.0 * (y0 - y1) + m0 + m1
        for j in range(2 * N_QUANTITIES):
            scratch[left + j] = scratch[right + j]
    size = math.hypot(L_Bx - L_OA, L_By) + math.hypot(L_Cx - L_Bx, L_Cy - L_By)
    worst = 0.0
    for i in range(TABLE_INTERVALS):
        theta = TABLE_LO + (i + 0.5) * h
        k = pose(theta, L_OA, L_Bx, L_By, L_Cx, L_Cy)
        t = table_pose(theta, L_OA, L_Bx, q, start)
        e = max(
            abs(t.ABy - k.ABy) / size,
            abs(t.Cx - k.Cx) / size,
            abs(t.Cy - k.Cy) / size,
            abs(t.dBy - k.dBy) / size,
            abs(t.dCy - k.dCy) / size,
            abs(t.phi - k.phi),
            abs(t.dphi - k.dphi),
        )
        if not math.isfinite(e):
            return math.inf
        worst = max(worst, e)
    return worst
