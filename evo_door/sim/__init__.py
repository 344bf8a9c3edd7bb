"""Compiled integrators (:mod:`.integrators`) and their Python entry points (:mod:`.simulate`)."""

from evo_door.sim.simulate import (
    Response,
    quasi_static_curve,
    quasi_static_force,
    simulate,
    simulate_batch,
)
from evo_door.sim_settings import METHODS

__all__ = [
    "METHODS",
    "Response",
    "simulate",
    "simulate_batch",
    "quasi_static_curve",
    "quasi_static_force",
]
