"""Compiled runs of an FMU over one trial: no Python between the steps.

``run_me`` integrates a model-exchange FMU with the classical fourth-order Runge-Kutta
method at a fixed step (``substeps`` steps per sample period), the force going linearly
from one sample to the next, as the workbench's own integrators do
(:mod:`evo_door.sim.integrators`). Each stage sets the time, the states and the input
and asks the FMU for the derivatives; after each step it reports the completed step and
reads the event indicators. Where an indicator changes sign, the crossing is located
within the step (:func:`locate`: the Illinois method on the step length, each trial a
fresh RK4 step from the same start, as :mod:`evo_door.sim.located` does for the
workbench's own switching surfaces, to :data:`LOCATE_TOL` of the sample period); the
step is cut just past it and the event handled there (event mode, discrete-state updates
until the FMU is done, continuous-time mode, states read back), and the step's rest
follows. Where the FMU asks for an event when a step is completed, the event is handled
at the end of that step. A time event (the next event time the FMU gave at
initialisation or at its last event) ends a shorter step at its very time, as the
standard asks, and the step's rest follows.

``run_cs`` steps a co-simulation FMU from one sample to the next (``fmi2DoStep`` /
``fmi3DoStep``), the force held at the sample's value over the step.

Both write the output channels at every sample into ``out`` (one row per sample, one
column per output variable, in the FMU's units) and return a status: :data:`OK`, or why
the run stopped (:data:`FMU_ERROR`, :data:`NOT_FINITE`, :data:`TERMINATED`); the rows
after a stop are NaN.

The FMI version is read from the types of the function tuple
(:func:`evo_door.models.fmu.calls.api`), so one kernel serves FMI 2 and 3.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.core import types
from numba.extending import overload

from evo_door.models.fmu.calls import (
    COMPLETED_STEP,
    DISCRETE_STATES,
    DO_STEP,
    ENTER_CONTINUOUS_MODE,
    ENTER_EVENT_MODE,
    GET_DERIVATIVES,
    GET_EVENT_INDICATORS,
    GET_REAL,
    GET_STATES,
    SET_REAL,
    SET_STATES,
    SET_TIME,
)

OK = 0
FMU_ERROR = 1
NOT_FINITE = 2
TERMINATED = 3
#: statuses fmiOK and fmiWarning: the call did what was asked
_GOOD = 1
#: what :func:`rk4_step` returns for a state that is not finite (no FMI status)
_NOT_FINITE_STEP = -1
#: at most this many discrete-state updates per event (an FMU that never settles)
MAX_EVENT_ITERATIONS = 100


@njit(cache=True, inline="always")
def at(array, offset):
    """The address of byte ``offset`` of ``array`` (a C pointer argument)."""
    return np.uintp(array.ctypes.data) + np.uintp(offset)


# -- the calls whose arguments differ between FMI 2 and FMI 3 ---------------------------
def _version(api) -> int:
    return 3 if api.types[SET_REAL].nargs == 5 else 2


def set_reals(api, comp, vr, values):
    """``fmi2SetReal`` / ``fmi3SetFloat64`` of ``values`` at value references ``vr``."""


def get_reals(api, comp, vr, values):
    """``fmi2GetReal`` / ``fmi3GetFloat64`` into ``values``."""


def completed_step(api, comp, flags):
    """Report a completed integrator step; True when the FMU asks for event mode."""


def do_step(api, comp, t, h, flags):
    """One communication step of a co-simulation FMU; its status."""


def update_discrete(api, comp, flags, times):
    """One discrete-state update in event mode: its status; ``flags[2]`` says another
    is needed, ``flags[3]`` terminate, ``flags[5]`` the states changed, ``flags[6]`` a
    next time event is set, at ``times[0]``."""


def _reals_call(index: int):
    """The overload of :func:`set_reals` / :func:`get_reals`: the C function at
    ``index`` of the tuple, with FMI 3's extra count of values."""

    def typer(api, comp, vr, values):
        if _version(api) == 3:
            return lambda api, comp, vr, values: api[index](
                comp, at(vr, 0), vr.size, at(values, 0), values.size
            )
        return lambda api, comp, vr, values: api[index](comp, at(vr, 0), vr.size, at(values, 0))

    return typer


