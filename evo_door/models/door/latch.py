"""Block LATCH: the plastic leaf-spring catch that holds the closed door (seed 3.3.2).

All forces are tangential at the handle, + toward closing, and enter the door as
torques ``L * force``; theta decreases as the door opens. Going down from closed:

* **seat**, the free play ``[theta_0, pi/2]``: the door seal presses the latched door
  out against its catch, ``-min(seat_force, k_1 (theta - theta_0))``. So the latched
  door rests *on* the catch, at theta_0, not at the far end of its free play: a pull
  meets the catch at once, with no run-up in which to gather speed;
* **unlocking** catch ``[theta_1, theta_0]``: ``+min(k_1 (theta_0 - theta),
  unlock_force)``, pulls the door back closed; it rises stiffly (``k_1``) to
  ``unlock_force``, then **holds** that force over ``open_hold`` before the hook lets
  go at theta_1, the apex;
* **locking** ramp ``[theta_3, theta_1]``: ``-min(k_2 (theta - theta_3), lock_force)``,
  pushes the door open; it rises to ``lock_force`` and holds it over ``close_hold``
  up to the apex;
* **wall** beyond closed (``theta > pi/2``): ``-k_w (theta - pi/2) - c_w dtheta``,
  one-sided (it never pulls).

with ``theta_0 = pi/2 - latch_loose_angle``, ``theta_1 = theta_0 - unlock_force / k_1
- open_hold`` and ``theta_3 = theta_1 - lock_force / k_2 - close_hold``. The force
reverses at the apex through the activation S of eq. 4.36::

    F_latch = min(k_1 (theta_0 - theta)+, unlock_force) S(theta, theta_1)
            - min(k_2 (theta - theta_3)+, lock_force) (1 - S(theta, theta_1))
            - latch_damping dtheta [S(theta, theta_3) - S(theta, theta_0 + seat / k_1)]

**Why the catch holds its force** (docs/physical-model.md, "The latch"): a pull that
never exceeds ``F_max`` does at most ``F_max * travel`` of work on the door between
its rest on the catch and the apex, whatever its timing; the catch asks for its
barrier ``B = unlock_force (w / 2 + open_hold)``, ``w = unlock_force / k_1``. A
barrier above that work stops every such pull, so no pull below the fraction
``1 - w / (2 (w + open_hold))`` of ``unlock_force`` can unlock the door, however brisk
(0.93 with the defaults; a catch without hold, a bare linear spring, guarantees only
0.5). The same holds for locking with ``close_hold``. A real hook does this with a
retention face that flattens as its leaf spring bends: the force at the handle stays
near its peak over the last millimetres of travel.

The apex edge is sharp (``latch_sharpness``) and lies on the holds' flat parts, so the
quasi-static peaks are exactly the declared forces. The springs are conservative
(:func:`latch_potential`); the damping inside the catch and at the wall only
dissipates.
"""

from __future__ import annotations

import math

from numba import njit

from evo_door.models.door.laws import activation


@njit(cache=True, nogil=True)
def latch_angles(unlock_force, lock_force, loose_angle, k_open, k_close, open_hold, close_hold):
    """Window edges ``(theta_0, theta_1, theta_3)`` in rad (closed door at pi/2).

    theta_0: the catch engages (end of the free play); theta_1: the apex, where the
    hook lets go; theta_3: the lock ramp begins.
    """
    theta_0 = 0.5 * math.pi - loose_angle
    theta_1 = theta_0 - unlock_force / k_open - open_hold
    theta_3 = theta_1 - lock_force / k_close - close_hold
    return theta_0, theta_1, theta_3


@njit(cache=True, nogil=True)
def latch_spring_force(
    theta,
    unlock_force,
    lock_force,
    loose_angle,
    k_open,
    k_close,
    open_hold,
    close_hold,
    seat_force,
    sharpness,
):
    """Conservative part of the latch force at the handle (N, + toward closing).

    The seat acts only when there is a catch to press the door against
    (``unlock_force > 0``).
    """
    theta_0, theta_1, theta_3 = latch_angles(
        unlock_force, lock_force, loose_angle, k_open, k_close, open_hold, close_hold
    )
    if theta >= theta_0:
        if unlock_force > 0.0:
            return -min(seat_force, k_open * (theta - theta_0))
        return 0.0
    s1 = activation(theta, theta_1, sharpness)
    catch = min(k_open * (theta_0 - theta), unlock_force)
    ramp = min(k_close * max(0.0, theta - theta_3), lock_force)
    return catch * s1 - ramp * (1.0 - s1)


