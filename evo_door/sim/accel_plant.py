"""A model given by one compiled ``accel(theta, dtheta, force, p)``, as a plant.

The bundled door and haptic model, and any model file that declares an ``accel``, are one
coordinate: the state is ``(theta, dtheta)`` and the model gives the acceleration. This
module is their :class:`~evo_door.sim.plant.Plant`: the compiled integrators of
:mod:`.integrators` (with the model's fast form where it registered one), the objective
kernels of :mod:`.objective`, and the quasi-static force from ``accel`` being affine in
the force, ``F = -a(F=0) / (a(F=1) - a(F=0))``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange, types

from evo_door.errors import UserError
from evo_door.params.sets import param_vector
from evo_door.sim.hold import HOLD_TYPE, hold_form, hold_rows_form
from evo_door.sim.integrators import (
    ACCEL_TYPE,
    integrate,
    integrate_batch,
    integrate_compiled,
    kernel_form,
    prepared_form,
)
from evo_door.sim.objective import accel_population_errors
from evo_door.sim.plant import CompiledPlant
from evo_door.sim.simulate import (
    Response,
    check_force,
    check_state,
    events_of,
    method_code,
)
from evo_door.sim_settings import tolerance_of

#: rows below which the inertia kernel runs on one thread (threads cost more than they give)
ROWS_IN_THREADS = 8
#: rows x angles from which the hold-force kernels share them across threads (one door's
#: force-angle curve for the perceptual objective is some 3000 angles)
HOLDS_IN_THREADS = 1024

_vec = types.float64[::1]
_mat = types.float64[:, ::1]


@njit(cache=True, nogil=True, inline="always")
def _hold(accel, p, theta, dtheta):
    """Force (N) holding ddtheta = 0 at (theta, dtheta): accel is affine in the force."""
    a0 = accel(theta, dtheta, 0.0, p)
    a1 = accel(theta, dtheta, 1.0, p)
    return -a0 / (a1 - a0)


_ROWS_SIGNATURE = types.void(ACCEL_TYPE, _mat, _vec, types.float64, _mat)
_HELD_SIGNATURE = types.void(HOLD_TYPE, _mat, _vec, types.float64, _mat)


# The hold-force kernels: one loop over every (row, angle) pair, so that the angles of one
# door are shared across threads as well as many doors; by ``accel`` (any model) or by a
# registered ``hold`` (the door's: the same numbers, its mechanism computed once).
@njit(_ROWS_SIGNATURE, cache=True, parallel=True)
def _hold_rows(accel, P, theta, dtheta, out):
    n = theta.shape[0]
    for k in prange(P.shape[0] * n):
        r = k // n
        out[r, k - r * n] = _hold(accel, P[r], theta[k - r * n], dtheta)


@njit(_ROWS_SIGNATURE, cache=True, nogil=True)
def _hold_rows_serial(accel, P, theta, dtheta, out):
    for r in range(P.shape[0]):
        for i in range(theta.shape[0]):
            out[r, i] = _hold(accel, P[r], theta[i], dtheta)


@njit(_HELD_SIGNATURE, cache=True, parallel=True)
def _held_rows(hold, P, theta, dtheta, out):
    n = theta.shape[0]
    for k in prange(P.shape[0] * n):
        r = k // n
        out[r, k - r * n] = hold(theta[k - r * n], dtheta, P[r])


@njit(_HELD_SIGNATURE, cache=True, nogil=True)
def _held_rows_serial(hold, P, theta, dtheta, out):
    for r in range(P.shape[0]):
        for i in range(theta.shape[0]):
            out[r, i] = hold(theta[i], dtheta, P[r])


# The same, each row at angles of its own (a row of ``theta``): a latch peak refined
# around where each door's coarse search found it.
_AT_SIGNATURE = types.void(HOLD_TYPE, _mat, _mat, types.float64, _mat)


@njit(_AT_SIGNATURE, cache=True, parallel=True)
def _held_at(hold, P, theta, dtheta, out):
    n = theta.shape[1]
    for k in prange(P.shape[0] * n):
        r = k // n
        out[r, k - r * n] = hold(theta[r, k - r * n], dtheta, P[r])


@njit(_AT_SIGNATURE, cache=True, nogil=True)
def _held_at_serial(hold, P, theta, dtheta, out):
    for r in range(P.shape[0]):
        for i in range(theta.shape[1]):
            out[r, i] = hold(theta[r, i], dtheta, P[r])


@njit(_ROWS_SIGNATURE, cache=True, parallel=True)
def _inertia_rows(accel, P, theta, dtheta, out):
    for r in prange(P.shape[0]):
        for i in range(theta.shape[0]):
            a0 = accel(theta[i], dtheta, 0.0, P[r])
            a1 = accel(theta[i], dtheta, 1.0, P[r])
            out[r, i] = 1.0 / (a1 - a0)


@njit(_ROWS_SIGNATURE, cache=True, nogil=True)
def _inertia_rows_serial(accel, P, theta, dtheta, out):
    for r in range(P.shape[0]):
        for i in range(theta.shape[0]):
            a0 = accel(theta[i], dtheta, 0.0, P[r])
            a1 = accel(theta[i], dtheta, 1.0, P[r])
            out[r, i] = 1.0 / (a1 - a0)


def _kernel_array(a) -> np.ndarray:
    """``a`` as the kernels' signatures take it: C-contiguous, float64, writable (a
    parameter set's own vector is read-only, a type of its own to numba)."""
    return np.require(a, np.float64, ["C", "W"])