overload(set_reals)(_reals_call(SET_REAL))
overload(get_reals)(_reals_call(GET_REAL))


@overload(completed_step)
def _completed_step(api, comp, flags):
    no_prior = types.uint8 if _version(api) == 3 else types.int32

    def impl(api, comp, flags):
        flags[0] = 0
        flags[1] = 0
        status = api[COMPLETED_STEP](comp, no_prior(1), at(flags, 0), at(flags, 4))
        return status, flags[0] != 0, flags[1] != 0

    return impl


@overload(do_step)
def _do_step(api, comp, t, h, flags):
    if _version(api) == 3:

        def impl3(api, comp, t, h, flags):
            flags[:] = 0
            return api[DO_STEP](
                comp, t, h, np.uint8(1), at(flags, 0), at(flags, 4), at(flags, 8), at(flags, 16)
            )

        return impl3
    return lambda api, comp, t, h, flags: api[DO_STEP](comp, t, h, np.int32(1))


@overload(update_discrete)
def _update_discrete(api, comp, flags, times):
    if _version(api) == 3:

        def impl3(api, comp, flags, times):
            flags[:] = 0
            return api[DISCRETE_STATES](
                comp,
                at(flags, 8),
                at(flags, 12),
                at(flags, 16),
                at(flags, 20),
                at(flags, 24),
                at(times, 0),
            )

        return impl3

    def impl2(api, comp, flags, times):
        # fmi2EventInfo: five fmi2Boolean (int), then the next event time (double,
        # at byte 24): laid over flags[2:7] and flags[8:10]
        flags[:] = 0
        status = api[DISCRETE_STATES](comp, at(flags, 8))
        times[0] = flags[8:10].view(np.float64)[0]
        return status

    return impl2


# -- events ------------------------------------------------------------------------------
@njit(cache=True)
def handle_event(api, comp, x, nx, flags, times):
    """Event mode at the current time: update the discrete states until the FMU is done,
    back to continuous time, read the states (they may have been reset). Returns a
    status of this module; ``times[1]`` is the next time event (inf if none)."""
    if api[ENTER_EVENT_MODE](comp) > _GOOD:
        return FMU_ERROR
    times[1] = math.inf
    for _ in range(MAX_EVENT_ITERATIONS):
        if update_discrete(api, comp, flags, times) > _GOOD:
            return FMU_ERROR
        if flags[3] != 0:
            return TERMINATED
        # the last update's word on the next time event holds (as at initialisation)
        times[1] = times[0] if flags[6] != 0 else math.inf
        if flags[2] == 0:
            break
    else:
        return FMU_ERROR
    if api[ENTER_CONTINUOUS_MODE](comp) > _GOOD:
        return FMU_ERROR
    if nx > 0 and api[GET_STATES](comp, at(x, 0), nx) > _GOOD:
        return FMU_ERROR
    return OK


# -- state events: located within the step -------------------------------------------------
#: width of a located crossing's bracket, as a fraction of the sample period
LOCATE_TOL = 1e-10
#: most Illinois iterations of one location
LOCATE_ITER = 100
#: crossings located in one step before the rest of it is handled at its end (a chatter)
MAX_LOCATED = 64


@njit(cache=True, inline="always")
def _copy(dst, src):
    """``dst[:] = src`` as a loop: a slice assignment of an array compiles numba's
    shape-mismatch error and its message formatting, some 2 s of the first compile.
    The twin of :func:`evo_door.sim.state_steps.copy_into`, kept here: the process of
    ``evo-door compile`` that compiles these runners imports nothing of
    ``evo_door.sim``, which the other process compiles (tests/test_kernel_cache.py)."""
    for i in range(dst.shape[0]):
        dst[i] = src[i]


@njit(cache=True, inline="always")
def crossed(a, b):
    """An event indicator's sign changed from ``a`` to ``b`` (0 counts as negative)."""
    return (a > 0.0) != (b > 0.0)


@njit(cache=True)
def first_crossing(z0, z1, skip):
    """The indicator that changed sign between ``z0`` and ``z1`` with the earliest
    linear estimate of its time (``skip`` left out), -1 if none."""
    best, best_u = -1, 2.0
    for i in range(z0.size):
        if i != skip and crossed(z0[i], z1[i]):
            u = z0[i] / (z0[i] - z1[i]) if z0[i] != z1[i] else 0.0
            if u < best_u:
                best, best_u = i, u
    return best


