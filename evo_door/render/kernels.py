"""The servo loop's compiled kernels: one cycle's force and its log row.

:func:`compute_command_implicit` (the default) and :func:`compute_command` (the
model's own tanh friction) take the device's state and measured force and write the
force to command (N, device frame) and the cycle's log row (the columns of
:data:`~evo_door.render.columns.COLUMNS`). They are compiled with numba and allocate
nothing: :class:`~evo_door.render.loop.ServoLoop` calls one of them every cycle.
"""

from __future__ import annotations

import math

from numba import njit

from evo_door.models.haptic import (
    C_ENERGY,
    DEVICE_OFFSET_Y,
    DEVICE_OFFSET_Z,
    FRICTION_CLOSING,
    FRICTION_OPENING,
    FRICTION_SPEED_THRESHOLD,
    RADIUS,
    device_force,
    section_scale,
    tangential_force,
)
from evo_door.render.columns import COMMAND, DTHETA, FORCE, POSITION, THETA, USER_FORCE, VELOCITY
from evo_door.render.friction import implicit_coulomb
from evo_door.render.safety import NON_FINITE, limit_force


@njit(cache=True)
def compute_command(pos, vel, user, p, limit, out, row):
    """The force to command (N, device frame) into ``out``; the log row into ``row``.

    The haptic model's force as it is, dry friction included (its explicit tanh).

    Returns the fault code of :func:`~evo_door.render.safety.limit_force`; any
    non-finite input (state, measured force, parameters) gives a zero force and
    :data:`~evo_door.render.safety.NON_FINITE`.
    """
    finite = _finite_state(pos, vel, user)
    if finite:
        device_force(pos[0], pos[1], pos[2], vel[0], vel[1], vel[2], p, out)
        code = limit_force(out, limit)
    else:
        code = _no_force(out)
    _fill_row(pos, vel, user, out, finite, row)
    return code


#: Finite-difference steps of the local stiffness and damping along the tangent:
#: angle (rad) and angular speed (rad/s), well inside the latch's release edge
#: (band / latch_sharpness, about 5e-4 rad) and its speed gate (1 / latch_gate_slope).
_DTHETA_STEP = 1e-7
_OMEGA_STEP = 1e-6


