"""The haptic model's declaration: its parameters, title and notes, without numba.

Split from :mod:`evo_door.models.haptic` (which re-exports every name here) so that
``evo-door params haptic``, the parser and anything else that only reads the
declaration start without importing numba or compiling the kernels.
"""

from __future__ import annotations

import math

from evo_door.models.base import Declaration
from evo_door.params import Param, ParamTable

#: Number of angular sections of the friction scale (eq. 4.48 / 5.8), over [0, pi/2].
N_SECTIONS = 8
#: Number of angles at which the balance force is set: the section boundaries, 0 to pi/2.
N_BALANCE = N_SECTIONS + 1
#: Closed door angle (rad).
CLOSED = 0.5 * math.pi
#: Origin of the model frame in device coordinates is (0, -0.158, -0.138) m (eq. 4.2):
#: y_m = y + DEVICE_OFFSET_Y, z_m = z + DEVICE_OFFSET_Z.
DEVICE_OFFSET_Y = 0.158
DEVICE_OFFSET_Z = 0.138

_DEG = math.pi / 180.0
#: Largest balance force (N) either way: half the weight of a heavy 10 kg door, its
#: whole push at the handle with no spring at all (docs/haptic-model.md, "Bounds that
#: keep a hand safe").
BALANCE_LIMIT = 50.0

