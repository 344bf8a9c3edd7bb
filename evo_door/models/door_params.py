"""Parameter declaration of the physical door model (seed chapter 3, tables 5.2-5.4).

It imports no numba: ``evo-door params door``, ``show`` and the other readers of a
results file take the names, units and bounds from here (:data:`DECLARATION`) without
the model's kernels (:mod:`evo_door.models.door`, which takes :data:`TABLE` from here).

Names are the seed's symbols written plainly (``T_atO`` for T_at_O); what the seed is,
and the conventions of angles, signs and units: ``docs/conventions.md``. Geometry is
given in the **fully-open pose** (theta = 0) in the cabinet frame of
``docs/physical-model.md``: origin at the door hinge O, x horizontal and positive out
of the cabinet (toward the user standing in front of the open door), y vertically up.

The declared defaults are the ``default`` preset (the virtual rig's door); the
``table53_*`` and ``table54_spec`` presets hold the seed's estimated values.
"""

from __future__ import annotations

import math

from evo_door.models.base import Declaration
from evo_door.params import Param, ParamTable

#: Standard gravity (m/s^2).
GRAVITY = 9.80665

#: Number of sections of the position-dependent pad friction (eq. 5.8-5.9).
N_SECTIONS = 8

_DEG = math.pi / 180.0

