"""Fixed-step integrators for one-degree-of-freedom models, compiled with numba.

Every model of the workbench is a door angle ``theta`` driven by a sampled user force:
its compiled *acceleration function* ``accel(theta, dtheta, force, p) -> ddtheta``
(``p`` the flat float64 parameter vector of the model's declaration) is handed to the
kernels below as a first-class argument, so each kernel compiles once per model and
is cached on disk (``cache=True``).

The acceleration function travels as a numba first-class function (``ACCEL_TYPE``):
the integrators are compiled once, with explicit signatures, cached on disk, and call
the model through a pointer. (A model passed as an ordinary dispatcher argument would
make numba recompile every kernel in every new process.)

The input force is sampled at a fixed period ``dt`` (1/1024 s for the seed's trials);
each sample period is split into ``substeps`` equal steps, with the force interpolated
linearly between samples. Outputs are reported at the sample instants. ``dopri5``
(:mod:`evo_door.sim.located`) chooses its steps within each period, and at one substep
takes one step over several periods where the force is linear over them
(:func:`try_span`, :mod:`evo_door.sim.spans`).

Two schemes:

``rk4`` (:data:`~evo_door.sim_settings.RK4`)
    Classic fourth-order Runge-Kutta. Accurate and cheap while the step stays inside
    the stability region of the stiffest spring or the steepest tanh friction.
``semi_implicit`` (:data:`~evo_door.sim_settings.SEMI_IMPLICIT`)
    The two-stage linearly implicit Rosenbrock method ROS2 (Verwer et al. 1999,
    gamma = 1 + 1/sqrt(2)), second order and L-stable. Its 2x2 Jacobian is taken by
    forward differences of ``accel`` once per sample period, keeping only its
    stabilising (non-positive) entries; being a W-method it keeps order 2 with that
    frozen, approximate Jacobian. Stable for the stiff latch springs and steep
    tanh frictions at any step.

A model may also have a faster form of its right-hand side that reads, besides the
parameters, data computed from them once per parameter set (the door's pose table):
:func:`register_prepared` declares it, as ``fast_accel(theta, dtheta, force, q)`` on a
*prepared vector* ``q`` that ``prepare(p, q)`` fills from the parameter vector ``p``.
The entry points (:func:`evo_door.sim.simulate`, :func:`evo_door.sim.simulate_batch`,
:func:`evo_door.optim.kernels.population_errors`) look the model's ``accel`` up with
:func:`prepared_form` and, where there is one, prepare each parameter set once and
integrate with the fast form; :func:`integrate_batch` does it per individual
inside the compiled parallel loop, so a population never holds more than one
prepared vector per individual in flight. A fast form may come with its own
:func:`integrate` compiled around it (:func:`integrate_with`, the right-hand side
inlined into the stages rather than called through a pointer): :func:`integrate`
runs it when handed that fast form.

**What is inlined.** The steps are written as small functions that numba inlines into
their callers (``inline="always"``, at the level of its own IR): called instead, each
would take its arrays as seven values each and its right-hand side through a pointer,
and the trials run measurably slower. That inlining is most of the time a kernel takes
to compile, and it grows with the number of inlined call sites, small ones included
(:mod:`evo_door.kernel_cache` makes numba's copy of each inlined body cheaper).
So the small helpers that do arithmetic on numbers or arrays
(:func:`~evo_door.sim.located._crossed`, :func:`~evo_door.sim.spans.dense`,
:func:`~evo_door.sim.objective.accumulate`, ...) are plain calls, which LLVM inlines on
its own, and so are the rare branches of the right-hand side's wrappers
(:func:`~evo_door.sim.located.other_side`, :func:`~evo_door.sim.located.stuck_rate`).
Each was kept inlined or not as the trials' timing said: the state vector's contact and
LU helpers stay inlined. A cold ``evo-door compile`` is timed in the benchmark suite's
start-up section (``python -m benchmarks --only startup``), the trials in its
``trial`` section.

Numba's disk cache keys a function on its own file only; :mod:`evo_door.kernel_cache`
stamps each cached kernel with every evo-door module it imports as well, so an edit of
one that a kernel compiles in (these steps into a model's specialised integrator)
compiles that kernel afresh.

Set ``NUMBA_DISABLE_JIT=1`` to run all kernels as plain Python (debugging, coverage).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit, prange, types

from evo_door.sim.located import (
    DOPRI5,
    SEMI_IMPLICIT,
    SWITCHES_TYPE,
    advance_located,
    jacobian,
    no_switches,
    rate,
    rk4_step,
    ros2_step,
    smooth_period,
)
from evo_door.sim.spans import (
    MAX_SPAN,
    MIN_SPAN,
    SPAN_COARSE,
    SPAN_KEPT,
    STIFF_LIMIT,
    kink_free,
    span_step,
    stiff_span_step,
    stiffness,
)

#: Angular speed (rad/s) beyond which a simulation counts as blown up.
BLOWUP_SPEED = 1.0e6


#: Signature every model's ``accel(theta, dtheta, force, p) -> ddtheta`` must have.
ACCEL_SIGNATURE = types.float64(types.float64, types.float64, types.float64, types.float64[::1])
#: The numba type of an acceleration function as a kernel argument.
ACCEL_TYPE = types.FunctionType(ACCEL_SIGNATURE)

#: Signature of a model's ``prepare(p, q)``: fill the prepared vector ``q`` from ``p``.
PREPARE_SIGNATURE = types.void(types.float64[::1], types.float64[::1])
#: The numba type of a ``prepare`` function as a kernel argument.
PREPARE_TYPE = types.FunctionType(PREPARE_SIGNATURE)

_vec = types.float64[::1]
_mat = types.float64[:, ::1]


@dataclass(frozen=True)
class Prepared:
    """The fast form of a model's right-hand side (see the module docstring).

    ``accel(theta, dtheta, force, q)`` has :data:`ACCEL_SIGNATURE` and takes a prepared
    vector ``q`` of ``size`` floats that ``prepare(p, q)`` (:data:`PREPARE_SIGNATURE`,
    compiled) fills from a parameter vector ``p``.
    """

    accel: Callable
    prepare: Callable
    size: int
    #: :func:`integrate` compiled around ``accel`` (:func:`integrate_with`), or None
    integrate: Callable | None = None
    #: the model's switching functions on a prepared vector, or None: the model's own
    #: (which read only the parameters at the vector's start)
    switches: Callable | None = None

    def switches_or(self, switches):
        """The switching functions the kernels hand a vector of this form: its own,
        else the model's ``switches``."""
        return self.switches if self.switches is not None else switches

    def vector(self, p) -> np.ndarray:
        """The prepared vector of the parameter vector ``p``."""
        q = np.empty(self.size)
        self.prepare(np.ascontiguousarray(p, dtype=np.float64), q)
        return q


