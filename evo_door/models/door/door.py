"""Block DOOR: the door rod OAE hinged to the cabinet at O (seed 3.3.1.1).

The door is the only body with mass. It turns about the fixed hinge O, so its
equation of motion is the moment balance about O::

    I_O * ddtheta = F * L + Q_gravity + Q_O + Q_ext
    I_O       = I_z + M (G_x^2 + G_y^2)                     (parallel axes)
    Q_gravity = -M g (G_x cos(theta) - G_y sin(theta))      (= -dV/dtheta, V = M g y_G)
    Q_O       = -T_atO tanh(a_rot * dtheta)                 (dry friction at O, eq. 3.1)

where ``F`` is the user force at the handle E (tangential, + toward closing) and
``Q_ext`` the generalised force (N m) of everything attached to the door: the plate
(spring, frictions, pad, slot) carried through joint A, the latch and the stop H.
"""

from __future__ import annotations

import math

from numba import njit

from evo_door.models.door.laws import dry_friction
from evo_door.models.door_params import GRAVITY


@njit(cache=True, nogil=True)
def door(theta, dtheta, force, q_ext, L, M, I_z, G_x, G_y, T_atO, a_rot):
    """Angular acceleration of the door.

    Inputs: ``theta`` (rad), ``dtheta`` (rad/s), ``force`` user force at E (N),
    ``q_ext`` generalised force of the attached blocks (N m); parameters ``L`` (m),
    ``M`` (kg), ``I_z`` (kg m^2), ``G_x``, ``G_y`` (m, centre of mass in the door frame),
    ``T_atO`` (N m), ``a_rot`` (s/rad).
    Output: ``ddtheta`` (rad/s^2). Affine in ``force``.
    """
    inertia_o = I_z + M * (G_x * G_x + G_y * G_y)
    q = door_moment(
        math.cos(theta), math.sin(theta), dtheta, force, q_ext, L, M, G_x, G_y, T_atO, a_rot
    )
    return q / inertia_o


@njit(cache=True, nogil=True, inline="always")
def door_moment(cos_theta, sin_theta, dtheta, force, q_ext, L, M, G_x, G_y, T_atO, a_rot):
    """The moment about O (N m), ``I_O ddtheta``, given ``cos theta`` and ``sin theta``
    (the pose table has them; the fast path multiplies by a stored ``1 / I_O``)."""
    q_gravity = -M * GRAVITY * (G_x * cos_theta - G_y * sin_theta)
    q_o = -dry_friction(T_atO, a_rot, dtheta)
    return force * L + q_gravity + q_o + q_ext


@njit(cache=True, nogil=True)
def door_potential(theta, M, G_x, G_y):
    """Gravity potential of the door, ``M g y_G`` (J), zero at the hinge height."""
    return M * GRAVITY * (G_x * math.sin(theta) + G_y * math.cos(theta))