class AccelPlant(CompiledPlant):
    """The :class:`~evo_door.sim.plant.Plant` of a model given by ``accel`` (``model``:
    its :class:`~evo_door.models.Model`, or anything with the same attributes)."""

    n_states = 2
    position = 0
    speed = 1
    state_names: tuple[str, ...] = ("theta", "dtheta")

    def simulate(
        self, params, force, dt, theta0=None, dtheta0=None, t0=0.0, method=None,
        substeps=None, tolerance=None, state=None,
    ) -> Response:  # fmt: skip
        """One trial (:meth:`~evo_door.sim.plant.Plant.simulate`)."""
        model = self.model
        force = check_force(force, dt)
        if state is not None:
            theta0, dtheta0 = check_state(state, 2, model.name)
        p = param_vector(params, model.params)
        theta0 = model.theta0 if theta0 is None else float(theta0)
        dtheta0 = 0.0 if dtheta0 is None else float(dtheta0)
        n = force.size
        t = t0 + dt * np.arange(n)
        out = np.empty((3, n))
        accel = model.accel
        fast = prepared_form(accel)
        switches, n_sw, stick = events_of(model, fast)
        if fast is not None:
            accel, p = fast.accel, self._prepared(fast, p)
        ok = integrate(
            accel, switches, p, force, float(dt), int(substeps or model.substeps), theta0,
            dtheta0, method_code(method or model.method), tolerance_of(model, tolerance),
            n_sw, stick, out[0], out[1], out[2],
        )  # fmt: skip
        final = np.array([out[0, -1], out[1, -1]])
        return Response(t, force, out[0], out[1], out[2], bool(ok), final=final)

    def _prepared(self, fast, p) -> np.ndarray:
        """The prepared vector of ``p``: the last one again when ``p`` is the last's (a
        closed-loop rig trial simulates a few samples at a time with one parameter set,
        where each call prepared the door's pose table afresh). One entry,
        replaced whole, so that threads sharing the plant read a matching pair; the
        kernels only read it. ``fast`` is the model's, fixed with the model."""
        key = p.tobytes()
        last = getattr(self, "_last_prepared", None)
        if last is not None and last[0] == key:
            return last[1]
        q = fast.vector(p)
        self._last_prepared = (key, q)
        return q

    def simulate_batch(
        self, P, force, dt, theta0=None, dtheta0=None, method=None, substeps=None,
        tolerance=None,
    ):  # fmt: skip
        """One input for every row of ``P``, in one compiled parallel call; a model
        with a fast form is prepared row by row inside the compiled loop."""
        model = self.model
        force = check_force(force, dt)
        P = np.ascontiguousarray(P, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != len(model.params):
            raise UserError(
                f"model {model.name!r}: parameter matrix must be (n, {len(model.params)})"
            )
        theta0 = model.theta0 if theta0 is None else float(theta0)
        dtheta0 = 0.0 if dtheta0 is None else float(dtheta0)
        n_ind, n = P.shape[0], force.size
        theta, dtheta, ddtheta = (np.empty((n_ind, n)) for _ in range(3))
        ok = np.zeros(n_ind, dtype=np.bool_)
        form = kernel_form(model.accel, P.shape[1])
        switches, n_sw, stick = events_of(model, form)
        integrate_batch(
            integrate_compiled, form.accel, form.prepare, switches, form.size, P, force, float(dt),
            int(substeps or model.substeps), theta0, dtheta0,
            method_code(method or model.method), tolerance_of(model, tolerance), n_sw, stick,
            theta, dtheta, ddtheta, ok,
        )  # fmt: skip
        return theta, dtheta, ddtheta, ok

    def population_errors(
        self, P, force, target, mask, offsets, dt, theta0, dtheta0, substeps, method, tol,
        derivative, kind, err_out, ok_out,
    ) -> None:  # fmt: skip
        """The compiled objective kernels of :mod:`.objective`."""
        accel_population_errors(
            self.model, P, force, target, mask, offsets, dt, theta0, dtheta0, substeps,
            method, tol, derivative, kind, err_out, ok_out,
        )  # fmt: skip

    def hold_forces(self, p, theta, dtheta) -> np.ndarray:
        """Force (N, + toward closing) holding ``ddtheta = 0`` at every ``theta``, in one
        compiled (for many angles, multi-threaded) call."""
        return self.hold_forces_rows(np.atleast_2d(p), theta, dtheta)[0]

    def hold_forces_rows(self, P, theta, dtheta) -> np.ndarray:
        """:meth:`hold_forces` of every row of ``P``, across threads when there are
        many rows or angles; by the model's registered ``hold_rows`` where it has one
        that takes these rows, else its registered ``hold`` (:mod:`evo_door.sim.hold`),
        else by ``accel``."""
        P = _kernel_array(np.atleast_2d(P))
        theta = _kernel_array(np.atleast_1d(theta))
        out = np.empty((P.shape[0], theta.size))
        many = out.size >= HOLDS_IN_THREADS
        rows = hold_rows_form(self.model.accel) if many else None
        if rows is not None and rows(P, theta, float(dtheta), out):
            return out  # the model shared work between the rows (the door's pose)
        hold = hold_form(self.model.accel)
        if hold is not None:
            (_held_rows if many else _held_rows_serial)(hold, P, theta, float(dtheta), out)
        else:
            kernel = _hold_rows if many else _hold_rows_serial
            kernel(self.model.accel, P, theta, float(dtheta), out)
        return out

    def hold_forces_at(self, P, theta, dtheta) -> np.ndarray:
        """:meth:`hold_forces_rows` with each row of ``P`` at the angles of the same row
        of ``theta`` (rows, angles), for a model with a registered ``hold``; else each
        row by :meth:`hold_forces_rows`. A door's force at an angle depends on nothing
        else, so any subset of a grid gives what the whole grid gives there."""
        P = _kernel_array(np.atleast_2d(P))
        theta = _kernel_array(np.atleast_2d(theta))
        hold = hold_form(self.model.accel)
        if hold is None:
            return np.array(
                [self.hold_forces_rows(p[None], t, dtheta)[0] for p, t in zip(P, theta)]
            )
        out = np.empty(theta.shape)
        kernel = _held_at if out.size >= HOLDS_IN_THREADS else _held_at_serial
        kernel(hold, P, theta, float(dtheta), out)
        return out

    def inertia_rows(self, P, theta, dtheta) -> np.ndarray:
        """Felt inertia: ``accel`` is affine in the force, its slope is 1 / inertia."""
        P = _kernel_array(np.atleast_2d(P))
        theta = _kernel_array(np.atleast_1d(theta))
        out = np.empty((P.shape[0], theta.size))
        kernel = _inertia_rows if P.shape[0] >= ROWS_IN_THREADS else _inertia_rows_serial
        kernel(self.model.accel, P, theta, float(dtheta), out)
        return out
