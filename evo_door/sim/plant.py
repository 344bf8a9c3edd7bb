"""The one contract every kind of model offers the layers above: :class:`Plant`.

A *plant* is what the simulator, the objective kernels, the force-angle curve, the
perceptual objective and the GA's sandbox need of a model, whatever computes it:

- :class:`~evo_door.sim.accel_plant.AccelPlant`: a one-coordinate model given by a
  compiled ``accel(theta, dtheta, force, p)`` (the bundled door and haptic model);
- :class:`~evo_door.sim.state_plant.StatePlant`: a model on a vector of states given by a
  compiled right-hand side ``rhs(x, force, p, dx)`` (an engineer's own mechanism with
  an elastic cable, a soft-close damper's fluid, two coupled bodies);
- an FMU (:mod:`evo_door.models.fmu`), which runs itself.

Every model has one: ``model.plant``. The layers above call its methods and never ask
which kind a model is.

The state is a vector of ``n_states`` floats named ``state_names``; the user's hand holds
the coordinate ``x[position]`` (``theta``, in the model's ``theta_unit``) whose speed is
``x[speed]`` (``dtheta``). The force is the user's, at the handle, + toward closing (N).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from evo_door.errors import UserError
from evo_door.params import ParamTable
from evo_door.sim.simulate import Response


@dataclass(frozen=True)
class StateLaw:
    """What a loop that integrates a state-vector model itself needs of it: the compiled
    ``rhs(x, force, p, dx)`` (:mod:`evo_door.sim.states`' contract: affine in the
    force), the speed states of its sign-law contacts, and ``initial_state(p, theta0,
    dtheta0)``, the whole state vector with the handle's entries set (the other states
    at their start)."""

    rhs: Callable
    contacts: tuple[int, ...]
    initial_state: Callable[..., np.ndarray]


@runtime_checkable
class Plant(Protocol):
    """What every kind of model offers (see the module docstring).

    Attributes
    ----------
    params : ParamTable
        The model's declaration; parameter vectors follow its order.
    n_states, position, speed : int
        Length of the state vector; indices of the handle's coordinate and speed in it.
    state_names : tuple of str
        One name per state (``theta``, ``dtheta`` and the model's own).
    contained : bool
        The plant runs native code nobody here compiled (an FMU): a fit evaluates it in a
        sandbox process (:mod:`evo_door.optim.sandbox`).

    A plant whose force at an angle depends on that angle alone may offer
    ``hold_forces_at(P, theta, dtheta)``: :meth:`hold_forces_rows` with each row at the
    angles of its own row of ``theta``. The perceptual objective then searches the latch
    peaks coarse to fine (:func:`~evo_door.perception.target.stroke_and_peaks`); the
    model given by ``accel`` has it, a state vector (each angle starts from the last
    one's equilibrium) does not.
    """

    @property
    def params(self) -> ParamTable:
        """The model's declaration."""

    n_states: int
    position: int
    speed: int
    state_names: tuple[str, ...]
    contained: bool

    def prepare(self) -> None:
        """Load what the first run would load (a sandbox's child does before a time limit
        counts): compiled kernels, a shared library."""

    def check_ready(self) -> None:
        """Refuse, in one line, a plant that cannot run at all (an FMU whose variables do
        not match the handle's channels)."""

    def not_a_parameter(self, name: str) -> str:
        """Why ``name``, which is not in ``params``, cannot be set (a variable of the plant
        that is no settable parameter), or "" when the plant knows no such name."""

    def check_start(self, theta0: float | None, dtheta0: float | None, where: str = "") -> None:
        """Refuse, in one line naming ``where``, an initial handle state the plant cannot
        be given."""

    def simulate(
        self,
        params,
        force,
        dt: float,
        theta0: float | None = None,
        dtheta0: float | None = None,
        t0: float = 0.0,
        method: str | None = None,
        substeps: int | None = None,
        tolerance: float | None = None,
        state: ArrayLike | None = None,
    ) -> Response:
        """One trial: the force sampled every ``dt`` s in, the handle's channels out (and
        the plant's other states in ``Response.states``, the last sample's whole state in
        ``Response.final``). ``theta0`` / ``dtheta0`` None: the plant's own initial
        state; ``state``: the whole initial state instead (a previous ``final``)."""

    def simulate_batch(
        self,
        P: ArrayLike,
        force,
        dt: float,
        theta0: float | None = None,
        dtheta0: float | None = None,
        method: str | None = None,
        substeps: int | None = None,
        tolerance: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One input for every row of ``P``: ``(theta, dtheta, ddtheta, ok)``."""

    def population_errors(
        self,
        P: np.ndarray,
        force: np.ndarray,
        target: np.ndarray,
        mask: np.ndarray,
        offsets: np.ndarray,
        dt: np.ndarray,
        theta0: np.ndarray,
        dtheta0: np.ndarray,
        substeps: int,
        method: int,
        tol: float,
        derivative: int,
        kind: int,
        err_out: np.ndarray,
        ok_out: np.ndarray,
    ) -> None:
        """The objective of every row of ``P`` on every trial (packed as
        :mod:`evo_door.sim.objective` describes) into ``err_out`` / ``ok_out``."""

    def check_curve(self, what: str) -> None:
        """Refuse, in one line, ``what`` (the force-angle curve, the perceptual
        objective) for a plant that cannot give the force at the handle at any state."""

    def hold_forces(self, p: ArrayLike, theta: ArrayLike, dtheta: float) -> np.ndarray:
        """The force at the handle (N) that holds it in static equilibrium at each
        ``theta`` while it moves at ``dtheta``: the quasi-static force-angle curve.
        A plant that cannot compute it refuses in one line."""

    def hold_forces_rows(self, P: ArrayLike, theta: ArrayLike, dtheta: float) -> np.ndarray:
        """:meth:`hold_forces` of every row of ``P``: an array (rows, angles)."""

    def inertia_rows(self, P: ArrayLike, theta: ArrayLike, dtheta: float) -> np.ndarray:
        """The inertia felt at the handle (force per acceleration) of every row of ``P``
        at each ``theta``: an array (rows, angles)."""

    def state_law(self, what: str) -> StateLaw:
        """The plant's compiled right-hand side on its state vector, for ``what`` (the
        renderer's loop integrates it itself); a plant without one refuses in one
        line naming ``what``."""


class CompiledPlant:
    """What a plant compiled here answers (:class:`~evo_door.sim.accel_plant.AccelPlant`,
    :class:`~evo_door.sim.state_plant.StatePlant`): nothing to load or contain, every
    variable a declared parameter, any start and any state for the curve."""

    contained = False

    def __init__(self, model) -> None:
        self.model = model

    @property
    def params(self) -> ParamTable:
        return self.model.params

    def prepare(self) -> None:
        """Nothing to load: the kernels are compiled on import."""

    def check_ready(self) -> None:
        """Always ready."""

    def not_a_parameter(self, name: str) -> str:
        """Every variable of the model is a declared parameter."""
        return ""

    def check_start(self, theta0, dtheta0, where: str = "") -> None:
        """Any initial state will do."""

    def check_curve(self, what: str) -> None:
        """The force at the handle is known at any state."""

    def state_law(self, what: str) -> StateLaw:
        """Refused: only a model on a state vector gives its right-hand side."""
        raise UserError(
            f"{what} takes a model on a state vector (a mechanism file, or a Model with "
            f"rhs=...); {self.model.name!r} is not one"
        )