#: model accel -> its :class:`Prepared` form: a registry, not a cache. A model's module
#: fills it once, when imported (:func:`register_prepared`; the door's and the haptic
#: model's do), and nothing changes it afterwards, so it holds one entry per right-hand
#: side with a fast form. It is
#: module-level because this layer sits below the models and may not name them: the
#: kernels find a right-hand side's fast form by the function itself (the layers'
#: registries, docs/architecture.md).
_PREPARED: dict[object, Prepared] = {}


def register_prepared(accel, fast_accel, prepare, size: int, integrate=None, switches=None) -> None:
    """Declare ``fast_accel`` on ``prepare``-d vectors of ``size`` floats as the fast
    form of the model right-hand side ``accel`` (the door and the haptic model do, at
    import).

    ``integrate``, if given, is :func:`integrate` without its first argument,
    compiled around ``fast_accel`` (a module-level ``njit`` that calls
    :func:`integrate_with` with ``fast_accel`` and the arrays of :func:`scratch`):
    :func:`integrate` then runs it when
    handed ``fast_accel``. Called directly rather than through a function pointer,
    the right-hand side is inlined into the RK4 stages (some 6 % of a door trial).
    ``switches``, if given, are the model's switching functions on prepared vectors
    (:data:`~evo_door.sim.located.SWITCHES_SIGNATURE`, the same values as the model's
    own), which the kernels then hand the integrator with them.
    """
    _PREPARED[accel] = Prepared(fast_accel, prepare, int(size), integrate, switches)


