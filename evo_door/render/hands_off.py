"""The door with no hand on it: a parameter set must not make it move fast by itself.

A haptic parameter set describes a door that moves on its own: its balance (weight and
springs), a return spring, the latch's snap. Released from rest with nobody holding
the handle, the device would swing the handle as that door swings, and a hand or a
face in its way takes the hit. :func:`hands_off_motion` simulates that door with no
user force from rest at angles covering the stroke and the latch, and
:func:`check_hands_off` refuses, in one line, a set whose door would move faster than
a limit (``evo-door render --hands-off-speed``, default :data:`HANDS_OFF_SPEED`). The
renderer checks the set it starts with and every change (a push, the console, the
keys): :class:`~evo_door.render.loop.ServoLoop`'s ``hands_off_speed``.

Light at import (the command line reads the constants for its flags): numpy and the
simulation are imported when a check runs. One check takes about 30 ms (2-CPU
machine; ``docs/haptic-model.md``, "Bounds that keep a hand safe", says why the
numbers are what they are).
"""

from __future__ import annotations

import math

from evo_door.errors import UserError

#: Default hands-off limit (rad/s): the fastest a door released from rest with no hand
#: may move. The project's choice (docs/haptic-model.md): a door slammed shut by a hand
#: reaches 3-5 rad/s, so a door that gets there by itself would hit a hand in its way
#: as hard as a slam; 3 rad/s is 1.8 m/s at a 0.6 m handle.
HANDS_OFF_SPEED = 3.0
#: The limits ``--hands-off-speed`` may take (rad/s): below 0.5 rad/s it comes near
#: the speed at which a door settles onto its catch by itself (0.2 rad/s for the
#: default set and the seed's); above 20 rad/s (12 m/s at the handle) it protects
#: nothing.
HANDS_OFF_RANGE = (0.5, 20.0)
#: Starts of the released door (deg): every 5 deg of the stroke, ends included; the
#: latch's angles are added by :func:`hands_off_starts`.
HANDS_OFF_STEP = 5.0
#: Sample period (s) of the hands-off simulation: the rig's (the speed is read there).
HANDS_OFF_DT = 1.0 / 1024.0


def hands_off_duration(limit: float) -> float:
    """How long (s) each released door is simulated: ``max(1, 1.25 pi / limit)``.

    A door pushed by a constant force reaches ``limit`` (rad/s) within its stroke of
    pi/2 only if it accelerates at ``limit**2 / pi`` or more, and then does so within
    ``pi / limit`` seconds; a quarter more is the margin. A push that varies over the
    stroke is caught by the start nearest where it is strong (every 5 deg).
    """
    return max(1.0, 1.25 * math.pi / float(limit))


def hands_off_starts(params):
    """The angles (rad) the door is released from: every :data:`HANDS_OFF_STEP` deg
    from open (0) to closed (pi/2), the latched rest ``theta_0``, the middle of the
    unlock band, of the snap zone and of the lock band, and just below the latch
    (``theta_3`` less 1e-3 rad)."""
    import numpy as np

    from evo_door.models.haptic import latch_angles_of

    la = latch_angles_of(params)
    grid = np.radians(np.arange(0.0, 90.0 + 0.5 * HANDS_OFF_STEP, HANDS_OFF_STEP))
    latch = [
        la["theta_0"],
        0.5 * (la["theta_0"] + la["theta_1"]),
        0.5 * (la["theta_1"] + la["theta_2"]),
        0.5 * (la["theta_2"] + la["theta_3"]),
        la["theta_3"] - 1e-3,
    ]
    return np.clip(np.concatenate([grid, latch]), 0.0, 0.5 * math.pi)


def hands_off_motion(params, limit: float = HANDS_OFF_SPEED, duration: float | None = None):
    """How fast the door of ``params`` moves by itself, released with no hand on it.

    The haptic model is simulated with zero user force (:func:`evo_door.sim.simulate`,
    as ``render-check`` does: Dormand-Prince, dry friction sticking) from rest at each
    of :func:`hands_off_starts`, for ``duration`` seconds (default
    :func:`hands_off_duration` of ``limit``), with ``c_energy``'s push along the motion
    (:func:`~evo_door.render.check.felt_vector`) and without the device's own damping,
    which only slows the door: a conservative reading.

    Returns ``{"ok", "speed", "start", "limit", "duration", "reason"}``: the largest
    ``|dtheta|`` (rad/s) of all starts, the start (rad) it came from, and a one-line
    reason when ``speed > limit`` (or a simulation failed: speed inf).
    """
    import numpy as np

    from evo_door.models.haptic import MODEL
    from evo_door.render.check import felt_vector
    from evo_door.sim import simulate

    limit = float(limit)
    duration = hands_off_duration(limit) if duration is None else float(duration)
    p = felt_vector(params)
    force = np.zeros(int(round(duration / HANDS_OFF_DT)) + 1)
    speed, start = -1.0, 0.0
    for theta0 in hands_off_starts(params):
        r = simulate(MODEL, p, force, HANDS_OFF_DT, theta0=float(theta0), dtheta0=0.0)
        fastest = float(np.max(np.abs(r.dtheta))) if r.ok else math.inf
        if not math.isfinite(fastest):
            fastest = math.inf
        if fastest > speed:
            speed, start = fastest, float(theta0)
    ok = speed <= limit
    reason = ""
    if not ok:
        reached = "blows up" if math.isinf(speed) else f"reaches {speed:.3g} rad/s"
        reason = (
            f"released from rest at {math.degrees(start):.4g} deg with no hand on it, the "
            f"door {reached} within {duration:.3g} s, above the hands-off limit of "
            f"{limit:g} rad/s"
        )
    return dict(ok=ok, speed=speed, start=start, limit=limit, duration=duration, reason=reason)


def check_hands_off(
    params,
    limit: float = HANDS_OFF_SPEED,
    how: str = "the renderer's --hands-off-speed RAD_S sets the limit",
):
    """``params`` if its door, released anywhere with no hand, stays within ``limit``
    (rad/s, :func:`hands_off_motion`); else a UserError with the reason, in one line,
    saying ``how`` to change the limit."""
    check = hands_off_motion(params, limit)
    if not check["ok"]:
        raise UserError(f"parameter set refused: {check['reason']} ({how})")
    return params
