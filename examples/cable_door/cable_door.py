"""An oven door whose closing spring pulls through an elastic cable: a user model with
a state of its own.

This file is the whole model; evo-door loads it as ``cable_door.py:MODEL``. Unlike a
model given by one ``accel(theta, dtheta, force, p)``, this one has three states, so it
gives a right-hand side on the state vector, ``rhs(x, force, p, dx)``:

- ``x[0] = angle`` (rad): the door's angle, 0 fully open (horizontal), pi/2 closed;
- ``x[1] = rate`` (rad/s): its speed, > 0 closing;
- ``x[2] = carriage`` (m): where the spring's carriage sits on its rail, 0 where the
  spring has its pre-load.

A cable wound on a drum of radius ``drum_radius`` at the hinge runs to the carriage; a
spring pulls the carriage back, and a damper slows it. Opening the door unwinds the
cable, which drags the carriage out against the spring. The cable stretches
(``cable_stiffness``) and goes slack when the carriage lags behind: it pulls, never
pushes. The carriage is light, so it has no mass of its own: its damper balances the
cable and the spring (a first-order state)::

    stretch = drum_radius * (pi/2 - angle) - carriage         m, cable's elongation
    tension = cable_stiffness * stretch   if stretch > 0, else 0              N
    carriage_damping * d(carriage)/dt = tension - spring_preload - spring_stiffness * carriage
    leaf_inertia * d(rate)/dt = hand_lever * force                the hand (N at the handle)
                              - weight_moment * cos(angle)        the leaf's weight opens it
                              + drum_radius * tension             the spring closes it
                              - hinge_friction * tanh(friction_slope * rate)
                              + stops                             rubber, at 0 and pi/2

The slack cable's kink and the two stops are switching functions (``switches``), which
the integrators locate within the step. ``start`` puts the carriage where the spring and the cable
balance at the trial's first angle. The handle (where the hand pushes) is the angle.
"""

import math

from numba import njit

from evo_door.models import Model
from evo_door.params import Param, ParamTable

PARAMS = ParamTable(
    "cable_door",
    [
        Param("leaf_inertia", "kg m^2", 1.2, 0.1, 10.0, "specification",
              "moment of inertia of the door leaf about its hinge"),
        Param("weight_moment", "N m", 30.0, 0.0, 100.0, "specification",
              "the leaf's weight times its centre's distance from the hinge"),
        Param("hand_lever", "m", 0.5, 0.1, 1.0, "geometry",
              "distance from the hinge to where the hand pushes"),
        Param("drum_radius", "m", 0.05, 0.01, 0.2, "geometry",
              "radius of the cable's drum at the hinge"),
        Param("cable_stiffness", "N/m", 20000.0, 100.0, 1.0e6, "specification",
              "axial stiffness of the cable, hinge to carriage"),
        Param("spring_stiffness", "N/m", 3000.0, 0.0, 50000.0, "specification",
              "stiffness of the closing spring"),
        Param("spring_preload", "N", 300.0, 0.0, 2000.0, "specification",
              "force of the closing spring with the carriage at 0"),
        Param("carriage_damping", "N s/m", 200.0, 1.0, 5000.0, "specification",
              "viscous damper on the spring's carriage"),
        Param("hinge_friction", "N m", 0.8, 0.0, 10.0, "specification",
              "dry friction torque of the hinges, against the motion"),
        Param("friction_slope", "s/rad", 50.0, 1.0, 1000.0, "numerics",
              "slope of the tanh that smooths the hinge friction's sign"),
        Param("stop_stiffness", "N m/rad", 3000.0, 10.0, 1.0e5, "numerics",
              "stiffness of the rubber stops, fully open and closed"),
        Param("stop_damping", "N m s/rad", 30.0, 0.0, 1000.0, "numerics",
              "damping of the rubber stops"),
    ],
)  # fmt: skip

J, WEIGHT, LEVER, RADIUS, K_CABLE, K_SPRING, PRELOAD, DAMPING, FRICTION, SLOPE = (
    PARAMS.index(name)
    for name in (
        "leaf_inertia", "weight_moment", "hand_lever", "drum_radius", "cable_stiffness",
        "spring_stiffness", "spring_preload", "carriage_damping", "hinge_friction",
        "friction_slope",
    )
)  # fmt: skip
K_STOP, C_STOP = PARAMS.index("stop_stiffness"), PARAMS.index("stop_damping")
CLOSED = 0.5 * math.pi
ANGLE, RATE, CARRIAGE = 0, 1, 2


@njit(cache=True)
def stretch(x, p):
    """The cable's elongation (m); it is slack where this is negative."""
    return p[RADIUS] * (0.5 * math.pi - x[ANGLE]) - x[CARRIAGE]


@njit(cache=True)
def stops(x, p):
    """Torque of the rubber stops (N m): they push the leaf back, never pull."""
    if x[ANGLE] < 0.0:
        return max(-p[K_STOP] * x[ANGLE] - p[C_STOP] * x[RATE], 0.0)
    if x[ANGLE] > CLOSED:
        return min(-p[K_STOP] * (x[ANGLE] - CLOSED) - p[C_STOP] * x[RATE], 0.0)
    return 0.0


@njit(cache=True)
def rhs(x, force, p, dx):
    tension = max(p[K_CABLE] * stretch(x, p), 0.0)
    spring = p[PRELOAD] + p[K_SPRING] * x[CARRIAGE]
    torque = (
        p[LEVER] * force
        - p[WEIGHT] * math.cos(x[ANGLE])
        + p[RADIUS] * tension
        - p[FRICTION] * math.tanh(p[SLOPE] * x[RATE])
        + stops(x, p)
    )
    dx[ANGLE] = x[RATE]
    dx[RATE] = torque / p[J]
    dx[CARRIAGE] = (tension - spring) / p[DAMPING]


@njit(cache=True)
def switches(x, force, p, g):
    g[0] = stretch(x, p)  # the cable goes slack
    g[1] = x[ANGLE]  # the open stop
    g[2] = x[ANGLE] - CLOSED  # the closed stop


@njit(cache=True)
def start(x, p):
    # the carriage at rest, cable taut: K_CABLE (s - c) = PRELOAD + K_SPRING c
    s = p[RADIUS] * (0.5 * math.pi - x[ANGLE])
    x[CARRIAGE] = (p[K_CABLE] * s - p[PRELOAD]) / (p[K_CABLE] + p[K_SPRING])


MODEL = Model(
    name="cable_door",
    title="oven door closed by a spring through an elastic cable (3 states)",
    params=PARAMS,
    rhs=rhs,
    states=("angle", "rate", "carriage"),
    handle=(ANGLE, RATE),
    start=start,
    switches=switches,
    n_switches=3,
    method="dopri5",
    tolerance=1e-8,
    substeps=4,
    theta0=0.0,
    rig_kinds=("impulse",),
    notes="Three states: the door's angle and speed, and the spring's carriage (m).",
)
