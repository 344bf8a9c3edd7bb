"""Optimisation: the problem (:mod:`.problem`), compiled objective kernels (:mod:`.kernels`),
the GA on DEAP (:mod:`.ga`, operators in :mod:`.operators`) and SLSQP refinement (:mod:`.local`).

An estimation is a :class:`Problem` (model, target trials, free parameters, objective)
handed to an algorithm (:class:`GeneticAlgorithm` with its :class:`Termination`, or
:func:`slsqp`); nothing here reads files or prints.
"""

from evo_door.optim.ga import GASettings, GAState, GeneticAlgorithm, Termination
from evo_door.optim.local import LocalResult, LocalSettings, polish, slsqp
from evo_door.optim.problem import COMBINE, Objective, Problem, TrialPack

__all__ = [
    "COMBINE",
    "GASettings",
    "GAState",
    "GeneticAlgorithm",
    "LocalResult",
    "LocalSettings",
    "Objective",
    "Problem",
    "Termination",
    "TrialPack",
    "polish",
    "slsqp",
]