@njit(cache=True)
def compute_command_implicit(pos, vel, user, p, p_free, mass, period, damping, limit, out, row):
    """:func:`compute_command` with the door's own law rendered implicitly.

    ``p`` is the parameter vector in force and ``p_free`` the same with both dry
    friction levels at zero: the model's force without its tanh friction. Along the
    door's tangent at the handle, ``e_t = (0, cos th, -sin th)`` (toward closing), the
    device's moving ``mass`` m (kg) takes one step of the loop ``period`` T (s) under
    the measured user force, its own ``damping`` (N s/m), the model's tangential force
    and the dry friction. Two things are solved over that step rather than taken
    from the state at its start:

    * **stiff springs and dampers** (latch bands, end stops, seal, snap zone): the
      model's tangential force is linearised about the state,
      ``f(x + T v', v') ~ f0 - K T v' - C (v' - v)`` with the local stiffness
      ``K = -df/dx`` (N/m, only its stiffening part) and damping ``C = -df/dv``
      (N s/m) by finite differences, and the new speed solves
      ``(m + T C + T^2 K) v' = (m + T C) v + T (F + f_fric)``: a backward-Euler step
      of the door, stable and dissipative at any stiffness, where the force of the
      state at the start of the step (explicit) is passive only while the device's
      damping exceeds ``K T / 2`` (Colgate-Schenkel);
    * **dry friction**, :func:`~evo_door.render.friction.implicit_coulomb` on that
      effective mass: the levels are ``A(theta) friction_closing`` against a step
      toward closing faster than ``friction_speed_threshold`` and
      ``A(theta) friction_opening`` otherwise, as the model selects them. It sticks
      (the handle stops this step) whenever the other forces stay below the level
      and never drives the handle through zero speed, whatever the level.

    The command along ``e_t`` is the model's force at the end of the step plus the
    friction; across it (the circle and the plane constraints) the model's force as
    it is. It assumes the device moves its mass m over T under the command, as an
    admittance device does (the loop passes the measured period as T).
    """
    finite = _finite_state(pos, vel, user)
    # a mass, period or damping that is not finite would spread NaN through the step;
    # the loop checks them (ServoLoop), this keeps the kernel safe on its own
    if finite and math.isfinite(mass) and math.isfinite(period) and math.isfinite(damping):
        device_force(pos[0], pos[1], pos[2], vel[0], vel[1], vel[2], p_free, out)
        ym = pos[1] + DEVICE_OFFSET_Y
        zm = pos[2] + DEVICE_OFFSET_Z
        r = math.sqrt(ym * ym + zm * zm)
        if r > 1e-9 and mass > 0.0 and period > 0.0:
            s = ym / r
            c = zm / r
            theta = math.atan2(ym, zm)
            v_t = vel[1] * c - vel[2] * s
            omega = v_t / r
            # local stiffness and damping of the tangential law (N/m, N s/m)
            f0 = _tangential(theta, omega, p_free)
            k = -(_tangential(theta + _DTHETA_STEP, omega, p_free) - f0) / _DTHETA_STEP / r
            cd = -(_tangential(theta, omega + _OMEGA_STEP, p_free) - f0) / _OMEGA_STEP / r
            k = max(k, 0.0)
            cd = max(cd, -0.5 * mass / period)  # keeps m + T C >= m / 2
            m_damped = mass + period * cd
            m_eff = m_damped + period * period * k
            v_start = m_damped * v_t / m_eff
            f_t = (user[1] + out[1]) * c - (user[2] + out[2]) * s - damping * v_t
            v_free = v_start + period * f_t / m_eff
            scale = section_scale(theta, p)
            opening = scale * p[FRICTION_OPENING]
            forward = opening
            if v_free > p[FRICTION_SPEED_THRESHOLD] * r:
                forward = scale * p[FRICTION_CLOSING]
            f = implicit_coulomb(v_start, f_t, m_eff, period, forward, opening)
            v_new = v_start + period * (f_t + f) / m_eff
            f += -k * period * v_new - cd * (v_new - v_t)
            out[1] += f * c
            out[2] -= f * s
        code = limit_force(out, limit)
    else:
        code = _no_force(out)
    _fill_row(pos, vel, user, out, finite, row)
    return code


@njit(cache=True)
def _tangential(theta, omega, p):
    """The model's force along e_theta (N): its tangential law and c_energy's push."""
    return tangential_force(theta, omega, p) + p[C_ENERGY] * p[RADIUS] * omega


@njit(cache=True)
def _no_force(out):
    """Zero force for a non-finite input; the fault code that says so."""
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    return NON_FINITE


@njit(cache=True)
def _finite_state(pos, vel, user):
    for i in range(3):
        if not (math.isfinite(pos[i]) and math.isfinite(vel[i]) and math.isfinite(user[i])):
            return False
    return True


@njit(cache=True)
def _fill_row(pos, vel, user, out, finite, row):
    """The log row of a cycle: state, measured and commanded force, door state."""
    for i in range(3):
        row[POSITION + i] = pos[i]
        row[VELOCITY + i] = vel[i]
        row[USER_FORCE + i] = user[i]
        row[COMMAND + i] = out[i]
    ym = pos[1] + DEVICE_OFFSET_Y
    zm = pos[2] + DEVICE_OFFSET_Z
    r2 = ym * ym + zm * zm
    if r2 > 1e-18 and finite:
        theta = math.atan2(ym, zm)
        row[THETA] = theta
        row[DTHETA] = (vel[1] * zm - vel[2] * ym) / r2
        # e_theta = (cos, -sin) in (y, z): toward closing
        row[FORCE] = user[1] * math.cos(theta) - user[2] * math.sin(theta)
    else:
        row[THETA] = math.nan if not finite else 0.0
        row[DTHETA] = math.nan if not finite else 0.0
        row[FORCE] = math.nan if not finite else 0.0
