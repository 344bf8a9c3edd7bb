"""Dry friction and stiff springs that a servo loop can render without ringing.

The haptic model writes dry friction as ``F = -F_c tanh(a v)`` (eq. 3.1). Near rest
that is a damper of ``F_c a`` (N s/m), and a virtual mass ``m`` updated explicitly
at period ``T`` rings once the damper's one-step velocity change overshoots:

    v_{n+1} = v_n (1 - T F_c a / m)     unstable once  F_c > 2 m v_s / T,  v_s = 1 / a

(with a one-cycle delay between reading the velocity and applying the force,
``v_{n+1} = v_n - k v_{n-1}``, ``k = T F_c / (m v_s)``, the bound halves to
``m v_s / T``). The instability does not blow up: ``tanh`` saturates, and the mass
settles on a period-2 cycle ``+-v_s u`` with ``2 u = k tanh(u)``, which has a
non-zero root exactly when ``k > 2``: a buzz at half the loop rate.

:func:`implicit_coulomb_step` renders Coulomb friction as a *set-valued* law solved
implicitly over the step (Kikuuwe et al., "Proxy-based sliding mode control" /
implicit Coulomb friction, derived here from scratch):

    m (v_{n+1} - v_n) / T = F + f,     f in -F_c Sgn(v_{n+1})

``F`` are all the other forces on the mass this step (the user's hand, springs).
Write ``v* = v_n + T F / m`` for the velocity the mass would reach without friction.
Then ``v_{n+1} = v* + T f / m`` and two cases exhaust ``Sgn``:

* **stick**, ``v_{n+1} = 0``: needs ``f = -m v* / T`` with ``|f| <= F_c``, i.e.
  ``|m v* / T| <= F_c``. From rest (``v_n = 0``) this is ``|F| <= F_c``: the
  friction cancels the other forces exactly and the mass does not move at all;
* **slide**, ``v_{n+1} != 0`` with the sign of ``v*``: ``f = -F_c sign(v*)`` and
  ``v_{n+1} = v* - T F_c sign(v*) / m`` keeps the sign of ``v*`` exactly when
  ``|m v* / T| > F_c`` (the complement of the stick case).

Both cases are one formula, ``f = -clip(m v* / T, -F_c, F_c)``: a saturated damper
whose gain ``m / T`` is exactly the gain that brings the mass to rest in one step, so
it can never overshoot through zero, whatever ``F_c``. Asymmetric levels
(``friction_closing`` forward, ``friction_opening`` backward) clip to
``[-f_forward, f_backward]``; the same two cases hold.

Stiff springs (the latch) have the analogous explicit bound: for the symplectic
update (``v`` first, then ``x`` with the new ``v``) of ``m x'' = -k x - c x'`` the
step is stable iff ``k T^2 / m + 2 c T / m < 4`` (Jury test on the 2x2 step matrix,
trace ``2 - kT^2/m - cT/m``, determinant ``1 - cT/m``); backward Euler
(:func:`simulate_spring` with ``implicit=True``) is stable for every ``k, c >= 0``.

Units are linear device units (m, m/s, N, kg). The haptic model's angular
parameters map as ``m = inertia / radius``, ``v_s = radius / friction_slope`` and
``k = latch_stiffness / radius`` (N/m), ``c = latch_damping / radius`` (N s/m).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from evo_door.errors import UserError

#: ``law`` codes of :func:`simulate_friction`.
LAW_IMPLICIT = 0
LAW_TANH = 1

#: The HapticMaster's servo rate (Hz), the default loop rate of the renderer.
DEFAULT_RATE = 2500.0


# ---------------------------------------------------------------------------------
# Friction laws (compiled, allocation-free, called once per servo cycle)
# ---------------------------------------------------------------------------------
@njit(cache=True)
def implicit_coulomb(velocity, force, mass, period, f_forward, f_backward):
    """Implicit Coulomb friction (N) on a virtual mass for the coming step.

    ``velocity`` (m/s) is the mass's velocity now, ``force`` (N) the sum of the other
    forces over the step, ``mass`` (kg), ``period`` (s); ``f_forward`` (N) opposes
    motion in +v, ``f_backward`` (N) motion in -v. Returns
    ``-clip(m v* / T, -f_forward, f_backward)`` with ``v* = velocity + T force / m``
    (module docstring for the derivation). Use it where something else integrates
    the mass (an admittance device with this ``mass`` and ``period``).
    """
    f_stick = -mass * (velocity + period * force / mass) / period
    if f_stick < -f_forward:
        return -f_forward
    if f_stick > f_backward:
        return f_backward
    return f_stick


@njit(cache=True)
def implicit_coulomb_step(velocity, force, mass, period, f_forward, f_backward):
    """One implicit velocity update with Coulomb friction: ``(v_next, friction)``.

    Same law as :func:`implicit_coulomb`, but the stick case returns a velocity of
    exactly 0.0 (not ``v* - v*`` after rounding), so a held mass is bit-still.
    """
    v_free = velocity + period * force / mass
    f_stick = -mass * v_free / period
    if f_stick < -f_forward:
        return v_free - period * f_forward / mass, -f_forward
    if f_stick > f_backward:
        return v_free + period * f_backward / mass, f_backward
    return 0.0, f_stick


@njit(cache=True)
def implicit_coulomb3(velocity, force, mass, period, f_c, out):
    """Isotropic implicit Coulomb friction on a 3-DOF point mass, into ``out`` (N).

    The vector form of :func:`implicit_coulomb`: with ``v* = velocity + T force / m``
    (3-vectors, m/s and N) the friction is ``-m v* / T`` (the mass stops this step)
    when ``|m v* / T| <= f_c``, else ``-f_c v* / |v*|`` (slides along ``v*``, slowed,
    never reversed). For a host loop on an admittance device of mass ``mass`` whose
    command is held over ``period``: ``force`` = measured user force + the host's
    other forces, and the host commands those plus ``out``.
    """
    n2 = 0.0
    for i in range(3):
        out[i] = -mass * (velocity[i] + period * force[i] / mass) / period
        n2 += out[i] * out[i]
    if n2 > f_c * f_c:
        scale = f_c / math.sqrt(n2)
        for i in range(3):
            out[i] *= scale


@njit(cache=True)
def tanh_friction(velocity, f_c, slope):
    """The haptic model's smooth dry friction, ``-f_c tanh(slope v)`` (N), explicit."""
    return -f_c * math.tanh(slope * velocity)


