"""Block FRICTIONFORCE: everything acting on the plate at the slotted link B (seed 3.3.1.4).

At B the plate's pin slides vertically in a slot of the cabinet and turns in it. The
block sums, at B:

* the pad friction carried from D (force ``(F_Bx, F_By)`` and torque ``T_pad`` from
  RELATIVESPEED; the horizontal part is taken by the slot and only changes the normal
  force, since B cannot move horizontally);
* the Coulomb friction of the slot, ``f_B = -mu |N| tanh(a v_By)``, with ``N`` the
  slot's horizontal normal force and ``v_By = dy_B/dtheta dtheta``;
* the dry-friction torque of the pin turning in the slot,
  ``T_b = -T_atB tanh(a_rot dphi/dtheta dtheta)``.

The normal force follows from the massless plate's moment balance about A (the joint
force at A drops out). With ``(d_x, d_y) = B - A`` and ``M0`` the moment about A of all
known plate loads (``m_plate`` from PLATE, the pad, ``T_b``)::

    M0 + d_x f_B - d_y N = 0,   f_B = -mu |N| s,   s = tanh(a v_By)
    =>  N = sigma |N|,  |N| = M0 / (sigma d_y + d_x mu s),  sigma = sign(M0) sign(d_y)

unique while the slot does not jam (``|d_y| > mu |d_x|``; true for the seed's geometry
with mu < 2). Generalised force: ``q = (F_By + f_B) dy_B/dtheta + (T_pad + T_b) dphi/dtheta``.
"""

from __future__ import annotations

from collections import namedtuple

from numba import njit

from evo_door.models.door.laws import dry_friction, tanh

#: Output of :func:`friction_force`: slot normal force N (N, + toward +x), total
#: vertical force at B (N), total torque at B (N m), generalised force q (N m).
SlotLoad = namedtuple("SlotLoad", ["N", "F_By", "T_B", "q"])


@njit(cache=True, nogil=True, inline="always")
def friction_force(k, dtheta, F_Bx, F_By, T_pad, m_plate, mu, T_atB, a, a_rot):
    """Slot friction at B, with the pad's effect, as one load on the plate.

    Inputs: ``k`` the :class:`~evo_door.models.door.kinematics.Pose`, ``dtheta``
    (rad/s), the pad load at B ``F_Bx``, ``F_By`` (N), ``T_pad`` (N m), ``m_plate`` the
    moment about A of the other plate loads (N m); parameters ``mu``, ``T_atB`` (N m),
    ``a`` (s/m), ``a_rot`` (s/rad). Output: a :data:`SlotLoad`.
    """
    t_b = -dry_friction(T_atB, a_rot, k.dphi * dtheta)
    s = tanh(a * k.dBy * dtheta)
    m0 = m_plate + k.ABx * F_By - k.ABy * F_Bx + T_pad + t_b
    sigma = 1.0 if m0 >= 0.0 else -1.0
    if k.ABy < 0.0:
        sigma = -sigma
    den = sigma * k.ABy + k.ABx * mu * s
    # no jamming: den has the sign of m0; guard the (unphysical) jammed case
    floor = 1e-3 * abs(k.ABy) + 1e-9
    if den * (1.0 if m0 >= 0.0 else -1.0) < floor:
        den = floor if m0 >= 0.0 else -floor
    n_abs = m0 / den
    normal = sigma * n_abs
    f_slide = -mu * n_abs * s
    f_by = F_By + f_slide
    t_total = T_pad + t_b
    return SlotLoad(normal, f_by, t_total, f_by * k.dBy + t_total * k.dphi)
