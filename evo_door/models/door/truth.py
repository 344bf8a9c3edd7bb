"""A richer truth for the virtual rig: the door with effects the door model leaves out.

The virtual rig (:mod:`evo_door.data.rig`) normally makes its trials with the model that
is then fitted to them, so a fit can match the data exactly but for noise (the "inverse
crime"). A real door never obliges: its frictions are not the model's tanh, its parts
have play, its sensors have dynamics. This module is the rig's richer truth for the
physical door (``evo-door rig generate --model door --truth rich``). It reuses the
door's own blocks and right-hand side (:func:`evo_door.models.door.accel`) and adds:

**Stribeck friction** at every contact of the door: the pads and slot (C, D, B sliding)
and the joints (O, A, B turning). Each friction magnitude follows Stribeck's curve of
its own slip speed ``v`` before the door's tanh regularisation is applied::

    F(v) = F_c (1 + (r - 1) exp(-(v / v_s)^2)) tanh(a v)

with ``F_c`` the door parameter (``F_atD``, ``T_atO``, ``mu``...), which is the Coulomb
level reached at speed, ``r = stribeck_ratio`` the static level over it (breakaway
takes ``r`` times the Coulomb force) and ``v_s`` the Stribeck speed
(``stribeck_speed`` in m/s for the sliding contacts, ``stribeck_speed_rot`` in rad/s
for the joints). The slip speeds are the blocks' own (``pose`` and
``relative_speed``). ``r = 1`` is the door model exactly.

**Handle play and compliance.** The load cell sits between the hand and the handle
(seed 3.4, fig. 3.15); here the handle side of it (mass ``handle_mass`` at the handle
radius L) is joined to the door leaf through a mount with a total free travel
``handle_play`` (m, at the handle) and, beyond it, a contact of stiffness
``handle_stiffness`` and damping ``handle_damping``. The load cell measures the hand's
force on the handle mass, not the force that reaches the door; the door moves only once
the play is taken up, and the handle rattles against the leaf. The door's total mass,
centre of mass and inertia stay the parameters' (``M``, ``G_x``, ``G_y``, ``I_z``):
the handle mass is taken out of the leaf, so that a handle joined rigidly to it gives
back the door model's body. Two degrees of freedom (door angle ``theta``, handle angle
``theta_h``)::

    f_c = k p + c L (dtheta_h - dtheta)    in contact (p != 0), only pushing (set in
                                           smoothly over handle_contact_width)
    p   = x - s/2 (x > s/2),  x + s/2 (x < -s/2),  0 inside the play;  x = L (theta_h - theta)
    door leaf:  the door's accel with the force f_c at the handle E
    handle:     m_h L ddtheta_h = F_hand - f_c - m_h g cos(theta_h)

``handle_mass = 0`` leaves the handle on the door (one degree of freedom, no play).

**Sensor dynamics** (applied by the rig, :class:`evo_door.data.sensors.FilteredSensor`):
the load cell and the gyroscope as low-pass systems of declared bandwidth
(``load_cell_bandwidth``, ``gyroscope_bandwidth``; 0 = ideal).

The extra parameters are declared once, in :data:`TABLE` (model name ``door_truth``);
:data:`OFF` switches every effect off, which gives the door model's trials bit for bit.
The truth is not a model of the workbench (``Model``): the handle is a second degree of
freedom that the 1-DOF integrators and fits do not have, and the parameters the fitted
door shares with it keep their meaning, so a fit of ``door`` to rich trials is scored
against them (``evo-door show``). Equations, numbers and what a fit makes of it:
``docs/model-mismatch.md``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from evo_door.errors import UserError
from evo_door.models.door import N_SWITCHES as DOOR_SWITCHES
from evo_door.models.door import TABLE as DOOR_TABLE
from evo_door.models.door import accel as door_accel
from evo_door.models.door import switches as door_switches
from evo_door.models.door.kinematics import pose
from evo_door.models.door.relativespeed import relative_speed
from evo_door.models.door_params import GRAVITY
from evo_door.params import Param, ParamSet, ParamTable, load_params, param_vector
from evo_door.sim.integrators import BLOWUP_SPEED, integrate
from evo_door.sim_settings import DEFAULT_TOLERANCE, METHODS

#: The name ``--truth`` takes for this truth.
NAME = "rich"

TABLE = ParamTable(
    "door_truth",
    [
        Param(
            "stribeck_ratio",
            "1",
            1.5,
            1.0,
            5.0,
            "specification",
            "static friction over Coulomb friction at every contact (1: no Stribeck effect)",
        ),
        Param(
            "stribeck_speed",
            "m/s",
            0.005,
            1.0e-5,
            1.0,
            "specification",
            "Stribeck speed of the sliding contacts at B, C and D",
        ),
        Param(
            "stribeck_speed_rot",
            "rad/s",
            0.1,
            1.0e-4,
            10.0,
            "specification",
            "Stribeck speed of the joints O, A and B",
        ),
        Param(
            "handle_mass",
            "kg",
            0.1,
            0.0,
            2.0,
            "device",
            "mass beyond the load cell's sensing element, on the handle's mount (part of M; "
            "0: the handle is rigid with the door)",
        ),
        Param(
            "handle_play",
            "m",
            0.001,
            0.0,
            0.02,
            "device",
            "free travel of the handle's mount along the door's path, at the handle",
        ),
        Param(
            "handle_stiffness",
            "N/m",
            3.0e4,
            1.0e3,
            1.0e7,
            "device",
            "stiffness of the handle's mount once the play is taken up",
        ),
        Param(
            "handle_damping",
            "N s/m",
            30.0,
            0.0,
            1.0e4,
            "device",
            "damping of the handle's mount in contact",
        ),
        Param(
            "handle_contact_width",
            "m",
            1.0e-4,
            1.0e-6,
            1.0e-2,
            "numerics",
            "penetration over which the handle's contact sets in smoothly (spring force "
            "quadratic, damping ramped in)",
        ),
        Param(
            "load_cell_bandwidth",
            "Hz",
            200.0,
            0.0,
            1.0e4,
            "device",
            "load cell: -3 dB bandwidth of its low-pass (second order; 0: ideal)",
        ),
        Param(
            "gyroscope_bandwidth",
            "Hz",
            40.0,
            0.0,
            1.0e4,
            "device",
            "gyroscope: -3 dB bandwidth of its low-pass (first order; 0: ideal)",
        ),
    ],
)

#: Values that switch every effect off: the truth is then the door model.
OFF = {
    "stribeck_ratio": 1.0,
    "handle_mass": 0.0,
    "handle_play": 0.0,
    "load_cell_bandwidth": 0.0,
    "gyroscope_bandwidth": 0.0,
}

#: Order of each sensor's low-pass (channel -> (bandwidth parameter, order)). A load
#: cell is a spring-mass transducer (second order, Butterworth-damped by its
#: conditioning); the rate gyroscope's output filter is a single pole.
SENSOR_DYNAMICS = {"force": ("load_cell_bandwidth", 2), "dtheta": ("gyroscope_bandwidth", 1)}

#: RK4 steps per sample for the door with a handle: the mount (87 Hz with the defaults)
#: wants a shorter step than the door alone. Against 128 steps, an impulse trial is
#: exact to about 1e-4 rad/s (a tenth of the gyroscope's noise); through the latch snap of an
#: unlock trial to 5e-2 rad/s, like the door model itself at its 2 steps.
HANDLE_SUBSTEPS = 4

N_DOOR = len(DOOR_TABLE)
# positions in the door's kernel vector, from its declaration
_L = DOOR_TABLE.index("L")
_L_OA = DOOR_TABLE.index("L_OA")
_L_BX = DOOR_TABLE.index("L_Bx")
_L_BY = DOOR_TABLE.index("L_By")
_L_CX = DOOR_TABLE.index("L_Cx")
_L_CY = DOOR_TABLE.index("L_Cy")
_L_DX = DOOR_TABLE.index("L_Dx")
_L_DY = DOOR_TABLE.index("L_Dy")
_A_LIN = DOOR_TABLE.index("a")
_T_ATO = DOOR_TABLE.index("T_atO")
_T_ATA = DOOR_TABLE.index("T_atA")
_T_ATB = DOOR_TABLE.index("T_atB")
_MU = DOOR_TABLE.index("mu")
_F_ATC = DOOR_TABLE.index("F_atC")
_F_ATD = DOOR_TABLE.index("F_atD")
# positions of the truth's parameters in the combined vector (door's, then the truth's)
_RATIO = N_DOOR + TABLE.index("stribeck_ratio")
_V_LIN = N_DOOR + TABLE.index("stribeck_speed")
_V_ROT = N_DOOR + TABLE.index("stribeck_speed_rot")
_M_H = N_DOOR + TABLE.index("handle_mass")
_PLAY = N_DOOR + TABLE.index("handle_play")
_K_H = N_DOOR + TABLE.index("handle_stiffness")
_C_H = N_DOOR + TABLE.index("handle_damping")
_WIDTH = N_DOOR + TABLE.index("handle_contact_width")


# -- kernels ----------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def stribeck_factor(speed, stribeck_speed, ratio):
    """Friction level over the Coulomb level at slip ``speed``: ``1 + (r - 1) exp(-(v/v_s)^2)``.

    Exactly 1.0 for ``ratio = 1``, so that the door model's values pass unchanged.
    """
    if ratio == 1.0:
        return 1.0
    u = speed / stribeck_speed
    return 1.0 + (ratio - 1.0) * math.exp(-u * u)


@njit(cache=True, nogil=True)
def stribeck_params(theta, dtheta, pq, out):
    """The door's kernel vector with every friction magnitude on its Stribeck curve.

    ``pq`` is the combined vector (door's parameters, then :data:`TABLE`'s); ``out``
    (length :data:`N_DOOR`) receives the door's vector with ``T_atO``, ``T_atA``,
    ``T_atB``, ``mu``, ``F_atC`` and ``F_atD`` scaled by :func:`stribeck_factor` of
    their contact's slip speed at this state.
    """
    for i in range(N_DOOR):
        out[i] = pq[i]
    ratio = pq[_RATIO]
    if ratio == 1.0:
        return
    v_lin = pq[_V_LIN]
    v_rot = pq[_V_ROT]
    k = pose(theta, pq[_L_OA], pq[_L_BX], pq[_L_BY], pq[_L_CX], pq[_L_CY])
    pad = relative_speed(k, dtheta, pq[_L_DX], pq[_L_DY], 1.0, pq[_A_LIN])
    out[_T_ATO] *= stribeck_factor(dtheta, v_rot, ratio)
    out[_T_ATA] *= stribeck_factor((k.dphi - 1.0) * dtheta, v_rot, ratio)
    out[_T_ATB] *= stribeck_factor(k.dphi * dtheta, v_rot, ratio)
    out[_MU] *= stribeck_factor(k.dBy * dtheta, v_lin, ratio)
    out[_F_ATC] *= stribeck_factor(k.dCy * dtheta, v_lin, ratio)
    out[_F_ATD] *= stribeck_factor(math.hypot(pad.V_Dx, pad.V_Dy), v_lin, ratio)


@njit(cache=True, nogil=True)
def rigid_accel(theta, dtheta, force, pq):
    """Door with Stribeck friction and the handle rigid on it (rad/s^2); ``accel``'s form.

    ``pq`` is the combined vector; with ``stribeck_ratio = 1`` this is the door's
    :func:`~evo_door.models.door.accel` itself.
    """
    if pq[_RATIO] == 1.0:
        return door_accel(theta, dtheta, force, pq)
    scaled = np.empty(N_DOOR)
    stribeck_params(theta, dtheta, pq, scaled)
    return door_accel(theta, dtheta, force, scaled)


@njit(cache=True, nogil=True)
def handle_force(theta, dtheta, theta_h, dtheta_h, L, play, stiffness, damping, width):
    """Force (N, + toward closing) the handle's mount puts on the door at the handle E.

    Zero inside the play; beyond it a spring-damper contact that can only push. The
    contact sets in smoothly over the first ``width`` (m) of penetration (spring force
    quadratic, damping ramped in), so that a fixed-step integrator crossing the edge
    stays accurate; beyond that, ``stiffness (pen - width / 2) + damping * speed``.
    """
    x = L * (theta_h - theta)
    half = 0.5 * play
    if x > half:
        pen = x - half
        side = 1.0
    elif x < -half:
        pen = -x - half
        side = -1.0
    else:
        return 0.0
    if pen < width:
        spring = 0.5 * stiffness * pen * pen / width
        ramp = pen / width
    else:
        spring = stiffness * (pen - 0.5 * width)
        ramp = 1.0
    f = spring + side * ramp * damping * L * (dtheta_h - dtheta)
    if f < 0.0:
        return 0.0
    return side * f


@njit(cache=True, nogil=True)
def handle_rates(y, force, pq, scratch, dy):
    """Time derivative ``dy`` of the state ``y = (theta, dtheta, theta_h, dtheta_h)``."""
    L = pq[_L]
    f_c = handle_force(y[0], y[1], y[2], y[3], L, pq[_PLAY], pq[_K_H], pq[_C_H], pq[_WIDTH])
    stribeck_params(y[0], y[1], pq, scratch)
    m_h = pq[_M_H]
    dy[0] = y[1]
    dy[1] = door_accel(y[0], y[1], f_c, scratch)
    dy[2] = y[3]
    dy[3] = (force - f_c - m_h * GRAVITY * math.cos(y[2])) / (m_h * L)


@njit(cache=True, nogil=True)
def integrate_handle(pq, force, dt, substeps, state, out):
    """RK4 over a sampled hand force, the force linear between samples.

    ``state`` (4,) is the start state, overwritten with the end state; ``out`` (5, n)
    receives theta, dtheta, ddtheta (door) and theta_h, dtheta_h (handle) at the
    samples. Returns False (and a NaN tail) when the state blows up.
    """
    n = force.shape[0]
    h = dt / substeps
    y = state.copy()
    scratch = np.empty(N_DOOR)
    k1 = np.empty(4)
    k2 = np.empty(4)
    k3 = np.empty(4)
    k4 = np.empty(4)
    tmp = np.empty(4)
    handle_rates(y, force[0], pq, scratch, k1)
    out[0, 0], out[1, 0], out[2, 0], out[3, 0], out[4, 0] = y[0], y[1], k1[1], y[2], y[3]
    for k in range(n - 1):
        df = (force[k + 1] - force[k]) / substeps
        for s in range(substeps):
            f0 = force[k] + s * df
            handle_rates(y, f0, pq, scratch, k1)
            for i in range(4):
                tmp[i] = y[i] + 0.5 * h * k1[i]
            handle_rates(tmp, f0 + 0.5 * df, pq, scratch, k2)
            for i in range(4):
                tmp[i] = y[i] + 0.5 * h * k2[i]
            handle_rates(tmp, f0 + 0.5 * df, pq, scratch, k3)
            for i in range(4):
                tmp[i] = y[i] + h * k3[i]
            handle_rates(tmp, f0 + df, pq, scratch, k4)
            for i in range(4):
                y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        if not (
            math.isfinite(y[0])
            and math.isfinite(y[2])
            and abs(y[1]) < BLOWUP_SPEED
            and abs(y[3]) < BLOWUP_SPEED
        ):
            for j in range(k + 1, n):
                for c in range(5):
                    out[c, j] = np.nan
            for i in range(4):
                state[i] = np.nan
            return False
        handle_rates(y, force[k + 1], pq, scratch, k1)
        out[0, k + 1], out[1, k + 1], out[2, k + 1] = y[0], y[1], k1[1]
        out[3, k + 1], out[4, k + 1] = y[2], y[3]
    for i in range(4):
        state[i] = y[i]
    return True


# -- orchestration ----------------------------------------------------------------------
def load_truth_params(spec=None, overrides=None) -> ParamSet:
    """The truth's parameters: declared defaults, a mapping or a YAML file, then overrides."""
    return load_params(TABLE, spec, overrides)