@njit(cache=True)
def locate(api, comp, ts, hh, x0, x, force, dforce, vr_in, u, k1, k2, k3, k4, xs, z0, z1, c, tol):
    """The step from ``(ts, x0)`` to just past the first sign change of the event
    indicators inside the step of length ``hh`` (which changed ``z0`` to ``z1``, ``c``
    first by the linear estimate): the Illinois method on the step length, each trial
    a fresh RK4 step from the same start, to a bracket of ``tol`` s; another indicator
    that changed sign before the bracket's far end takes its place. Returns ``(length,
    status)``: ``x`` holds the state at the far end (the indicator crossed, by at most
    the bracket), ``k1`` its derivatives, ``z1`` its indicators."""
    lo, hi = 0.0, hh
    v_lo, v_hi = z0[c], z1[c]
    for _ in range(z0.size + 1):
        last = 0  # the bracket's end that moved last (Illinois)
        for _ in range(LOCATE_ITER):
            if hi - lo <= tol:
                break
            s = (lo * v_hi - hi * v_lo) / (v_hi - v_lo) if v_hi != v_lo else 0.5 * (lo + hi)
            if not (lo < s < hi):
                s = 0.5 * (lo + hi)
            _copy(x, x0)
            st = derivatives(api, comp, ts, x, force, vr_in, u, k1)
            if st <= _GOOD:
                st = rk4_step(api, comp, ts, s, ts + s, x, force, dforce * (s / hh), vr_in, u,
                              k1, k2, k3, k4, xs)  # fmt: skip
            if st == _NOT_FINITE_STEP or st > _GOOD:
                return s, st
            if api[GET_EVENT_INDICATORS](comp, at(z1, 0), z1.size) > _GOOD:
                return s, FMU_ERROR
            v = z1[c]
            if crossed(v_lo, v):
                hi, v_hi = s, v
                if last == 1:
                    v_lo *= 0.5
                last = 1
            else:
                lo, v_lo = s, v
                if last == -1:
                    v_hi *= 0.5
                last = -1
        # the step to the bracket's far end: the state the event is handled at
        _copy(x, x0)
        st = derivatives(api, comp, ts, x, force, vr_in, u, k1)
        if st <= _GOOD:
            st = rk4_step(api, comp, ts, hi, ts + hi, x, force, dforce * (hi / hh), vr_in, u,
                          k1, k2, k3, k4, xs)  # fmt: skip
        if st == _NOT_FINITE_STEP or st > _GOOD:
            return hi, st
        if api[GET_EVENT_INDICATORS](comp, at(z1, 0), z1.size) > _GOOD:
            return hi, FMU_ERROR
        earlier = first_crossing(z0, z1, c)
        if earlier < 0 or hi <= tol:
            break
        # another indicator changed sign within the kept step: it may come first
        c, lo = earlier, 0.0
        v_lo, v_hi = z0[c], z1[c]
    return hi, OK


# -- model exchange ----------------------------------------------------------------------
@njit(cache=True)
def derivatives(api, comp, t, x, force, vr_in, u, dx):
    """``dx = f(t, x, force)`` of the FMU; its status (> 1: failed)."""
    s = api[SET_TIME](comp, t)
    if s <= _GOOD:
        s = max(s, api[SET_STATES](comp, at(x, 0), x.size))
    if s <= _GOOD and vr_in.size:
        u[0] = force
        s = max(s, set_reals(api, comp, vr_in, u))
    if s <= _GOOD:
        s = max(s, api[GET_DERIVATIVES](comp, at(dx, 0), dx.size))
    return s


@njit(cache=True)
def read_outputs(api, comp, t, x, force, vr_in, u, vr_out, row):
    """The outputs at ``(t, x, force)`` into ``row``; the status."""
    s = api[SET_TIME](comp, t)
    if s <= _GOOD and x.size:
        s = max(s, api[SET_STATES](comp, at(x, 0), x.size))
    if s <= _GOOD and vr_in.size:
        u[0] = force
        s = max(s, set_reals(api, comp, vr_in, u))
    if s <= _GOOD:
        s = max(s, get_reals(api, comp, vr_out, row))
    return s


