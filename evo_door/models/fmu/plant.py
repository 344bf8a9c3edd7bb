"""An FMU as a :class:`~evo_door.sim.plant.Plant`: the FMU runs itself.

It integrates its own equations (:class:`~evo_door.models.fmu.model.FmuRunner`), so the
plant hands every run to the runner. It is ``contained``: a fit runs it in a sandbox
process (:mod:`evo_door.optim.sandbox`), since its native code may crash or hang. What
needs the force at the handle at any state (the force-angle curve) it gives where the
runner can (a model-exchange FMU whose states are the angle and the speed), else refuses
in one line; the perceptual objective and the tolerances, which need the felt inertia
too, are refused.
"""

from __future__ import annotations

from typing import NoReturn

import numpy as np

from evo_door.errors import UserError
from evo_door.params import ParamTable
from evo_door.params.sets import param_vector
from evo_door.sim.simulate import Response, check_force, check_state


class FmuPlant:
    """The plant of an :class:`~evo_door.models.fmu.model.FmuModel` (``model``)."""

    n_states = 2
    position = 0
    speed = 1
    state_names: tuple[str, ...] = ("theta", "dtheta")
    contained = True

    def __init__(self, model) -> None:
        self.model = model
        self.runner = model.runner

    @property
    def params(self) -> ParamTable:
        return self.model.params

    def prepare(self) -> None:
        """Load the FMU and its kernels in this process, running no trial."""
        self.runner.prepare()

    def check_ready(self) -> None:
        """Refuse an FMU whose variables do not match the handle's channels."""
        self.model.info.check_channels()

    def not_a_parameter(self, name: str) -> str:
        """Why the FMU's variable ``name`` cannot be set, or "" if it has none."""
        info = self.model.info
        var = next((v for v in info.description.modelVariables if v.name == name), None)
        if var is None:
            return ""
        return (
            f"{name!r} of FMU {info.path.name} cannot be set (causality {var.causality}, "
            f"variability {var.variability}, type {var.type}): only real parameters "
            "(causality parameter, fixed or tunable) can be fitted"
        )

    def check_start(self, theta0, dtheta0, where: str = "") -> None:
        """Refuse an initial state the FMU cannot be given (one line naming ``where``)."""
        self.runner.check_start(theta0, dtheta0, where)

    def simulate(
        self, params, force, dt, theta0=None, dtheta0=None, t0=0.0, method=None,
        substeps=None, tolerance=None, state=None,
    ) -> Response:  # fmt: skip
        """One run of the FMU (``method`` and ``tolerance`` are the FMU's own; a
        ``state`` sets the handle's position and speed); ``theta0`` / ``dtheta0`` None:
        the FMU's own start values."""
        force = check_force(force, dt)
        if state is not None:
            theta0, dtheta0 = check_state(state, 2, self.model.name)
        p = param_vector(params, self.model.params)
        theta0 = None if theta0 is None else float(theta0)
        dtheta0 = None if dtheta0 is None else float(dtheta0)
        steps = int(substeps or self.model.substeps)
        t = t0 + dt * np.arange(force.size)
        th, w, a, ok = self.runner.simulate(p, force, float(dt), theta0, dtheta0, t0, steps)
        return Response(t, force, th, w, a, bool(ok), final=np.array([th[-1], w[-1]]))

    def simulate_batch(
        self, P, force, dt, theta0=None, dtheta0=None, method=None, substeps=None,
        tolerance=None,
    ):  # fmt: skip
        """One run per row of ``P`` (an FMU instance is not shared between threads)."""
        force = check_force(force, dt)
        P = np.ascontiguousarray(np.atleast_2d(P), dtype=np.float64)
        n_ind, n = P.shape[0], force.size
        theta, dtheta, ddtheta = (np.empty((n_ind, n)) for _ in range(3))
        ok = np.zeros(n_ind, dtype=np.bool_)
        for i, p in enumerate(P):
            r = self.simulate(p, force, dt, theta0, dtheta0, substeps=substeps)
            theta[i], dtheta[i], ddtheta[i], ok[i] = r.theta, r.dtheta, r.ddtheta, r.ok
        return theta, dtheta, ddtheta, ok

    def population_errors(
        self, P, force, target, mask, offsets, dt, theta0, dtheta0, substeps, method, tol,
        derivative, kind, err_out, ok_out,
    ) -> None:  # fmt: skip
        """The runner's own loop (the FMU's own method and tolerance)."""
        self.runner.population_errors(
            P, force, target, mask, offsets, dt, theta0, dtheta0, substeps, derivative,
            kind, err_out, ok_out,
        )  # fmt: skip

    def _refuse(self, what: str) -> NoReturn:
        raise UserError(
            f"model {self.model.name!r} is an FMU: {what} needs the model's acceleration "
            "at any state, which an FMU gives only along a simulation"
        )

    def check_curve(self, what: str) -> None:
        """Refused (the perceptual objective, the tolerances: they need the felt inertia
        too, and run inside a fit's compiled loops): see :meth:`_refuse`."""
        self._refuse(what)

    def state_law(self, what: str) -> NoReturn:
        """Refused: an FMU gives no compiled right-hand side (see :meth:`_refuse`)."""
        self._refuse(what)

    def hold_forces(self, p, theta, dtheta) -> np.ndarray:
        """The force that holds the door at each ``theta`` moving at ``dtheta``, from the
        FMU's derivatives with its states set there (a model-exchange FMU whose states
        are the angle and the speed: :meth:`FmuRunner.hold_force`), else refused in one
        line saying why."""
        return self.runner.hold_force(p, theta, float(dtheta))

    def hold_forces_rows(self, P, theta, dtheta) -> np.ndarray:
        """:meth:`hold_forces` of every row of ``P``."""
        P = np.atleast_2d(np.asarray(P, dtype=np.float64))
        return np.array([self.hold_forces(p, theta, dtheta) for p in P])

    def inertia_rows(self, P, theta, dtheta) -> np.ndarray:
        """Refused: see :meth:`_refuse`."""
        self._refuse("the felt inertia")
