"""Block PLATE: the plate A-B-C(-H) between the door and the cabinet (seed 3.3.1.2).

The plate is massless (only the door has significant inertia), so it transmits its
loads to the door instantaneously; by virtual work their generalised force on
``theta`` is sum(F . dr/dtheta) + sum(T . dangle/dtheta). This block holds the loads
that act on the plate at C and A, and the stop H:

* spring at C, vertical, pushing C up (toward closing): ``F_s = F_load - K (y_C - y_C0)``
  with ``y_C0 = L_Cy`` its fully-open height; potential ``-F_load dy + K dy^2 / 2``;
* vertical dry friction at C: ``F_c = -F_atC tanh(a v_Cy)``, ``v_Cy = dy_C/dtheta dtheta``;
* dry-friction torque at the revolute joint A on the plate, opposing the plate's
  rotation relative to the door: ``T_A = -T_atA tanh(a_rot (dphi/dtheta - 1) dtheta)``
  (the door receives ``-T_A``; the pair does virtual work ``T_A (dphi/dtheta - 1)``);
* stop H at fully open, a one-sided penalty contact in theta (``stop_h``).

Outputs per load: the generalised force ``q`` (N m) and the moment ``m`` about A of the
loads acting on the plate (N m), which block FRICTIONFORCE needs to find the slot's
normal force.
"""

from __future__ import annotations

from collections import namedtuple

from numba import njit

from evo_door.models.door.laws import dry_friction

#: Output of :func:`plate`: spring force at C (N, + up), friction at C (N, + up),
#: friction torque at A on the plate (N m, + counter-clockwise), generalised force q
#: (N m) and moment about A on the plate m (N m).
PlateLoad = namedtuple("PlateLoad", ["F_spring", "F_fricC", "T_A", "q", "m"])


@njit(cache=True, nogil=True, inline="always")
def plate(k, dtheta, L_Cy, K, F_load, F_atC, T_atA, a, a_rot):
    """Loads of the plate at C (spring, friction) and A (joint friction).

    Inputs: ``k`` the :class:`~evo_door.models.door.kinematics.Pose`, ``dtheta``
    (rad/s); parameters ``L_Cy`` (m), ``K`` (N/m), ``F_load`` (N), ``F_atC`` (N),
    ``T_atA`` (N m), ``a`` (s/m), ``a_rot`` (s/rad). Output: a :data:`PlateLoad`.
    """
    f_spring = F_load - K * (k.Cy - L_Cy)
    f_fric_c = -dry_friction(F_atC, a, k.dCy * dtheta)
    t_a = -dry_friction(T_atA, a_rot, (k.dphi - 1.0) * dtheta)
    fy = f_spring + f_fric_c
    q = fy * k.dCy + t_a * (k.dphi - 1.0)
    m = (k.Cx - k.Ax) * fy + t_a
    return PlateLoad(f_spring, f_fric_c, t_a, q, m)


@njit(cache=True, nogil=True)
def spring_potential(k, L_Cy, K, F_load):
    """Potential energy of the spring at C relative to the fully-open pose (J)."""
    dy = k.Cy - L_Cy
    return -F_load * dy + 0.5 * K * dy * dy


@njit(cache=True, nogil=True)
def stop_h(theta, dtheta, stop_stiffness, stop_damping):
    """End stop H at fully open: generalised force (N m) on theta, zero for theta >= 0.

    A one-sided spring-damper in theta that can only push (never pull the door
    back onto the stop), so it stores ``stop_stiffness theta^2 / 2`` and dissipates.
    """
    if theta >= 0.0:
        return 0.0
    q = -stop_stiffness * theta - stop_damping * dtheta
    return q if q > 0.0 else 0.0
