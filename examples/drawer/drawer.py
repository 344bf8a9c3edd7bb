"""A kitchen drawer on ball-bearing runners, with a soft-close catch: a user model.

This file is the whole model; evo-door loads it as ``drawer.py:MODEL`` (a path to
this file, then the object's name), no installation or PYTHONPATH needed::

    evo-door params drawer.py:MODEL

The workbench's models are 1-DOF: a coordinate ``theta`` driven by a user force at
the handle. For a door ``theta`` is an angle; here it is the drawer's **position**
along its stroke, in metres, read with the workbench's conventions:

- ``theta = 0`` is fully open (pulled out to the runners' end), ``theta = STROKE``
  closed; so ``dtheta`` (m/s) > 0 is closing, < 0 opening;
- the user's force (N, on the handle, along the runners) is positive when it pushes
  the drawer in.

The dynamics, with ``x = theta`` and ``v = dtheta``::

    mass * dv/dt = F_user                                     the hand
                 - runner_friction * tanh(friction_slope * v)  dry friction of the runners
                 - viscous_damping * v                         grease
                 + C(x) (softclose_force - softclose_damping v)   soft-close, last stretch
                 + stops                                       full extension and closed

``C(x)`` switches the soft-close on over its last ``softclose_length`` before closed
(smoothly, over ~1/softclose_sharpness metres): a pre-tensioned spring pulls the
drawer shut and a damper slows it so that it does not slam. The end stops are stiff
penalty springs with damping that push and never pull.

Each parameter is declared once, below, with its unit, bounds, group and meaning;
``accel`` reads them from the flat vector through the indices the declaration gives.
"""

import math

from numba import njit

from evo_door.models import Model
from evo_door.params import Param, ParamTable

#: Travel of the runners from fully open to closed (m): a catalogue value of the
#: slides (450 mm full extension), not something to estimate. Another drawer: edit it.
STROKE = 0.45

PARAMS = ParamTable(
    "drawer",
    [
        Param(
            "mass",
            "kg",
            6.0,
            0.5,
            60.0,
            "specification",
            "moving mass: drawer box, front and contents",
        ),
        Param(
            "runner_friction",
            "N",
            1.2,
            0.0,
            30.0,
            "specification",
            "dry friction of the runners, against the motion",
        ),
        Param(
            "viscous_damping",
            "N s/m",
            1.5,
            0.0,
            200.0,
            "specification",
            "viscous drag of the runners' grease, force c v against the motion",
        ),
        Param(
            "softclose_length",
            "m",
            0.05,
            0.0,
            0.15,
            "geometry",
            "travel before closed over which the soft-close catch acts",
        ),
        Param(
            "softclose_force",
            "N",
            8.0,
            0.0,
            60.0,
            "specification",
            "pull of the soft-close spring toward closed, inside its travel",
        ),
        Param(
            "softclose_damping",
            "N s/m",
            60.0,
            0.0,
            1000.0,
            "specification",
            "damper of the soft-close, inside its travel (stops the slam)",
        ),
        Param(
            "stop_stiffness",
            "N/m",
            1.0e5,
            1.0e3,
            1.0e7,
            "specification",
            "end stops at full extension (0) and closed (STROKE)",
        ),
        Param(
            "stop_damping", "N s/m", 500.0, 0.0, 1.0e4, "specification", "damping of the end stops"
        ),
        Param(
            "friction_slope",
            "s/m",
            200.0,
            10.0,
            5000.0,
            "numerics",
            "tanh slope of the dry friction, F = f tanh(a v)",
        ),
        Param(
            "softclose_sharpness",
            "1/m",
            2000.0,
            10.0,
            1.0e5,
            "numerics",
            "how sharply the soft-close catch engages (1 / width of its onset)",
        ),
    ],
)

# Positions in the kernel vector, from the declaration (never written as literals).
MASS = PARAMS.index("mass")
RUNNER_FRICTION = PARAMS.index("runner_friction")
VISCOUS_DAMPING = PARAMS.index("viscous_damping")
SOFTCLOSE_LENGTH = PARAMS.index("softclose_length")
SOFTCLOSE_FORCE = PARAMS.index("softclose_force")
SOFTCLOSE_DAMPING = PARAMS.index("softclose_damping")
STOP_STIFFNESS = PARAMS.index("stop_stiffness")
STOP_DAMPING = PARAMS.index("stop_damping")
FRICTION_SLOPE = PARAMS.index("friction_slope")
SOFTCLOSE_SHARPNESS = PARAMS.index("softclose_sharpness")


@njit(cache=True)
def accel(theta, dtheta, force, p):
    """Acceleration (m/s^2) of the drawer at position ``theta`` (m), speed ``dtheta``
    (m/s), under the user's force ``force`` (N, + pushing in)."""
    x = theta
    v = dtheta
    f = force
    f -= p[RUNNER_FRICTION] * math.tanh(p[FRICTION_SLOPE] * v)
    f -= p[VISCOUS_DAMPING] * v

    # soft-close: a logistic switch centred where the catch engages; beyond 20 widths
    # it is exactly 0 or 1, and exp() is not called (most of the stroke is out there)
    u = p[SOFTCLOSE_SHARPNESS] * (x - (STROKE - p[SOFTCLOSE_LENGTH]))
    if u > -20.0:
        catch = 1.0 if u > 20.0 else 1.0 / (1.0 + math.exp(-2.0 * u))
        f += catch * (p[SOFTCLOSE_FORCE] - p[SOFTCLOSE_DAMPING] * v)

    # end stops: penalty spring-dampers that push the drawer back, never pull it
    if x > STROKE:
        f += min(0.0, -p[STOP_STIFFNESS] * (x - STROKE) - p[STOP_DAMPING] * v)
    elif x < 0.0:
        f += max(0.0, -p[STOP_STIFFNESS] * x - p[STOP_DAMPING] * v)
    return f / p[MASS]


@njit(cache=True)
def switches(theta, dtheta, force, p, g):
    """Where ``accel`` has a kink or a jump, as functions whose sign changes there: the
    two end stops, and where each stop's damper would pull (it never does). The
    integrators locate these within the step; 1 where a function does not apply."""
    g[0] = theta
    g[1] = -p[STOP_STIFFNESS] * theta - p[STOP_DAMPING] * dtheta if theta < 0.0 else 1.0
    g[2] = theta - STROKE
    pen = theta - STROKE
    g[3] = p[STOP_STIFFNESS] * pen + p[STOP_DAMPING] * dtheta if pen > 0.0 else 1.0


MODEL = Model(
    name="drawer",
    title="Kitchen drawer with soft-close (example user model)",
    params=PARAMS,
    accel=accel,
    # ROS2 treats the stiff parts (end stops, steep dry friction on a light drawer)
    # implicitly: stable over the whole declared range at 1024 Hz, 2 steps per sample
    method="semi_implicit",
    substeps=2,
    # the end stops' kinks, located within the step (docs/integration.md)
    switches=switches,
    n_switches=4,
    theta0=0.0,
    theta_range=(0.0, STROKE),
    theta_unit="m",
    # no latch near closed for the rig's hand to feel: only impulse trials (a push
    # from fully open, then free motion) make sense
    rig_kinds=("impulse",),
    notes=f"theta is the drawer's position (m): 0 fully open, {STROKE} closed; dtheta in "
    "m/s, + closing; force in N along the runners, + pushing in. "
    "See examples/drawer/README.md.",
)
