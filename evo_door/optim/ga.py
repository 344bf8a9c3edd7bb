"""The genetic algorithm: AMESim's five settings on DEAP, with a generator the run owns.

AMESim's GA dialog (seed table 5.1) has population size, maximum number of
generations, reproduction ratio, mutation probability, mutation amplitude, and a seed.
They map onto DEAP as follows (``N`` population, ``r`` reproduction ratio, ``p_m``
mutation probability, ``a`` mutation amplitude, each gene ``i`` searched in
``[lo_i, hi_i]``)::

    generation 0   N individuals drawn uniformly inside the bounds, evaluated
    each next generation:
      elite        the `elite` best individuals are copied unchanged
      reproduction round(r N) children (at most N - elite) by SBX crossover
                   (bounded, distribution index `crossover_eta`) of parents
                   picked by tournament (size `tournament`)
      survivors    the remaining places are filled with tournament-picked copies
      mutation     every non-elite gene mutates with probability p_m to a draw from
                   a Gaussian N(x, (a (hi - lo))^2) truncated to [lo, hi]
      evaluation   only individuals whose genes changed are evaluated again,
                   all of them in one batched compiled call
    stop after `generations` generations (or once the best fitness <= target)

Genes never leave their bounds: SBX is cut at the bounds, the mutation is drawn from
the truncated Gaussian. DEAP supplies the individual and fitness types, the
:class:`~deap.base.Toolbox` through which the operators are called, the
:class:`~deap.tools.HallOfFame` and the :class:`~deap.tools.Logbook`; the operators
themselves (:mod:`evo_door.optim.operators`) draw from the run's own
:class:`random.Random`, never from the global ``random``, so that the run's state is
fully captured by its population, hall of fame, logbook and generator state
(:meth:`GeneticAlgorithm.snapshot` / :meth:`GeneticAlgorithm.restore`).
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import dataclass, field
from functools import partial

import numpy as np
from deap import base, creator, tools

from evo_door.optim.operators import (
    cx_sbx_bounded,
    mut_gaussian_bounded,
    rng_from_state,
    rng_state,
    sel_tournament,
    uniform_individual,
)

# DEAP's creator puts classes into a module-level namespace; create them once.
if not hasattr(creator, "EvoDoorFitness"):
    creator.create("EvoDoorFitness", base.Fitness, weights=(-1.0,))
if not hasattr(creator, "EvoDoorIndividual"):
    creator.create("EvoDoorIndividual", list, fitness=creator.EvoDoorFitness)

Individual = creator.EvoDoorIndividual


def clone_individual(ind):
    """A copy of an individual: its genes (floats) and its fitness, if it has one.

    What DEAP's default clone (``copy.deepcopy``) makes of it, without walking the
    object graph for each of the some 2000 copies a GA 100 x 20 makes."""
    twin = Individual(ind)
    if ind.fitness.valid:
        twin.fitness.values = ind.fitness.values
    return twin


#: Logbook columns, in order.
LOG_FIELDS = ("gen", "evals", "blowups", "min", "mean", "max", "std")


@dataclass(frozen=True)
class GASettings:
    """AMESim's GA settings (first six) plus the details AMESim does not expose.

    ``reproduction_ratio``, ``mutation_probability`` are fractions (AMESim's 60 % is 0.6);
    ``mutation_amplitude`` is the standard deviation of a mutation as a fraction of each
    gene's search range.
    """

    population: int = 100
    generations: int = 20
    reproduction_ratio: float = 0.6
    mutation_probability: float = 0.1
    mutation_amplitude: float = 0.8
    seed: int = 1
    elite: int = 1
    tournament: int = 3
    crossover_eta: float = 10.0
    hall_of_fame: int = 10
    target_fitness: float | None = None
    #: stop early once the best fitness has not improved for this many generations
    patience: int | None = None

    def __post_init__(self):
        if self.population < 2:
            raise ValueError("population must be at least 2")
        if self.generations < 0:
            raise ValueError("generations must be >= 0")
        for name in ("reproduction_ratio", "mutation_probability"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1]")
        if not self.mutation_amplitude > 0:
            raise ValueError("mutation_amplitude must be > 0")
        if not 0 <= self.elite < self.population:
            raise ValueError("elite must be in [0, population)")
        if self.tournament < 1 or self.hall_of_fame < 1 or not self.crossover_eta > 0:
            raise ValueError("tournament, hall_of_fame >= 1 and crossover_eta > 0 required")
        if self.patience is not None and self.patience < 1:
            raise ValueError("patience must be at least 1 (or None)")

    @property
    def children(self) -> int:
        """Individuals made by crossover each generation."""
        n = int(math.floor(self.reproduction_ratio * self.population + 0.5))
        return min(n, self.population - self.elite)


class Termination:
    """When the GA stops: after ``generations`` generations, or at ``target_fitness``."""

    def __init__(self, generations: int, target_fitness: float | None = None):
        self.generations = int(generations)
        self.target_fitness = target_fitness

    def reason(self, state: GAState) -> str | None:
        """Why the run should stop now, or None to go on."""
        if self.target_fitness is not None and state.best_fitness <= self.target_fitness:
            return f"best fitness {state.best_fitness:.6g} <= target {self.target_fitness:g}"
        if state.generation >= self.generations:
            return f"{self.generations} generations done"
        return None


@dataclass
class GAState:
    """Everything a GA run needs to go on: checkpointed every generation."""

    generation: int
    population: list
    hof: tools.HallOfFame
    logbook: tools.Logbook
    rng: random.Random
    evaluations: int = 0
    blowups: int = 0
    #: per generation: genes (N, n_var), fitness (N,), generator state before breeding
    history_x: list = field(default_factory=list)
    history_f: list = field(default_factory=list)
    history_rng: list = field(default_factory=list)
    #: per generation wall time (s) and time spent evaluating (s)
    times: list = field(default_factory=list)
    eval_times: list = field(default_factory=list)
    #: why :meth:`GeneticAlgorithm.run` stopped (not checkpointed)
    stop_reason: str | None = None

    @property
    def best(self):
        return self.hof[0]

    @property
    def best_fitness(self) -> float:
        return float(self.hof[0].fitness.values[0])

    @property
    def best_x(self) -> np.ndarray:
        return np.array(self.hof[0], dtype=np.float64)


def _finite(values):
    values = np.asarray(values, dtype=np.float64)
    return values[np.isfinite(values)]


def _stat(fn):
    def stat(values):
        v = _finite(values)
        return float(fn(v)) if v.size else math.inf

    return stat


class GeneticAlgorithm:
    """Generational GA with AMESim's settings (see the module docstring).

    Parameters
    ----------
    settings : GASettings
    """

    def __init__(self, settings: GASettings):
        self.settings = settings

    # -- set-up -----------------------------------------------------------------
    def toolbox(self, problem, rng: random.Random) -> base.Toolbox:
        """DEAP toolbox with the bounded operators bound to ``rng``."""
        s = self.settings
        low, up = list(map(float, problem.lower)), list(map(float, problem.upper))
        sigma = [s.mutation_amplitude * (hi - lo) for lo, hi in zip(low, up)]
        tb = base.Toolbox()
        tb.register("individual", lambda: Individual(uniform_individual(low, up, rng)))
        tb.register("mate", partial(cx_sbx_bounded, eta=s.crossover_eta, low=low, up=up, rng=rng))
        tb.register(
            "mutate",
            partial(
                mut_gaussian_bounded,
                sigma=sigma,
                low=low,
                up=up,
                indpb=s.mutation_probability,
                rng=rng,
            ),
        )
        tb.register("select", partial(sel_tournament, tournsize=s.tournament, rng=rng))
        tb.register("clone", clone_individual)
        return tb

    @staticmethod
    def statistics() -> tools.Statistics:
        stats = tools.Statistics(key=lambda ind: ind.fitness.values[0])
        stats.register("min", _stat(np.min))
        stats.register("mean", _stat(np.mean))
        stats.register("max", _stat(np.max))
        stats.register("std", _stat(np.std))
        return stats

    def new_state(self, rng: random.Random) -> GAState:
        logbook = tools.Logbook()
        logbook.header = list(LOG_FIELDS)
        return GAState(
            generation=-1,
            population=[],
            hof=tools.HallOfFame(self.settings.hall_of_fame),
            logbook=logbook,
            rng=rng,
        )

    def initialize(self, problem, rng: random.Random | None = None) -> GAState:
        """Generation 0: a uniform random population, evaluated."""
        rng = rng if rng is not None else random.Random(self.settings.seed)
        state = self.new_state(rng)
        start_state = rng_state(rng)
        t0 = time.perf_counter()
        tb = self.toolbox(problem, rng)
        population = [tb.individual() for _ in range(self.settings.population)]
        state.generation = 0
        self._finish_generation(problem, state, population, start_state, t0)
        return state

    # -- one generation -----------------------------------------------------------
    def step(self, problem, state: GAState) -> GAState:
        """Breed, mutate and evaluate the next generation (in place)."""
        s = self.settings
        start_state = rng_state(state.rng)
        t0 = time.perf_counter()
        tb = self.toolbox(problem, state.rng)
        pop = state.population
        n = len(pop)
        clone = tb.clone
        offspring = [clone(ind) for ind in tools.selBest(pop, s.elite)]
        n_elite = len(offspring)
        n_children = s.children
        children = []
        while len(children) < n_children:
            p1, p2 = (clone(ind) for ind in tb.select(pop, 2))
            before = (list(p1), list(p2))
            c1, c2 = tb.mate(p1, p2)
            for c, b in zip((c1, c2), before):
                if list(c) != b:
                    del c.fitness.values
            children.extend((c1, c2))
        offspring.extend(children[:n_children])
        offspring.extend(clone(ind) for ind in tb.select(pop, n - len(offspring)))
        for ind in offspring[n_elite:]:
            before = list(ind)
            tb.mutate(ind)
            if list(ind) != before:
                del ind.fitness.values
        state.generation += 1
        self._finish_generation(problem, state, offspring, start_state, t0)
        return state

    def _finish_generation(self, problem, state, population, start_state, t0):
        n_fresh, blowups, t_eval = evaluate_fresh(problem, population, _single)
        state.population = population
        state.hof.update(population)
        state.evaluations += n_fresh
        state.blowups += blowups
        record = self.statistics().compile(population)
        state.logbook.record(gen=state.generation, evals=n_fresh, blowups=blowups, **record)
        state.history_x.append(np.array([list(ind) for ind in population], dtype=np.float64))
        state.history_f.append(np.array([ind.fitness.values[0] for ind in population]))
        state.history_rng.append(start_state)
        state.times.append(time.perf_counter() - t0)
        state.eval_times.append(t_eval)

    def run(
        self,
        problem,
        state: GAState | None = None,
        hooks=(),
        termination: Termination | None = None,
    ) -> GAState:
        """Run (or continue ``state``) until ``termination`` or a hook says stop.

        This is the one GA loop: what happens around it after every generation
        (checkpoint, progress display, early stop) is a *hook*, an object with
        ``after_generation(state) -> str | None`` (a reason to stop, or None to go on)
        and, optionally, ``close()``, called however the loop ends
        (:mod:`evo_door.optim.hooks`). Every hook sees every generation, generation 0
        included; the reason the run stopped is left in ``state.stop_reason``.

        Any object with search bounds and a batched ``evaluate`` is a problem:

        >>> class Sphere:
        ...     lower, upper = np.zeros(2), np.ones(2)
        ...     def evaluate(self, X):
        ...         return ((X - 0.3) ** 2).sum(axis=1), np.zeros(len(X), dtype=bool)
        >>> class Record:
        ...     seen = []
        ...     def after_generation(self, state):
        ...         self.seen.append(state.generation)
        >>> ga = GeneticAlgorithm(GASettings(population=20, generations=3, seed=1))
        >>> state = ga.run(Sphere(), hooks=[Record()])
        >>> Record.seen, state.stop_reason, state.best_fitness < 0.01
        ([0, 1, 2, 3], '3 generations done', True)
        """
        termination = termination or Termination(
            self.settings.generations, self.settings.target_fitness
        )
        hooks = list(hooks)
        try:
            reason = None
            if state is None:
                state = self.initialize(problem)
                reason = _notify(hooks, state)
            while reason is None and (reason := termination.reason(state)) is None:
                self.step(problem, state)
                reason = _notify(hooks, state)
            state.stop_reason = reason
            return state
        finally:
            for hook in hooks:
                close = getattr(hook, "close", None)
                if close is not None:
                    close()

    # -- checkpoint ---------------------------------------------------------------
    @staticmethod
    def snapshot(state: GAState) -> dict:
        """Arrays that capture ``state`` exactly (see :meth:`restore`)."""
        log = {k: np.array(state.logbook.select(k)) for k in LOG_FIELDS}
        return {
            "generation": state.generation,
            "evaluations": state.evaluations,
            "blowups": state.blowups,
            "population": np.array(state.history_x),
            "fitness": np.array(state.history_f),
            "rng_states": np.array(state.history_rng, dtype=np.int64),
            "rng_state": np.array(rng_state(state.rng), dtype=np.int64),
            "hof_x": np.array([list(ind) for ind in state.hof], dtype=np.float64),
            "hof_fitness": np.array([ind.fitness.values[0] for ind in state.hof]),
            "logbook": log,
            "times": np.array(state.times),
            "eval_times": np.array(state.eval_times),
        }

    def restore(self, snap: dict) -> GAState:
        """Rebuild a :class:`GAState` from :meth:`snapshot` arrays, bit for bit."""
        state = restore_history(self.new_state(rng_from_state(snap["rng_state"])), snap)
        population = []
        for x, f in zip(state.history_x[-1], state.history_f[-1]):
            ind = Individual(map(float, x))
            ind.fitness.values = (float(f),)
            population.append(ind)
        state.population = population
        # The hall of fame keeps items best first and their fitnesses in ascending
        # order of DEAP's comparison (worst first); rebuild both lists as stored.
        items = []
        for x, f in zip(snap["hof_x"], snap["hof_fitness"]):
            ind = Individual(map(float, x))
            ind.fitness.values = (float(f),)
            items.append(ind)
        state.hof.items = items
        state.hof.keys = [ind.fitness for ind in reversed(items)]
        return state


def restore_history(state: GAState, snap: dict) -> GAState:
    """Put a :meth:`GeneticAlgorithm.snapshot`'s counters, histories and logbook into a
    fresh ``state`` (the population and the hall of fame are the algorithm's to rebuild)."""
    state.generation = int(snap["generation"])
    state.evaluations = int(snap["evaluations"])
    state.blowups = int(snap["blowups"])
    state.history_x = [np.array(x) for x in snap["population"]]
    state.history_f = [np.array(f) for f in snap["fitness"]]
    state.history_rng = [list(map(int, r)) for r in snap["rng_states"]]
    state.times = list(map(float, snap["times"]))
    state.eval_times = list(map(float, snap["eval_times"]))
    log = snap["logbook"]
    for i in range(len(log["gen"])):
        state.logbook.record(**{k: log[k][i].item() for k in LOG_FIELDS})
    return state


def evaluate_fresh(problem, population, fitness_of) -> tuple[int, int, float]:
    """Evaluate the individuals of ``population`` without a valid fitness, in one batched
    call; ``fitness_of(row)`` turns a row of the problem's answer into DEAP's fitness
    values. Returns (individuals evaluated, blow-ups, seconds)."""
    fresh = [ind for ind in population if not ind.fitness.valid]
    t0 = time.perf_counter()
    blowups = 0
    if fresh:
        X = np.array([list(ind) for ind in fresh], dtype=np.float64)
        values, blown = problem.evaluate(X)
        for ind, v in zip(fresh, values):
            ind.fitness.values = fitness_of(v)
        blowups = int(np.sum(blown))
    return len(fresh), blowups, time.perf_counter() - t0


def _single(value) -> tuple[float]:
    return (float(value),)


def _notify(hooks, state: GAState) -> str | None:
    """Call every hook on ``state``; the first reason to stop that one gives, or None."""
    reason = None
    for hook in hooks:
        said = hook.after_generation(state)
        if reason is None and said:
            reason = said
    return reason