def prepared_form(accel) -> Prepared | None:
    """The :class:`Prepared` form registered for ``accel``, or None."""
    try:
        return _PREPARED.get(accel)
    except TypeError:  # an unhashable callable: no fast form
        return None


@njit(PREPARE_SIGNATURE, cache=True, nogil=True)
def copy_params(p, q):
    """The prepared vector of a model without a fast form: its parameter vector (a
    loop: ``q[:] = p`` compiles numba's shape-mismatch error and its message
    formatting, some 2 s of the first compile)."""
    for i in range(q.shape[0]):
        q[i] = p[i]


def kernel_form(accel, n_params: int) -> Prepared:
    """What the batch kernels integrate for the model right-hand side ``accel`` of
    ``n_params`` parameters: its registered fast form, else ``accel`` itself on a copy
    of each parameter vector (one kernel serves both)."""
    return prepared_form(accel) or Prepared(accel, copy_params, int(n_params))


@njit(cache=True, nogil=True, inline="always")
def advance(accel, p, theta, dtheta, f0, f1, a_start, dt, substeps, method):
    """Move the state over one sample period ``dt`` in ``substeps`` steps.

    The force goes linearly from ``f0`` to ``f1``; ``a_start`` is
    ``accel(theta, dtheta, f0, p)`` (callers have it: it is the previous sample's
    output), so no evaluation is repeated. The ROS2 Jacobian is frozen over the period.
    """
    h = dt / substeps
    df = (f1 - f0) / substeps
    a_s = a_start
    if method == SEMI_IMPLICIT:
        a_t, a_w = jacobian(accel, p, theta, dtheta, f0, a_start)
        for s in range(substeps):
            if s > 0:
                a_s = accel(theta, dtheta, f0 + s * df, p)
            theta, dtheta = ros2_step(
                accel, p, theta, dtheta, a_s, f0 + (s + 1) * df, h, a_t, a_w, 0
            )
    else:
        for s in range(substeps):
            if s > 0:
                a_s = accel(theta, dtheta, f0 + s * df, p)
            theta, dtheta = rk4_step(
                accel, p, theta, dtheta, a_s, f0 + s * df, f0 + (s + 1) * df, h, 0
            )
    return theta, dtheta


#: Most periods a trial goes straight to the locating loop after the shortcut failed
#: again and again (it waits 1, 2, 4, ... periods before it tries the shortcut anew).
MAX_SKIP = 64