# ---------------------------------------------------------------------------------
# Virtual-mass simulations (the servo loop's update, compiled)
# ---------------------------------------------------------------------------------
@njit(cache=True)
def simulate_friction(user_force, mass, period, f_c, slope, law, v0, delay):
    """A virtual mass under a user force and dry friction, updated every ``period``.

    ``user_force`` (N, one value per step), ``mass`` (kg), ``period`` (s), friction
    level ``f_c`` (N, both directions), ``slope`` (s/m, tanh law only), ``law``
    (:data:`LAW_IMPLICIT` or :data:`LAW_TANH`), initial velocity ``v0`` (m/s),
    ``delay`` (0 or 1 steps between the velocity the tanh law reads and the step it
    acts on; the implicit law always solves on the current step).

    Explicit symplectic update, as a servo loop does it:
    ``v_{n+1} = v_n + T (F_u + f_n) / m``, ``x_{n+1} = x_n + T v_{n+1}``.
    Returns ``(x, v, f)``: position (m) and velocity (m/s), ``n + 1`` samples from
    ``x_0 = 0, v_0``; friction force (N), ``n`` samples.
    """
    n = user_force.shape[0]
    x = np.zeros(n + 1)
    v = np.zeros(n + 1)
    f = np.zeros(n)
    v[0] = v0
    for i in range(n):
        if law == LAW_IMPLICIT:
            v[i + 1], f[i] = implicit_coulomb_step(v[i], user_force[i], mass, period, f_c, f_c)
        else:
            seen = v[i - 1] if (delay > 0 and i > 0) else v[i]
            f[i] = tanh_friction(seen, f_c, slope)
            v[i + 1] = v[i] + period * (user_force[i] + f[i]) / mass
        x[i + 1] = x[i] + period * v[i + 1]
    return x, v, f


