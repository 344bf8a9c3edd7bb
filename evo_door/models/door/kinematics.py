"""Kinematics of the closed linkage: door OAE, plate ABC(H) and the vertical slot at B.

Frame (cabinet-fixed, see ``docs/physical-model.md``): origin at the hinge O, x
horizontal, positive out of the cabinet; y up. The door is the rod OAE through O at
angle ``theta`` from the horizontal: ``u = (cos theta, sin theta)``, so theta = 0 is
the door lying open toward +x and theta = pi/2 the door standing closed.

Chain (one degree of freedom):

* A = L_OA u (a revolute joint on the door, between O and the handle E = L u);
* B = (L_Bx, y_B): the plate's pin in a vertical slot of the cabinet; the plate may
  also turn about B. The plate is rigid, so |AB| = l_AB (its fully-open length) and
  ``y_B = A_y + sqrt(l_AB^2 - (L_Bx - A_x)^2)`` (the root on the side where B lies
  in the open pose);
* the plate turns by ``phi`` (0 fully open) with the direction of AB; any plate point
  with fully-open position P0 is at ``B + R(phi) (P0 - B0)``; C is such a point;
* D is fixed on the cabinet (the friction pad); the plate point under D slides past it.

Everything is closed form, so the closure error is round-off. ``pose`` also returns
the velocity ratios (d/dtheta of the positions and of phi) that the virtual-work
generalised forces need; the plate is massless, so no second derivatives are needed.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

#: One pose of the chain and its velocity ratios (SI: m, rad; ``d*`` are d/dtheta).
Pose = namedtuple(
    "Pose",
    [
        "Ax",
        "Ay",
        "dAx",
        "dAy",  # joint A and dA/dtheta
        "Bx",
        "By",
        "dBy",  # slot pin B (Bx constant) and dy_B/dtheta
        "ABx",
        "ABy",  # vector A -> B (its length is l_AB)
        "phi",
        "dphi",  # plate rotation from the open pose, dphi/dtheta
        "Cx",
        "Cy",
        "dCx",
        "dCy",  # spring point C and dC/dtheta
    ],
)

#: Fully-open position of the plate's stop corner H. The seed gives no coordinates for
#: H (it only limits the stroke, which the model does as a contact in theta); this
#: point is used to draw the plate A-B-C-H so that it covers the pad D over the stroke.
H_OPEN = (-0.06, 0.0)


@njit(cache=True, nogil=True)
def pose(theta, L_OA, L_Bx, L_By, L_Cx, L_Cy):
    """Pose of the chain at door angle ``theta``.

    Inputs: ``theta`` (rad) and the fully-open geometry (m). Output: a :data:`Pose`.
    """
    c = math.cos(theta)
    s = math.sin(theta)
    ax = L_OA * c
    ay = L_OA * s
    dax = -L_OA * s
    day = L_OA * c
    # plate length |AB| and its direction in the open pose (A0 = (L_OA, 0))
    l2 = (L_Bx - L_OA) ** 2 + L_By * L_By
    side = 1.0 if L_By >= 0.0 else -1.0
    hx = L_Bx - ax
    r = l2 - hx * hx
    if r < 1e-18:  # dead centre: AB horizontal (outside the stroke of any sane geometry)
        r = 1e-18
    hy = side * math.sqrt(r)
    by = ay + hy
    dby = day + hx * dax / hy
    # plate rotation phi: the angle from AB's open-pose direction (L_Bx - L_OA, L_By) to
    # AB (hx, hy), two vectors of the same length sqrt(l2): its cosine and sine are their
    # dot and cross products over l2, no trigonometry (phi itself is wanted by the pose
    # tables and the drawing; where nothing reads it, the compiler drops its atan2)
    ox = L_Bx - L_OA
    cp = (ox * hx + L_By * hy) / l2
    sp = (ox * hy - L_By * hx) / l2
    phi = math.atan2(sp, cp)
    dphi = (hx * (dby - day) - hy * (-dax)) / l2
    # C is carried by the plate
    rx = L_Cx - L_Bx
    ry = L_Cy - L_By
    qx = cp * rx - sp * ry
    qy = sp * rx + cp * ry
    cx = L_Bx + qx
    cy = by + qy
    dcx = -dphi * qy
    dcy = dby + dphi * qx
    return Pose(ax, ay, dax, day, L_Bx, by, dby, hx, hy, phi, dphi, cx, cy, dcx, dcy)


def plate_point(k, L_Bx, L_By, x0, y0):
    """Current position of the plate point whose fully-open position is (x0, y0)."""
    cp, sp = math.cos(k.phi), math.sin(k.phi)
    rx, ry = x0 - L_Bx, y0 - L_By
    return np.array([k.Bx + cp * rx - sp * ry, k.By + sp * rx + cp * ry])


def points(theta: float, values) -> dict[str, np.ndarray]:
    """Named points of the mechanism at ``theta`` for drawing (plain Python).

    ``values`` maps parameter names to values (a :class:`~evo_door.params.ParamSet`
    works). Returns O, A, B, C, D, E, G, H (2-vectors, m) and ``plate``, the outline
    A-B-C-H of the plate as a (4, 2) array.
    """
    g = {
        n: float(values[n])
        for n in ("L", "L_OA", "L_Bx", "L_By", "L_Cx", "L_Cy", "L_Dx", "L_Dy", "G_x", "G_y")
    }
    k = pose(float(theta), g["L_OA"], g["L_Bx"], g["L_By"], g["L_Cx"], g["L_Cy"])
    u = np.array([math.cos(theta), math.sin(theta)])
    n = np.array([-u[1], u[0]])
    pts = {
        "O": np.zeros(2),
        "A": np.array([k.Ax, k.Ay]),
        "B": np.array([k.Bx, k.By]),
        "C": np.array([k.Cx, k.Cy]),
        "D": np.array([g["L_Dx"], g["L_Dy"]]),
        "E": g["L"] * u,
        "G": g["G_x"] * u + g["G_y"] * n,
        "H": plate_point(k, g["L_Bx"], g["L_By"], *H_OPEN),
    }
    pts["plate"] = np.array([pts["A"], pts["B"], pts["C"], pts["H"]])
    return pts
