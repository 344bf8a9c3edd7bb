"""A model on a vector of states, as a plant: :class:`StatePlant`.

An engineer's mechanism often has more than the handle's position and speed: an elastic
cable between the door and its spring (the cable's far end has a state of its own), a
soft-close damper whose fluid has a pressure, two bodies coupled by a spring. Its model
file gives a compiled right-hand side ``rhs(x, force, p, dx)`` on the state vector ``x``
(:mod:`evo_door.sim.states` states the contract) and says which two states are the
handle's position and speed (``Model.handle``). This module makes it a
:class:`~evo_door.sim.plant.Plant`:

- trials and populations run in the compiled state-vector integrators
  (:mod:`evo_door.sim.states`, :mod:`evo_door.sim.state_objective`), with the model's
  switching functions located in the step and stick-slip per contact;
- the initial state is the model's ``x0`` with the handle's entries replaced by the
  trial's start, then completed by the model's ``start(x, p)`` if it has one (an
  elastic element at rest, which depends on the parameters);
- the quasi-static force is a static equilibrium (:mod:`evo_door.sim.equilibrium`).
"""

from __future__ import annotations

import numpy as np

from evo_door.errors import UserError
from evo_door.params.sets import param_vector
from evo_door.sim.equilibrium import hold_states, hold_states_rows
from evo_door.sim.plant import CompiledPlant, StateLaw
from evo_door.sim.simulate import (
    Response,
    check_force,
    check_state,
    method_code,
)
from evo_door.sim.state_objective import population_errors_states
from evo_door.sim.states import (
    integrate_states,
    integrate_states_batch,
    no_state_switches,
    settings,
)
from evo_door.sim_settings import tolerance_of


