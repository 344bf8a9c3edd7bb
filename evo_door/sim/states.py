"""Compiled integrators on state vectors: models with more than one coordinate.

:mod:`evo_door.sim.integrators` integrates one coordinate, ``ddtheta = accel(theta,
dtheta, force, p)``. A model with more states (an elastic cable whose far end has its
own first-order state, two coupled bodies, a soft-close damper with a fluid state) is
integrated here, with the same algorithms on a vector ``x`` of ``n`` states
(``n`` small: the Jacobian of ``semi_implicit`` is dense, n x n).

**The contract for a model author.**

*State layout.* ``x`` is a flat float64 vector in the model's own order and units;
the caller says which entry is the handle's coordinate and which its speed (the
objective kernel's ``position`` and ``speed``). A second-order coordinate takes two
entries, a position and its speed; a first-order state (a massless carriage on a
damper, a fluid volume) one.

*Right-hand side.* ``rhs(x, force, p, dx)`` (:data:`RHS_SIGNATURE`, compiled with
that explicit signature) writes ``dx = f(x, force, p)``: ``force`` the hand's force
(N, the input's sample linearly interpolated), ``p`` the model's parameter vector.
It must be *affine in the force* (``f = a(x, p) + force * b(x, p)``): the break-away
of a stuck contact is solved exactly from that, as in the one-coordinate form.

*Switching functions.* ``switches(x, force, p, g)`` (:data:`STATE_SWITCHES_SIGNATURE`)
writes the model's ``n_switches`` values ``g[i]``, each changing sign where the
rhs kinks or jumps (a stop, the start of a latch band); :func:`no_state_switches`
for a model with none. Each crossing is located within the step (Illinois on the step
length), the state moved across by a tiny Euler step, as
:func:`evo_door.sim.located.advance_located` does; a surface crossed more than
``MAX_EVENTS`` times in one period, or grazed, is stepped over for the rest of it.

*Contacts (stick-slip).* ``contacts`` (int64 vector, may be empty) lists the speed
states of the frictional contacts whose dry friction is a sign law, ``-F_c sgn(v)``
with ``sgn(0) = 0``. Each contact's friction acts on its own speed's rate ``dx[k]``
and the contacts' laws are independent of one another's signs. A contact at rest
(``x[k] == 0.0``) sticks while ``rhs`` with ``x[k] = +CREEP`` gives ``dx[k] <= 0`` and
with ``x[k] = -CREEP`` gives ``dx[k] >= 0``: its speed is then held at exactly 0 and
its rate reported 0, while the other states move on. When they break the stick the
contact slips from ``+-CREEP``; the instant is solved exactly where nothing else moves
(the rhs affine in the force, the force linear in time), else located like a surface.
A sliding contact's speed zero is located, where it comes to rest; during a step's
stages its friction is held on the side it slides (the one-coordinate ``sided``).

**Methods** (codes :data:`~evo_door.sim.located.RK4` = 0, ``SEMI_IMPLICIT`` = 1,
``DOPRI5`` = 2): per sample period ``dt`` the force is linear between samples and the
period is cut into ``substeps`` steps. ``rk4`` the classic fourth order; ``semi_implicit``
ROS2 (gamma = 1 + 1/sqrt(2)) with the n x n Jacobian taken by forward differences of
``rhs`` once per period (:func:`evo_door.sim.state_steps.jacobian`); ``dopri5`` the
adaptive 5(4) pair, ``|err_i| <= tol (1 + |x_i|)`` per component, steps never above
``dt / substeps``, each period's first step the length the last one's first step asked
for (:func:`evo_door.sim.located.advance_located`), first same as last.

**Packed arguments.** :func:`settings` packs ``dt, substeps, method, tol, n_switches``
into one float64 vector (the indices :data:`DT` ... :data:`N_SWITCHES`). The objective
kernel (:func:`evo_door.sim.state_objective.population_errors_states`) runs each
trial at its own period, ``dt[j]``, and reads everything but ``DT`` from the packed
vector (build it with ``dt=None``).

**Against the one-coordinate integrators.** On ``dx = (x[1], accel(x[0], x[1], f,
p))`` (:func:`second_order`, ``contacts = [1]`` for a stick-slip model), ``rk4`` and
``dopri5`` give :func:`evo_door.sim.integrators.integrate`'s results: the same
expressions per component, the same rhs evaluations, the same located crossings, so
bit for bit where the two compile alike (``tests/test_states.py`` holds them to
1e-12 on the haptic model and the door). ``semi_implicit`` is not bit for bit: its
linear systems are solved by LU, not Cramer's rule, and its Jacobian differs. The
one-coordinate form keeps only the non-positive entries ``d ddtheta / d theta`` and
``d ddtheta / d dtheta``; a general state vector has no such rule (the positive
off-diagonal entries of coupled springs stabilise), so this one keeps the whole
forward-difference Jacobian but for positive diagonal entries, and drops it for a
step whose ``det(I - gamma h J)`` falls below
:data:`~evo_door.sim.state_steps.MIN_DETERMINANT`. Where the door's stiffness is not
negative the two agree to rounding; through a latch's snap (a negative stiffness)
they differ by less than a tenth of either's own error (the test again).

The compiled functions trust their arguments (shapes, codes); :func:`simulate_states`
and :func:`simulate_states_batch` check them (one-line :class:`~evo_door.errors.UserError`)
and allocate the outputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange, types

from evo_door.errors import UserError
from evo_door.sim.integrators import BLOWUP_SPEED
from evo_door.sim.state_located import period
from evo_door.sim.state_steps import R, Y, sample_rate, workspace
from evo_door.sim_settings import DEFAULT_TOLERANCE, METHODS

_vec = types.float64[::1]
_mat = types.float64[:, ::1]
_cube = types.float64[:, :, ::1]
_ivec = types.int64[::1]

#: Signature of a model's ``rhs(x, force, p, dx)``: writes ``dx = f(x, force, p)``.
RHS_SIGNATURE = types.void(_vec, types.float64, _vec, _vec)
#: The numba type of an ``rhs`` as a kernel argument.
RHS_TYPE = types.FunctionType(RHS_SIGNATURE)
#: Signature of a model's ``switches(x, force, p, g)``: writes its switching values.
STATE_SWITCHES_SIGNATURE = types.void(_vec, types.float64, _vec, _vec)
#: The numba type of a state model's ``switches`` as a kernel argument.
STATE_SWITCHES_TYPE = types.FunctionType(STATE_SWITCHES_SIGNATURE)
#: ``start(x, p)``: a model's completion of its initial state from the parameters (an
#: elastic element at rest), called by the plant before a run (not in a kernel).
START_SIGNATURE = types.void(_vec, _vec)

#: A state of magnitude at least this (model units) counts as a blow-up (the
#: one-coordinate integrators' speed bound, :data:`~evo_door.sim.integrators.BLOWUP_SPEED`).
BLOWUP = BLOWUP_SPEED

#: Indices of the packed settings vector (:func:`settings`).
DT, SUBSTEPS, METHOD, TOLERANCE, N_SWITCHES = range(5)
SETTINGS_SIZE = 5
#: Most states :func:`simulate_states` accepts (the ROS2 Jacobian is dense).
MAX_STATES = 64


@njit(STATE_SWITCHES_SIGNATURE, cache=True, nogil=True)
def no_state_switches(x, force, p, g):
    """The ``switches`` of a state model that declares none."""


def settings(dt, substeps, method, tol=DEFAULT_TOLERANCE, n_switches=0) -> np.ndarray:
    """The packed settings vector: ``dt`` (s; None for the objective kernel, which
    takes each trial's), ``substeps`` (>= 1), ``method`` (a code or a name of
    :data:`~evo_door.sim_settings.METHODS`), ``tol`` (``dopri5``'s, in (0, 1)),
    ``n_switches`` (the model's switching values)."""
    if isinstance(method, str):
        if method not in METHODS:
            raise UserError(
                f"unknown integration method {method!r}; choose from {', '.join(METHODS)}"
            )
        method = METHODS[method]
    try:
        packed = np.array(
            [math.nan if dt is None else dt, substeps, method, tol, n_switches], dtype=np.float64
        )
    except (TypeError, ValueError):
        raise UserError("settings take numbers: dt, substeps, method, tol, n_switches") from None
    return check_settings(packed)


def check_settings(setup) -> np.ndarray:
    """The packed settings, checked (a one-line UserError), as the kernels take them."""
    s = np.ascontiguousarray(setup, dtype=np.float64)
    if s.shape != (SETTINGS_SIZE,):
        raise UserError(f"settings must be the {SETTINGS_SIZE} numbers of states.settings()")
    dt, substeps, method, tol, n_sw = s.tolist()
    if not (math.isnan(dt) or (math.isfinite(dt) and dt > 0)):
        raise UserError(f"sample period must be positive, got {dt!r} s")
    if not (math.isfinite(substeps) and substeps == int(substeps) and 1 <= substeps <= 4096):
        raise UserError(f"substeps must be a whole number from 1 to 4096, got {substeps!r}")
    if method not in METHODS.values():
        raise UserError(f"unknown integration method code {method!r}")
    if not (math.isfinite(tol) and 0.0 < tol < 1.0):
        raise UserError(f"integration tolerance must be a number in (0, 1), got {tol!r}")
    if not (math.isfinite(n_sw) and n_sw == int(n_sw) and 0 <= n_sw <= 4096):
        raise UserError(f"n_switches must be a whole number from 0 to 4096, got {n_sw!r}")
    return s


@njit(cache=True, nogil=True)
def blown_up(x):
    """True when a state is not finite or of magnitude :data:`BLOWUP` or more."""
    for v in x:
        if not (abs(v) < BLOWUP):
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def put_column(out, k, x):
    """``out[:, k] = x`` as a loop: a slice assignment of an array compiles numba's
    shape-mismatch error with its message formatting (some 2 s of the first compile)."""
    for i in range(x.shape[0]):
        out[i, k] = x[i]


#: Signature of :func:`integrate_trial`.
TRIAL_SIGNATURE = types.boolean(
    RHS_TYPE, STATE_SWITCHES_TYPE, _vec, _vec, _vec, types.float64, _vec, _ivec, _mat, _mat
)
#: The numba type of :func:`integrate_trial` as a kernel argument.
TRIAL_TYPE = types.FunctionType(TRIAL_SIGNATURE)


# Compiled once, with its signature; the parallel kernels (the batch here, the objective's)
# take it as an argument and call it through a pointer, once a trial: called directly,
# each would link its code and LLVM would optimise all of it again in each.
@njit(TRIAL_SIGNATURE, cache=True, nogil=True)
def integrate_trial(rhs, switches, p, force, x0, dt, setup, contacts, x_out, dx_out):
    """:func:`integrate_states` at the sample period ``dt`` (``setup[DT]`` unread)."""
    n = x0.shape[0]
    substeps = int(setup[SUBSTEPS])
    method = int(setup[METHOD])
    tol = setup[TOLERANCE]
    n_sw = int(setup[N_SWITCHES])
    W, G, JM, piv, modes = workspace(n, n_sw + contacts.shape[0], contacts.shape[0])
    x = x0.copy()
    dx = np.empty(n)
    sample_rate(rhs, p, x, force[0], contacts, dx, W[Y], W[R])
    put_column(x_out, 0, x)
    put_column(dx_out, 0, dx)
    h0 = dt / substeps  # dopri5's first step in the next period
    for k in range(force.shape[0] - 1):
        h0 = period(
            rhs, switches, p, x, force[k], force[k + 1], dx, dt, substeps, method, tol, n_sw,
            contacts, W, G, JM, piv, modes, h0,
        )  # fmt: skip
        if not blown_up(x):
            sample_rate(rhs, p, x, force[k + 1], contacts, dx, W[Y], W[R])
            put_column(x_out, k + 1, x)
            put_column(dx_out, k + 1, dx)
            continue
        x_out[:, k + 1 :] = np.nan
        dx_out[:, k + 1 :] = np.nan
        return False
    return True


@njit(
    types.boolean(RHS_TYPE, STATE_SWITCHES_TYPE, _vec, _vec, _vec, _vec, _ivec, _mat, _mat),
    cache=True,
    nogil=True,
)
def integrate_states(rhs, switches, p, force, x0, settings, contacts, x_out, dx_out):
    """Integrate one trial from the state ``x0``; fill ``x_out`` and ``dx_out``
    (``(n_states, n_samples)``) with the state and its rate at each sample instant.

    ``force`` is sampled every ``settings[DT]``; ``contacts`` the contacts' speed
    states (the module docstring). Returns False when a state became non-finite or
    reached :data:`BLOWUP` (the rest of the outputs is then NaN), else True.
    """
    return integrate_trial(
        rhs, switches, p, force, x0, settings[DT], settings, contacts, x_out, dx_out
    )


def integrate_states_batch(rhs, switches, P, force, X0, settings, contacts, x_out, dx_out, ok_out):
    """:func:`integrate_states` for every row of ``P`` (``(n_ind, n_params)``) from the
    initial states ``X0[i]`` into ``x_out[i]``, ``dx_out[i]`` and ``ok_out[i]``, the
    rows in parallel (numba prange)."""
    _batch(integrate_trial, rhs, switches, P, force, X0, settings, contacts, x_out, dx_out, ok_out)


@njit(
    types.void(
        TRIAL_TYPE, RHS_TYPE, STATE_SWITCHES_TYPE, _mat, _vec, _mat, _vec, _ivec, _cube, _cube,
        types.boolean[::1],
    ),
    cache=True,
    parallel=True,
)  # fmt: skip
def _batch(trial, rhs, switches, P, force, X0, settings, contacts, x_out, dx_out, ok_out):
    """:func:`integrate_states_batch` with :func:`integrate_trial` as ``trial``."""
    for i in prange(P.shape[0]):
        ok_out[i] = trial(
            rhs, switches, P[i], force, X0[i], settings[DT], settings, contacts, x_out[i], dx_out[i]
        )


# -- Python entry points: check, allocate, call ----------------------------------------
@dataclass
class StatesResponse:
    """A simulated trial of a state model: ``x`` and ``dx`` are ``(n_states,
    n_samples)``, sampled at ``t`` (s); ``ok`` False when it blew up (NaN tail)."""

    t: np.ndarray
    x: np.ndarray
    dx: np.ndarray
    ok: bool


def check_vector(values, name: str, size: int | None = None) -> np.ndarray:
    """A finite float64 vector (of ``size`` entries, if given), or a one-line UserError."""
    try:
        v = np.ascontiguousarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise UserError(f"{name} must be numbers") from None
    if v.ndim != 1 or (size is not None and v.size != size):
        want = f"{size} numbers" if size is not None else "a list of numbers"
        raise UserError(f"{name} must be {want}, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise UserError(
            f"{name} has a non-finite entry at index {int(np.flatnonzero(~np.isfinite(v))[0])}"
        )
    return v


def check_contacts(contacts, n_states: int) -> np.ndarray:
    """The contacts' speed states as an int64 vector, or a one-line UserError."""
    try:
        c = np.asarray(contacts if contacts is not None else (), dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise UserError(f"contacts must be state indices, got {contacts!r}") from None
    if np.any(c != np.round(c)) or np.any(c < 0) or np.any(c >= n_states):
        raise UserError(
            f"contacts must be state indices from 0 to {n_states - 1}, got {c.tolist()}"
        )
    if len(set(c.tolist())) != c.size:
        raise UserError(f"contacts name a state twice: {c.astype(int).tolist()}")
    return np.ascontiguousarray(c, dtype=np.int64)


def check_out(out, shape: tuple, name: str) -> np.ndarray:
    """A float64 C-contiguous output array of ``shape`` (a new one for None)."""
    if out is None:
        return np.empty(shape)
    if not (
        isinstance(out, np.ndarray)
        and out.dtype == np.float64
        and out.shape == shape
        and out.flags.c_contiguous
    ):
        got = getattr(out, "shape", type(out).__name__)
        raise UserError(f"{name} must be a contiguous float64 array of shape {shape}, got {got}")
    return out


def check_compiled(func, signature, what: str) -> None:
    """A one-line UserError unless ``func`` is compiled with ``signature``."""
    compiled = getattr(func, "nopython_signatures", ())
    if not any(sig.args == signature.args for sig in compiled):
        raise UserError(
            f"{what} must be compiled with numba's @njit(states.{what.upper()}_SIGNATURE), "
            f"got {getattr(func, '__name__', type(func).__name__)}"
        )


def _check_common(rhs, switches, force, setup, n_states, contacts):
    check_compiled(rhs, RHS_SIGNATURE, "rhs")
    if switches is not None:
        check_compiled(switches, STATE_SWITCHES_SIGNATURE, "state_switches")
    if not (isinstance(n_states, (int, np.integer)) and 1 <= n_states <= MAX_STATES):
        raise UserError(f"n_states must be a whole number from 1 to {MAX_STATES}, got {n_states!r}")
    s = check_settings(setup)
    force = check_vector(force, "the input force")
    if force.size < 2:
        raise UserError("the input force needs at least two samples")
    if s[N_SWITCHES] > 0 and switches is None:
        raise UserError(f"settings declare {int(s[N_SWITCHES])} switching values but no switches")
    return s, force, check_contacts(contacts, n_states), switches or no_state_switches


def simulate_states(
    rhs, p, force, x0, setup, n_states, switches=None, contacts=(), x_out=None, dx_out=None
) -> StatesResponse:
    """Simulate a state model (``rhs``, ``switches`` compiled with
    :data:`RHS_SIGNATURE` / :data:`STATE_SWITCHES_SIGNATURE`) from ``x0`` under
    ``force`` with the packed ``setup`` (:func:`settings`), every argument checked
    (a one-line :class:`~evo_door.errors.UserError`); ``x_out`` / ``dx_out``, if
    given, are filled (shape ``(n_states, len(force))``)."""
    s, force, contacts, switches = _check_common(rhs, switches, force, setup, n_states, contacts)
    if math.isnan(s[DT]):
        raise UserError("settings for a simulation need the sample period dt")
    x0 = check_vector(x0, "the initial state x0", n_states)
    p = check_vector(p, "the parameter vector")
    shape = (n_states, force.size)
    x_out = check_out(x_out, shape, "x_out")
    dx_out = check_out(dx_out, shape, "dx_out")
    ok = integrate_states(rhs, switches, p, force, x0, s, contacts, x_out, dx_out)
    return StatesResponse(s[DT] * np.arange(force.size), x_out, dx_out, bool(ok))


def simulate_states_batch(rhs, P, force, X0, setup, n_states, switches=None, contacts=()):
    """:func:`simulate_states` for every row of ``P`` from the initial states ``X0``
    (one row per individual, or one state for all) in one parallel call. Returns
    ``(x, dx, ok)``: ``(n_ind, n_states, n_samples)`` twice and ``(n_ind,)`` bool."""
    s, force, contacts, switches = _check_common(rhs, switches, force, setup, n_states, contacts)
    if math.isnan(s[DT]):
        raise UserError("settings for a simulation need the sample period dt")
    P = np.ascontiguousarray(P, dtype=np.float64)
    if P.ndim != 2 or not np.all(np.isfinite(P)):
        raise UserError(
            f"the parameter matrix must be finite, one row per individual, got {P.shape}"
        )
    X0 = np.asarray(X0, dtype=np.float64)
    if X0.shape == (n_states,):  # one initial state for every individual
        X0 = np.broadcast_to(X0, (len(P), n_states))
    X0 = np.ascontiguousarray(X0)
    if X0.shape != (len(P), n_states) or not np.all(np.isfinite(X0)):
        raise UserError(f"X0 must be finite, of shape ({len(P)}, {n_states}), got {X0.shape}")
    x = np.empty((len(P), n_states, force.size))
    dx = np.empty_like(x)
    ok = np.empty(len(P), dtype=np.bool_)
    integrate_states_batch(rhs, switches, P, force, X0, s, contacts, x, dx, ok)
    return x, dx, ok


def second_order(accel, switches=None) -> tuple:
    """A one-coordinate model as a two-state model: ``(rhs, state_switches)`` compiled
    with the state signatures around its ``accel(theta, dtheta, force, p)`` and
    ``switches(theta, dtheta, force, p, g)`` (None: none). ``x = (theta, dtheta)``;
    a stick-slip model's contact is state 1. Compiled afresh in each process (a
    closure is not cached on disk)."""

    @njit(RHS_SIGNATURE, nogil=True)
    def rhs(x, force, p, dx):
        dx[0] = x[1]
        dx[1] = accel(x[0], x[1], force, p)

    if switches is None:
        return rhs, no_state_switches

    @njit(STATE_SWITCHES_SIGNATURE, nogil=True)
    def state_switches(x, force, p, g):
        switches(x[0], x[1], force, p, g)

    return rhs, state_switches
