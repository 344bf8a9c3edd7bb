"""Block LATCH: the catch that holds the closed door (seed 3.3.2).

Three springs, each active inside an angle window (theta decreases as the door opens;
all forces are tangential at the handle, + toward closing, and enter the door as
torques ``L * force``):

* **unlocking** spring on ``[theta_1, theta_0]``: ``+k_1 (theta_0 - theta)``, pulls
  the door back closed, growing to ``unlock_force`` at theta_1, the catch's apex;
* **locking** spring on ``[theta_3, theta_1]``: ``-k_2 (theta - theta_3)``, pushes the
  door open, growing to ``lock_force`` at the apex when closing;
* **wall** beyond closed (``theta > pi/2``): ``-k_w (theta - pi/2) - c_w dtheta``,
  one-sided (it never pulls).

with ``theta_0 = pi/2 - latch_loose_angle`` (free play of the closed door),
``theta_1 = theta_0 - unlock_force / k_1`` and ``theta_3 = theta_1 - lock_force / k_2``.
The force reverses at the apex through the activation S of eq. 4.36::

    F_latch = k_1 max(0, theta_0 - theta) S(theta, theta_1)
            - k_2 max(0, theta - theta_3) (1 - S(theta, theta_1))
            - latch_damping dtheta [S(theta, theta_3) - S(theta, theta_0)]

The edge at the apex has width ~1/sharpness; where the spring meets it the smooth
product ``(theta_0 - theta) S`` peaks a little below the apex force, by a fraction
``(1 + ln(2 s w)) / (2 s w)`` (s the sharpness, w the band width). The default
sharpness (1e6 1/rad on a 1e-3 rad band) keeps that under 0.5 %: in effect the apex is
a jump, which the integrators step over.

So the force changes direction with the side of the apex: pulling the closed door
open meets ``unlock_force``, pushing the open door closed meets ``lock_force``, and the
user feels a threshold with almost no motion (the catch deflects
``unlock_force / k_1`` rad). The springs are conservative (a potential barrier); the
damping inside the catch and at the wall only dissipates.
"""

from __future__ import annotations

import math

from numba import njit

from evo_door.models.door.laws import activation


@njit(cache=True, nogil=True)
def latch_angles(unlock_force, lock_force, loose_angle, k_open, k_close):
    """Window edges ``(theta_0, theta_1, theta_3)`` in rad (closed door at pi/2)."""
    theta_0 = 0.5 * math.pi - loose_angle
    theta_1 = theta_0 - unlock_force / k_open
    theta_3 = theta_1 - lock_force / k_close
    return theta_0, theta_1, theta_3


@njit(cache=True, nogil=True)
def latch_spring_force(theta, unlock_force, lock_force, loose_angle, k_open, k_close, sharpness):
    """Conservative part of the latch force at the handle (N, + toward closing)."""
    theta_0, theta_1, theta_3 = latch_angles(unlock_force, lock_force, loose_angle, k_open, k_close)
    s1 = activation(theta, theta_1, sharpness)
    return k_open * max(0.0, theta_0 - theta) * s1 - k_close * max(0.0, theta - theta_3) * (
        1.0 - s1
    )


@njit(cache=True, nogil=True)
def latch(
    theta,
    dtheta,
    L,
    unlock_force,
    lock_force,
    loose_angle,
    k_open,
    k_close,
    latch_damping,
    sharpness,
    wall_stiffness,
    wall_damping,
):
    """Generalised force of the latch on theta.

    Inputs: ``theta`` (rad), ``dtheta`` (rad/s); parameters ``L`` (m, the catch acts
    at the handle), ``unlock_force``, ``lock_force`` (N), ``loose_angle`` (rad),
    ``k_open``, ``k_close`` (N/rad), ``latch_damping`` (N s/rad), ``sharpness``
    (1/rad), ``wall_stiffness`` (N/rad), ``wall_damping`` (N s/rad).
    Output: ``q_latch`` (N m).
    """
    theta_0, theta_1, theta_3 = latch_angles(unlock_force, lock_force, loose_angle, k_open, k_close)
    if (theta_3 - theta) * sharpness > 20.0:
        # far below the catch every activation is 0 to double precision: skip the
        # three tanh calls (this is most of the stroke)
        return 0.0
    f = latch_spring_force(theta, unlock_force, lock_force, loose_angle, k_open, k_close, sharpness)
    window = activation(theta, theta_3, sharpness) - activation(theta, theta_0, sharpness)
    f -= latch_damping * dtheta * window
    pen = theta - 0.5 * math.pi
    if pen > 0.0:
        wall = -wall_stiffness * pen - wall_damping * dtheta
        if wall < 0.0:
            f += wall
    return L * f
