"""Experiments: YAML files (:mod:`.config`), resolution into a problem (:mod:`.setup`),
runs with checkpoints (:mod:`.runner`), HDF5 results (:mod:`.store`, :mod:`.results`).

The library entry points::

    from evo_door.experiment import load_experiment, run_experiment, resume_run
    exp = load_experiment("experiments/default.yaml", overrides=["algorithm.seed=3"])
    run = run_experiment(exp, out="results/a.h5")
    run.result["best_x"], run.path

The same from keyword arguments, with typed results: :mod:`evo_door.api`
(``evo_door.Experiment``, ``docs/api.md``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

import evo_door.plugins  # noqa: F401 (render logs as parameter files, also in a worker)

#: the names below and the module of each, loaded on first use: a command that reads a
#: results file (``show``) imports :mod:`.reader`, not the runner and its kernels
_WHERE = {
    "ExperimentConfig": "evo_door.experiment.config",
    "load_experiment": "evo_door.experiment.config",
    "Results": "evo_door.experiment.results",
    "ExperimentRun": "evo_door.experiment.runner",
    "Interrupted": "evo_door.experiment.runner",
}

if TYPE_CHECKING:
    from evo_door.experiment.config import ExperimentConfig, load_experiment
    from evo_door.experiment.results import Results
    from evo_door.experiment.runner import ExperimentRun, Interrupted


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))


def run_experiment(
    exp, out=None, overrides=None, trials=None, progress=False, on_checkpoint=None
) -> ExperimentRun:
    """Run an experiment (an :class:`ExperimentConfig` or a YAML path) to completion.

    ``trials`` replaces the target's trials (in-memory data); ``on_checkpoint(run, job)``
    is called after each checkpoint written to ``out``.

    The main job, made quick (20 x 3 instead of 100 x 20, no polish):

    >>> import tempfile
    >>> from pathlib import Path
    >>> import evo_door
    >>> from evo_door.experiment import Results, load_experiment
    >>> main_job = Path(evo_door.__file__).parents[1] / "experiments" / "default.yaml"
    >>> exp = load_experiment(main_job, overrides=["algorithm.population=20",
    ...                       "algorithm.generations=3", "algorithm.polish=none"])
    >>> run = run_experiment(exp, out=Path(tempfile.mkdtemp()) / "quick.h5")
    >>> run.status, run.free, run.jobs[0].ga_stop
    ('complete', ['F_load', 'M', 'F_atD'], '3 generations done')
    >>> {name: f"{value:.3g}" for name, value in Results(run.path).best().items()}
    {'F_load': '88.7', 'M': '1.23', 'F_atD': '9.05'}

    (60 evaluations give a rough answer; the full job's 2000 and its SLSQP polish land
    within 3 % of the true 101.45 N, 1.232 kg and 18.8 N.)
    """
    from evo_door.experiment.config import ExperimentConfig, load_experiment
    from evo_door.experiment.runner import ExperimentRun

    if not isinstance(exp, ExperimentConfig):
        exp = load_experiment(exp, overrides)
    run = ExperimentRun.create(exp, out, trials)
    return run.run(progress=progress, on_checkpoint=on_checkpoint)


def resume_run(path, progress=False, on_checkpoint=None) -> ExperimentRun:
    """Continue an interrupted run from its results file (a complete run is left as is)."""
    from evo_door.experiment.runner import ExperimentRun

    run = ExperimentRun.open(path)
    if run.status == "complete":
        return run
    return run.run(progress=progress, on_checkpoint=on_checkpoint)


__all__ = [
    "ExperimentConfig",
    "ExperimentRun",
    "Interrupted",
    "Results",
    "load_experiment",
    "resume_run",
    "run_experiment",
]
