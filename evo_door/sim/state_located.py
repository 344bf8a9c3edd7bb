"""One sample period of the state-vector integrators with the switching surfaces and
the contacts located within the steps (compiled): :func:`period`.

:func:`evo_door.sim.located.advance_located`'s algorithm on a state vector (its module
docstring tells it; :mod:`evo_door.sim.states` gives the contract): after every step
the signs of the switching values are compared with those at its start, a crossing is
located by the Illinois method on the step length, the step short of it kept and the
state moved across by a tiny Euler step; a surface crossed more than ``MAX_EVENTS``
times in a period, or grazed, is stepped over for the rest of it.

The contacts (stick-slip friction, one speed state each) add one switching value
each (:func:`~evo_door.sim.state_steps.surfaces`): a sliding contact's speed, whose
zero is located and where the contact comes to rest (its speed exactly 0.0); a stuck
contact's ``min(-forward, backward)``, its speed's rates at ``+-CREEP``, which turns
negative when the other forces beat its friction (the break-away). While every rate
is 0 with the stuck contacts held (a one-body door at rest), the break-away instant is
solved exactly, the rhs being affine in the force and the force linear in time; while
other states move (a carriage on its damper), the break-away is located like any
surface.

Like the steps, every function here is compiled without numba's runtime
(``_nrt=False``: :mod:`evo_door.sim.state_steps` tells why) and allocates nothing.
"""

from __future__ import annotations

import math

from evo_door.sim.located import (
    CREEP,
    DOPRI5,
    LOCATE_ITER,
    LOCATE_TOL,
    MAX_EVENTS,
    MAX_REJECTS,
    SEMI_IMPLICIT,
    next_length,
)
from evo_door.sim.state_steps import (
    A1,
    DX,
    K7,
    X1,
    XE,
    XLO,
    XT,
    R,
    Y,
    copy_into,
    jacobian,
    no_runtime,
    plain_period,
    set_modes,
    side_rate,
    stage_rate,
    surfaces,
    trial_step,
)


@no_runtime(inline="always")
def crossed(a, b):
    """True when ``a`` and ``b`` lie on two sides of zero (0 counts as positive)."""
    return (a < 0.0) != (b < 0.0)


@no_runtime(inline="always")
def first_crossing(g0, g1, n, active):
    """Index of the active crossing with the smallest linear estimate of its time, -1
    if none (the model's surfaces first on a tie, as the one-coordinate form)."""
    best = -1
    best_u = 2.0
    for i in range(n):
        if active[i] != 0.0 and crossed(g0[i], g1[i]):
            u = g0[i] / (g0[i] - g1[i])
            if u < best_u:
                best, best_u = i, u
    return best


@no_runtime(inline="always")
def release(rhs, p, x, force, contacts, y, r):
    """Case 1 of a period's loop for each contact at rest: slip it (``x[k] = +-CREEP``)
    where the other forces beat its friction. Returns (contacts at rest, still stuck)."""
    at_rest = 0
    stuck = 0
    for j in range(contacts.shape[0]):
        k = contacts[j]
        if x[k] != 0.0:
            continue
        at_rest += 1
        if side_rate(rhs, p, x, force, k, 1.0, y, r) > 0.0:
            x[k] = CREEP
        elif side_rate(rhs, p, x, force, k, -1.0, y, r) < 0.0:
            x[k] = -CREEP
        else:
            stuck += 1
    return at_rest, stuck


@no_runtime(inline="always")
def frozen_until(rhs, p, x, force, f1, t, dt, contacts, modes, W):
    """When nothing moves while the stuck contacts hold (every rate 0 at ``force`` and
    at the period's end force ``f1``: the rhs is affine in the force, so 0 between
    too), the time of the period the first of them breaks away (``dt``: none does),
    solved exactly as the one-coordinate form does; -1 when something moves."""
    dx, y, r = W[DX], W[Y], W[R]
    for f in (force, f1):
        stage_rate(rhs, p, x, f, contacts, modes, dx, y, r)
        for i in range(x.shape[0]):
            if dx[i] != 0.0:
                return -1.0
    free = dt
    for j in range(contacts.shape[0]):
        if modes[j] != 0:
            continue
        k = contacts[j]
        forward = side_rate(rhs, p, x, force, k, 1.0, y, r)
        backward = side_rate(rhs, p, x, force, k, -1.0, y, r)
        forward_end = side_rate(rhs, p, x, f1, k, 1.0, y, r)
        backward_end = side_rate(rhs, p, x, f1, k, -1.0, y, r)
        if forward_end > 0.0:
            free = min(free, t + (dt - t) * (-forward) / (forward_end - forward))
        if backward_end < 0.0:
            free = min(free, t + (dt - t) * (-backward) / (backward_end - backward))
    return free


