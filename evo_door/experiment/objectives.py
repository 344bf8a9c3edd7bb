"""How a fit is scored whatever its objective: the objectives and one yardstick for all.

A fit is scored by its experiment's objective (``objective.kind`` max-square, seed eq.
5.3, or ISE, eq. 5.4, on ``objective.derivative`` 0, 1 or 2; the compiled kernels are in
:mod:`evo_door.optim.kernels`). Fitnesses of different objectives are not on one scale
(``(rad/s)^2`` against ``(rad/s)^2 s``, speed against angle), so :func:`yardstick`
scores any run on one: the RMS and the largest absolute error of the angular speed
(``dtheta``; of the channel the trials carry when they have no speed) of the run's
answer, simulated on the fitted and on the validation trials, over the samples the
sensor did not saturate.

Comparing the objectives on one experiment (``evo-door compare-objectives``) builds on
this: the plan and its runs (:mod:`.comparison`), one row per objective
(:mod:`.comparison_summary`), the tables and the figure
(:mod:`evo_door.reporting.comparison_outputs`).
"""

from __future__ import annotations

import math

import numpy as np

from evo_door.channels import unit
from evo_door.experiment.results import Results
from evo_door.experiment.stored import setup_from_tree
from evo_door.sim_settings import KINDS as _KINDS

#: objective kinds, in the order the seed writes them (eq. 5.3, eq. 5.4)
KINDS = tuple(_KINDS)
DERIVATIVES = (0, 1, 2)
#: the channel of the common yardstick, in order of preference (speed first: the seed's
#: measured channel and the one people feel)
YARDSTICK_CHANNELS = ("dtheta", "theta", "ddtheta")


def yardstick(res: Results) -> dict:
    """The run's answer scored on one channel whatever the objective: RMS and max error.

    The channel is the angular speed ``dtheta`` when every fitted and validation trial
    carries it, else ``theta``, else ``ddtheta``; the run's answer is simulated on each
    trial (as the run itself did) and compared sample by sample, saturated samples left
    out. Returns ``{"channel", "unit", "fit", "validation", "fit_max",
    "validation_max"}``: the RMS and the largest absolute error over the samples of the
    fitted and of the validation trials, in the channel's SI unit (None without
    validation trials, inf where a simulation blew up). The RMS is ISE's measure and the
    max max-square's: both are given so that neither objective is judged on its own.
    """
    setup = setup_from_tree(res.tree)
    trials = setup.fit + setup.validation
    channel = next(
        c for c in YARDSTICK_CHANNELS if all(getattr(tr, c) is not None for tr in trials)
    )
    problem = setup.problem()
    x = np.asarray(res.tree["best"]["x"], dtype=np.float64)
    out = {"channel": channel, "unit": unit(channel, setup.model.theta_unit)}
    for role, pack in (("fit", problem.fit), ("validation", problem.validation)):
        out[role] = out[f"{role}_max"] = None
        if not len(pack):
            continue
        squares, count, largest = 0.0, 0, 0.0
        for tr, r in zip(pack.trials, problem.responses(x, pack)):
            if not r.ok:
                squares = largest = math.inf
                break
            keep = tr.unsaturated(channel)
            e = getattr(r, channel)[keep] - getattr(tr, channel)[keep]
            squares += float(e @ e)
            count += int(keep.sum())
            largest = max(largest, float(np.max(np.abs(e), initial=0.0)))
        finite = count and math.isfinite(squares)
        out[role] = math.sqrt(squares / count) if finite else math.inf
        out[f"{role}_max"] = largest if finite else math.inf
    return out
