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
period ``dt[j]`` from its own initial state ``X0[j]`` (``(n_trials, n_states)``).
The packed settings (:func:`evo_door.sim.states.settings`, built with ``dt=None``)
give everything else; their ``DT`` entry is not read.

The response is reduced while it is integrated (nothing of a trial's size is stored
per individual), with the same periods, rates and blow-up test as
:func:`evo_door.sim.states.integrate_states`, so an individual's error equals the one
computed from that function's output to rounding. The loop over individuals runs in
parallel; ``rhs`` and ``switches`` travel as first-class functions, so the kernel is
compiled once, cached on disk and shared by every state model.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange, types

from evo_door.sim.objective import accumulate
from evo_door.sim.state_located import period
from evo_door.sim.state_steps import R, Y, sample_rate, workspace
from evo_door.sim.states import (
    METHOD,
    N_SWITCHES,
    RHS_TYPE,
    STATE_SWITCHES_TYPE,
    SUBSTEPS,
    TOLERANCE,
    blown_up,
)
from evo_door.sim_settings import ISE, MAX_SQUARE

__all__ = ["ISE", "MAX_SQUARE", "population_errors_states", "trial_error_states"]

_vec = types.float64[::1]
_mat = types.float64[:, ::1]
_ivec = types.int64[::1]
_bvec = types.boolean[::1]
_bmat = types.boolean[:, ::1]


@njit(cache=True, nogil=True)
def trial_error_states(
    rhs, switches, p, force, target, mask, start, stop, dt, x0, setup, contacts,
    position, speed, derivative, kind, ws,
):  # fmt: skip
    """Objective of one trial (samples ``start:stop``) from the state ``x0`` at the
    sample period ``dt``; ``ws`` the scratch arrays of
    :func:`~evo_door.sim.state_steps.workspace`. Returns ``(error, ok)``; ``ok`` False
    (and ``error`` inf) when the simulation blew up or the error is not finite."""
    W, G, JM, piv, modes = ws
    substeps = int(setup[SUBSTEPS])
    method = int(setup[METHOD])
    tol = setup[TOLERANCE]
    n_sw = int(setup[N_SWITCHES])
    x = x0.copy()
    dx = np.empty(x.shape[0])
    sample_rate(rhs, p, x, force[start], contacts, dx, W[Y], W[R])
    acc = 0.0
    for k in range(start, stop):
        if k > start:
            period(
                rhs, switches, p, x, force[k - 1], force[k], dx, dt, substeps, method, tol,
                n_sw, contacts, W, G, JM, piv, modes,
            )  # fmt: skip
            if blown_up(x):
                return math.inf, False
            sample_rate(rhs, p, x, force[k], contacts, dx, W[Y], W[R])
        if not mask[k]:
            continue
        if derivative == 0:
            y = x[position]
        elif derivative == 1:
            y = x[speed]
        else:
            y = dx[speed]
        acc = accumulate(acc, y - target[k], k, start, stop, dt, kind)
    if not math.isfinite(acc):
        return math.inf, False
    return acc, True


@njit(
    types.void(
        RHS_TYPE, STATE_SWITCHES_TYPE, _mat, _vec, _vec, _bvec, _ivec, _vec, _mat, _vec,
        _ivec, types.int64, types.int64, types.int64, types.int64, _mat, _bmat,
    ),
    cache=True,
    parallel=True,
)  # fmt: skip
def population_errors_states(
    rhs, switches, P, force, target, mask, offsets, dt, X0, setup, contacts,
    position, speed, derivative, kind, err_out, ok_out,
):  # fmt: skip
    """Objective of every individual (rows of ``P``) on every trial into
    ``err_out[i, j]`` and ``ok_out[i, j]`` (the module docstring gives the packing of
    trials and ``setup``); individuals in parallel, one set of scratch arrays each."""
    n_trials = offsets.shape[0] - 1
    n = X0.shape[1]
    n_sw = int(setup[N_SWITCHES])
    for i in prange(P.shape[0]):
        ws = workspace(n, n_sw + contacts.shape[0], contacts.shape[0])
        for j in range(n_trials):
            e, ok = trial_error_states(
                rhs, switches, P[i], force, target, mask, offsets[j], offsets[j + 1], dt[j],
                X0[j], setup, contacts, position, speed, derivative, kind, ws,
            )  # fmt: skip
            err_out[i, j] = e
            ok_out[i, j] = ok
