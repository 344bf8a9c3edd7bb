"""Block RELATIVESPEED: slip of the plate on the fixed pad D, and its friction (seed 3.3.1.3).

The pad D is fixed on the cabinet at (L_Dx, L_Dy). With ``y = y_B - L_Dy`` the height
of B above D and ``D_x = L_Bx - L_Dx`` the (constant) horizontal distance from D to B,
the plate point under D is at ``D - B = (-D_x, -y)`` from B, at distance
``R = sqrt(y^2 + D_x^2)`` (eq. 3.2). A rigid body moving with B's vertical speed
``dy/dt`` and turning at ``w = dphi/dt`` gives it the velocity (eq. 3.3-3.4, written as
``v_B + w x (D - B)``)::

    V_Dx = w * y
    V_Dy = dy/dt - w * D_x

The pad's dry friction opposes that slip with magnitude ``F_atD tanh(a |V_D|)``
(eq. 3.1 applied to the slip speed; the seed's eq. 3.6-3.7 apply tanh per component,
which makes the horizontal component even in V_Dx, so we use the vector law)::

    F_D = -F_atD A(theta) tanh(a |V_D|) V_D / |V_D|

and it is carried to B as a force and the torque about B (eq. 3.8)::

    T_B = (D - B) x F_D = -D_x F_Dy + y F_Dx

``A(theta)`` is the optional position-dependent scale of eq. 5.8-5.9 (``section_scale``),
1 by default.
"""

from __future__ import annotations

import math
from collections import namedtuple

from numba import njit

from evo_door.models.door.laws import activation, dry_friction_2d

#: Output of :func:`relative_speed`: slip velocity of the plate at D (m/s), pad
#: friction force on the plate (N) and its torque about B (N m).
PadLoad = namedtuple("PadLoad", ["V_Dx", "V_Dy", "F_Dx", "F_Dy", "T_B"])


@njit(cache=True, nogil=True, inline="always")
def relative_speed(k, dtheta, L_Dx, L_Dy, F_atD, a):
    """Pad friction at D carried to B.

    Inputs: ``k`` the :class:`~evo_door.models.door.kinematics.Pose`, ``dtheta``
    (rad/s); parameters ``L_Dx``, ``L_Dy`` (m), ``F_atD`` (N, already scaled by
    ``A(theta)``), ``a`` (s/m). Output: a :data:`PadLoad`.
    """
    y = k.By - L_Dy
    d_x = k.Bx - L_Dx
    w = k.dphi * dtheta
    v_x = w * y
    v_y = k.dBy * dtheta - w * d_x
    fx, fy = dry_friction_2d(F_atD, a, v_x, v_y)
    f_x = -fx
    f_y = -fy
    return PadLoad(v_x, v_y, f_x, f_y, -d_x * f_y + y * f_x)


@njit(cache=True, nogil=True)
def section_scale(theta, scales, sharpness):
    """``A(theta) = sum_k A_k (S(theta, theta_k-1) - S(theta, theta_k))`` (eq. 5.8).

    ``scales`` holds A_1..A_n for n equal sections of [0, pi/2]. The outer edges of the
    first and last sections are left open (at -inf and +inf) so that A = A_1 at
    theta = 0 and A = A_n at pi/2, rather than half of it.
    """
    n = scales.shape[0]
    width = 0.5 * math.pi / n
    total = 0.0
    for j in range(n):
        lo = 1.0 if j == 0 else activation(theta, j * width, sharpness)
        hi = 0.0 if j == n - 1 else activation(theta, (j + 1) * width, sharpness)
        total += scales[j] * (lo - hi)
    return total
