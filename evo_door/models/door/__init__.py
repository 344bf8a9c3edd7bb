"""The physical model of the dishwasher door: the mechanism AMESim held (seed chapter 3).

Five blocks, each in its own module with explicit inputs and outputs, as in the seed's
block diagram (fig. 3.5):

==================  ====================================================================
block               what it does
==================  ====================================================================
kinematics.pose     the closed chain O-A-B(-C) at angle theta and its velocity ratios
DOOR   (door)       the door rod OAE: inertia, gravity, hinge friction, user force
PLATE  (plate)      the plate ABC: spring and friction at C, joint friction at A, stop H
RELATIVESPEED       slip of the plate on the cabinet pad D and the pad's friction
FRICTIONFORCE       slot at B: normal force, Coulomb friction, pin friction
LATCH  (latch)      the catch near closed: unlock / lock springs and the wall
==================  ====================================================================

:func:`accel` wires them into the one compiled right-hand side that the integrators
take. Every block returns the generalised force (N m) it puts on theta, found by
virtual work (the plate is massless), and :func:`accel` sums them; a new block (a
soft-close damper, say) is one more function and one more ``q +=`` line here.

:func:`energy` gives the door's mechanical energy (kinetic, gravity, spring, latch and
stop potentials) for the conservation tests. Equations and the drawing of the
mechanism: ``docs/physical-model.md``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from evo_door.models.base import Model
from evo_door.models.door.door import door, door_potential
from evo_door.models.door.frictionforce import friction_force
from evo_door.models.door.kinematics import pose
from evo_door.models.door.latch import latch, latch_potential
from evo_door.models.door.parameters import N_SECTIONS, TABLE
from evo_door.models.door.plate import plate, spring_potential, stop_h
from evo_door.models.door.relativespeed import relative_speed, section_scale
from evo_door.params import param_vector

PARAMS = TABLE

# Positions in the kernel vector, from the declaration (never literal).
L = TABLE.index("L")
L_OA = TABLE.index("L_OA")
L_BX = TABLE.index("L_Bx")
L_BY = TABLE.index("L_By")
L_CX = TABLE.index("L_Cx")
L_CY = TABLE.index("L_Cy")
L_DX = TABLE.index("L_Dx")
L_DY = TABLE.index("L_Dy")
G_X = TABLE.index("G_x")
G_Y = TABLE.index("G_y")
K = TABLE.index("K")
F_LOAD = TABLE.index("F_load")
M = TABLE.index("M")
I_Z = TABLE.index("I_z")
T_ATO = TABLE.index("T_atO")
T_ATA = TABLE.index("T_atA")
T_ATB = TABLE.index("T_atB")
MU = TABLE.index("mu")
F_ATC = TABLE.index("F_atC")
F_ATD = TABLE.index("F_atD")
UNLOCK_FORCE = TABLE.index("unlock_force")
LOCK_FORCE = TABLE.index("lock_force")
LATCH_LOOSE_ANGLE = TABLE.index("latch_loose_angle")
LATCH_OPEN_STIFFNESS = TABLE.index("latch_open_stiffness")
LATCH_CLOSE_STIFFNESS = TABLE.index("latch_close_stiffness")
LATCH_OPEN_HOLD = TABLE.index("latch_open_hold")
LATCH_CLOSE_HOLD = TABLE.index("latch_close_hold")
LATCH_SEAT_FORCE = TABLE.index("latch_seat_force")
FRICTION_SCALE_1 = TABLE.index("friction_scale_1")
A_LIN = TABLE.index("a")
A_ROT = TABLE.index("a_rot")
SECTION_SHARPNESS = TABLE.index("section_sharpness")
LATCH_SHARPNESS = TABLE.index("latch_sharpness")
LATCH_DAMPING = TABLE.index("latch_damping")
WALL_STIFFNESS = TABLE.index("wall_stiffness")
WALL_DAMPING = TABLE.index("wall_damping")
STOP_STIFFNESS = TABLE.index("stop_stiffness")
STOP_DAMPING = TABLE.index("stop_damping")

assert all(
    TABLE.index(f"friction_scale_{k + 1}") == FRICTION_SCALE_1 + k for k in range(N_SECTIONS)
)

CLOSED = 0.5 * math.pi


@njit(cache=True, nogil=True)
def pad_scale(theta, p):
    """A(theta) of eq. 5.8-5.9; exactly 1 (and free) when every section scale is 1."""
    uniform = True
    for j in range(N_SECTIONS):
        if p[FRICTION_SCALE_1 + j] != 1.0:
            uniform = False
    if uniform:
        return 1.0
    return section_scale(
        theta, p[FRICTION_SCALE_1 : FRICTION_SCALE_1 + N_SECTIONS], p[SECTION_SHARPNESS]
    )


@njit(cache=True, nogil=True)
def mechanism_force(theta, dtheta, p):
    """Generalised force (N m) of the plate, pad, slot, latch and stop on theta.

    The wiring of fig. 3.5: pose -> PLATE -> RELATIVESPEED -> FRICTIONFORCE, with
    LATCH and the stop H beside them. Everything but the door's own inertia, gravity
    and hinge friction.
    """
    k = pose(theta, p[L_OA], p[L_BX], p[L_BY], p[L_CX], p[L_CY])
    pl = plate(k, dtheta, p[L_CY], p[K], p[F_LOAD], p[F_ATC], p[T_ATA], p[A_LIN], p[A_ROT])
    pad = relative_speed(k, dtheta, p[L_DX], p[L_DY], p[F_ATD] * pad_scale(theta, p), p[A_LIN])
    slot = friction_force(
        k, dtheta, pad.F_Dx, pad.F_Dy, pad.T_B, pl.m, p[MU], p[T_ATB], p[A_LIN], p[A_ROT]
    )
    q = pl.q + slot.q
    q += latch(
        theta,
        dtheta,
        p[L],
        p[UNLOCK_FORCE],
        p[LOCK_FORCE],
        p[LATCH_LOOSE_ANGLE],
        p[LATCH_OPEN_STIFFNESS],
        p[LATCH_CLOSE_STIFFNESS],
        p[LATCH_OPEN_HOLD],
        p[LATCH_CLOSE_HOLD],
        p[LATCH_SEAT_FORCE],
        p[LATCH_DAMPING],
        p[LATCH_SHARPNESS],
        p[WALL_STIFFNESS],
        p[WALL_DAMPING],
    )
    q += stop_h(theta, dtheta, p[STOP_STIFFNESS], p[STOP_DAMPING])
    return q


@njit(cache=True, nogil=True)
def accel(theta, dtheta, force, p):
    """Angular acceleration (rad/s^2) of the door under the user force ``force`` (N at E)."""
    return door(
        theta,
        dtheta,
        force,
        mechanism_force(theta, dtheta, p),
        p[L],
        p[M],
        p[I_Z],
        p[G_X],
        p[G_Y],
        p[T_ATO],
        p[A_ROT],
    )


@njit(cache=True, nogil=True)
def energy(theta, dtheta, p):
    """Mechanical energy (J): kinetic + gravity + spring at C + latch springs + stops.

    Zero-referenced at the fully-open pose at rest. The latch's potential is in closed
    form (:func:`~evo_door.models.door.latch.latch_potential`), the stop and wall
    potentials are the one-sided ``k x^2 / 2``.
    """
    inertia_o = p[I_Z] + p[M] * (p[G_X] ** 2 + p[G_Y] ** 2)
    e = 0.5 * inertia_o * dtheta * dtheta
    e += door_potential(theta, p[M], p[G_X], p[G_Y]) - door_potential(0.0, p[M], p[G_X], p[G_Y])
    k = pose(theta, p[L_OA], p[L_BX], p[L_BY], p[L_CX], p[L_CY])
    e += spring_potential(k, p[L_CY], p[K], p[F_LOAD])
    # latch: V(theta) = -int L F_latch dtheta, in closed form (latch.latch_potential)
    if p[UNLOCK_FORCE] > 0.0 or p[LOCK_FORCE] > 0.0:
        e += p[L] * latch_potential(
            theta,
            p[UNLOCK_FORCE],
            p[LOCK_FORCE],
            p[LATCH_LOOSE_ANGLE],
            p[LATCH_OPEN_STIFFNESS],
            p[LATCH_CLOSE_STIFFNESS],
            p[LATCH_OPEN_HOLD],
            p[LATCH_CLOSE_HOLD],
            p[LATCH_SEAT_FORCE],
        )
    if theta > CLOSED:
        e += 0.5 * p[WALL_STIFFNESS] * p[L] * (theta - CLOSED) ** 2
    if theta < 0.0:
        e += 0.5 * p[STOP_STIFFNESS] * theta * theta
    return e


def energy_of(params, theta, dtheta) -> np.ndarray:
    """:func:`energy` over arrays (J), for a ParamSet or a kernel vector."""
    p = param_vector(params, TABLE)
    theta = np.asarray(theta, dtype=np.float64)
    dtheta = np.broadcast_to(np.asarray(dtheta, dtype=np.float64), theta.shape)
    return np.array(
        [energy(float(a), float(b), p) for a, b in zip(theta.ravel(), dtheta.ravel())]
    ).reshape(theta.shape)


_NOTES = """\
theta: 0 = fully open (door horizontal), pi/2 = closed; forces + toward closing, at
the handle E (L from the hinge O). Geometry (L_*, G_*) is the fully-open pose in the
cabinet frame: origin O, x out of the cabinet, y up. Presets: default (the virtual
rig's door), table53_min / table53_mid / table53_max (seed table 5.3), table54_spec
(seed table 5.4). Equations and drawing: docs/physical-model.md."""

#: RK4, 2 steps per 1024 Hz sample. The stiffest smooth elements of the defaults (the
#: latch wall, 1e5 N/rad at the handle, and the tanh frictions) need h |lambda| < 0.3,
#: far inside RK4's stability limit of 2.8; the latch apex is a near-jump that a fixed
#: step crosses. Against a 64-sub-step reference, an impulse trial is exact to 1e-4
#: deg/s and an unlock trial to 2 deg/s at the snap (docs/physical-model.md).
#: Very stiff user values (a, latch or wall stiffness far above the defaults) want
#: ``method="semi_implicit"``.
MODEL = Model(
    name="door",
    title="Physical model of the dishwasher door",
    params=TABLE,
    accel=accel,
    method="rk4",
    substeps=2,
    theta0=0.0,
    notes=_NOTES,
    rig_kinds=("impulse", "unlock", "lock"),
)