@njit(cache=True, nogil=True, inline="always")
def step_period(
    accel, switches, p, theta, dtheta, f0, f1, a_start, g_ready, dt, substeps, method, tol,
    n_sw, stick, g, skip, backoff, h0,
):  # fmt: skip
    """Move the state over one sample period: :func:`advance`, or where the model has
    switching surfaces, stick-slip friction or the method is ``dopri5``,
    :func:`~evo_door.sim.located.advance_located` (``g``: 4 rows of scratch; with
    ``g_ready`` its first row holds the switching functions at the start).

    Unless ``skip`` is positive, the period's steps are first tried without the
    locating loop (:func:`~evo_door.sim.located.smooth_period`: the same numbers,
    without the loop's cost), which serves every period that crosses nothing and cuts
    no step. Where it cannot (a door resting on its stiff stop cuts every step), the
    try would cost a step a period: after a failure the next ``backoff`` periods skip
    it, and ``backoff`` doubles while it keeps failing (up to :data:`MAX_SKIP`). A
    trial starts with ``skip`` 0 and ``backoff`` 1. ``dopri5``'s first step in the
    period is ``h0`` long: what the last period's first step asked for
    (:func:`~evo_door.sim.located.advance_located`; the first period, and after a step
    over several periods: ``dt / substeps``).

    Returns ``(theta, dtheta, a_end, a_ok, skip, backoff, h_next)``: where ``a_ok``,
    ``a_end`` is the acceleration at the end that the last step already computed;
    ``skip``, ``backoff`` and ``h0`` for the next period."""
    if method == DOPRI5 or n_sw > 0 or stick:
        if skip > 0:
            skip -= 1
        else:
            ok, th1, w1, a_end, a_ok, h_next = smooth_period(
                accel, switches, p, theta, dtheta, f0, f1, a_start, g_ready, dt, substeps,
                method, tol, n_sw, stick, g[0], g[1], h0,
            )  # fmt: skip
            if ok:
                return th1, w1, a_end, a_ok, 0, 1, h_next
            g_ready = True  # smooth_period left the switching functions at the start
            h0 = h_next  # ... and its first step cut, where only its error failed it
            skip, backoff = backoff, min(2 * backoff, MAX_SKIP)
        theta, dtheta, a_end, a_ok, h_next = advance_located(
            accel, switches, p, theta, dtheta, f0, f1, a_start, g_ready, dt, substeps, method,
            tol, n_sw, stick, g[0], g[1], g[2], g[3], h0,
        )  # fmt: skip
        return theta, dtheta, a_end, a_ok, skip, backoff, h_next
    theta, dtheta = advance(accel, p, theta, dtheta, f0, f1, a_start, dt, substeps, method)
    return theta, dtheta, 0.0, False, 0, 1, dt / substeps


@njit(cache=True, nogil=True, inline="always")
def span_factor(err, exponent, small):
    """How much longer (or shorter) the next step over several periods is made after one
    of error ``err`` (its tolerance 1): ``0.9 err**exponent`` within 0.2 and 5, and 5
    below ``small``. ``exponent`` is minus one over the order of the error estimate (a
    ``dopri5`` span's -1/5, ROS2's -1/2)."""
    if err < small:
        return 5.0
    return min(5.0, max(0.2, 0.9 * err**exponent))


