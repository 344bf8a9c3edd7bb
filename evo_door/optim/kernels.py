"""The objective of a whole population, for every kind of model.

:func:`population_errors` hands the work to the model's plant
(:class:`~evo_door.sim.plant.Plant`): the compiled kernels of
:mod:`evo_door.sim.objective` for a model given by ``accel``, those of
:mod:`evo_door.sim.state_objective` for a model on a state vector, an FMU's own loop.
The objectives and the packing of trials are described in :mod:`evo_door.sim.objective`.
"""

from __future__ import annotations

import numpy as np

from evo_door.sim_settings import ISE, KINDS, MAX_SQUARE

__all__ = ["ISE", "KINDS", "MAX_SQUARE", "population_errors"]


def population_errors(
    model,
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
    """Objective of every individual (rows of ``P``) on every trial of ``model``.

    Fills ``err_out[i, j]`` and ``ok_out[i, j]`` for individual ``i`` and trial ``j``;
    ``tol`` is ``dopri5``'s tolerance. The errors are those of
    :func:`evo_door.sim.simulate`'s output, to rounding.
    """
    model.plant.population_errors(
        P, force, target, mask, offsets, dt, theta0, dtheta0, substeps, method, tol,
        derivative, kind, err_out, ok_out,
    )  # fmt: skip