PARAMS = ParamTable(
    "haptic",
    [
        # -- sensations: what the operator tunes ------------------------------------
        Param(
            "inertia",
            "kg m",
            1.2,
            0.05,
            20.0,
            "sensation",
            "equivalent inertia at the handle, I = m R (heaviness)",
            symbol="I",
        ),
        Param(
            "friction_closing",
            "N",
            3.0,
            0.0,
            100.0,
            "sensation",
            "dry friction while closing (dtheta > friction_speed_threshold)",
            symbol="c_at+",
        ),
        Param(
            "friction_opening",
            "N",
            2.0,
            0.0,
            100.0,
            "sensation",
            "dry friction while opening (dtheta < friction_speed_threshold)",
            symbol="c_at-",
        ),
        *[
            Param(
                f"friction_scale_{k}",
                "1",
                1.0,
                0.0,
                1.0,
                "sensation",
                f"dry-friction scale on section {k} of 8, "
                f"[{(k - 1) * 90 / N_SECTIONS:g}, {k * 90 / N_SECTIONS:g}] deg",
                symbol=f"A_{k}",
            )
            for k in range(1, N_SECTIONS + 1)
        ],
        *[
            Param(
                f"balance_{k}",
                "N",
                0.0,
                -BALANCE_LIMIT,
                BALANCE_LIMIT,
                "sensation",
                f"the door's own push at rest at {(k - 1) * 90 / N_SECTIONS:g} deg, + toward "
                "closing (weight and springs); linear between the nine angles",
                symbol=f"B_{k}",
            )
            for k in range(1, N_BALANCE + 1)
        ],
        Param(
            "viscous_damping",
            "N s/rad",
            0.2,
            0.0,
            100.0,
            "sensation",
            "viscous friction, force c_v * |dtheta| against the motion (eq. 4.42)",
            symbol="c_v",
        ),
        Param(
            "return_stiffness",
            "N/rad",
            0.0,
            0.0,
            1000.0,
            "sensation",
            "return spring toward return_angle, e.g. a soft close (eq. 4.43); 0 = none",
            symbol="k_ret",
        ),
        Param(
            "return_angle",
            "rad",
            CLOSED,
            0.0,
            CLOSED,
            "sensation",
            "rest angle of the return spring (pi/2 pulls toward closed)",
            symbol="theta_k",
        ),
        Param(
            "return_onset",
            "rad",
            0.25 * math.pi,
            0.0,
            CLOSED,
            "sensation",
            "the return spring acts above this angle",
        ),
        Param(
            "open_force",
            "N",
            20.0,
            0.0,
            200.0,
            "sensation",
            "latch force to overcome to unlock (peak of the opening force); 0 = none",
            symbol="k_1inf (theta_0 - theta_1)",
        ),
        Param(
            "close_force",
            "N",
            12.0,
            0.0,
            200.0,
            "sensation",
            "latch force to overcome to lock (peak of the closing force); 0 = none",
            symbol="k_2inf (theta_2 - theta_3)",
        ),
        Param(
            "loose_angle",
            "rad",
            0.5 * _DEG,
            0.0,
            0.1,
            "sensation",
            "free play below closed before the latch engages (seed: 0.5 deg)",
            symbol="pi/2 - theta_0",
        ),
        Param(
            "transition_angle",
            "rad",
            0.005,
            0.0,
            0.1,
            "sensation",
            "snap zone between the unlock and the lock band",
        ),
        Param(
            "open_hold",
            "rad",
            0.0,
            0.0,
            0.2,
            "sensation",
            "travel over which the latch holds open_force before it gives (push-through)",
        ),
        Param(
            "close_hold",
            "rad",
            0.0,
            0.0,
            0.2,
            "sensation",
            "travel over which the latch holds close_force before the door snaps shut",
        ),
        Param(
            "seat_force",
            "N",
            3.0,
            0.0,
            100.0,
            "sensation",
            "push of the door seal holding the latched door against its catch; 0 = none",
        ),
        Param(
            "gasket_stiffness",
            "N/rad",
            200.0,
            0.0,
            1.0e4,
            "sensation",
            "soft push toward opening in the loose band (door seal)",
            symbol="k_l",
        ),
        Param(
            "transition_damping",
            "N s/rad",
            5.0,
            0.0,
            1000.0,
            "sensation",
            "negative damping in the snap zone: the door leaves it on its own (eq. 4.41)",
            symbol="c_n",
        ),
        # -- the door's end stops -----------------------------------------------------
        Param(
            "stop_stiffness",
            "N/rad",
            2.0e4,
            0.0,
            1.0e5,
            "specification",
            "end stops beyond closed (pi/2) and fully open (0); 0 = none",
        ),
        Param(
            "stop_damping",
            "N s/rad",
            200.0,
            0.0,
            1000.0,
            "specification",
            "damping of the end stops",
        ),
        # -- device: what a renderer can afford ---------------------------------------
        Param(
            "latch_stiffness",
            "N/rad",
            2000.0,
            100.0,
            1.0e5,
            "device",
            "stiffness of the latch springs; band widths are force / stiffness",
            symbol="k_inf",
        ),
        Param(
            "latch_damping",
            "N s/rad",
            20.0,
            0.0,
            1000.0,
            "device",
            "damping inside the latch bands (eq. 4.40)",
            symbol="c_inf",
        ),
        Param(
            "radius",
            "m",
            0.3,
            0.05,
            1.0,
            "device",
            "radius of the handle's circular path on the device",
            symbol="R",
        ),
        Param(
            "k_radial",
            "N/m",
            2000.0,
            0.0,
            1.0e5,
            "device",
            "spring holding the end effector on the circle (eq. 4.32-4.33)",
            symbol="k_r",
        ),
        Param(
            "c_radial",
            "N s/m",
            200.0,
            0.0,
            1.0e4,
            "device",
            "damper on the end effector's radial speed, toward the circle",
            symbol="c_r",
        ),
        Param(
            "k_plane",
            "N/m",
            300.0,
            0.0,
            1.0e5,
            "device",
            "spring holding the end effector in the plane x = 0 (eq. 4.21)",
            symbol="k_x",
        ),
        Param(
            "c_plane",
            "N s/m",
            100.0,
            0.0,
            1.0e4,
            "device",
            "damper holding the end effector in the plane x = 0",
            symbol="c_x",
        ),
        Param(
            "c_energy",
            "N s/m",
            0.0,
            0.0,
            1.0e4,
            "device",
            "tangential negative damping, felt as -c_e R of viscous damping (eq. 4.34-4.35)",
            symbol="c_e",
        ),
        # -- numerics: smoothness of the switches ---------------------------------------
        Param(
            "friction_slope",
            "s/rad",
            100.0,
            0.0,
            2000.0,
            "numerics",
            "tanh slope of dry friction, F = c tanh(a dtheta) (eq. 3.1)",
            symbol="a",
        ),
        Param(
            "friction_speed_threshold",
            "rad/s",
            0.0,
            0.0,
            1.0,
            "numerics",
            "speed above which closing friction takes over from opening friction",
            symbol="dtheta_0",
        ),
        Param(
            "window_slope",
            "1/rad",
            100.0,
            1.0,
            1.0e4,
            "numerics",
            "activation slope of the friction sections and the return onset",
        ),
        Param(
            "latch_sharpness",
            "1",
            20.0,
            5.0,
            1000.0,
            "numerics",
            "latch band width / width of its release edge",
        ),
        Param(
            "latch_gate_slope",
            "s/rad",
            500.0,
            10.0,
            1.0e4,
            "numerics",
            "slope of the speed gate that mutes the lock spring while opening",
        ),
    ],
)

NOTES = """\
theta: 0 = fully open, pi/2 = closed; forces + toward closing. The latch bands follow
from the sensations, going down from closed: loose band [theta_0, pi/2] with
theta_0 = pi/2 - loose_angle (the seal's seat_force holds a latched door at theta_0);
unlock band down to theta_1 = theta_0 - open_force / latch_stiffness - open_hold;
snap zone of transition_angle; lock band of close_force / latch_stiffness +
close_hold. Device space: virtual mass inertia / radius, model origin at device
(0, -0.158, -0.138) m. Equations: docs/haptic-model.md."""

DECLARATION = Declaration(
    name="haptic",
    title="Haptic model of the dishwasher door",
    params=PARAMS,
    notes=NOTES,
)
