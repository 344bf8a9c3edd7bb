"""The compiled cycle of a rendered mechanism: the device <-> handle map, the force on
the hand, the other states integrated over the cycle.

A state-vector model (a mechanism file, ``Model(rhs=...)``) is rendered through its
handle, one coordinate ``x[ih]`` with its speed ``x[iv]``. Each cycle
:func:`mechanism_command`:

1. reads the handle's coordinate and speed off the device (:func:`handle_of`): on a
   rotary handle the angle on the haptic model's circle, on a linear one the device's
   y axis;
2. sets them into the state vector and calls the model's ``rhs`` with no hand force:
   the force the mechanism puts on the hand is ``dx[iv] / gain`` (:func:`hand_force`),
   ``gain`` the handle's acceleration per newton of the hand (the rhs is affine in the
   force), so the handle's own mass is not in it: the device renders that (its
   moving mass is set to it);
3. adds the constraints that hold the device on the handle's path (stiff springs and
   dampers across it) and limits the force (:func:`~evo_door.render.safety.limit_force`);
4. advances the other states over the cycle with the handle's imposed: ``nsub``
   classic Runge-Kutta steps, the handle moving at the speed read
   (:func:`advance_others`).

Everything here is compiled and allocates nothing; the model's ``rhs`` is a numba
first-class function (:data:`~evo_door.sim.states.RHS_TYPE`), as
:mod:`evo_door.sim.state_steps` takes it. The kernels that call it have explicit
signatures over that type: compiled once for every mechanism, and numba's cache holds
no mechanism's function. Typed by the function each was first called with, they were
compiled again for each mechanism, and their cache index named every mechanism
rendered before, each of which a later process compiled again when it read that index:
a render started later the more mechanisms the machine had rendered.
"""

from __future__ import annotations

import math

from numba import njit, types

from evo_door.models.haptic import DEVICE_OFFSET_Y, DEVICE_OFFSET_Z
from evo_door.render.columns import COMMAND, DTHETA, FORCE, POSITION, THETA, USER_FORCE, VELOCITY
from evo_door.render.safety import NON_FINITE, limit_force
from evo_door.sim.states import RHS_TYPE

_vec = types.float64[::1]
_mat = types.float64[:, ::1]

#: entries of the geometry vector ``geo`` (:func:`geometry` in
#: :mod:`evo_door.render.mechanism` fills it)
G_LINEAR = 0  # 1.0: a linear handle on the device's y axis; 0.0: rotary, on the circle
G_RADIUS = 1  # m, the circle's radius (rotary)
G_CENTRE = 2  # the handle's coordinate at device y = 0 (linear, m)
G_K_ACROSS = 3  # N/m: off the circle (rotary) / along z (linear)
G_C_ACROSS = 4  # N s/m
G_K_PLANE = 5  # N/m: along x
G_C_PLANE = 6  # N s/m
G_GAIN = 7  # the handle's acceleration per newton of the hand ((m/s^2)/N or (rad/s^2)/N)
N_GEOMETRY = 8

#: rows of the work array: dx, the four Runge-Kutta rates, the stage state
N_WORK = 6


@njit(cache=True)
def handle_of(pos, vel, geo, out):
    """The handle's coordinate and speed (``out[0]``, ``out[1]``) and the unit vector
    toward closed in device axes (``out[2:5]``) for the device at ``pos`` (m) moving
    at ``vel`` (m/s)."""
    if geo[G_LINEAR] != 0.0:
        out[0] = pos[1] + geo[G_CENTRE]
        out[1] = vel[1]
        out[2] = 0.0
        out[3] = 1.0
        out[4] = 0.0
        return
    ym = pos[1] + DEVICE_OFFSET_Y
    zm = pos[2] + DEVICE_OFFSET_Z
    r2 = ym * ym + zm * zm
    if r2 > 1e-18:
        r = math.sqrt(r2)
        out[0] = math.atan2(ym, zm)
        out[1] = (vel[1] * zm - vel[2] * ym) / r2
        out[3] = zm / r  # e_theta = (cos th, -sin th) in (y, z): toward closed
        out[4] = -ym / r
    else:  # on the hinge axis: no direction, no rate
        out[0] = 0.0
        out[1] = 0.0
        out[3] = 1.0
        out[4] = 0.0
    out[2] = 0.0


@njit(types.float64(RHS_TYPE, _vec, _vec, types.int64, types.float64, _vec), cache=True)
def hand_force(rhs, x, p, iv, gain, dx):
    """The force (N, + toward closed) the mechanism in state ``x`` puts on the hand:
    the handle's acceleration with no hand force, ``dx[iv]``, over ``gain``."""
    rhs(x, 0.0, p, dx)
    return dx[iv] / gain