@njit(cache=True, inline="always")
def _stage(xs, x, c, k):
    """``xs[:] = x + c * k`` as a loop."""
    for i in range(x.shape[0]):
        xs[i] = x[i] + c * k[i]


@njit(cache=True)
def rk4_step(api, comp, t, h, t_end, x, force, dforce, vr_in, u, k1, k2, k3, k4, xs):
    """One classical RK4 step of ``x`` from ``t`` to ``t_end = t + h`` (given apart, so
    that a step ending at a time event ends at its time to the bit), the force going
    linearly from ``force`` to ``force + dforce``. ``k1`` holds f at the start (the
    caller evaluates it, or has it from the step before); on return it holds f at the
    end (the next step's first stage). The FMU's worst status, or ``_NOT_FINITE_STEP``."""
    # the other three stages, stopping at the first the FMU refuses
    _stage(xs, x, 0.5 * h, k1)
    st = derivatives(api, comp, t + 0.5 * h, xs, force + 0.5 * dforce, vr_in, u, k2)
    if st <= _GOOD:
        _stage(xs, x, 0.5 * h, k2)
        st = derivatives(api, comp, t + 0.5 * h, xs, force + 0.5 * dforce, vr_in, u, k3)
    if st <= _GOOD:
        _stage(xs, x, h, k3)
        st = derivatives(api, comp, t_end, xs, force + dforce, vr_in, u, k4)
    if st > _GOOD:
        return st
    x += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    for i in range(x.size):
        if not math.isfinite(x[i]):
            return _NOT_FINITE_STEP
    # the state at the end of the step: the FMU holds it for the step's completion and
    # its event indicators, and its derivatives are the next step's k1
    return derivatives(api, comp, t_end, x, force + dforce, vr_in, u, k1)


@njit(cache=True)
def run_me(api, comp, x, n_events, next_event, force, t0, dt, substeps, vr_in, vr_out, out):
    """Integrate a model-exchange FMU over the samples of ``force`` (see the module
    docstring); ``x`` holds the initial states (after initialisation) and is advanced;
    ``next_event`` is the time event the initialisation set (inf if none)."""
    # long: one compiled loop over the samples, their steps and the pieces an event cuts
    # a step into, sharing the work arrays and the FMU's event state
    n, nx = force.size, x.size
    out[:] = np.nan
    u = np.zeros(1)
    k1, k2, k3, k4, xs = np.empty(nx), np.empty(nx), np.empty(nx), np.empty(nx), np.empty(nx)
    z0, z1 = np.empty(n_events), np.empty(n_events)
    x0 = np.empty(nx)  # a step's start, which the location of an event steps from again
    tol = LOCATE_TOL * dt
    flags = np.zeros(10, dtype=np.int32)
    times = np.array([math.inf, math.inf])
    if n_events and api[GET_EVENT_INDICATORS](comp, at(z0, 0), n_events) > _GOOD:
        return FMU_ERROR
    h = dt / substeps
    fresh = False  # k1 already holds f at the step's start (the last step's end)
    for k in range(n):
        t = t0 + k * dt
        if read_outputs(api, comp, t, x, force[k], vr_in, u, vr_out, out[k]) > _GOOD:
            return FMU_ERROR
        for j in range(out.shape[1]):
            if not math.isfinite(out[k, j]):
                out[k:] = np.nan
                return NOT_FINITE
        if k == n - 1:
            break
        f0, df = force[k], (force[k + 1] - force[k]) / substeps
        for s in range(substeps):
            ts, fs, end = t + s * h, f0 + s * df, t + s * h + h
            hs, dfs = h, df
            located = 0
            while True:
                # a time event inside the step ends a shorter step at its time (the
                # standard: integrate at most until the next event time), the rest of
                # the step follows it
                split = ts < next_event < end
                te = next_event if split else end
                hh = te - ts if split else hs
                dff = dfs * (hh / hs) if split else dfs
                _copy(x0, x)
                st = OK if fresh else derivatives(api, comp, ts, x, fs, vr_in, u, k1)
                if st <= _GOOD:
                    st = rk4_step(api, comp, ts, hh, te, x, fs, dff, vr_in, u, k1, k2, k3, k4, xs)
                fresh = True
                # a state event inside the step: the step is cut just past it (its
                # completion is reported only for the step kept)
                c = -1
                if n_events and st <= _GOOD and st != _NOT_FINITE_STEP:
                    if api[GET_EVENT_INDICATORS](comp, at(z1, 0), n_events) > _GOOD:
                        return FMU_ERROR
                    if located < MAX_LOCATED:
                        c = first_crossing(z0, z1, -1)
                if c >= 0 and hh > tol:
                    located += 1
                    cut, st = locate(api, comp, ts, hh, x0, x, fs, dff, vr_in, u,
                                     k1, k2, k3, k4, xs, z0, z1, c, tol)  # fmt: skip
                    if cut < hh:
                        split, te, dff, hh = True, ts + cut, dff * (cut / hh), cut
                if st == _NOT_FINITE_STEP or st > _GOOD:
                    out[k + 1 :] = np.nan
                    return NOT_FINITE if st == _NOT_FINITE_STEP else FMU_ERROR
                # no call after one that failed: the step is reported only when done
                status, enter, terminate = completed_step(api, comp, flags)
                if status > _GOOD:
                    out[k + 1 :] = np.nan
                    return FMU_ERROR
                if terminate:
                    out[k + 1 :] = np.nan
                    return TERMINATED
                changed = False
                for i in range(n_events):
                    if crossed(z0[i], z1[i]):
                        changed = True
                if enter or changed or te >= next_event:
                    r = handle_event(api, comp, x, nx, flags, times)
                    if r != OK:
                        out[k + 1 :] = np.nan
                        return r
                    next_event = times[1]
                    fresh = False  # the states or the law may have changed
                    if n_events:
                        api[GET_EVENT_INDICATORS](comp, at(z1, 0), n_events)
                _copy(z0, z1)
                if not split:
                    break
                ts, fs, hs, dfs = te, fs + dff, end - te, dfs - dff
    return OK