@njit(cache=True, nogil=True, inline="always")
def try_span(
    accel, switches, p, theta, dtheta, a_now, force, k, stop, dt, tol, n_sw, stick, g0, g1,
    span, wait, patience, stiff, th_s, w_s,
):  # fmt: skip
    """Try to move the state from sample ``k`` by one step over several periods
    (:func:`~evo_door.sim.spans.span_step`), up to ``span`` of them and not past
    sample ``stop - 1``.

    A step too coarse is tried again shorter, as the error estimate says, while it
    still spans two periods. Where none can (a door resting on its stiff stop, a noisy
    measured force, whose kinks at every sample a longer step cannot follow), or a
    surface lies within the step, the next ``patience`` periods are stepped one by one
    (``wait``), and ``patience`` doubles while that keeps happening (up to
    :data:`MAX_SKIP`): what a failed try costs stays a small share of the trial. A
    kept step sets the next ``span`` from its error, as a step's length is set. A trial
    starts with ``span`` :data:`~evo_door.sim.spans.MIN_SPAN`, ``wait`` 0,
    ``patience`` 1 and ``stiff`` False.

    Where the force is constant, a smooth friction's model and a ``dopri5`` step refused
    while its length stood past its stability limit (:data:`~evo_door.sim.spans.
    STIFF_LIMIT`: a door creeping against its friction), the step is tried as ROS2
    (:func:`~evo_door.sim.spans.stiff_span_step`), and ``stiff`` says to try ROS2 first
    next time, while the force stays constant and the Jacobian says the step would still
    be past ``dopri5``'s limit.

    Returns ``(m, a_end, span, wait, patience, stiff)``: ``m`` the periods the step
    spanned (the states at samples ``k + 1`` ... ``k + m`` in ``th_s`` and ``w_s``,
    ``a_end`` the acceleration at the last), 0 when the next period is
    :func:`step_period`'s.
    """
    if wait > 0:
        return 0, 0.0, span, wait - 1, patience, stiff
    run = kink_free(force, k, min(max(span, MIN_SPAN), stop - 1 - k))
    if run < MIN_SPAN:  # the force kinks within the next periods: nothing to try
        return 0, 0.0, span, 0, patience, False
    m = min(span, run)
    level = not stick and force[k + 1] == force[k]  # constant over the run (kink_free)
    a_t, a_w = 0.0, 0.0
    have_j = level and stiff  # the Jacobian, taken at most once a try
    if have_j:
        a_t, a_w = stiffness(accel, p, theta, dtheta, force[k], a_now)
    while m >= 2:
        if not (have_j and m * dt * a_w < -STIFF_LIMIT):
            found, err, a_end = span_step(
                accel, switches, p, theta, dtheta, a_now, force, k, m, dt, tol, n_sw, stick,
                g0, g1, th_s, w_s,
            )  # fmt: skip
            if found == SPAN_KEPT:
                m_next = min(MAX_SPAN, max(2, int(m * span_factor(err, -0.2, 1e-4))))
                return m, a_end, m_next, 0, 1, False
            if found != SPAN_COARSE or not math.isfinite(err):
                break
            if level and not have_j:
                have_j = True
                a_t, a_w = stiffness(accel, p, theta, dtheta, force[k], a_now)
            if not (m * dt * a_w < -STIFF_LIMIT):
                m = int(m * span_factor(err, -0.2, 1e-4))
                continue
        # past dopri5's stability limit at this length: the L-stable step
        found, err, a_end = stiff_span_step(
            accel, switches, p, theta, dtheta, a_now, force, k, m, dt, tol, n_sw, g0, g1,
            th_s, w_s, a_t, a_w,
        )  # fmt: skip
        if found == SPAN_KEPT:
            m_next = min(MAX_SPAN, max(2, int(m * span_factor(err, -0.5, 1e-3))))
            return m, a_end, m_next, 0, 1, True
        if found != SPAN_COARSE or not math.isfinite(err):
            break
        m = int(m * span_factor(err, -0.5, 1e-3))
    return 0, 0.0, MIN_SPAN, patience, min(2 * patience, MAX_SKIP), False


@njit(cache=True, nogil=True)
def scratch(n_sw):
    """The work arrays of one trial of :func:`integrate_with`: the switching functions'
    rows ``g`` (4 x ``max(n_sw, 1)``) and a span's samples ``th_s``, ``w_s``
    (:data:`MAX_SPAN` + 1 each). A caller of many trials allocates them once."""
    return np.empty((4, max(n_sw, 1))), np.empty(MAX_SPAN + 1), np.empty(MAX_SPAN + 1)


