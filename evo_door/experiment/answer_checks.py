"""The checks a finished fit makes of its answer, each of which may fail without losing it:
its identifiability (against trials, or against a chosen feel) and its integration error.
"""

from __future__ import annotations

import numpy as np

from evo_door.errors import UserError


def identifiability_of(problem, x, measured: bool = True):
    """The identifiability of a fit at ``x`` (None if the check cannot be made: a run's
    answer is never lost to it): against a chosen feel, intervals of one JND; else
    widened for model mismatch if the target is ``measured`` (a model's target is
    noise-free: no truth beyond the best fit to cover)."""
    from evo_door.optim.feel_identifiability import feel_identifiability
    from evo_door.optim.identifiability import identifiability

    try:
        if problem.objective.perceptual:
            return feel_identifiability(problem, x)
        return identifiability(problem, x, mismatch=measured)
    except (UserError, ValueError, np.linalg.LinAlgError):
        return None


def integration_error_of(setup, fit_x, validation_x):
    """The answer's integration error, estimated a posteriori
    (:mod:`evo_door.experiment.integration_error`); None if it cannot be made: a run's
    answer is never lost to it."""
    from evo_door.experiment.integration_error import estimate

    if not setup.fit:  # a chosen feel alone: a curve, no integration
        return None
    try:
        return estimate(setup, fit_x, validation_x)
    except (UserError, ValueError):
        return None
