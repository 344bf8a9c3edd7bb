"""NSGA-II on DEAP: two objectives at once, with the run's own generator.

The specification stage does not want one best door; it wants the doors that feel
like the chosen feel *and* change the product as little as possible, and then the one
of least change that a hand cannot tell from the chosen feel. That is a front of two
objectives (:class:`~evo_door.optim.smallest_change.ChangeObjectives`: the perceptual
error in JND^2 and the size of the change), searched with NSGA-II (Deb, Pratap,
Agarwal and Meyarivan, 2002) as DEAP's examples run it, on the GA's settings
(:class:`~evo_door.optim.ga.GASettings`, seed table 5.1)::

    generation 0   the AS-IS door (the problem's ``start``) and N - 1 individuals
                   drawn uniformly inside the bounds, evaluated, ranked by
                   deap.tools.selNSGA2 (fronts, crowding distance)
    each next generation:
      parents      N picked by binary tournament on rank, then crowding distance
      crossover    each pair, with probability r (reproduction_ratio), by bounded
                   SBX (distribution index crossover_eta)
      mutation     every gene of every child with probability p_m, truncated
                   Gaussian of standard deviation a (hi - lo)
      evaluation   only children whose genes changed, in one batched call
      survivors    deap.tools.selNSGA2 over parents and children keeps N
    the archive    deap.tools.ParetoFront: every non-dominated point seen so far
    stop after `generations` (or once the least perceptual error <= target_fitness)

``elite``, ``tournament`` and ``hall_of_fame`` of the GA's settings have no part here
(NSGA-II's survivors are its elite; its tournament is binary on rank). Every random
draw comes from the run's :class:`random.Random` (:mod:`evo_door.optim.operators`);
DEAP's own selection is deterministic. A state holds the population *with* its
crowding distances (they were assigned over parents and children together, and the
next tournament reads them), the archive, the logbook and the generator's state, so
:meth:`NSGA2.restore` continues a run exactly where :meth:`NSGA2.snapshot` left it.
"""

from __future__ import annotations

import copy
import math
import random
import time
from dataclasses import dataclass, field

import numpy as np
from deap import base, creator, tools

from evo_door.optim.ga import (
    LOG_FIELDS,
    GASettings,
    GAState,
    GeneticAlgorithm,
    Termination,
    evaluate_fresh,
    restore_history,
)
from evo_door.optim.operators import (
    cx_sbx_bounded,
    mut_gaussian_bounded,
    rng_from_state,
    rng_state,
    sel_tournament_dcd,
    uniform_individual,
)

if not hasattr(creator, "EvoDoorFitness2"):
    creator.create("EvoDoorFitness2", base.Fitness, weights=(-1.0, -1.0))
if not hasattr(creator, "EvoDoorIndividual2"):
    creator.create("EvoDoorIndividual2", list, fitness=creator.EvoDoorFitness2)

Individual2 = creator.EvoDoorIndividual2

#: a blown-up candidate's perceptual error: finite, so that crowding distances stay finite
BLOWN = 1.0e30


@dataclass
class FrontState(GAState):
    """A :class:`~evo_door.optim.ga.GAState` whose ``hof`` is the Pareto archive
    (:class:`deap.tools.ParetoFront`, least perceptual error first) and whose fitness
    history holds both objectives per individual (``(N, 2)`` a generation)."""

    #: crowding distance of each individual of ``population``, in its order
    crowding: list = field(default_factory=list)

    @property
    def front_x(self) -> np.ndarray:
        """The archive's genes, one row a point, least perceptual error first."""
        return np.array([list(ind) for ind in self.hof], dtype=np.float64).reshape(
            len(self.hof), -1
        )

    @property
    def front_f(self) -> np.ndarray:
        """The archive's objectives (perceptual error JND^2, change 1), one row a point."""
        return np.array([ind.fitness.values for ind in self.hof], dtype=np.float64).reshape(
            len(self.hof), 2
        )


