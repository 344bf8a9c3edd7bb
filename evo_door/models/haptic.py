"""The haptic model of the door: the feel as a handful of *sensations*.

This is the simplified, real-time model of the case study (seed chapter 4, spec
section "Haptic model"). Its parameters are what an operator tunes while a user
tries the door (opening effort, closing effort, smoothness, free play), not the
dimensions of a mechanism. It has two faces that share one parameter vector:

``accel(theta, dtheta, force, p)``
    the reduced 1-DOF dynamics ``I ddtheta = F_tan(theta, dtheta) + F_u`` used for
    simulation and fitting (eq. 5.7);
``device_force(x, y, z, vx, vy, vz, p, out)``
    the force field of eq. 4.52 in the coordinates of a 3-DOF haptic device: the end
    effector held on the door's circular path by spring-dampers, plus the same
    tangential law rotated into device axes. A servo loop (1-2.5 kHz) calls it.

Everything that shapes the feel is in one function, :func:`tangential_force`, to be
read top to bottom. Conventions (``docs/conventions.md``): ``theta`` 0 = fully open, pi/2 = closed;
``dtheta < 0`` is opening; a tangential force is positive toward closing; SI units.
The equations, and how they correct the seed's eqs. 4.39-4.47, are written out in
``docs/haptic-model.md``.

Size: under 700 lines: the one law and every compiled form the integrators, the
perceptual objective and the renderer take of it (its hold of one state and of many
rows, its switching functions and their prepared form, the device's force field)
belong beside the law, so that a change to it is made, and checked, in one place.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numba import njit, prange

from evo_door.models.base import Model
from evo_door.models.haptic_params import (  # noqa: F401 (re-exported)
    _DEG,
    CLOSED,
    DECLARATION,
    DEVICE_OFFSET_Y,
    DEVICE_OFFSET_Z,
    N_BALANCE,
    N_SECTIONS,
    PARAMS,
)
from evo_door.params import ParamTable, param_vector
from evo_door.sim.hold import HOLD_ROWS_SIGNATURE, HOLD_SIGNATURE, register_hold, register_hold_rows
from evo_door.sim.integrators import PREPARE_SIGNATURE, register_prepared
from evo_door.sim.located import SWITCHES_SIGNATURE

# Positions in the kernel vector, generated from the declaration (never literal).
INERTIA = PARAMS.index("inertia")
FRICTION_CLOSING = PARAMS.index("friction_closing")
FRICTION_OPENING = PARAMS.index("friction_opening")
FRICTION_SCALE_1 = PARAMS.index("friction_scale_1")
VISCOUS_DAMPING = PARAMS.index("viscous_damping")
BALANCE_1 = PARAMS.index("balance_1")
RETURN_STIFFNESS = PARAMS.index("return_stiffness")
RETURN_ANGLE = PARAMS.index("return_angle")
RETURN_ONSET = PARAMS.index("return_onset")
OPEN_FORCE = PARAMS.index("open_force")
CLOSE_FORCE = PARAMS.index("close_force")
LOOSE_ANGLE = PARAMS.index("loose_angle")
TRANSITION_ANGLE = PARAMS.index("transition_angle")
GASKET_STIFFNESS = PARAMS.index("gasket_stiffness")
OPEN_HOLD = PARAMS.index("open_hold")
CLOSE_HOLD = PARAMS.index("close_hold")
SEAT_FORCE = PARAMS.index("seat_force")
TRANSITION_DAMPING = PARAMS.index("transition_damping")
STOP_STIFFNESS = PARAMS.index("stop_stiffness")
STOP_DAMPING = PARAMS.index("stop_damping")
LATCH_STIFFNESS = PARAMS.index("latch_stiffness")
LATCH_DAMPING = PARAMS.index("latch_damping")
RADIUS = PARAMS.index("radius")
K_RADIAL = PARAMS.index("k_radial")
C_RADIAL = PARAMS.index("c_radial")
K_PLANE = PARAMS.index("k_plane")
C_PLANE = PARAMS.index("c_plane")
C_ENERGY = PARAMS.index("c_energy")
FRICTION_SLOPE = PARAMS.index("friction_slope")
FRICTION_SPEED_THRESHOLD = PARAMS.index("friction_speed_threshold")
WINDOW_SLOPE = PARAMS.index("window_slope")
LATCH_SHARPNESS = PARAMS.index("latch_sharpness")
LATCH_GATE_SLOPE = PARAMS.index("latch_gate_slope")

assert all(
    PARAMS.index(f"friction_scale_{k + 1}") == FRICTION_SCALE_1 + k for k in range(N_SECTIONS)
)
assert all(PARAMS.index(f"balance_{k + 1}") == BALANCE_1 + k for k in range(N_BALANCE))


# ---------------------------------------------------------------------------------
# Building blocks
# ---------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def activation(x, x0, slope):
    """S(x, x0, a) = (tanh(a (x - x0)) + 1) / 2 (eq. 4.36): ~0 below x0, ~1 above.

    Beyond |a (x - x0)| = 20 tanh is +-1 to double precision, so the branches return
    the exact value without a transcendental call (most switches are far away most of
    the time).
    """
    u = slope * (x - x0)
    if u > 20.0:
        return 1.0
    if u < -20.0:
        return 0.0
    # (tanh(u) + 1) / 2 = 1 / (1 + exp(-2 u)), the same to 3e-16 and twice as fast
    return 1.0 / (1.0 + math.exp(-2.0 * u))


@njit(cache=True, inline="always")
def release(x, sharpness):
    """Smooth end of a latch band: ~1 inside it (x > 0), ~0 beyond it (x < 0).

    ``x`` is the distance from the band's end, in rise widths (force / stiffness),
    positive inside. R(x) = S(x, -delta, n), edge slope n = latch_sharpness per rise
    width, centred delta = (ln 2n + 1) / 2n widths *beyond* the end: then a spring
    that reaches F at the band's end and goes on rising at the same slope beyond it,
    F (1 - x) R(x) near the end, peaks at exactly F (at x = -1/2n), where an edge
    centred on the end would cut the peak by (ln 2n + 1) / 2n.
    """
    u = sharpness * x
    if u > 25.0:  # n delta <= 4.3 for n <= 1000: S is exactly 1 or 0 out here
        return 1.0
    if u < -25.0:
        return 0.0
    return 1.0 / (1.0 + math.exp(-2.0 * u - math.log(2.0 * sharpness) - 1.0))


@njit(cache=True, inline="always")
def rise_and_hold(d, rise, hold):
    """Deflection the latch spring acts on (rad) at a deflection ``d`` into its band.

    ``d - min(max(d - rise, 0), hold)``: ``k`` times it rises with ``d`` to the band's
    force ``k rise``, **holds** that force over ``hold``, and rises again beyond the
    band's end (where the release edge R has let go; the rise past the end is what
    makes R's smooth peak exactly the force).
    """
    return d - min(max(d - rise, 0.0), hold)


@njit(cache=True)
def latch_angles(p):
    """The latch band limits (rad), derived from the sensations.

    Returns ``(theta_0, theta_1, theta_2, theta_3)``, going down from closed (pi/2):
    loose band [theta_0, pi/2], unlock band [theta_1, theta_0] (rise open_force /
    latch_stiffness, then open_hold), snap zone [theta_2, theta_1], lock band
    [theta_3, theta_2] (rise close_force / latch_stiffness, then close_hold).
    """
    k = p[LATCH_STIFFNESS]
    theta_0 = CLOSED - p[LOOSE_ANGLE]
    theta_1 = theta_0 - p[OPEN_FORCE] / k - p[OPEN_HOLD]
    theta_2 = theta_1 - p[TRANSITION_ANGLE]
    theta_3 = theta_2 - p[CLOSE_FORCE] / k - p[CLOSE_HOLD]
    return theta_0, theta_1, theta_2, theta_3


@njit(cache=True, inline="always")
def section_scale(theta, p):
    """A(theta): the per-section friction scale (eq. 4.48 / 5.8), smooth, in [0, 1].

    A = A_1 + sum_{k=2..8} (A_k - A_{k-1}) S(theta, theta_{k-1}), section boundaries
    theta_j = j pi/16. The first and last sections extend beyond [0, pi/2] (the
    telescoping sum never fades to zero at the ends); all A_k = 1 gives A = 1 exactly
    (and costs no transcendental call).
    """
    scale = p[FRICTION_SCALE_1]
    width = CLOSED / N_SECTIONS
    for k in range(1, N_SECTIONS):
        step = p[FRICTION_SCALE_1 + k] - p[FRICTION_SCALE_1 + k - 1]
        if step != 0.0:
            scale += step * activation(theta, k * width, p[WINDOW_SLOPE])
    return scale


@njit(cache=True, inline="always")
def balance(theta, p):
    """B(theta): the door's own push at rest (N, + toward closing), what weight and
    springs give a real door over its whole stroke.

    Linear between the nine values balance_1..balance_9 set at the section boundaries
    theta_j = j pi/16 (0 to pi/2), held at the end values beyond them. All zero
    (the default) is no force. Conservative: it depends on the angle alone, so it
    shifts the opening and the closing curve alike, where a friction moves them apart.
    """
    width = CLOSED / N_SECTIONS
    u = theta / width
    if u <= 0.0:
        return p[BALANCE_1]
    if u >= N_SECTIONS:
        return p[BALANCE_1 + N_SECTIONS]
    j = min(int(u), N_SECTIONS - 1)
    w = u - j
    return (1.0 - w) * p[BALANCE_1 + j] + w * p[BALANCE_1 + j + 1]


# ---------------------------------------------------------------------------------
# The tangential force law: the whole feel, top to bottom
# ---------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _scale_at(theta, p, scale):
    """``scale`` where given, else A(theta) of ``p`` (:func:`section_scale`): NaN asks
    for it (a constant NaN, inlined, costs nothing)."""
    return section_scale(theta, p) if scale != scale else scale


@njit(cache=True, inline="always")
def dry_friction(theta, dtheta, p, sign_law, scale):
    """The dry friction (N, + toward closing), asymmetric (eqs. 3.1, 4.44-4.48, corrected).

    With the seed's smooth law (``sign_law`` False)::

        sigma  = S(dtheta, dtheta_0, a)                    closing selector
        c      = c_open + (c_close - c_open) sigma         magnitude
        F_dry  = -A(theta) c tanh(a dtheta)

    At speed well above dtheta_0 the door feels friction_closing, below it
    friction_opening (the seed's eq. 4.47 selected them the other way round and eq.
    4.46 had tanh(a theta) for tanh(a dtheta)). With the sign law (its limit as
    a -> inf, what the renderer solves): ``F_dry = -A(theta) c sgn(dtheta)``, ``c``
    friction_closing above dtheta_0 and friction_opening below it, 0 at rest.
    ``scale``: A(theta) where the caller has it (:func:`hold_rows`), else NaN.
    """
    if sign_law:
        if dtheta == 0.0:
            return 0.0
        level = p[FRICTION_CLOSING] if dtheta > p[FRICTION_SPEED_THRESHOLD] else p[FRICTION_OPENING]
        if level == 0.0:
            return 0.0
        return -_scale_at(theta, p, scale) * level * (1.0 if dtheta > 0.0 else -1.0)
    a = p[FRICTION_SLOPE]
    forward = activation(dtheta, 0.0, a)  # tanh(a dtheta) = 2 forward - 1
    threshold = p[FRICTION_SPEED_THRESHOLD]
    sigma = forward if threshold == 0.0 else activation(dtheta, threshold, a)
    magnitude = p[FRICTION_OPENING] + (p[FRICTION_CLOSING] - p[FRICTION_OPENING]) * sigma
    if magnitude == 0.0:
        return 0.0
    return -_scale_at(theta, p, scale) * magnitude * (2.0 * forward - 1.0)


@njit(cache=True, inline="always")
def tangential_force_law(theta, dtheta, p, sign_law):
    """F_tan(theta, dtheta): force (N) the door exerts on the hand, + toward closing
    (:func:`scaled_force_law`, the dry friction's A(theta) computed there)."""
    return scaled_force_law(theta, dtheta, p, sign_law, math.nan)


@njit(cache=True, inline="always")
def scaled_force_law(theta, dtheta, p, sign_law, scale):
    """F_tan(theta, dtheta): force (N) the door exerts on the hand, + toward closing,
    with the dry friction's section scale A(theta) ``scale`` (NaN: computed here).

    ``sign_law`` picks the dry friction's law: its Coulomb limit
    ``-A(theta) c sgn(dtheta)`` (0 at rest: the integrators and the renderer solve the
    stick) or the seed's ``-A(theta) c tanh(a dtheta)`` (docs/haptic-model.md).

    Sum of the phases of seed section 4.3.3, with the behaviour its text describes
    (where its equations say otherwise: ``docs/conventions.md``). Every effect
    is switched off by a zero: frictions, viscous_damping, return_stiffness,
    open_force and close_force (both zero: no latch at all), open_hold, close_hold,
    the nine balance values, seat_force, gasket_stiffness, transition_damping, stop_stiffness.
    """
    # long: the sum of the seed's phases (section 4.3.3) in the order the text gives
    # them, each a few lines under its equation; one compiled function the kernels call
    # at every step, read best as the one sum it is
    f = 0.0

    # 1. Dry friction, asymmetric (eqs. 3.1, 4.44-4.48, corrected): dry_friction
    f = dry_friction(theta, dtheta, p, sign_law, scale)

    # 2. Viscous friction (eq. 4.42):  F_v = -c_v dtheta
    f -= p[VISCOUS_DAMPING] * dtheta

    # 2b. The balance: the door's own push at rest over the stroke (weight, springs),
    #     linear between its nine angles (not in the seed: docs/haptic-model.md)
    f += balance(theta, p)

    # 3. Return spring above its onset (eq. 4.43):
    #      F_ret = -k_ret (theta - theta_k) S(theta, theta_on)
    if p[RETURN_STIFFNESS] != 0.0:
        f -= (
            p[RETURN_STIFFNESS]
            * (theta - p[RETURN_ANGLE])
            * activation(theta, p[RETURN_ONSET], p[WINDOW_SLOPE])
        )

    # 4. Loose band [theta_0, pi/2] and beyond: the door seal pushes toward opening,
    #      F_g = -k_l (theta - theta_0) - min(F_seat, k (theta - theta_0)),  theta > theta_0
    #    (zero at theta_0, where the latch hook takes over). The seat F_seat, reached
    #    at the latch stiffness k (what the device renders), beats friction, so a
    #    latched door rests on its catch at theta_0, not anywhere in the free play:
    #    a pull meets the catch at once, with no run-up (only with a catch to press
    #    against, open_force > 0).
    theta_0 = CLOSED - p[LOOSE_ANGLE]
    if theta > theta_0:
        f -= p[GASKET_STIFFNESS] * (theta - theta_0)
        if p[OPEN_FORCE] > 0.0:
            f -= min(p[SEAT_FORCE], p[LATCH_STIFFNESS] * (theta - theta_0))

    # 5. The latch (eqs. 4.39-4.41, corrected), only if it has a force to give.
    #    Skipped below the lowest angle any latch term reaches: theta_0 minus
    #    (1.4 + 20 / n) latch lengths (written without divisions).
    open_force = p[OPEN_FORCE]
    close_force = p[CLOSE_FORCE]
    k = p[LATCH_STIFFNESS]
    n = p[LATCH_SHARPNESS]
    # k (theta_0 - theta_3)
    k_length = open_force + close_force + k * (p[TRANSITION_ANGLE] + p[OPEN_HOLD] + p[CLOSE_HOLD])
    if (open_force > 0.0 or close_force > 0.0) and (theta_0 - theta) * k * n < k_length * (
        1.4 * n + 20.0
    ):
        c = p[LATCH_DAMPING]
        w_1 = open_force / k  # unlock rise
        w_2 = close_force / k  # lock rise
        h_1 = p[OPEN_HOLD]
        h_2 = p[CLOSE_HOLD]
        theta_1 = theta_0 - w_1 - h_1
        theta_2 = theta_1 - p[TRANSITION_ANGLE]
        theta_3 = theta_2 - w_2 - h_2

        # 5a. Unlock band [theta_1, theta_0]: the hook, pushing toward closing; it
        #     rises from 0 at theta_0 to open_force over w_1, holds it over open_hold
        #     h_1, then lets go at theta_1:
        #       F_o = [k H(theta_0 - theta; w_1, h_1) - c dtheta] R((theta - theta_1) / w_1)
        #     (H: `rise_and_hold`; R: `release`; the smooth peak is exactly
        #     open_force). The hold is what makes it a threshold: a pull below
        #     open_force (1 - w_1 / 2 (w_1 + h_1)) cannot do the work the band asks,
        #     however brisk (docs/haptic-model.md). Active in both directions: it
        #     holds the latched door against the seal and pulls a closing door in.
        if open_force > 0.0 and theta < theta_0:
            spring = k * rise_and_hold(theta_0 - theta, w_1, h_1)
            f += (spring - c * dtheta) * release((theta - theta_1) / w_1, n)

        # 5b. Snap zone [theta_2, theta_1]: negative damping, the door does not stay
        #       F_t = +c_n dtheta [S(theta, theta_2) - S(theta, theta_1)],  slope n / width
        width = theta_1 - theta_2
        c_n = p[TRANSITION_DAMPING]
        if (
            c_n != 0.0
            and width > 0.0
            and (theta_2 - theta) * n < 20.0 * width
            and (theta - theta_1) * n < 20.0 * width
        ):
            slope = n / width
            f += (
                c_n
                * dtheta
                * (activation(theta, theta_2, slope) - activation(theta, theta_1, slope))
            )

        # 5c. Lock band [theta_3, theta_2]: the hook's ramp, pushing toward opening,
        #     from 0 at theta_3 up to close_force over w_2, held over close_hold h_2,
        #     then lets go at theta_2:
        #       F_c = -[k H(theta - theta_3; w_2, h_2) + c dtheta] R((theta_2 - theta) / w_2) G,
        #       G   = S(dtheta, -3 / a_g, a_g)   ~1 unless clearly opening,
        #     so an opening door, once unlocked, feels ~0 here (the seed gates this
        #     spring with the closing direction too).
        if close_force > 0.0 and theta > theta_3:
            r = release((theta_2 - theta) / w_2, n)
            if r > 0.0:
                a_g = p[LATCH_GATE_SLOPE]
                gate = activation(dtheta, -3.0 / a_g, a_g)
                spring = k * rise_and_hold(theta - theta_3, w_2, h_2)
                f -= (spring + c * dtheta) * r * gate

    # 6. End stops: stiff, damped, never pulling (closed wall at pi/2, open stop at 0).
    ks = p[STOP_STIFFNESS]
    if ks > 0.0:
        if theta > CLOSED:
            f += min(0.0, -ks * (theta - CLOSED) - p[STOP_DAMPING] * dtheta)
        elif theta < 0.0:
            f += max(0.0, -ks * theta - p[STOP_DAMPING] * dtheta)
    return f


@njit(cache=True, inline="always")
def tangential_force(theta, dtheta, p):
    """F_tan with the seed's tanh friction (:func:`tangential_force_law`): what the
    device force field of eq. 4.52 (:func:`device_force`) renders as it is."""
    return tangential_force_law(theta, dtheta, p, False)


@njit(cache=True)
def accel(theta, dtheta, force, p):
    """Reduced dynamics (eq. 5.7): ddtheta = (F_tan(theta, dtheta) + F_u) / I.

    ``theta`` (rad), ``dtheta`` (rad/s), ``force`` (N at the handle, + toward closing),
    ``p`` the kernel vector; returns rad/s^2. Dry friction is the sign law the
    renderer solves (:func:`tangential_force_law`): the integrators hold the door
    at rest while it can (``stick_slip``). With the seed's rendering set:

    >>> from evo_door.params import param_vector
    >>> p = param_vector(MODEL.load_params("seed_trial"), PARAMS)
    >>> accel(0.8, 0.0, 0.0, p)     # at rest mid-stroke, no hand: stays
    0.0
    >>> # opening at 0.5 rad/s: (1.0 N dry friction + 0.2 N s/rad x 0.5) / 1.2 kg m
    >>> round(accel(0.8, -0.5, 0.0, p), 4)
    0.9167
    """
    return (tangential_force_law(theta, dtheta, p, True) + force) / p[INERTIA]


@njit(cache=True)
def accel_tanh(theta, dtheta, force, p):
    """:func:`accel` with the seed's tanh dry friction (model ``haptic_tanh``)."""
    return (tangential_force_law(theta, dtheta, p, False) + force) / p[INERTIA]


@njit(cache=True, inline="always")
def _hold(theta, dtheta, p, sign_law, scale):
    """What two calls of the right-hand side give for the force that holds the door still
    (:mod:`evo_door.sim.hold`), its tangential force computed once (``scale``: the dry
    friction's A(theta) where the caller has it, else NaN)."""
    f = scaled_force_law(theta, dtheta, p, sign_law, scale)
    a0 = (f + 0.0) / p[INERTIA]
    a1 = (f + 1.0) / p[INERTIA]
    return -a0 / (a1 - a0)


@njit(HOLD_SIGNATURE, cache=True, nogil=True)
def hold(theta, dtheta, p):
    """Force (N at the handle) that holds the door still at ``(theta, dtheta)``: :func:`accel`'s."""
    return _hold(theta, dtheta, p, True, math.nan)


@njit(HOLD_SIGNATURE, cache=True, nogil=True)
def hold_tanh(theta, dtheta, p):
    """:func:`hold` of :func:`accel_tanh`."""
    return _hold(theta, dtheta, p, False, math.nan)


@njit(HOLD_ROWS_SIGNATURE, cache=True, parallel=True)
def hold_rows(P, theta, dtheta, out):
    """:func:`hold` of every row of ``P`` at every ``theta`` into ``out`` (rows, angles),
    across threads; registered with :func:`~evo_door.sim.hold.register_hold_rows`.

    The section scale's seven steps depend on the angle and ``window_slope`` alone:
    for rows of one slope (a population that fits the scales leaves it alone) they
    are computed once an angle, and each row's A(theta) is its sum of them, as
    :func:`section_scale` sums them (the same numbers, to the last bit). Returns
    False, with nothing written, for rows of slopes of their own.
    """
    slope = P[0, WINDOW_SLOPE]
    for r in range(1, P.shape[0]):
        if P[r, WINDOW_SLOPE] != slope:
            return False
    n = theta.shape[0]
    width = CLOSED / N_SECTIONS
    steps = np.empty((n, N_SECTIONS))
    for i in prange(n):
        for k in range(1, N_SECTIONS):
            steps[i, k] = activation(theta[i], k * width, slope)
    for j in prange(P.shape[0] * n):
        r = j // n
        i = j - r * n
        p = P[r]
        scale = p[FRICTION_SCALE_1]
        for k in range(1, N_SECTIONS):
            step = p[FRICTION_SCALE_1 + k] - p[FRICTION_SCALE_1 + k - 1]
            if step != 0.0:
                scale += step * steps[i, k]
        out[r, i] = _hold(theta[i], dtheta, p, True, scale)
    return True


register_hold(accel, hold)
register_hold(accel_tanh, hold_tanh)
register_hold_rows(accel, hold_rows)


#: How many switching functions :func:`switches` writes.
N_SWITCHES = 12


@njit(cache=True, nogil=True, inline="always")
def write_switches(theta, dtheta, p, g, theta_0, theta_1, theta_2, theta_3, seat, opens, closes):
    """The twelve values of :func:`switches` into ``g``, the latch's angles given (the
    bands' limits, the seat's width, where the unlock and the lock bands' rises end):
    what it and :func:`switches_prepared` share."""
    ks = p[STOP_STIFFNESS]
    g[0] = theta
    g[1] = -ks * theta - p[STOP_DAMPING] * dtheta if theta < 0.0 and ks > 0.0 else 1.0
    g[2] = theta - CLOSED
    g[3] = ks * (theta - CLOSED) + p[STOP_DAMPING] * dtheta if theta > CLOSED and ks > 0.0 else 1.0
    g[4] = theta - theta_0
    g[5] = theta - theta_0 - seat if p[OPEN_FORCE] > 0.0 else 1.0
    if p[OPEN_FORCE] > 0.0:
        g[6] = theta - opens
        g[7] = theta - theta_1
    else:
        g[6] = 1.0
        g[7] = 1.0
    if p[CLOSE_FORCE] > 0.0:
        g[8] = theta - theta_3
        g[9] = theta - closes
        g[10] = theta - theta_2
    else:
        g[8] = 1.0
        g[9] = 1.0
        g[10] = 1.0
    g[11] = dtheta - p[FRICTION_SPEED_THRESHOLD] if p[FRICTION_SPEED_THRESHOLD] != 0.0 else 1.0


@njit(cache=True, nogil=True, inline="always")
def latch_edges(p):
    """:func:`latch_angles` and the seat's width past theta_0, where the unlock band's
    rise ends and where the lock band's rise ends (rad): what :func:`switches` needs."""
    theta_0, theta_1, theta_2, theta_3 = latch_angles(p)
    k = p[LATCH_STIFFNESS]
    seat = p[SEAT_FORCE] / k
    opens = theta_0 - p[OPEN_FORCE] / k
    closes = theta_3 + p[CLOSE_FORCE] / k
    return theta_0, theta_1, theta_2, theta_3, seat, opens, closes


@njit(SWITCHES_SIGNATURE, cache=True, nogil=True)
def switches(theta, dtheta, force, p, g):
    """The haptic law's switching functions (where it has a kink or a jump), into ``g``.

    The stops and where their damper would pull (it never does), the loose band's
    start and the seat's rise, the latch bands' rise and hold ends
    (:func:`rise_and_hold`), and the speed at which the friction's level changes.
    The release edges and speed gates are smooth (the adaptive step follows them).
    A function that does not apply is 1.
    """
    theta_0, theta_1, theta_2, theta_3, seat, opens, closes = latch_edges(p)
    write_switches(theta, dtheta, p, g, theta_0, theta_1, theta_2, theta_3, seat, opens, closes)


#: The prepared vector of the kernels (:func:`~evo_door.sim.integrators.register_prepared`):
#: the parameters, then the seven angles of :func:`latch_edges` from ``EDGES`` on.
EDGES = len(PARAMS)
#: Length of a prepared vector.
PREPARED_SIZE = EDGES + 7


@njit(PREPARE_SIGNATURE, cache=True, nogil=True)
def prepare(p, q):
    """The prepared vector ``q`` of the parameters ``p``: ``p``, then the latch's angles
    (:func:`latch_edges`), which :func:`switches_prepared` reads. :func:`accel` reads
    only the parameters, so it runs on the prepared vector as it is."""
    for i in range(p.shape[0]):
        q[i] = p[i]
    edges = latch_edges(p)
    for i in range(7):
        q[EDGES + i] = edges[i]


@njit(SWITCHES_SIGNATURE, cache=True, nogil=True)
def switches_prepared(theta, dtheta, force, q, g):
    """:func:`switches` on a :func:`prepare`-d vector ``q``, to the last bit: the latch's
    angles read rather than worked out at every call (five divisions, most of its
    time; the integrators call it at the end of every step)."""
    e = EDGES
    write_switches(
        theta, dtheta, q, g, q[e], q[e + 1], q[e + 2], q[e + 3], q[e + 4], q[e + 5], q[e + 6]
    )


# the right-hand sides read only the parameters at the prepared vector's start: they are
# their own fast form, with the switching functions on the prepared vector
register_prepared(accel, accel, prepare, PREPARED_SIZE, switches=switches_prepared)
register_prepared(accel_tanh, accel_tanh, prepare, PREPARED_SIZE, switches=switches_prepared)


# ---------------------------------------------------------------------------------
# Device space (eq. 4.2-4.8, 4.20-4.35, 4.52)
# ---------------------------------------------------------------------------------
@njit(cache=True)
def device_force(x, y, z, vx, vy, vz, p, out):
    """Force (N) on the end effector, in device axes, written to ``out[0:3]``.

    ``(x, y, z)`` (m) and ``(vx, vy, vz)`` (m/s) are the device's internal end-effector
    position and velocity. Pure and allocation-free: a servo loop calls it.

    Model frame (eq. 4.2): y_m = y + 0.158, z_m = z + 0.138; theta = atan2(y_m, z_m),
    dtheta = (vy z_m - vz y_m) / r^2 (eq. 4.5). Unit vectors in (y, z):
    e_r = (sin th, cos th), e_th = (cos th, -sin th) (toward closing).

    F_x = -k_x x - c_x vx                                           (4.21)
    Q = R (sin th, cos th) is the nearest path point;                (4.26-4.31)
    F_(y,z) = -k_r (P - Q) - c_r [(dP/dt - dQ/dt) . e_r] e_r         (4.32-4.33)
            + c_e R dtheta e_th                                      (4.34-4.35)
            + F_tan(theta, dtheta) e_th                              (4.6-4.8, 4.50)

    The damper takes only the radial part of the velocity relative to Q, dr/dt (the
    seed's takes all of it): at speed the handle runs outside the circle, where the
    whole relative velocity holds (r - R) dtheta along e_th too, and damping that
    braked the door with a force rising with the cube of its speed, which no
    parameter of the model holds (docs/haptic-model.md, "Device space").
    """
    ym = y + DEVICE_OFFSET_Y
    zm = z + DEVICE_OFFSET_Z
    r2 = ym * ym + zm * zm
    if r2 > 1e-18:
        theta = math.atan2(ym, zm)
        dtheta = (vy * zm - vz * ym) / r2
        r = math.sqrt(r2)
        s = ym / r  # sin(theta)
        c = zm / r  # cos(theta)
    else:  # on the hinge axis: no direction, no rate
        theta = 0.0
        dtheta = 0.0
        s = 0.0
        c = 1.0
    radius = p[RADIUS]
    # constraint to the circle: offset from the path point Q, and the radial part of
    # the velocity relative to it (dQ/dt is along e_theta: the radial speed dr/dt)
    dy = ym - radius * s
    dz = zm - radius * c
    v_r = vy * s + vz * c
    ddy = v_r * s
    ddz = v_r * c
    # tangential behaviour, plus the energy compensation, along e_theta
    f_t = tangential_force(theta, dtheta, p) + p[C_ENERGY] * radius * dtheta
    out[0] = -p[K_PLANE] * x - p[C_PLANE] * vx
    out[1] = -p[K_RADIAL] * dy - p[C_RADIAL] * ddy + f_t * c
    out[2] = -p[K_RADIAL] * dz - p[C_RADIAL] * ddz - f_t * s


def device_force_vector(position, velocity, params, out=None) -> np.ndarray:
    """Python convenience around :func:`device_force`: the force as a 3-vector (N).

    ``position`` and ``velocity`` are (x, y, z) in device coordinates (m, m/s), as
    tuples, lists or arrays; ``params`` is the kernel vector (``param_vector(ps)``,
    fastest) or a :class:`~evo_door.params.ParamSet`. ``out`` (a float64 array of 3)
    is filled and returned when given, else a new array is.
    """
    if type(params) is not np.ndarray:
        params = param_vector(params, PARAMS)
    if out is None:
        out = np.empty(3)
    # numba dispatches fastest on Python floats: unpack arrays through tolist()
    x, y, z = position.tolist() if type(position) is np.ndarray else position
    vx, vy, vz = velocity.tolist() if type(velocity) is np.ndarray else velocity
    device_force(x, y, z, vx, vy, vz, params, out)
    return out


def device_mass(params) -> float:
    """Virtual mass (kg) a device must give the end effector: m = I / R (eq. 4.53)."""
    p = param_vector(params, PARAMS)
    return float(p[INERTIA] / p[RADIUS])


def on_path(theta, radius) -> tuple[float, float, float]:
    """Device coordinates (x, y, z) of the handle at door angle ``theta`` (rad)."""
    return (
        0.0,
        radius * math.sin(theta) - DEVICE_OFFSET_Y,
        radius * math.cos(theta) - DEVICE_OFFSET_Z,
    )


def latch_angles_of(params) -> dict[str, float]:
    """The latch band limits (rad) of a parameter set, by name."""
    names = ("theta_0", "theta_1", "theta_2", "theta_3")
    return dict(zip(names, (float(v) for v in latch_angles(param_vector(params, PARAMS)))))


#: Dormand-Prince 5(4), adaptive, steps of at most one 1024 Hz sample, the latch's
#: kinks and the stops located, dry friction sticking as the renderer renders it; see
#: docs/haptic-model.md "Integration".
MODEL = Model(
    name="haptic",
    title=DECLARATION.title,
    params=PARAMS,
    accel=accel,
    method="dopri5",
    substeps=1,
    theta0=CLOSED,
    notes=DECLARATION.notes,
    rig_kinds=("impulse", "unlock", "lock", "slow"),
    switches=switches,
    n_switches=N_SWITCHES,
    stick_slip=True,
)

#: The same model with the seed's literal tanh dry friction (eq. 3.1): smooth, so no
#: stick; its parameters and presets are the haptic model's. ROS2 (semi-implicit)
#: with 2 steps per sample stays stable for its steepest tanh.
MODEL_TANH = replace(
    MODEL,
    name="haptic_tanh",
    title=DECLARATION.title + " (seed's tanh friction)",
    params=ParamTable("haptic_tanh", PARAMS.params, reads=("haptic",)),
    accel=accel_tanh,
    method="semi_implicit",
    substeps=2,
    stick_slip=False,
)
