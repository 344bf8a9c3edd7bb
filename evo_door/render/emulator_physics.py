"""The emulated HapticMaster's physics: the compiled kernel that moves its mass.

The device's own admittance model: a point mass (``inertia``, kg) with viscous
damping, Coulomb friction and the enabled springs (isotropic or along a direction,
with a deadband and a force cap) and dampers (per axis), moved by the sum of the
enabled bias forces and a scripted user force. It runs in its own simulated time at
:data:`DEVICE_RATE`, stepped with :func:`advance_effects`, whose velocity update is
implicit in the damping and in the friction (a stick-or-slip projection) and which
substeps stiff springs (at most :data:`MAX_SUBSTEPS` per step, which the emulator's
limits keep it under), so it is stable at any setting the emulator accepts.

The protocol server that holds the device's state and calls this kernel before it
answers a frame is :mod:`evo_door.render.emulator`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Rate of the device's own control loop (Hz).
DEVICE_RATE = 2500.0

#: Most substeps per device step (:func:`advance_effects`). Within the emulator's
#: :data:`~evo_door.render.emulator.LIMITS` the stiffest case,
#: :data:`~evo_door.render.emulator.MAX_EFFECTS` springs of 1e6 N/m on 0.01 kg, needs 114.
MAX_SUBSTEPS = 256

#: Largest angle (rad) the springs together turn through per kernel step: beyond it
#: an advance cuts each device step into substeps. The springs are explicit
#: (symplectic Euler), stable below 2 rad; at 0.2 rad their frequency is within
#: 0.2 % and their energy swings within +-10 % over a period, without drift.
MAX_SPRING_PHASE = 0.2


@njit(cache=True, nogil=True)
def advance(pos, vel, n, dt, mass, damping, coulomb, force, spring_k, spring_pos, spring_b):
    """``n`` steps of the device's mass with isotropic springs (no deadband, no cap).

    The springs of :func:`advance_effects` without direction, deadband and maxforce;
    see there.
    """
    ns = spring_k.shape[0]
    d, z, c = np.zeros((ns, 3)), np.zeros(ns), np.full(ns, np.inf)  # any way, no band, no cap
    return advance_effects(
        pos, vel, n, dt, mass, damping, coulomb, force, spring_k, spring_pos, spring_b, d, z, c
    )


@njit(cache=True, nogil=True)
def advance_effects(
    pos,
    vel,
    n,
    dt,
    mass,
    damping,
    coulomb,
    force,
    spring_k,
    spring_pos,
    spring_b,
    spring_dir,
    spring_deadband,
    spring_maxforce,
):
    """``n`` steps of the device's mass; ``pos``/``vel`` updated in place.

    One long function on purpose: numba compiles it into one loop over the steps with
    its scratch arrays allocated once, and the spring, damping and friction terms of a
    step share its running sums; cut into helpers, each step would pay their calls
    and the reading of the algebra below would be spread over several places.

    Spring s pulls toward ``spring_pos[s]`` with stiffness ``spring_k[s]`` (N/m) and
    damping ``spring_b[s]`` (N s/m). With a unit ``spring_dir[s]`` it acts only along
    that direction, on the displacement's component along it (a plane constraint);
    with a zero one, isotropically. Within ``spring_deadband[s]`` (m) of its position
    it gives no force at all (no damping either); beyond, its elastic force is
    ``k (distance - deadband)``, its magnitude capped at ``spring_maxforce[s]`` (N; the
    cap is on the elastic part, the damping is never cut).

    Per step the external force (``force`` plus the springs' elastic forces at the
    current position) is explicit; damping (``damping`` per axis, N s/m, plus the
    springs' damping, along their direction) and Coulomb friction of magnitude
    ``coulomb`` are implicit: the new velocity solves
    ``m (v' - v) = dt (f - B v' - coulomb v' / |v'|)`` with B the 3 x 3 damping matrix
    (exactly when the free velocity is along an eigenvector of B, as for a motion
    along an axis or any B = b I; else with B's value along that velocity in the
    friction term); it is zero (sticking) when one step of friction can cancel the
    free velocity, so the friction never reverses the motion or chatters. Each step
    is cut into substeps when the springs together would turn more than
    :data:`MAX_SPRING_PHASE` rad per step, so the explicit springs stay stable at any
    stiffness and mass up to :data:`MAX_SUBSTEPS` substeps (the most it takes: the
    time an advance takes stays bounded). Returns the last acceleration.
    """
    # long: one compiled loop over the steps on purpose (the docstring says why)
    acc = np.zeros(3)
    f = np.zeros(3)
    v_free = np.zeros(3)
    bm = np.zeros((3, 3))
    ns = spring_k.shape[0]
    k_sum = 0.0
    for s in range(ns):
        k_sum += spring_k[s]
    sub = 1
    if k_sum > 0.0:
        turns = dt * math.sqrt(k_sum / mass) / MAX_SPRING_PHASE
        # bounded whatever the settings (a NaN or inf too): an advance never hangs
        sub = MAX_SUBSTEPS if not turns < MAX_SUBSTEPS else max(1, int(math.ceil(turns)))
    h = dt / sub
    for _ in range(n * sub):
        for a in range(3):
            f[a] = force[a]
            for c in range(3):
                bm[a, c] = 0.0
            bm[a, a] = damping[a]
        coupled = False
        for s in range(ns):
            d0 = spring_dir[s, 0]
            d1 = spring_dir[s, 1]
            d2 = spring_dir[s, 2]
            directional = d0 * d0 + d1 * d1 + d2 * d2 > 0.0
            e0 = pos[0] - spring_pos[s, 0]
            e1 = pos[1] - spring_pos[s, 1]
            e2 = pos[2] - spring_pos[s, 2]
            if directional:
                along = e0 * d0 + e1 * d1 + e2 * d2
                e0 = along * d0
                e1 = along * d1
                e2 = along * d2
                dist = abs(along)
            else:
                dist = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
            deadband = spring_deadband[s]
            if deadband > 0.0 and dist <= deadband:
                continue  # inside the deadband: no force of any kind
            if dist > 0.0:
                magnitude = min(spring_k[s] * (dist - deadband), spring_maxforce[s])
                f[0] -= magnitude * e0 / dist
                f[1] -= magnitude * e1 / dist
                f[2] -= magnitude * e2 / dist
            b_s = spring_b[s]
            if b_s > 0.0:
                if directional:
                    for a in range(3):
                        for c in range(3):
                            bm[a, c] += b_s * spring_dir[s, a] * spring_dir[s, c]
                    coupled = coupled or (d0 * d1 != 0.0 or d0 * d2 != 0.0 or d1 * d2 != 0.0)
                else:
                    for a in range(3):
                        bm[a, a] += b_s
        # (m I + h B) v_free = m v + h f
        r0 = mass * vel[0] + h * f[0]
        r1 = mass * vel[1] + h * f[1]
        r2 = mass * vel[2] + h * f[2]
        if coupled:
            a00 = mass + h * bm[0, 0]
            a11 = mass + h * bm[1, 1]
            a22 = mass + h * bm[2, 2]
            a01 = h * bm[0, 1]
            a02 = h * bm[0, 2]
            a12 = h * bm[1, 2]
            c00 = a11 * a22 - a12 * a12
            c01 = a02 * a12 - a01 * a22
            c02 = a01 * a12 - a02 * a11
            c11 = a00 * a22 - a02 * a02
            c12 = a01 * a02 - a00 * a12
            c22 = a00 * a11 - a01 * a01
            det = a00 * c00 + a01 * c01 + a02 * c02
            v_free[0] = (c00 * r0 + c01 * r1 + c02 * r2) / det
            v_free[1] = (c01 * r0 + c11 * r1 + c12 * r2) / det
            v_free[2] = (c02 * r0 + c12 * r1 + c22 * r2) / det
        else:
            v_free[0] = r0 / (mass + h * bm[0, 0])
            v_free[1] = r1 / (mass + h * bm[1, 1])
            v_free[2] = r2 / (mass + h * bm[2, 2])
        speed2 = v_free[0] ** 2 + v_free[1] ** 2 + v_free[2] ** 2
        scale = 1.0
        if coulomb > 0.0:
            scale = 0.0
            if speed2 > 0.0:
                b_v = 0.0  # damping along the free velocity
                for a in range(3):
                    for c in range(3):
                        b_v += v_free[a] * bm[a, c] * v_free[c]
                b_v /= speed2
                speed = math.sqrt(speed2)
                slip = h * coulomb / (mass + h * b_v)
                scale = 0.0 if speed <= slip else 1.0 - slip / speed
        for a in range(3):
            v_new = v_free[a] * scale
            acc[a] = (v_new - vel[a]) / h
            vel[a] = v_new
            pos[a] += h * v_new
    return acc


def compile_kernel() -> None:
    """Compile :func:`advance_effects` (or load it from numba's cache) with no effect on
    anything: an emulator does it before any client waits on an answer."""
    advance_effects(
        np.zeros(3),
        np.zeros(3),
        0,
        1.0 / DEVICE_RATE,
        1.0,
        np.zeros(3),
        0.0,
        np.zeros(3),
        np.zeros(0),
        np.zeros((0, 3)),
        np.zeros(0),
        np.zeros((0, 3)),
        np.zeros(0),
        np.zeros(0),
    )
