"""The objective kernel on state vectors: a population of a state model
(:mod:`evo_door.sim.states`) over every trial, reduced sample by sample.

The objectives are those of :mod:`evo_door.optim.kernels` (:data:`MAX_SQUARE`,
:data:`ISE`: the largest squared error, or ``dt`` times the trapezoid-weighted sum of
squared errors), on one signal of the simulated state against the target:
``derivative`` 0 reads the handle's coordinate ``x[position]``, 1 its speed
``x[speed]``, 2 the speed's rate ``dx[speed]`` (the acceleration, a stuck contact's
0 included). Samples whose ``mask`` is False do not count.

Trials are concatenated as there: ``force``, ``target`` and ``mask`` hold every trial
one after the other, trial ``j`` in ``offsets[j]:offsets[j + 1]``, at its own sample
period ``dt[j]`` from its own initial state: ``X0[j]`` (``(n_trials, n_states)``) for
every individual, or ``X0[i, j]`` (``(n_individuals, n_trials, n_states)``) where it
depends on the individual (a model whose ``start`` completes the state from the
parameters: an elastic element at rest).
The packed settings (:func:`evo_door.sim.states.settings`, built with ``dt=None``)
give everything else; their ``DT`` entry is not read.

Each trial of an individual is integrated by
:func:`evo_door.sim.states.integrate_trial`, what
:func:`evo_door.sim.states.integrate_states` runs, into arrays of the trial's length,
and its error computed from them: an individual's error is the one computed from that
function's output. The loop over individuals runs in
parallel; ``rhs`` and ``switches`` travel as first-class functions, so the kernel is
compiled once, cached on disk and shared by every state model.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange, types

from evo_door.sim.objective import accumulate
from evo_door.sim.states import RHS_TYPE, STATE_SWITCHES_TYPE, TRIAL_TYPE, integrate_trial
from evo_door.sim_settings import ISE, MAX_SQUARE

__all__ = ["ISE", "MAX_SQUARE", "population_errors_states", "trial_error_states"]

_vec = types.float64[::1]
_mat = types.float64[:, ::1]
_ivec = types.int64[::1]
_bvec = types.boolean[::1]
_bmat = types.boolean[:, ::1]
_cube = types.float64[:, :, ::1]


@njit(cache=True, nogil=True)
def trial_error_states(
    trial, rhs, switches, p, force, target, mask, start, stop, dt, x0, setup, contacts,
    position, speed, derivative, kind,
):  # fmt: skip
    """Objective of one trial (samples ``start:stop``) from the state ``x0`` at the
    sample period ``dt``, integrated by ``trial``
    (:func:`~evo_door.sim.states.integrate_trial`). Returns ``(error, ok)``; ``ok``
    False (and ``error`` inf) when the simulation blew up or the error is not finite."""
    n = stop - start
    x = np.empty((x0.shape[0], n))
    dx = np.empty((x0.shape[0], n))
    if not trial(rhs, switches, p, force[start:stop], x0, dt, setup, contacts, x, dx):
        return math.inf, False
    acc = 0.0
    for k in range(start, stop):
        if not mask[k]:
            continue
        if derivative == 0:
            y = x[position, k - start]
        elif derivative == 1:
            y = x[speed, k - start]
        else:
            y = dx[speed, k - start]
        acc = accumulate(acc, y - target[k], k, start, stop, dt, kind)
    if not math.isfinite(acc):
        return math.inf, False
    return acc, True


def population_errors_states(
    rhs, switches, P, force, target, mask, offsets, dt, X0, setup, contacts,
    position, speed, derivative, kind, err_out, ok_out,
):  # fmt: skip
    """Objective of every individual (rows of ``P``) on every trial into
    ``err_out[i, j]`` and ``ok_out[i, j]`` (the module docstring gives the packing of
    trials, of the initial states ``X0`` and of ``setup``); individuals in parallel."""
    X0 = np.asarray(X0, dtype=np.float64)
    if X0.ndim == 2:  # the same initial states for every individual
        X0 = np.repeat(X0[None], P.shape[0], axis=0)
    _population_errors_states(
        integrate_trial, rhs, switches, P, force, target, mask, offsets, dt,
        np.ascontiguousarray(X0), setup, contacts, position, speed, derivative, kind,
        err_out, ok_out,
    )  # fmt: skip


@njit(
    types.void(
        TRIAL_TYPE, RHS_TYPE, STATE_SWITCHES_TYPE, _mat, _vec, _vec, _bvec, _ivec, _vec, _cube,
        _vec, _ivec, types.int64, types.int64, types.int64, types.int64, _mat, _bmat,
    ),
    cache=True,
    parallel=True,
)  # fmt: skip
def _population_errors_states(
    trial, rhs, switches, P, force, target, mask, offsets, dt, X0, setup, contacts,
    position, speed, derivative, kind, err_out, ok_out,
):  # fmt: skip
    """:func:`population_errors_states` with :func:`~evo_door.sim.states.integrate_trial`
    as ``trial`` (called through a pointer, not linked in: see there)."""
    n_trials = offsets.shape[0] - 1
    for i in prange(P.shape[0]):
        for j in range(n_trials):
            e, ok = trial_error_states(
                trial, rhs, switches, P[i], force, target, mask, offsets[j], offsets[j + 1],
                dt[j], X0[i, j], setup, contacts, position, speed, derivative, kind,
            )  # fmt: skip
            err_out[i, j] = e
            ok_out[i, j] = ok