class StatePlant(CompiledPlant):
    """The :class:`~evo_door.sim.plant.Plant` of a model given by ``rhs`` (``model``);
    the force at the handle is the equilibrium solve's."""

    def __init__(self, model) -> None:
        super().__init__(model)
        self.state_names = tuple(model.states)
        self.n_states = len(self.state_names)
        self.position, self.speed = (int(i) for i in model.handle)
        self.contacts = np.array(model.contacts, dtype=np.int64)
        self.switches = model.switches or no_state_switches
        self.n_switches = int(model.n_switches) if model.switches is not None else 0

    # -- the initial state ---------------------------------------------------------
    def initial_state(self, p, theta0=None, dtheta0=None) -> np.ndarray:
        """The state a trial starts from (see the module docstring)."""
        model = self.model
        x = np.zeros(self.n_states)
        if len(model.x0):
            x[:] = np.asarray(model.x0, dtype=np.float64)
        x[self.position] = model.theta0 if theta0 is None else float(theta0)
        x[self.speed] = 0.0 if dtheta0 is None else float(dtheta0)
        if model.start is not None:
            model.start(x, np.ascontiguousarray(p, dtype=np.float64))
        if not np.all(np.isfinite(x)):
            raise UserError(f"model {model.name!r}: its initial state is not finite: {x}")
        return x

    def _settings(self, dt, method, substeps, tolerance) -> np.ndarray:
        model = self.model
        return settings(
            None if dt is None else float(dt),
            int(substeps or model.substeps),
            method_code(method or model.method),
            tolerance_of(model, tolerance),
            self.n_switches,
        )

    # -- runs ------------------------------------------------------------------------
    def simulate(
        self, params, force, dt, theta0=None, dtheta0=None, t0=0.0, method=None,
        substeps=None, tolerance=None, state=None,
    ) -> Response:  # fmt: skip
        """One trial; the states besides the handle's are in ``Response.states``."""
        force = check_force(force, dt)
        p = param_vector(params, self.model.params)
        if state is not None:
            x0 = check_state(state, self.n_states, self.model.name)
        else:
            x0 = self.initial_state(p, theta0, dtheta0)
        n = force.size
        x_out = np.empty((self.n_states, n))
        dx_out = np.empty((self.n_states, n))
        ok = integrate_states(
            self.model.rhs, self.switches, p, force, x0,
            self._settings(dt, method, substeps, tolerance), self.contacts, x_out, dx_out,
        )  # fmt: skip
        i, j = self.position, self.speed
        others = {name: x_out[k] for k, name in enumerate(self.state_names) if k not in (i, j)}
        t = t0 + dt * np.arange(n)
        final = x_out[:, -1].copy()
        return Response(t, force, x_out[i], x_out[j], dx_out[j], bool(ok), others, final)

    def simulate_batch(
        self, P, force, dt, theta0=None, dtheta0=None, method=None, substeps=None,
        tolerance=None,
    ):  # fmt: skip
        """One input for every row of ``P``, in one compiled parallel call."""
        force = check_force(force, dt)
        P = np.ascontiguousarray(P, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != len(self.params):
            raise UserError(
                f"model {self.model.name!r}: parameter matrix must be (n, {len(self.params)})"
            )
        X0 = np.array([self.initial_state(p, theta0, dtheta0) for p in P])
        n_ind, n = P.shape[0], force.size
        x_out = np.empty((n_ind, self.n_states, n))
        dx_out = np.empty((n_ind, self.n_states, n))
        ok = np.zeros(n_ind, dtype=np.bool_)
        integrate_states_batch(
            self.model.rhs, self.switches, P, force, X0,
            self._settings(dt, method, substeps, tolerance), self.contacts, x_out, dx_out, ok,
        )  # fmt: skip
        i, j = self.position, self.speed
        return (
            np.ascontiguousarray(x_out[:, i]),
            np.ascontiguousarray(x_out[:, j]),
            np.ascontiguousarray(dx_out[:, j]),
            ok,
        )

    def population_errors(
        self, P, force, target, mask, offsets, dt, theta0, dtheta0, substeps, method, tol,
        derivative, kind, err_out, ok_out,
    ) -> None:  # fmt: skip
        """The compiled objective kernel on state vectors, every individual in one
        parallel call; where the initial state depends on the parameters (``start``),
        each individual's states are completed first (a ``start`` call per individual
        and trial, in Python: microseconds, against milliseconds for its trials)."""
        n_trials = offsets.size - 1

        def starts(p):
            return np.array([self.initial_state(p, theta0[j], dtheta0[j]) for j in range(n_trials)])

        setup = settings(None, int(substeps), int(method), float(tol), self.n_switches)
        if self.model.start is None:
            X0 = starts(P[0]) if P.shape[0] else np.zeros((n_trials, self.n_states))
        else:
            X0 = np.array([starts(p) for p in P]).reshape(P.shape[0], n_trials, self.n_states)
        population_errors_states(
            self.model.rhs, self.switches, np.ascontiguousarray(P), force, target, mask,
            offsets, dt, X0, setup, self.contacts, self.position,
            self.speed, derivative, kind, err_out, ok_out,
        )  # fmt: skip

    def state_law(self, what: str) -> StateLaw:
        """The model's rhs, contacts and initial state (for a loop of its own)."""
        return StateLaw(self.model.rhs, tuple(int(k) for k in self.contacts), self.initial_state)

    # -- the force at the handle -----------------------------------------------------
    def _hold(self, p, theta, dtheta) -> tuple[np.ndarray, np.ndarray]:
        theta = np.ascontiguousarray(np.atleast_1d(theta), dtype=np.float64)
        p = np.ascontiguousarray(p, dtype=np.float64)
        out = np.empty(theta.shape)
        slope = np.empty(theta.shape)
        if theta.size == 0:
            return out, slope
        x0 = self.initial_state(p, theta[0], dtheta)
        hold_states(
            self.model.rhs, p, theta, float(dtheta), x0, self.position, self.speed, out, slope
        )
        return out, slope

    def hold_forces(self, p, theta, dtheta) -> np.ndarray:
        """The force holding the handle at each ``theta`` (in order: each angle starts
        from the last one's equilibrium), the other states at rest."""
        return self._hold(p, theta, dtheta)[0]

    def _hold_rows(self, P, theta, dtheta) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_hold` of every row of ``P``, in one parallel compiled call."""
        P = np.ascontiguousarray(np.atleast_2d(P), dtype=np.float64)
        theta = np.ascontiguousarray(np.atleast_1d(theta), dtype=np.float64)
        out = np.empty((P.shape[0], theta.size))
        slope = np.empty((P.shape[0], theta.size))
        if theta.size == 0 or P.shape[0] == 0:
            return out, slope
        X0 = np.array([self.initial_state(p, theta[0], dtheta) for p in P])
        hold_states_rows(
            self.model.rhs, P, theta, float(dtheta), X0, self.position, self.speed, out, slope
        )
        return out, slope

    def hold_forces_rows(self, P, theta, dtheta) -> np.ndarray:
        """:meth:`hold_forces` of every row of ``P``, the rows in parallel."""
        return self._hold_rows(P, theta, dtheta)[0]

    def inertia_rows(self, P, theta, dtheta) -> np.ndarray:
        """The inertia felt at the handle at equilibrium: 1 / (d ddtheta / d force), the
        other states held; every row of ``P``, in parallel."""
        return 1.0 / self._hold_rows(P, theta, dtheta)[1]
