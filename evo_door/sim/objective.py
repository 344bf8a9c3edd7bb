"""Compiled objective kernels: simulate a whole population over every trial and reduce.

What a plant's ``population_errors`` (:class:`~evo_door.sim.plant.Plant`) runs for a
model given by ``accel``; :func:`evo_door.optim.kernels.population_errors` is the entry
point of the layers above, for every kind of model.

The objectives of the seed (eq. 5.3 and 5.4), on the state derivative ``n``
(0 angle, 1 angular speed, 2 angular acceleration) of the simulated response
``y_s = d^n theta_s`` against the target ``y_h = d^n theta_h``, both sampled at the
trial's instants ``t_k = k dt``:

``max_square``  ``max_k (y_s[k] - y_h[k])^2``                            (eq. 5.3)
``ise``         ``dt * sum_k w_k (y_s[k] - y_h[k])^2``, trapezoid weights
                ``w_0 = w_{N-1} = 1/2``, else 1: the integral of eq. 5.4.

Samples whose ``mask`` is False are left out of both (a saturated sensor sample says
only that the true value is beyond the range; see ``Trial.unsaturated``).

Each trial of an individual is integrated by
:func:`evo_door.sim.integrators.integrate_compiled`, what :func:`evo_door.sim.simulate`
runs, into arrays of the trial's length, and reduced from them: the error of one
individual is the one computed from :func:`evo_door.sim.simulate`'s output.
The integrator is compiled once and called here through a pointer
(:data:`~evo_door.sim.integrators.INTEGRATE_TYPE`), once a trial: neither compiled again
into this kernel nor optimised again with it (it is most of the compile time). The
acceleration inside a step over several periods is computed only for ``derivative`` 2.

Trials are passed concatenated: ``force`` and ``target`` hold every trial one after
the other, trial ``j`` occupying ``offsets[j]:offsets[j + 1]``, with its own sample
period ``dt[j]`` and initial state ``theta0[j], dtheta0[j]``.

:func:`accel_population_errors` takes the model's ``accel``; the compiled kernels behind it
take it as a numba first-class function (:data:`~evo_door.sim.integrators.ACCEL_TYPE`)
with an explicit signature, so they are compiled once, cached on disk and shared by
every model and every process; the loop over individuals runs in parallel
(``prange``). A model with a fast form (:func:`~evo_door.sim.integrators.prepared_form`,
the door's pose table) runs it: each individual's parameters are prepared once, inside
the parallel loop, and serve all its trials.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange, types

from evo_door.sim.integrators import (
    ACCEL_TYPE,
    INTEGRATE_TYPE,
    PREPARE_TYPE,
    ROW_BLOCKS,
    integrate_compiled,
    kernel_form,
    scratch,
)
from evo_door.sim.located import SWITCHES_TYPE
from evo_door.sim.simulate import events_of
from evo_door.sim_settings import MAX_SQUARE

_vec = types.float64[::1]
_mat = types.float64[:, ::1]
_ivec = types.int64[::1]
_bmat = types.boolean[:, ::1]
_bvec = types.boolean[::1]


@njit(cache=True, nogil=True)
def accumulate(acc, e, k, start, stop, dt, kind):
    """The objective so far, ``acc``, with the error ``e`` of sample ``k`` of the trial
    ``start:stop`` added: the largest square, or the trapezoid sum of squares (the
    trial's ends weighted 1/2) times the sample period ``dt``."""
    if kind == MAX_SQUARE:
        if e * e > acc or not math.isfinite(e):
            return e * e
        return acc
    if k == start or k == stop - 1:
        return acc + 0.5 * dt * e * e
    return acc + dt * e * e


@njit(cache=True, nogil=True)
def sample_value(theta, dtheta, ddtheta, derivative):
    """What the objective compares at a sample: angle, speed or acceleration."""
    if derivative == 0:
        return theta
    if derivative == 1:
        return dtheta
    return ddtheta


@njit(cache=True, nogil=True)
def trial_error(
    trial,
    accel,
    switches,
    p,
    force,
    target,
    mask,
    start,
    stop,
    dt,
    substeps,
    theta0,
    dtheta0,
    method,
    tol,
    n_sw,
    stick,
    derivative,
    kind,
    g,
    th_s,
    w_s,
):
    """Objective of one trial (samples ``start:stop`` of ``force`` / ``target`` / ``mask``).

    ``trial`` is :func:`~evo_door.sim.integrators.integrate_compiled`, ``g``, ``th_s``
    and ``w_s`` its scratch (:func:`~evo_door.sim.integrators.scratch`). Samples where
    ``mask`` is False (a saturated sensor, say) do not count.
    Returns ``(error, ok)``; ``ok`` is False (and ``error`` is inf) when the
    simulation blew up or the error is not finite.
    """
    n = stop - start
    theta = np.empty(n)
    dtheta = np.empty(n)
    ddtheta = np.empty(n)
    if not trial(
        accel, switches, p, force[start:stop], dt, substeps, theta0, dtheta0, method, tol,
        n_sw, stick, theta, dtheta, ddtheta, derivative == 2, g, th_s, w_s,
    ):  # fmt: skip
        return math.inf, False
    acc = 0.0
    for k in range(start, stop):
        if mask[k]:
            y = sample_value(theta[k - start], dtheta[k - start], ddtheta[k - start], derivative)
            acc = accumulate(acc, y - target[k], k, start, stop, dt, kind)
    if not math.isfinite(acc):
        return math.inf, False
    return acc, True


def accel_population_errors(
    model,
    P,
    force,
    target,
    mask,
    offsets,
    dt,
    theta0,
    dtheta0,
    substeps,
    method,
    tol,
    derivative,
    kind,
    err_out,
    ok_out,
):
    """Objective of every individual (rows of ``P``) on every trial, for a model given
    by ``accel`` (an :class:`~evo_door.sim.accel_plant.AccelPlant`).

    Fills ``err_out[i, j]`` and ``ok_out[i, j]`` for individual ``i`` and trial ``j``
    (see the module docstring for the packing of trials). ``model`` gives the
    right-hand side, its switching surfaces and friction law; where the right-hand
    side has a fast form, that runs (the errors are those of
    :func:`evo_door.sim.simulate`, which runs it too). ``tol``: ``dopri5``'s tolerance.
    """
    form = kernel_form(model.accel, P.shape[1])
    switches, n_sw, stick = events_of(model, form)
    _population_errors(
        integrate_compiled, form.accel, form.prepare, switches, form.size, P, force, target,
        mask, offsets, dt, theta0, dtheta0, substeps, method, tol, n_sw, stick, derivative,
        kind, err_out, ok_out,
    )  # fmt: skip


@njit(
    types.void(
        INTEGRATE_TYPE,
        ACCEL_TYPE,
        PREPARE_TYPE,
        SWITCHES_TYPE,
        types.int64,
        _mat,
        _vec,
        _vec,
        _bvec,
        _ivec,
        _vec,
        _vec,
        _vec,
        types.int64,
        types.int64,
        types.float64,
        types.int64,
        types.boolean,
        types.int64,
        types.int64,
        _mat,
        _bmat,
    ),
    cache=True,
    parallel=True,
)
def _population_errors(
    trial,
    accel,
    prepare,
    switches,
    size,
    P,
    force,
    target,
    mask,
    offsets,
    dt,
    theta0,
    dtheta0,
    substeps,
    method,
    tol,
    n_sw,
    stick,
    derivative,
    kind,
    err_out,
    ok_out,
):
    """:func:`accel_population_errors` on a :func:`~evo_door.sim.integrators.kernel_form`:
    each row of ``P`` is prepared (``prepare`` into ``size`` floats) once and serves
    every trial. The rows go to the threads in
    :data:`~evo_door.sim.integrators.ROW_BLOCKS` blocks, each block's rows prepared into
    one vector: what a row shares with the last (the door's pose table, where the
    geometry is not free) is kept, not made again."""
    n_trials = offsets.shape[0] - 1
    rows = P.shape[0]
    for b in prange(ROW_BLOCKS):
        p = np.empty(size)
        g, th_s, w_s = scratch(n_sw)
        for i in range(b * rows // ROW_BLOCKS, (b + 1) * rows // ROW_BLOCKS):
            prepare(P[i], p)
            for j in range(n_trials):
                e, ok = trial_error(
                    trial, accel, switches, p, force, target, mask, offsets[j],
                    offsets[j + 1], dt[j], substeps, theta0[j], dtheta0[j], method, tol,
                    n_sw, stick, derivative, kind, g, th_s, w_s,
                )  # fmt: skip
                err_out[i, j] = e
                ok_out[i, j] = ok