@njit(cache=True, nogil=True, inline="always")
def integrate_with(
    accel, switches, p, force, dt, substeps, theta0, dtheta0, method, tol, n_sw, stick,
    theta_out, dtheta_out, ddtheta_out, rates, g, th_s, w_s,
):  # fmt: skip
    """The body of :func:`integrate`, generic in ``accel`` and ``switches``; ``g``,
    ``th_s`` and ``w_s`` are its scratch (:func:`scratch`), which it does not allocate.

    :func:`integrate_compiled` hands it first-class functions (called through a
    pointer); a model's specialised integrator (:func:`register_prepared`) hands it
    its compiled right-hand side by name, which LLVM then inlines into the stages.
    ``inline="always"`` here and in the steps is what lets numba cache that: the
    right-hand side stays a direct call, never a value passed to another compiled
    function (a dispatcher as a value is a "dynamic global" numba will not cache).
    """

    n = force.shape[0]
    theta = theta0
    dtheta = dtheta0
    a_now = rate(accel, p, theta, dtheta, force[0], stick)
    theta_out[0] = theta
    dtheta_out[0] = dtheta
    ddtheta_out[0] = a_now
    skip, backoff = 0, 1
    spans = method == DOPRI5 and substeps == 1  # steps over several periods
    span, wait, patience, stiff = MIN_SPAN, 0, 1, False
    h_max = dt / substeps
    h0 = h_max  # the first step of the next period (dopri5)
    if spans:
        switches(theta, dtheta, force[0], p, g[0])
    k = 0
    while k < n - 1:
        m = 0
        if spans:
            m, a_end, span, wait, patience, stiff = try_span(
                accel, switches, p, theta, dtheta, a_now, force, k, n, dt, tol, n_sw, stick,
                g[0], g[1], span, wait, patience, stiff, th_s, w_s,
            )  # fmt: skip
        if m > 0:
            for j in range(1, m):
                theta_out[k + j] = th_s[j]
                dtheta_out[k + j] = w_s[j]
                if rates:
                    ddtheta_out[k + j] = rate(accel, p, th_s[j], w_s[j], force[k + j], stick)
                else:
                    ddtheta_out[k + j] = np.nan
            theta, dtheta, a_now = th_s[m], w_s[m], a_end
            h0 = h_max  # a step over several periods: the motion is smooth
        else:
            m = 1
            theta, dtheta, a_end, a_ok, skip, backoff, h0 = step_period(
                accel, switches, p, theta, dtheta, force[k], force[k + 1], a_now, k > 0 or spans,
                dt, substeps, method, tol, n_sw, stick, g, skip, backoff, h0,
            )  # fmt: skip
            if math.isfinite(theta) and abs(dtheta) < BLOWUP_SPEED:
                a_now = a_end if a_ok else rate(accel, p, theta, dtheta, force[k + 1], stick)
        k += m
        if not (math.isfinite(theta) and abs(dtheta) < BLOWUP_SPEED):
            for j in range(k, n):
                theta_out[j] = np.nan
                dtheta_out[j] = np.nan
                ddtheta_out[j] = np.nan
            return False
        theta_out[k] = theta
        dtheta_out[k] = dtheta
        ddtheta_out[k] = a_now
    return True


#: Signature of :func:`integrate` without its first argument (a specialised form).
INTEGRATE_SIGNATURE = types.boolean(
    _vec,  # p
    _vec,  # force
    types.float64,  # dt
    types.int64,  # substeps
    types.float64,  # theta0
    types.float64,  # dtheta0
    types.int64,  # method
    types.float64,  # tol
    types.int64,  # n_sw
    types.boolean,  # stick
    _vec,
    _vec,
    _vec,
    types.boolean,  # rates
)


#: Signature of :func:`integrate_compiled`: :data:`INTEGRATE_SIGNATURE` with the
#: right-hand side and switching functions first and the scratch of :func:`scratch` last.
INTEGRATE_COMPILED_SIGNATURE = types.boolean(
    ACCEL_TYPE, SWITCHES_TYPE, *INTEGRATE_SIGNATURE.args, _mat, _vec, _vec
)
#: The numba type of :func:`integrate_compiled` as a kernel argument: the parallel kernels
#: (:func:`integrate_batch`, the objective's) take it so and call it through a pointer,
#: once a trial; called directly, each would link its code, and numba's LLVM would
#: optimise the whole integrator again in each.
INTEGRATE_TYPE = types.FunctionType(INTEGRATE_COMPILED_SIGNATURE)


# Without numba's runtime: it allocates nothing (the caller hands it the scratch), and
# the atomic reference counts on every array it hands a step took 8-10 % of a trial.
@njit(INTEGRATE_COMPILED_SIGNATURE, cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]
def integrate_compiled(
    accel, switches, p, force, dt, substeps, theta0, dtheta0, method, tol, n_sw, stick,
    theta_out, dtheta_out, ddtheta_out, rates, g, th_s, w_s,
):  # fmt: skip
    """:func:`integrate` for compiled callers: ``accel`` and ``switches`` through
    function pointers, the scratch of :func:`scratch` (``g`` at least ``n_sw`` wide).
    The objective kernels call it too (:mod:`evo_door.sim.objective`), so its steps are
    compiled once for both."""
    return integrate_with(
        accel, switches, p, force, dt, substeps, theta0, dtheta0, method, tol, n_sw, stick,
        theta_out, dtheta_out, ddtheta_out, rates, g, th_s, w_s,
    )  # fmt: skip