class NSGA2:
    """NSGA-II on the GA's settings (see the module docstring).

    ``problem`` is any object with ``lower``, ``upper``, ``start`` (the AS-IS vector)
    and ``evaluate(X) -> (F, blown)``, ``F`` of shape (n, 2)
    (:class:`~evo_door.optim.smallest_change.ChangeObjectives`).

    >>> class Two:
    ...     lower, upper, start = np.zeros(2), np.ones(2), np.zeros(2)
    ...     def evaluate(self, X):
    ...         F = np.c_[((X - 0.6) ** 2).sum(axis=1), np.abs(X).mean(axis=1)]
    ...         return F, np.zeros(len(X), dtype=bool)
    >>> state = NSGA2(GASettings(population=20, generations=5, seed=2)).run(Two())
    >>> F = state.front_f
    >>> bool(np.all(np.diff(F[:, 0]) >= 0) and np.all(np.diff(F[:, 1]) <= 0))
    True
    """

    def __init__(self, settings: GASettings):
        self.settings = settings

    # -- set-up ---------------------------------------------------------------------
    def operators(self, problem, rng: random.Random):
        """(mate, mutate) bound to ``rng`` and the problem's bounds."""
        s = self.settings
        low, up = list(map(float, problem.lower)), list(map(float, problem.upper))
        sigma = [s.mutation_amplitude * (hi - lo) for lo, hi in zip(low, up)]

        def mate(a, b):
            return cx_sbx_bounded(a, b, eta=s.crossover_eta, low=low, up=up, rng=rng)

        def mutate(ind):
            return mut_gaussian_bounded(
                ind, sigma=sigma, low=low, up=up, indpb=s.mutation_probability, rng=rng
            )

        return mate, mutate

    def new_state(self, rng: random.Random) -> FrontState:
        logbook = tools.Logbook()
        logbook.header = list(LOG_FIELDS)
        return FrontState(
            generation=-1, population=[], hof=tools.ParetoFront(), logbook=logbook, rng=rng
        )

    def initialize(self, problem, rng: random.Random | None = None) -> FrontState:
        """Generation 0: the AS-IS door and uniform draws, evaluated and ranked."""
        rng = rng if rng is not None else random.Random(self.settings.seed)
        state = self.new_state(rng)
        start_state = rng_state(rng)
        t0 = time.perf_counter()
        low, up = list(map(float, problem.lower)), list(map(float, problem.upper))
        asis = np.clip(np.asarray(problem.start, dtype=np.float64), low, up)
        population = [Individual2(map(float, asis))]
        while len(population) < self.settings.population:
            population.append(Individual2(uniform_individual(low, up, rng)))
        state.generation = 0
        self._evaluate(problem, state, population)
        population = tools.selNSGA2(population, len(population))
        self._finish_generation(state, population, start_state, t0)
        return state

    # -- one generation ---------------------------------------------------------------
    def step(self, problem, state: FrontState) -> FrontState:
        """Select, breed, mutate, evaluate and keep the best N (in place)."""
        s = self.settings
        start_state = rng_state(state.rng)
        t0 = time.perf_counter()
        mate, mutate = self.operators(problem, state.rng)
        pop = state.population
        for ind, d in zip(pop, state.crowding):
            ind.fitness.crowding_dist = d
        offspring = [copy.deepcopy(ind) for ind in sel_tournament_dcd(pop, len(pop), rng=state.rng)]
        for a, b in zip(offspring[::2], offspring[1::2]):
            if state.rng.random() < s.reproduction_ratio:
                pair = (list(a), list(b))
                mate(a, b)
                for c, old in zip((a, b), pair):
                    if list(c) != old:
                        del c.fitness.values
        for ind in offspring:
            before = list(ind)
            mutate(ind)
            if list(ind) != before:
                del ind.fitness.values
        state.generation += 1
        self._evaluate(problem, state, offspring)
        population = tools.selNSGA2(pop + offspring, len(pop))
        self._finish_generation(state, population, start_state, t0)
        return state

    def _evaluate(self, problem, state: FrontState, population) -> None:
        n_fresh, blowups, seconds = evaluate_fresh(problem, population, _pair)
        state.evaluations += n_fresh
        state.blowups += blowups
        state.eval_times.append(seconds)
        state.logbook.record(gen=state.generation, evals=n_fresh, blowups=blowups)

    def _finish_generation(self, state: FrontState, population, start_state, t0) -> None:
        state.population = population
        state.crowding = [float(ind.fitness.crowding_dist) for ind in population]
        state.hof.update(population)
        errors = [ind.fitness.values[0] for ind in population]
        record = GeneticAlgorithm.statistics().compile(
            [_Scored(e) for e in errors]
        )  # the perceptual error's statistics, in the GA's columns
        state.logbook[-1].update(record)
        state.history_x.append(np.array([list(ind) for ind in population], dtype=np.float64))
        state.history_f.append(np.array([ind.fitness.values for ind in population]))
        state.history_rng.append(start_state)
        state.times.append(time.perf_counter() - t0)

    def run(self, problem, state: FrontState | None = None, hooks=(), termination=None):
        """Run (or continue ``state``) with the GA's one loop and hooks
        (:meth:`GeneticAlgorithm.run <evo_door.optim.ga.GeneticAlgorithm.run>`)."""
        termination = termination or Termination(
            self.settings.generations, self.settings.target_fitness
        )
        return GeneticAlgorithm.run(self, problem, state, hooks, termination)  # type: ignore[arg-type]

    # -- checkpoint ---------------------------------------------------------------------
    @staticmethod
    def snapshot(state: FrontState) -> dict:
        """Arrays that capture ``state`` exactly (:meth:`restore`); as the GA's, with
        both objectives and the crowding distances."""
        snap = GeneticAlgorithm.snapshot(state)
        snap["hof_fitness"] = state.front_f
        snap["hof_x"] = state.front_x
        snap["crowding"] = np.array(state.crowding, dtype=np.float64)
        return snap

    def restore(self, snap: dict) -> FrontState:
        """Rebuild a :class:`FrontState` from :meth:`snapshot` arrays, bit for bit."""
        state = self.new_state(rng_from_state(snap["rng_state"]))
        restore_history(state, snap)
        state.crowding = list(map(float, snap["crowding"]))
        state.population = _individuals(state.history_x[-1], state.history_f[-1])
        for ind, d in zip(state.population, state.crowding):
            ind.fitness.crowding_dist = d
        items = _individuals(snap["hof_x"], snap["hof_fitness"])
        state.hof.items = items
        state.hof.keys = [ind.fitness for ind in reversed(items)]
        return state


class _Scored:
    """One value dressed as an individual for the GA's statistics (``fitness.values[0]``)."""

    def __init__(self, value: float):
        self.fitness = self
        self.values = (value if math.isfinite(value) and value < BLOWN else math.inf,)


def _pair(row) -> tuple[float, float]:
    """Both objectives of one candidate; a blown-up one's error made finite (:data:`BLOWN`)."""
    error, change = (float(v) for v in row)
    return (error if math.isfinite(error) else BLOWN, change)


def _individuals(X, F) -> list:
    out = []
    for x, f in zip(np.asarray(X), np.asarray(F)):
        ind = Individual2(map(float, x))
        ind.fitness.values = tuple(map(float, f))
        out.append(ind)
    return out