@no_runtime(inline="always")
def euler_across(rhs, switches, p, x, t, f0, slope, dt, width, c, n_sw, contacts, modes, G, W):
    """Case 4: move ``x`` across surface ``c`` by an Euler step of the bracket's
    ``width`` (widened up to 4^11 times until it is across), a sliding contact whose
    speed changes sign on the way left at rest. Returns the new time."""
    gx, dx, xe, y, r = G[2], W[DX], W[XE], W[Y], W[R]
    before = G[0][c]
    n = x.shape[0]
    for _ in range(12):
        force = f0 + slope * t
        stage_rate(rhs, p, x, force, contacts, modes, dx, y, r)
        for i in range(n):
            xe[i] = x[i] + width * dx[i]
        surfaces(rhs, switches, p, xe, force + slope * width, n_sw, contacts, modes, gx, y, r)
        if crossed(gx[c], before) or width > 1e-6 * dt:
            for j in range(contacts.shape[0]):
                k = contacts[j]
                if crossed(xe[k], x[k]) and x[k] != 0.0:
                    xe[k] = 0.0
            copy_into(x, xe, x.shape[0])
            t += width
            break
        width *= 4.0
    return t


@no_runtime(inline="always")
def all_finite(x):
    """True when every entry of ``x`` is finite."""
    for v in x:
        if not math.isfinite(v):
            return False
    return True