def leaf_params(door_values: np.ndarray, handle_mass: float) -> np.ndarray:
    """The door's vector with the handle's mass taken out of the leaf (mass, centre, inertia).

    The handle is a point mass at the handle E = (L, 0) in the door's frame; joined
    rigidly to the returned leaf it gives back ``door_values``' body.
    """
    p = np.array(door_values, dtype=np.float64)
    if handle_mass == 0.0:
        return p
    i_m, i_gx, i_gy, i_iz = (DOOR_TABLE.index(n) for n in ("M", "G_x", "G_y", "I_z"))
    m, gx, gy, iz, length = p[i_m], p[i_gx], p[i_gy], p[i_iz], p[_L]
    leaf_m = m - handle_mass
    if leaf_m <= 0.0:
        raise UserError(
            f"truth: handle_mass = {handle_mass:g} kg is not smaller than the door's mass "
            f"M = {m:g} kg (the handle is part of M)"
        )
    leaf_gx = (m * gx - handle_mass * length) / leaf_m
    leaf_gy = m * gy / leaf_m
    inertia_o = iz + m * (gx * gx + gy * gy) - handle_mass * length * length
    leaf_iz = inertia_o - leaf_m * (leaf_gx * leaf_gx + leaf_gy * leaf_gy)
    if leaf_iz <= 0.0:
        raise UserError(
            f"truth: handle_mass = {handle_mass:g} kg at the handle holds more inertia than the "
            f"door has (I_z = {iz:g} kg m^2, M = {m:g} kg); make it smaller"
        )
    p[i_m], p[i_gx], p[i_gy], p[i_iz] = leaf_m, leaf_gx, leaf_gy, leaf_iz
    return p