@njit(
    types.void(
        RHS_TYPE, _vec, _vec, types.int64, types.int64, types.float64, types.float64,
        types.float64, types.float64, types.int64, _mat,
    ),
    cache=True,
)  # fmt: skip
def advance_others(rhs, x, p, ih, iv, q, dq, force, period, nsub, work):
    """The states of ``x`` other than the handle's over ``period`` (s): ``nsub`` classic
    Runge-Kutta steps of ``rhs`` with the hand's ``force`` (N), the handle imposed at
    ``q + dq t``, speed ``dq``. ``x`` holds the handle at ``q``, ``dq`` on entry and at
    ``q + dq period``, ``dq`` on exit; ``nsub`` 0: nothing to do (no other states)."""
    if nsub <= 0:  # no other states
        return
    n = x.shape[0]
    h = period / nsub
    k1, k2, k3, k4, xt = work[1], work[2], work[3], work[4], work[5]
    for step in range(nsub):
        t0 = step * h
        rhs(x, force, p, k1)
        for i in range(n):
            xt[i] = x[i] + 0.5 * h * k1[i]
        xt[ih] = q + dq * (t0 + 0.5 * h)
        xt[iv] = dq
        rhs(xt, force, p, k2)
        for i in range(n):
            xt[i] = x[i] + 0.5 * h * k2[i]
        xt[ih] = q + dq * (t0 + 0.5 * h)
        xt[iv] = dq
        rhs(xt, force, p, k3)
        for i in range(n):
            xt[i] = x[i] + h * k3[i]
        xt[ih] = q + dq * (t0 + h)
        xt[iv] = dq
        rhs(xt, force, p, k4)
        for i in range(n):
            x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        x[ih] = q + dq * (t0 + h)
        x[iv] = dq


@njit(cache=True)
def constraint_force(pos, vel, geo, out):
    """The springs and dampers that hold the device on the handle's path (N, device
    axes) into ``out``: across the path ``-k (off) - c (speed off)``, the haptic
    model's circle constraint on a rotary handle (its radial damper on the radial
    speed only), the y axis's on a linear one."""
    out[0] = -geo[G_K_PLANE] * pos[0] - geo[G_C_PLANE] * vel[0]
    if geo[G_LINEAR] != 0.0:
        out[1] = 0.0
        out[2] = -geo[G_K_ACROSS] * pos[2] - geo[G_C_ACROSS] * vel[2]
        return
    ym = pos[1] + DEVICE_OFFSET_Y
    zm = pos[2] + DEVICE_OFFSET_Z
    r = math.sqrt(ym * ym + zm * zm)
    s, c = (ym / r, zm / r) if r > 1e-9 else (0.0, 1.0)
    radius = geo[G_RADIUS]
    v_r = vel[1] * s + vel[2] * c
    out[1] = -geo[G_K_ACROSS] * (ym - radius * s) - geo[G_C_ACROSS] * v_r * s
    out[2] = -geo[G_K_ACROSS] * (zm - radius * c) - geo[G_C_ACROSS] * v_r * c


@njit(
    types.int64(
        RHS_TYPE, _vec, _vec, _vec, _vec, _vec, _vec, types.int64, types.int64,
        types.float64, types.int64, types.float64, _vec, _mat, _vec, _vec,
    ),
    cache=True,
)  # fmt: skip
def mechanism_command(rhs, pos, vel, user, x, p, geo, ih, iv, period, nsub, limit, hs, work,
                      out, row):  # fmt: skip
    """One cycle (the module docstring): the force to command (N, device axes) into
    ``out``, the log row into ``row`` (theta, dtheta: the handle's coordinate and
    speed; force: the user's force toward closed), ``x`` advanced over ``period``.

    ``hs`` (5 floats) receives :func:`handle_of`'s answer; ``work`` is (N_WORK, n).
    Returns :func:`~evo_door.render.safety.limit_force`'s code; a non-finite reading,
    state or force gives zero force and :data:`~evo_door.render.safety.NON_FINITE`
    (the other states are then left as they were).
    """
    finite = True
    for i in range(3):
        if not (math.isfinite(pos[i]) and math.isfinite(vel[i]) and math.isfinite(user[i])):
            finite = False
    f_user = math.nan
    if finite:
        handle_of(pos, vel, geo, hs)
        q, dq = hs[0], hs[1]
        f_user = user[0] * hs[2] + user[1] * hs[3] + user[2] * hs[4]
        x[ih] = q
        x[iv] = dq
        f_t = hand_force(rhs, x, p, iv, geo[G_GAIN], work[0])
        constraint_force(pos, vel, geo, out)
        for i in range(3):
            out[i] += f_t * hs[2 + i]
        code = limit_force(out, limit)
        if code != NON_FINITE:
            advance_others(rhs, x, p, ih, iv, q, dq, f_user, period, nsub, work)
    else:
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0
        code = NON_FINITE
    for i in range(3):
        row[POSITION + i] = pos[i]
        row[VELOCITY + i] = vel[i]
        row[USER_FORCE + i] = user[i]
        row[COMMAND + i] = out[i]
    row[THETA] = hs[0] if finite else math.nan
    row[DTHETA] = hs[1] if finite else math.nan
    row[FORCE] = f_user
    return code