@no_runtime(inline="always")
def located_period(
    rhs, switches, p, x, f0, f1, a_start, dt, substeps, method, tol, n_sw, contacts, W, G, JM,
    piv, modes, h0,
):  # fmt: skip
    """Move ``x`` over one sample period ``dt`` (force linear from ``f0`` to ``f1``),
    the model's ``n_sw`` surfaces and the contacts' located within the steps
    (:func:`evo_door.sim.located.advance_located` on a state vector). ``a_start`` is
    the rate at the start (:func:`~evo_door.sim.state_steps.sample_rate`'s): the first
    step's first stage where no contact is at rest (the same rhs call, so the same
    numbers as computing it again, one call less a period). The first step is ``h0``
    long; returns the next period's, as :func:`~evo_door.sim.located.advance_located`
    does."""
    # long: advance_located's one loop over the period's steps, its four cases read
    # top to bottom (contacts at rest; the step; a crossing located; the move across
    # it), sharing the period's clock, step length and scratch rows
    n_g = n_sw + contacts.shape[0]
    g0, g1, gx, active = G[0], G[1], G[2], G[3]
    a1, x1, xt, xlo, y, r = W[A1], W[X1], W[XT], W[XLO], W[Y], W[R]
    slope = (f1 - f0) / dt
    h_max = dt / substeps
    h = min(h0, h_max)
    h_next = -1.0  # the length after the period's first step (advance_located's)
    t = 0.0
    for i in range(n_g):
        active[i] = 1.0
    events = 0
    rejects = 0
    copy_into(a1, a_start, a1.shape[0])  # unless a contact is at rest: then case 1 computes it anew
    fresh = True  # a1 holds the rate at the current state
    if method == SEMI_IMPLICIT:
        jacobian(rhs, p, x, f0, JM[0], W[DX], y, r)
    set_modes(x, contacts, modes)
    surfaces(rhs, switches, p, x, f0, n_sw, contacts, modes, g0, y, r)
    while dt - t > LOCATE_TOL * dt:
        force = f0 + slope * t
        # 1. contacts at rest: each slips or sticks; when all that moves is held, the
        # break-away instant is solved exactly
        if contacts.shape[0] > 0:
            at_rest, stuck = release(rhs, p, x, force, contacts, y, r)
            if at_rest > 0:
                fresh = False
                set_modes(x, contacts, modes)
                if stuck > 0:
                    free = frozen_until(rhs, p, x, force, f1, t, dt, contacts, modes, W)
                    if free >= dt:
                        return h_next if h_next > 0.0 else h_max
                    if free >= 0.0:
                        t = max(free, t + LOCATE_TOL * dt)
                        continue
                surfaces(rhs, switches, p, x, force, n_sw, contacts, modes, g0, y, r)
        # 2. the step (sliding contacts' friction held on their sides, stuck ones held)
        set_modes(x, contacts, modes)
        h_want = h
        h = min(max(h, LOCATE_TOL * dt), dt - t)  # never a step of nothing
        if not fresh:
            stage_rate(rhs, p, x, force, contacts, modes, a1, y, r)
        fresh = False
        err = trial_step(
            rhs, p, x, a1, t, h, f0, slope, method, tol, contacts, modes, JM, piv, W, x1
        )
        coarse = not (err <= 1.0) and rejects < MAX_REJECTS and h > LOCATE_TOL * dt
        surfaces(rhs, switches, p, x1, f0 + slope * (t + h), n_sw, contacts, modes, g1, y, r)
        c = -1
        if events < MAX_EVENTS and all_finite(x1):
            c = first_crossing(g0, g1, n_g, active)
        if coarse:
            shorter = h * (max(0.2, 0.9 * err**-0.2) if math.isfinite(err) else 0.2)
            if c >= 0 and g0[c] / (g0[c] - g1[c]) * h <= shorter:
                shorter = h  # the crossing lies within the accurate length: locate now
            if shorter < h:
                rejects += 1
                h = shorter
                fresh = True  # the same start: a1 stands
                continue
        if c < 0:
            copy_into(x, x1, x.shape[0])
            from_start = t == 0.0
            t += h
            copy_into(g0, g1, n_g)
            if method == DOPRI5:
                h = next_length(h, h_want, err, h_max)
                if h_next < 0.0:  # the period's first step: from its start, or after an event
                    h_next = h if from_start else h_max
                copy_into(a1, W[K7], a1.shape[0])  # first same as last
                fresh = True
            continue
        # 3. a crossing: the longest step short of it, by Illinois on the length
        events += 1
        lo, hi = 0.0, h
        err_lo = 0.0
        while True:
            v_lo = g0[c]
            v_hi = g1[c]
            last = 0  # the bracket's end that moved last (Illinois)
            copy_into(xlo, x, xlo.shape[0])
            err_lo = 0.0
            for _ in range(LOCATE_ITER):
                if hi - lo <= LOCATE_TOL * dt:
                    break
                s = (lo * v_hi - hi * v_lo) / (v_hi - v_lo)
                if v_hi == 0.0:  # hi lies on the surface: try just short of it
                    s = hi - 0.5 * LOCATE_TOL * dt
                if not (lo < s < hi):
                    s = 0.5 * (lo + hi)
                err_s = trial_step(
                    rhs, p, x, a1, t, s, f0, slope, method, tol, contacts, modes, JM, piv, W, xt
                )
                surfaces(
                    rhs, switches, p, xt, f0 + slope * (t + s), n_sw, contacts, modes, gx, y, r
                )
                v = gx[c]
                if crossed(v, v_lo):
                    hi, v_hi = s, v
                    if last == 1:
                        v_lo *= 0.5
                    last = 1
                else:
                    lo, v_lo, err_lo = s, v, err_s
                    copy_into(xlo, xt, xlo.shape[0])
                    if last == -1:
                        v_hi *= 0.5
                    last = -1
            # a surface crossed before the located one takes its place
            surfaces(rhs, switches, p, xlo, f0 + slope * (t + lo), n_sw, contacts, modes, gx, y, r)
            earlier = first_crossing(g0, gx, n_g, active)
            if earlier < 0 or lo <= 0.0:
                break
            c = earlier
            hi = lo
            lo = 0.0
            copy_into(x1, xlo, x1.shape[0])
            copy_into(g1, gx, n_g)
        if not (err_lo <= 1.0) and rejects < MAX_REJECTS:
            # the step to the surface is too coarse: a shorter one, and locate again
            rejects += 1
            h = lo * (max(0.2, 0.9 * err_lo**-0.2) if math.isfinite(err_lo) else 0.2)
            continue
        # 4. keep the step to the surface, then cross it
        copy_into(x, xlo, x.shape[0])
        t += lo
        if c >= n_sw and modes[c - n_sw] != 0:
            x[contacts[c - n_sw]] = 0.0  # a contact's speed at zero: stick or slip (case 1)
            set_modes(x, contacts, modes)
            surfaces(rhs, switches, p, x, f0 + slope * t, n_sw, contacts, modes, g0, y, r)
            continue
        before = g0[c]
        width = max(hi - lo, LOCATE_TOL * dt)
        t = euler_across(
            rhs, switches, p, x, t, f0, slope, dt, width, c, n_sw, contacts, modes, G, W
        )
        surfaces(rhs, switches, p, x, f0 + slope * min(t, dt), n_sw, contacts, modes, g0, y, r)
        if not crossed(g0[c], before):
            active[c] = 0.0  # grazes it: step over it for the rest of the period
    return h_next if h_next > 0.0 else h_max


# Not inlined: compiled once, for the first-class function types of the kernels that
# call it (integrate_states, the objective kernel), like advance_located.
@no_runtime()
def period(
    rhs, switches, p, x, f0, f1, a_start, dt, substeps, method, tol, n_sw, contacts,
    W, G, JM, piv, modes, h0,
):  # fmt: skip
    """Move the state ``x`` (in place) over one sample period: :func:`plain_period`,
    or where the model has switching surfaces or contacts, or the method is ``dopri5``,
    :func:`located_period`. ``a_start`` is the rate at the period's start; ``h0`` the
    length of ``dopri5``'s first step. Returns the next period's ``h0``."""
    if method != DOPRI5 and n_sw == 0 and contacts.shape[0] == 0:
        plain_period(rhs, p, x, f0, f1, a_start, dt, substeps, method, contacts, modes, JM, piv, W)
        return dt / substeps
    return located_period(
        rhs, switches, p, x, f0, f1, a_start, dt, substeps, method, tol, n_sw, contacts,
        W, G, JM, piv, modes, h0,
    )  # fmt: skip