class DoorTruth:
    """The rich truth of one door parameter set, as the rig simulates it.

    Parameters
    ----------
    model : Model
        The physical door (``door``); any other model is refused.
    params : ParamSet
        The door's parameters: what a fit of the door model is scored against.
    values : ParamSet, optional
        The truth's own parameters (:data:`TABLE`; default its declared defaults).
    method, substeps :
        Integration of the door without a handle (default the model's); the door with
        a handle is integrated by RK4 with :data:`HANDLE_SUBSTEPS` per sample.

    The state is ``(theta, dtheta, theta_h, dtheta_h)``; without a handle mass the
    handle is the door (``theta_h = theta``).
    """

    name = NAME

    def __init__(self, model, params, values: ParamSet | None = None, method=None, substeps=None):
        if tuple(model.params.names) != DOOR_TABLE.names:
            raise UserError(
                f"--truth {NAME} is built on the physical door: use --model door "
                f"(model {model.name!r} is not it)"
            )
        self.model = model
        self.params = params
        self.values = values if values is not None else load_truth_params()
        q = param_vector(self.values, TABLE)
        handle_mass = float(self.values["handle_mass"])
        if handle_mass == 0.0 and float(self.values["handle_play"]) > 0.0:
            raise UserError(
                "truth: handle_play needs a handle_mass > 0 (a massless handle transmits the "
                "hand's force at once, whatever its play); set both, or handle_play=0"
            )
        self.has_handle = handle_mass > 0.0
        door_values = param_vector(params, DOOR_TABLE)
        self.pq = np.ascontiguousarray(np.concatenate([leaf_params(door_values, handle_mass), q]))
        if self.has_handle:
            if method not in (None, "rk4"):
                raise UserError(
                    f"truth: the door with a handle (handle_mass > 0) is integrated by rk4, "
                    f"not {method!r}"
                )
            self.method, self.substeps = "rk4", int(substeps or HANDLE_SUBSTEPS)
        else:
            self.method = method or model.method
            if self.method not in METHODS:
                raise UserError(
                    f"unknown integration method {self.method!r}; choose from {', '.join(METHODS)}"
                )
            self.substeps = int(substeps or model.substeps)

    def state(self, theta: float, dtheta: float) -> np.ndarray:
        """A start state: the handle in the middle of its play, moving with the door."""
        return np.array([theta, dtheta, theta, dtheta], dtype=np.float64)

    def simulate(self, force, dt: float, state: np.ndarray):
        """Respond to a sampled hand force from ``state``.

        Returns ``(out, end_state, ok)``: ``out`` a dict of ``theta``, ``dtheta``,
        ``ddtheta`` (door) and ``theta_h``, ``dtheta_h`` (handle) at the samples.
        """
        force = np.ascontiguousarray(force, dtype=np.float64)
        n = force.size
        out = np.empty((5, n))
        if self.has_handle:
            end = np.array(state, dtype=np.float64)
            ok = integrate_handle(self.pq, force, float(dt), self.substeps, end, out)
        else:
            # the door's switching surfaces: the combined vector begins with the door's
            # parameters (the richer truth's own kinks are followed by the step control)
            ok = integrate(
                rigid_accel,
                door_switches,
                self.pq,
                force,
                float(dt),
                self.substeps,
                float(state[0]),
                float(state[1]),
                METHODS[self.method],
                DEFAULT_TOLERANCE,
                DOOR_SWITCHES,
                False,
                out[0],
                out[1],
                out[2],
            )
            out[3], out[4] = out[0], out[1]
            end = np.array([out[0, -1], out[1, -1], out[0, -1], out[1, -1]])
        names = ("theta", "dtheta", "ddtheta", "theta_h", "dtheta_h")
        return dict(zip(names, out)), end, bool(ok)

    def sensor_dynamics(self) -> dict[str, tuple[float, int]]:
        """Channel -> (bandwidth in Hz, low-pass order) of the sensors with dynamics."""
        return {
            ch: (float(self.values[name]), order)
            for ch, (name, order) in SENSOR_DYNAMICS.items()
            if float(self.values[name]) > 0.0
        }

    def record(self) -> dict:
        """What a trial stores about this truth (next to the door's parameters)."""
        return {
            "params": self.values.as_dict(),
            "units": {p.name: p.unit for p in TABLE},
            "params_source": self.values.source,
        }
