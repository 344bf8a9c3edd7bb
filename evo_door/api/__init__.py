"""The library's public face: experiments and pipelines built in Python, run, and read
back as typed objects (``docs/api.md``)::

    import evo_door
    exp = evo_door.Experiment(
        model="door",
        target=evo_door.trial_file("experiments/data/default.h5", kinds=["impulse"]),
        free={"F_load": [80.0, 120.0], "M": [0.3, 2.5], "F_atD": [5.0, 70.0]},
    )
    run = exp.run(out="results/x.h5")
    run.estimates["M"].value, run.estimates["M"].unit

Every name here is also an attribute of the package itself (``evo_door.Experiment``),
imported only when first asked for: ``import evo_door`` stays light
(``docs/architecture.md``, "The public face"). An experiment built here is checked by
the experiment files' own code, with the same messages naming the Python argument
(:mod:`.build`); a results file is read into dataclasses (:mod:`.outcome`).
"""

from __future__ import annotations

from evo_door.api.build import Experiment, Pipeline, TrialFile, trial_file
from evo_door.api.outcome import Checks, Estimate, Identifiable, PipelineResult, Run, load
from evo_door.errors import UserError

__all__ = [
    "Checks",
    "Estimate",
    "Experiment",
    "Identifiable",
    "Pipeline",
    "PipelineResult",
    "Run",
    "TrialFile",
    "UserError",
    "load",
    "trial_file",
]