@njit(cache=True)
def hold_me(api, comp, x, angle, speed, t, theta, dtheta, vr_in, out):
    """The input (the FMU's force, in its unit) that holds the speed state still at each
    ``(theta[i], dtheta[i])`` (the FMU's units), written to ``out[i]``: the derivative
    of the speed state at the inputs 0 and 1, ``a0`` and ``a1``, and ``-a0 / (a1 - a0)``
    (the derivative is affine in the force). ``x`` holds the states, ``angle`` and
    ``speed`` their positions. The FMU's worst status (> 1: failed, ``out`` NaN on)."""
    u = np.zeros(1)
    dx = np.empty(x.size)
    out[:] = np.nan
    for i in range(theta.size):
        x[angle] = theta[i]
        x[speed] = dtheta[i]
        s = derivatives(api, comp, t, x, 0.0, vr_in, u, dx)
        if s > _GOOD:
            return s
        a0 = dx[speed]
        s = derivatives(api, comp, t, x, 1.0, vr_in, u, dx)
        if s > _GOOD:
            return s
        out[i] = -a0 / (dx[speed] - a0)
    return OK


# -- co-simulation -----------------------------------------------------------------------
@njit(cache=True)
def run_cs(api, comp, force, t0, dt, vr_in, vr_out, out):
    """Step a co-simulation FMU over the samples of ``force`` (module docstring)."""
    n = force.size
    out[:] = np.nan
    u = np.zeros(1)
    flags = np.zeros(10, dtype=np.int32)
    for k in range(n):
        t = t0 + k * dt
        u[0] = force[k]
        if vr_in.size and set_reals(api, comp, vr_in, u) > _GOOD:
            return FMU_ERROR
        if get_reals(api, comp, vr_out, out[k]) > _GOOD:
            out[k] = np.nan
            return FMU_ERROR
        for j in range(out.shape[1]):
            if not math.isfinite(out[k, j]):
                out[k:] = np.nan
                return NOT_FINITE
        if k == n - 1:
            break
        if do_step(api, comp, t, dt, flags) > _GOOD:
            return FMU_ERROR
        if flags[1] != 0:
            return TERMINATED
    return OK