@njit(cache=True)
def simulate_spring(n, mass, period, stiffness, damping, x0, implicit):
    """Free vibration of a mass on a spring-damper (the latch), ``n`` steps.

    Explicit (``implicit=False``): symplectic Euler with the force of the current
    state, stable iff ``k T^2 / m + 2 c T / m < 4``. Implicit (``True``): backward
    Euler, spring and damper evaluated at the new state (a 2x2 solve written out),
    stable for all ``k, c >= 0``. Returns ``(x, v)``, ``n + 1`` samples from
    ``(x0, 0)``; units m, m/s, kg, s, N/m, N s/m.
    """
    x = np.zeros(n + 1)
    v = np.zeros(n + 1)
    x[0] = x0
    h = period / mass
    for i in range(n):
        if implicit:
            # v' = v + h (-k x' - c v'),  x' = x + T v'  =>  v' (1 + h c + h k T) = v - h k x
            v[i + 1] = (v[i] - h * stiffness * x[i]) / (1.0 + h * damping + h * stiffness * period)
        else:
            v[i + 1] = v[i] + h * (-stiffness * x[i] - damping * v[i])
        x[i + 1] = x[i] + period * v[i + 1]
    return x, v


# ---------------------------------------------------------------------------------
# Bounds and helpers (plain Python)
# ---------------------------------------------------------------------------------
def tanh_stability_limit(mass, velocity_scale, period, delay=0) -> float:
    """Largest tanh friction level (N) an explicit update keeps stable at rest.

    ``2 m v_s / T`` without delay, ``m v_s / T`` with a one-step delay; ``mass`` (kg),
    ``velocity_scale`` ``v_s = 1 / slope`` (m/s), ``period`` (s).
    """
    if mass <= 0 or velocity_scale <= 0 or period <= 0:
        raise UserError("mass, velocity scale and period must be positive")
    if delay not in (0, 1):
        raise UserError(f"delay must be 0 or 1 step, got {delay!r}")
    return (2.0 if delay == 0 else 1.0) * mass * velocity_scale / period


def spring_stability_limit(mass, period, damping=0.0) -> float:
    """Largest spring stiffness (N/m) the explicit symplectic update keeps stable.

    ``k < 4 m / T^2 - 2 c / T`` for ``mass`` (kg), ``period`` (s), ``damping`` c (N s/m).
    """
    if mass <= 0 or period <= 0 or damping < 0:
        raise UserError("mass and period must be positive and damping not negative")
    return 4.0 * mass / period**2 - 2.0 * damping / period


def limit_cycle_amplitude(k) -> float:
    """Amplitude ``u`` (in units of v_s) of the explicit tanh law's period-2 cycle.

    The positive root of ``2 u = k tanh(u)``, ``k = T F_c / (m v_s)``; 0 for
    ``k <= 2`` (no cycle: the rest state is stable). Solved by bisection.
    """
    if k <= 2.0:
        return 0.0
    lo, hi = 1e-12, 0.5 * k + 1.0  # g(lo) > 0 > g(hi) for g(u) = k tanh(u) - 2u
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if k * math.tanh(mid) - 2.0 * mid > 0.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def device_friction_terms(params) -> dict[str, float]:
    """The haptic set's friction in linear device units.

    ``params`` is a haptic ParamSet or kernel vector. Returns ``mass`` (kg, inertia /
    radius), ``velocity_scale`` (m/s, radius / friction_slope; inf for slope 0),
    ``latch_stiffness`` (N/m) and ``latch_damping`` (N s/m).
    """
    from evo_door.models import haptic
    from evo_door.params import param_vector

    p = param_vector(params, haptic.PARAMS)
    radius = float(p[haptic.RADIUS])
    slope = float(p[haptic.FRICTION_SLOPE])
    return {
        "mass": float(p[haptic.INERTIA]) / radius,
        "velocity_scale": radius / slope if slope > 0 else math.inf,
        "latch_stiffness": float(p[haptic.LATCH_STIFFNESS]) / radius,
        "latch_damping": float(p[haptic.LATCH_DAMPING]) / radius,
    }


def force_profile(segments, period) -> np.ndarray:
    """Piecewise-constant user force (N per step) from ``[(force N, duration s), ...]``."""
    if period <= 0:
        raise UserError(f"period must be positive, got {period!r} s")
    parts = []
    for force, duration in segments:
        if duration < 0:
            raise UserError(f"a profile segment lasts {duration!r} s; durations must be >= 0")
        parts.append(np.full(int(round(duration / period)), float(force)))
    return np.concatenate(parts) if parts else np.zeros(0)


def sign_changes(velocity, eps=0.0) -> int:
    """Number of sign reversals of ``velocity`` (samples with ``|v| <= eps`` skipped)."""
    v = np.asarray(velocity, dtype=float)
    s = np.sign(v[np.abs(v) > eps])
    return int(np.count_nonzero(s[1:] != s[:-1]))
