"""The specification a supplier builds, of a run against its chosen feel: where the
experiment layer meets :mod:`evo_door.optim.tolerance` and :mod:`evo_door.optim.process`.

A run with the perceptual objective (a chosen feel, ``Setup.feel``) on a model with
built specifications (a door: each parameter's declared process kind) computes it when
it completes (:func:`stage_specification`): the supplier's process from the
experiment's ``process:`` table and the kinds' defaults, the centred nominal, the
yield on a fresh sample and, where the target is out of reach, the allocation. Its
results file keeps it (``tolerance/``); :func:`tolerances_of` reads it back, or
computes it for a file written before it was kept (``export-spec`` says so in a
note). The specifications are the rows of the run's specification table
(:func:`evo_door.optim.specification.spec_names`); the report's figure of it is
:func:`evo_door.reporting.figures.plot_tolerances`.
"""

from __future__ import annotations

import numpy as np

from evo_door.errors import UserError
from evo_door.experiment.stored import setup_from_tree
from evo_door.optim.process import process_for
from evo_door.optim.specification import spec_names
from evo_door.optim.tolerance import Specification, specify

#: the note of a specification computed for a results file that has none
COMPUTED_NOTE = (
    "computed now: the results file has none in this form (written before it was kept, "
    "or with the old tolerance bands alone and together, which it replaces)"
)


def stage_specification(setup, config: dict, full, progress: bool = False):
    """The specification of a finished run's door ``full`` (its whole kernel vector),
    None for a run without a chosen feel, a model with nothing a supplier builds, or
    where it cannot be made (a run's answer is never lost to it)."""
    if setup.feel is None or not setup.objective.perceptual:
        return None
    model = setup.model
    names = spec_names(model, setup.free)
    if not any(getattr(model.params[n], "process", "") for n in names):
        return None  # a haptic model's sensations: nothing a supplier builds
    try:
        process = process_for(model, names, config.get("process"))
        feel_model, feel_params = _feel_set(config)
        return specify(
            model,
            full,
            setup.feel,
            names,
            process,
            list(setup.free),
            setup.lower,
            setup.upper,
            asis=setup.base,
            feel_model=feel_model,
            feel_params=feel_params,
            progress=progress,
        )
    except (UserError, ValueError):
        return None


def _feel_set(config: dict):
    """The chosen feel's model and parameter vector (a model target), else (None, None)."""
    from evo_door.models import get_model

    target = config.get("target") or {}
    if target.get("kind") != "model":
        return None, None
    model = get_model(target["model"])
    try:
        model.plant.check_curve("the tolerances")
    except UserError:
        return None, None  # a plant without a force-angle curve (an FMU): none to move
    params = model.load_params(target.get("params"), target.get("set") or {})
    return model, np.array(params.vector, dtype=np.float64)


def tolerances_of(res, compute: bool = True) -> Specification | None:
    """The specification of the complete run ``res`` (a
    :class:`~evo_door.experiment.results.Results`): as stored, else (``compute``)
    computed from its chosen feel with :data:`COMPUTED_NOTE`; None for a run without one."""
    if res.record.tolerance is not None:
        return res.record.tolerance
    tree = res.tree
    if not compute or tree is None or "feel" not in tree["setup"] or "best" not in tree:
        return None
    setup = setup_from_tree(tree)
    full = np.asarray(tree["best"]["full"], dtype=np.float64)
    out = stage_specification(setup, res.config, full)
    if out is not None:
        out.note = "; ".join(x for x in (out.note, COMPUTED_NOTE) if x)
        res.record.tolerance = out  # once a read: the table and the report share it
    return out
