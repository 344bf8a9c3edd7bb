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

The response is reduced sample by sample while it is integrated, so nothing of the
size of a trial is stored per individual. The stepping is the same as
:func:`evo_door.sim.integrators.integrate` (same steps, same force interpolation, same
blow-up test), so the error of one individual equals the error computed from
:func:`evo_door.sim.simulate` output to rounding.

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
    BLOWUP_SPEED,
    PREPARE_TYPE,
    kernel_form,
    step_period,
    try_span,
)
from evo_door.sim.located import SWITCHES_TYPE, rate
from evo_door.sim.simulate import events_of
from evo_door.sim.spans import MAX_SPAN, MIN_SPAN
from evo_door.sim_settings import DOPRI5, MAX_SQUARE

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
    g,
    derivative,
    kind,
):
    """Objective of one trial (samples ``start:stop`` of ``force`` / ``target`` / ``mask``).

    Samples where ``mask`` is False (a saturated sensor, say) do not count.
    Returns ``(error, ok)``; ``ok`` is False (and ``error`` is inf) when the
    simulation blew up or the error is not finite.
    """
    theta = theta0
    dtheta = dtheta0
    a_now = rate(accel, p, theta, dtheta, force[start], stick)
    skip, backoff = 0, 1
    spans = method == DOPRI5 and substeps == 1  # steps over several periods (try_span)
    th_s = np.empty(MAX_SPAN + 1)
    w_s = np.empty(MAX_SPAN + 1)
    span, wait, patience = MIN_SPAN, 0, 1
    if spans:
        switches(theta, dtheta, force[start], p, g[0])
    acc = 0.0
    if mask[start]:
        y = sample_value(theta, dtheta, a_now, derivative)
        acc = accumulate(acc, y - target[start], start, start, stop, dt, kind)
    k = start
    while k < stop - 1:
        m = 0
        if spans:
            m, a_end, span, wait, patience = try_span(
                accel, switches, p, theta, dtheta, a_now, force, k, stop, dt, tol, n_sw, stick,
                g[0], g[1], span, wait, patience, th_s, w_s,
            )  # fmt: skip
        if m > 0:
            for j in range(1, m):
                if mask[k + j]:
                    a_j = 0.0
                    if derivative == 2:
                        a_j = rate(accel, p, th_s[j], w_s[j], force[k + j], stick)
                    y = sample_value(th_s[j], w_s[j], a_j, derivative)
                    acc = accumulate(acc, y - target[k + j], k + j, start, stop, dt, kind)
            theta, dtheta, a_now = th_s[m], w_s[m], a_end
        else:
            m = 1
            theta, dtheta, a_end, a_ok, skip, backoff = step_period(
                accel, switches, p, theta, dtheta, force[k], force[k + 1], a_now,
                k > start or spans, dt, substeps, method, tol, n_sw, stick, g, skip, backoff,
            )  # fmt: skip
        if not (math.isfinite(theta) and abs(dtheta) < BLOWUP_SPEED):
            return math.inf, False
        k += m
        if m == 1:
            a_now = a_end if a_ok else rate(accel, p, theta, dtheta, force[k], stick)
        if mask[k]:
            y = sample_value(theta, dtheta, a_now, derivative)
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
    switches, n_sw, stick = events_of(model)
    _population_errors(
        form.accel, form.prepare, switches, form.size, P, force, target, mask, offsets, dt,
        theta0, dtheta0, substeps, method, tol, n_sw, stick, derivative, kind, err_out, ok_out,
    )  # fmt: skip


@njit(
    types.void(
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
    every trial."""
    n_trials = offsets.shape[0] - 1
    for i in prange(P.shape[0]):
        p = np.empty(size)
        prepare(P[i], p)
        g = np.empty((4, max(n_sw, 1)))
        for j in range(n_trials):
            e, ok = trial_error(
                accel,
                switches,
                p,
                force,
                target,
                mask,
                offsets[j],
                offsets[j + 1],
                dt[j],
                substeps,
                theta0[j],
                dtheta0[j],
                method,
                tol,
                n_sw,
                stick,
                g,
                derivative,
                kind,
            )
            err_out[i, j] = e
            ok_out[i, j] = ok