def integrate(
    accel, switches, p, force, dt, substeps, theta0, dtheta0, method, tol, n_sw, stick,
    theta_out, dtheta_out, ddtheta_out, rates=True,
):  # fmt: skip
    """Integrate one trial; fill the three output arrays at the force's sample instants.

    ``switches`` writes the model's ``n_sw`` switching functions and ``stick`` says
    its dry friction is a sign law (:mod:`evo_door.sim.located`); ``tol`` is the
    tolerance of ``dopri5``. Returns ``True`` on success, ``False`` if the state
    became non-finite or the speed exceeded :data:`BLOWUP_SPEED` (the rest of the
    outputs is then NaN). ``rates`` False leaves NaN for the acceleration at the samples
    inside a step over several periods (:mod:`evo_door.sim.spans`), which then costs
    no call of ``accel`` each: for a caller that does not read it. Runs the integrator
    specialised to ``accel`` where one is registered (:func:`register_prepared`), else
    :func:`integrate_compiled`.
    """
    args = (
        p, force, dt, substeps, theta0, dtheta0, method, tol, n_sw, stick,
        theta_out, dtheta_out, ddtheta_out, rates,
    )  # fmt: skip
    special = next((f.integrate for f in _PREPARED.values() if f.accel is accel), None)
    if special is not None:
        return special(*args)
    return integrate_compiled(accel, switches or no_switches, *args, *scratch(n_sw))


#: How many blocks a population's rows are split into for the threads to share
#: (:func:`integrate_batch`, :func:`evo_door.sim.objective._population_errors`): each
#: block prepares its rows one after another into one vector, so that what a row shares
#: with the last (the door's pose table, where the geometry is not free) is kept, not
#: made again. More blocks than threads, so that numba shares them out over every
#: thread as it shared the rows (a block's rows are consecutive, as a thread's were).
ROW_BLOCKS = 16


@njit(
    types.void(
        INTEGRATE_TYPE,
        ACCEL_TYPE,
        PREPARE_TYPE,
        SWITCHES_TYPE,
        types.int64,
        _mat,
        _vec,
        types.float64,
        types.int64,
        types.float64,
        types.float64,
        types.int64,
        types.float64,
        types.int64,
        types.boolean,
        _mat,
        _mat,
        _mat,
        types.boolean[::1],
    ),
    cache=True,
    parallel=True,
)
def integrate_batch(
    trial,
    accel,
    prepare,
    switches,
    size,
    P,
    force,
    dt,
    substeps,
    theta0,
    dtheta0,
    method,
    tol,
    n_sw,
    stick,
    theta_out,
    dtheta_out,
    ddtheta_out,
    ok_out,
):
    """Integrate one trial for every row of the parameter matrix ``P`` (numba prange).

    ``accel``, ``prepare`` and ``size`` are a :func:`kernel_form`: each row is prepared
    (into a vector of ``size`` floats) inside the parallel loop and integrated with
    ``accel`` on it by ``trial``, :func:`integrate_compiled` (:data:`INTEGRATE_TYPE`);
    ``switches``, ``n_sw`` and ``stick`` as in :func:`integrate`. The rows go to the
    threads in :data:`ROW_BLOCKS` blocks, each block's rows prepared into one vector."""
    rows = P.shape[0]
    for b in prange(ROW_BLOCKS):
        q = np.empty(size)
        g, th_s, w_s = scratch(n_sw)
        for i in range(b * rows // ROW_BLOCKS, (b + 1) * rows // ROW_BLOCKS):
            prepare(P[i], q)
            ok_out[i] = trial(
                accel, switches, q, force, dt, substeps, theta0, dtheta0, method, tol, n_sw,
                stick, theta_out[i], dtheta_out[i], ddtheta_out[i], True, g, th_s, w_s,
            )  # fmt: skip
