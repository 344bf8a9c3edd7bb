"""Experiments: YAML files (:mod:`.config`), resolution into a problem (:mod:`.setup`),
runs with checkpoints (:mod:`.runner`), HDF5 results (:mod:`.store`, :mod:`.results`).

The library entry points::

    from evo_door.experiment import load_experiment, run_experiment, resume_run
    exp = load_experiment("experiments/default.yaml", overrides=["algorithm.seed=3"])
    run = run_experiment(exp, out="results/a.h5")
    run.result["best_x"], run.path
"""

from __future__ import annotations

from evo_door.experiment.config import Experiment, load_experiment
from evo_door.experiment.results import Results
from evo_door.experiment.runner import ExperimentRun, Interrupted


def run_experiment(exp, out=None, overrides=None, trials=None, progress=False,
                   on_checkpoint=None) -> ExperimentRun:
    """Run an experiment (an :class:`Experiment` or a YAML path) to completion.

    ``trials`` replaces the target's trials (in-memory data); ``on_checkpoint(run, job)``
    is called after each checkpoint written to ``out``.
    """
    if not isinstance(exp, Experiment):
        exp = load_experiment(exp, overrides)
    run = ExperimentRun.create(exp, out, trials)
    return run.run(progress=progress, on_checkpoint=on_checkpoint)


def resume_run(path, progress=False, on_checkpoint=None) -> ExperimentRun:
    """Continue an interrupted run from its results file (a complete run is left as is)."""
    run = ExperimentRun.open(path)
    if run.status == "complete":
        return run
    return run.run(progress=progress, on_checkpoint=on_checkpoint)


__all__ = ["Experiment", "ExperimentRun", "Interrupted", "Results", "load_experiment",
           "resume_run", "run_experiment"]