@njit(cache=True, nogil=True)
def _ramp_hold_integral(x, k, force):
    """``int_0^x min(k s, force) ds`` for x >= 0 (N rad): a stiff rise, then a hold."""
    if x <= 0.0:
        return 0.0
    rise = force / k
    if x <= rise:
        return 0.5 * k * x * x
    return 0.5 * force * rise + force * (x - rise)


@njit(cache=True, nogil=True)
def latch_potential(
    theta,
    unlock_force,
    lock_force,
    loose_angle,
    k_open,
    k_close,
    open_hold,
    close_hold,
    seat_force,
):
    """Potential of :func:`latch_spring_force`, ``-int F dtheta`` (N rad), 0 below theta_3.

    Exact for the sharp apex; the smooth edge of the activation changes it by nothing
    (it lies between two flat holds, where the tanh's two halves cancel) unless a hold
    is zero, and then by less than ``force / latch_sharpness``. Multiply by ``L`` for J.
    """
    theta_0, theta_1, theta_3 = latch_angles(
        unlock_force, lock_force, loose_angle, k_open, k_close, open_hold, close_hold
    )
    if theta <= theta_3:
        return 0.0
    # up the lock ramp (the force pushes toward opening: the potential rises)
    v = _ramp_hold_integral(min(theta, theta_1) - theta_3, k_close, lock_force)
    if theta <= theta_1:
        return v
    # past the apex the catch pulls the door in (the potential falls) ...
    v -= _ramp_hold_integral(theta_0 - theta_1, k_open, unlock_force)
    v += _ramp_hold_integral(theta_0 - min(theta, theta_0), k_open, unlock_force)
    # ... and in the free play the seat pushes it out again
    if theta > theta_0 and unlock_force > 0.0:
        v += _ramp_hold_integral(theta - theta_0, k_open, seat_force)
    return v


@njit(cache=True, nogil=True)
def _wall(theta, dtheta, wall_stiffness, wall_damping):
    """The wall beyond closed (N at the handle): one-sided, it never pulls."""
    pen = theta - 0.5 * math.pi
    if pen > 0.0:
        return min(0.0, -wall_stiffness * pen - wall_damping * dtheta)
    return 0.0


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
    open_hold,
    close_hold,
    seat_force,
    latch_damping,
    sharpness,
    wall_stiffness,
    wall_damping,
):
    """Generalised force of the latch on theta.

    Inputs: ``theta`` (rad), ``dtheta`` (rad/s); parameters ``L`` (m, the catch acts
    at the handle), ``unlock_force``, ``lock_force`` (N), ``loose_angle`` (rad),
    ``k_open``, ``k_close`` (N/rad), ``open_hold``, ``close_hold`` (rad),
    ``seat_force`` (N), ``latch_damping`` (N s/rad), ``sharpness`` (1/rad),
    ``wall_stiffness`` (N/rad), ``wall_damping`` (N s/rad).
    Output: ``q_latch`` (N m).
    """
    theta_0, theta_1, theta_3 = latch_angles(
        unlock_force, lock_force, loose_angle, k_open, k_close, open_hold, close_hold
    )
    if (unlock_force <= 0.0 and lock_force <= 0.0) or (theta_3 - theta) * sharpness > 20.0:
        # no latch at all (both forces zero: only the wall is left), or far below the
        # catch, where every activation is 0 to double precision: skip the tanh calls
        # (this is most of the stroke)
        return L * _wall(theta, dtheta, wall_stiffness, wall_damping)
    f = latch_spring_force(
        theta,
        unlock_force,
        lock_force,
        loose_angle,
        k_open,
        k_close,
        open_hold,
        close_hold,
        seat_force,
        sharpness,
    )
    # damped from the foot of the lock ramp to the top of the seat's rise, so that a
    # door bouncing between the seal and the hook settles
    top = theta_0 + seat_force / k_open if unlock_force > 0.0 else theta_0
    window = activation(theta, theta_3, sharpness) - activation(theta, top, sharpness)
    f -= latch_damping * dtheta * window
    return L * (f + _wall(theta, dtheta, wall_stiffness, wall_damping))