_PARAMS = [
    # -- geometry (table 5.2, fully-open pose) ------------------------------------
    Param(
        "L",
        "m",
        0.6,
        0.2,
        1.2,
        "geometry",
        "door length: hinge O to the handle E, where the user force acts",
    ),
    Param(
        "L_OA",
        "m",
        0.03,
        0.005,
        0.1,
        "geometry",
        "hinge O to the plate joint A, along the door toward E",
    ),
    Param(
        "L_Bx",
        "m",
        -0.01,
        -0.2,
        0.2,
        "geometry",
        "x of the slotted-link pin B (constant: the slot is vertical)",
    ),
    Param("L_By", "m", 0.09, 0.0, 0.3, "geometry", "y of B when the door is fully open"),
    Param("L_Cx", "m", -0.06, -0.3, 0.3, "geometry", "x of the spring point C, fully open"),
    Param("L_Cy", "m", 0.08, -0.3, 0.3, "geometry", "y of the spring point C, fully open"),
    Param(
        "L_Dx", "m", -0.05, -0.3, 0.3, "geometry", "x of the fixed friction pad D on the cabinet"
    ),
    Param("L_Dy", "m", 0.06, -0.3, 0.3, "geometry", "y of the fixed friction pad D on the cabinet"),
    Param(
        "G_x",
        "m",
        0.3,
        0.0,
        1.2,
        "geometry",
        "door centre of mass: distance from O along the door (toward E)",
    ),
    Param(
        "G_y",
        "m",
        0.0,
        -0.2,
        0.2,
        "geometry",
        "door centre of mass: offset across the door (+ up when the door is open)",
    ),
    # -- technical specifications (tables 5.3, 5.4) ------------------------------
    Param(
        "K",
        "N/m",
        400.64,
        0.0,
        2000.0,
        "specification",
        "stiffness of the vertical spring at C",
        process="spring_rate",
    ),
    Param(
        "F_load",
        "N",
        101.45,
        0.0,
        500.0,
        "specification",
        "spring pre-load at C with the door fully open (pushes C up, toward closing)",
        process="spring_preload",
    ),
    Param("M", "kg", 1.232, 0.05, 20.0, "specification", "door mass", process="mass"),
    Param(
        "I_z",
        "kg m^2",
        0.1275,
        0.001,
        2.0,
        "specification",
        "door moment of inertia about its centre of mass",
        process="inertia",
    ),
    Param(
        "T_atO",
        "N m",
        0.006145,
        0.0,
        1.0,
        "specification",
        "dry-friction torque at the hinge O",
        process="friction_torque",
    ),
    Param(
        "T_atA",
        "N m",
        0.00904,
        0.0,
        1.0,
        "specification",
        "dry-friction torque at the door-plate joint A",
        process="friction_torque",
    ),
    Param(
        "T_atB",
        "N m",
        0.004935,
        0.0,
        1.0,
        "specification",
        "dry-friction torque of the plate's rotation at the slotted link B",
        process="friction_torque",
    ),
    Param(
        "mu",
        "1",
        0.8065,
        0.0,
        1.5,
        "specification",
        "friction coefficient of the vertical sliding at B (force = mu |normal force|)",
        process="friction_coefficient",
    ),
    Param(
        "F_atC",
        "N",
        28.92,
        0.0,
        300.0,
        "specification",
        "vertical dry friction at C",
        process="friction_force",
    ),
    Param(
        "F_atD",
        "N",
        18.8,
        0.0,
        300.0,
        "specification",
        "dry friction of the fixed pad D rubbing the plate",
        process="friction_force",
    ),
    Param(
        "unlock_force",
        "N",
        40.0,
        0.0,
        300.0,
        "specification",
        "latch: extra user pull at the handle needed to unlock the closed door",
        process="latch_force",
    ),
    Param(
        "lock_force",
        "N",
        30.0,
        0.0,
        300.0,
        "specification",
        "latch: extra user push at the handle needed to lock the door",
        process="latch_force",
    ),
    Param(
        "latch_loose_angle",
        "rad",
        0.4 * _DEG,
        0.0,
        5.0 * _DEG,
        "specification",
        "latch: free play of the closed door before the catch engages",
        process="latch_angle",
    ),
    Param(
        "latch_open_stiffness",
        "N/rad",
        4.0e4,
        1.0e2,
        1.0e7,
        "specification",
        "latch: catch stiffness felt at the handle while unlocking",
        process="spring_rate",
    ),
    Param(
        "latch_close_stiffness",
        "N/rad",
        2.0e4,
        1.0e2,
        1.0e7,
        "specification",
        "latch: catch stiffness felt at the handle while locking",
        process="spring_rate",
    ),
    Param(
        "latch_open_hold",
        "rad",
        0.006,
        0.0,
        5.0 * _DEG,
        "specification",
        "latch: travel over which the catch holds unlock_force before it lets go",
        process="latch_angle",
    ),
    Param(
        "latch_close_hold",
        "rad",
        0.009,
        0.0,
        5.0 * _DEG,
        "specification",
        "latch: travel over which the lock ramp holds lock_force before the door snaps in",
        process="latch_angle",
    ),
    Param(
        "latch_seat_force",
        "N",
        10.0,
        0.0,
        300.0,
        "specification",
        "latch: push of the door seal that holds the latched door out against its catch",
        process="latch_force",
    ),
]
_PARAMS += [
    Param(
        f"friction_scale_{k}",
        "1",
        1.0,
        0.0,
        1.0,
        "specification",
        f"pad friction F_atD scale A_{k} on section {k} of {N_SECTIONS} of [0, 90] deg "
        f"(eq. 5.8-5.9)",
        symbol=f"A_{k}",
        process="section_scale",
    )
    for k in range(1, N_SECTIONS + 1)
]
_PARAMS += [
    # -- numerics: regularisation and contact penalties ---------------------------
    Param(
        "a",
        "s/m",
        2000.0,
        1.0,
        1.0e6,
        "numerics",
        "tanh sensitivity of the sliding frictions at B, C and D (eq. 3.1)",
    ),
    Param(
        "a_rot",
        "s/rad",
        100.0,
        0.1,
        1.0e5,
        "numerics",
        "tanh sensitivity of the joint friction torques at O, A and B (eq. 3.1)",
    ),
    Param(
        "section_sharpness",
        "1/rad",
        50.0,
        1.0,
        1.0e5,
        "numerics",
        "slope of the activation S between pad-friction sections (eq. 5.8)",
    ),
    Param(
        "latch_sharpness",
        "1/rad",
        1.0e6,
        1.0e2,
        1.0e8,
        "numerics",
        "slope of the activation S where the latch force reverses",
    ),
    Param(
        "latch_damping",
        "N s/rad",
        50.0,
        0.0,
        1.0e5,
        "numerics",
        "damping inside the latch catch, as a force at the handle",
    ),
    Param(
        "wall_stiffness",
        "N/rad",
        3.0e5,
        1.0e2,
        1.0e8,
        "numerics",
        "latch wall beyond closed (theta > pi/2), as a force at the handle",
    ),
    Param(
        "wall_damping",
        "N s/rad",
        500.0,
        0.0,
        1.0e5,
        "numerics",
        "damping of the latch wall, as a force at the handle",
    ),
    Param(
        "stop_stiffness",
        "N m/rad",
        2.0e4,
        1.0e1,
        1.0e7,
        "numerics",
        "end stop H at fully open (theta < 0), as a torque at O",
    ),
    Param("stop_damping", "N m s/rad", 100.0, 0.0, 1.0e4, "numerics", "damping of the end stop H"),
]

#: The declaration; kernel vectors follow this order.
TABLE = ParamTable("door", _PARAMS)

NOTES = """\
theta: 0 = fully open (door horizontal), pi/2 = closed; forces + toward closing, at
the handle E (L from the hinge O). Geometry (L_*, G_*) is the fully-open pose in the
cabinet frame: origin O, x out of the cabinet, y up. Presets: default (the virtual
rig's door), table53_min / table53_mid / table53_max (seed table 5.3), table54_spec
(seed table 5.4). Equations and drawing: docs/physical-model.md."""

TITLE = "Physical model of the dishwasher door"

#: What can be read of the door without its kernels (:func:`~evo_door.models.get_declaration`)
DECLARATION = Declaration(name="door", title=TITLE, params=TABLE, notes=NOTES)
