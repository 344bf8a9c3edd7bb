"""What happens after every generation of the GA: hooks of :meth:`GeneticAlgorithm.run`.

A hook is any object with ``after_generation(state) -> str | None``: it may save the
state, draw a progress bar, or return a reason to stop the run early; ``close()``, if
it has one, is called however the run ends. The GA keeps one loop; an experiment run
(:mod:`evo_door.experiment.runner`) only chooses and wires its hooks::

    state = GeneticAlgorithm(settings).run(problem, state, hooks=[
        ProgressBar("default", settings.generations),
        Callback(lambda state: save(state)),
        EarlyStop(patience=5),
    ])
"""

from __future__ import annotations

import sys

import numpy as np


class Callback:
    """Call ``function(state)`` after every generation (its return value is ignored)."""

    def __init__(self, function):
        self.function = function

    def after_generation(self, state) -> None:
        self.function(state)


class EarlyStop:
    """Stop once the best fitness has not improved by more than ``min_delta`` for ``patience`` generations.

    It reads the run's logbook only, so a resumed run stops exactly where the
    uninterrupted one would.

    >>> from deap import tools
    >>> class State:
    ...     logbook = tools.Logbook()
    >>> stop, s = EarlyStop(patience=2), State()
    >>> for gen, best in enumerate([3.0, 1.0, 1.0, 1.0]):
    ...     s.logbook.record(gen=gen, min=best)
    ...     said = stop.after_generation(s)
    >>> said
    'best fitness 1 not improved for 2 generations'
    """

    def __init__(self, patience: int, min_delta: float = 0.0):
        if patience < 1:
            raise ValueError("patience must be at least 1")
        self.patience = int(patience)
        self.min_delta = float(min_delta)

    def after_generation(self, state) -> str | None:
        best, improved_at = np.inf, 0
        for gen, low in zip(state.logbook.select("gen"), state.logbook.select("min")):
            if low < best - self.min_delta:
                improved_at = gen
            best = min(best, low)
        if state.logbook and state.logbook[-1]["gen"] - improved_at >= self.patience:
            return f"best fitness {best:.6g} not improved for {self.patience} generations"
        return None


class ProgressBar:
    """A tqdm bar on stderr: generation, best and mean fitness, evaluations per second.

    ``initial`` is the generation a resumed run starts from.
    """

    def __init__(self, label: str, generations: int, initial: int = 0, file=None):
        from tqdm import tqdm

        self.bar = tqdm(
            total=generations,
            unit="gen",
            desc=label,
            file=file or sys.stderr,
            dynamic_ncols=True,
            initial=max(initial, 0),
        )

    def after_generation(self, state) -> None:
        log = state.logbook[-1]
        # throughput of this session's GA so far (breeding + evaluation, not I/O)
        rate = state.evaluations / max(float(np.sum(state.times)), 1e-9)
        self.bar.set_postfix_str(
            f"best {state.best_fitness:.4g}  mean {log['mean']:.4g}  "
            f"{rate:,.0f} evals/s" + (f"  blow-ups {state.blowups}" if state.blowups else ""),
            refresh=False,
        )
        self.bar.update(1 if state.generation > 0 else 0)

    def close(self) -> None:
        self.bar.close()
