"""Which specifications a chosen feel determines: identifiability of a perceptual fit.

A fit to a chosen feel (:mod:`evo_door.perception.target`) has no measurement noise to
set its intervals by; what sets them is the hand. Its residual is the feel's difference
in JND units, whose squares sum to the perceptual objective, so the interval of a
specification is how far it can move, the others following as best they can, before
the feel changes by one JND (the objective rises by 1): ``sqrt(diag (J^T J)^-1)`` of
that residual's Jacobian ``J`` at the estimate. A specification whose interval is wider
than ``max_relative_ci`` of its value (:data:`FEEL_MAX_RELATIVE_CI`, 25 %: with force
JNDs of 7-10 %, a latch force is pinned by its peak to about +-10-15 % at one JND, and
one that may move by a quarter of its value unnoticed is not set by the feel) is one the
feel does not determine: it is *not identifiable*, and a specification built from the
feel keeps its value of the product it starts from (``kept``). Singular directions and parameters without sensitivity
(the mass, on a static curve without dynamics) are found as for trials
(:func:`~evo_door.optim.covariance.covariance`).
"""

from __future__ import annotations

import math
import time

import numpy as np

from evo_door.optim.covariance import MAX_CONDITION, MIN_SENSITIVITY, covariance
from evo_door.optim.identifiability import (
    MAX_CORRELATION,
    Identifiability,
    _bound_reason,
    _partners,
    _verdict,
)
from evo_door.optim.sensitivity import check_estimate

#: finite-difference step, as a fraction of each search range (central differences)
FEEL_STEP = 1e-4
#: the widest 1-JND interval, relative to the value, of a specification the feel sets
FEEL_MAX_RELATIVE_CI = 0.25


def feel_identifiability(
    problem,
    x,
    step: float = FEEL_STEP,
    max_correlation: float = MAX_CORRELATION,
    max_relative_ci: float = FEEL_MAX_RELATIVE_CI,
) -> Identifiability:
    """Identifiability of ``problem``'s free parameters at ``x`` against its chosen feel
    (``problem.feel``, the perceptual objective): intervals of one JND (module docstring)."""
    t0 = time.perf_counter()
    x = check_estimate(problem, x)
    names = list(problem.free)
    width = problem.upper - problem.lower
    model, feel = problem.model, problem.feel

    def residual(z):
        return feel.residuals(model, problem.full(z)[0])

    r = residual(x)
    J = _jacobian(residual, x, problem.lower, problem.upper, step * width, r.size)
    cov = covariance(J, r, None, width, MAX_CONDITION, MIN_SENSITIVITY, names)
    keep = [j for j in range(x.size) if j not in cov.reasons]
    se = np.full(x.size, math.inf)
    if keep:
        inv = np.linalg.pinv(J[:, keep].T @ J[:, keep])
        se[keep] = np.sqrt(np.maximum(np.diag(inv), 0.0))
    ci_rel = np.where(x != 0.0, se / np.maximum(np.abs(x), 1e-300), math.inf)
    partners, partner_r = _partners(cov.correlation, names)
    verdicts, reasons = [], []
    for i in range(len(names)):
        on_bound = _bound_reason(
            names[i], model.params[names[i]].unit, x[i], problem.lower[i], problem.upper[i]
        )
        verdict, why = _verdict(
            cov.reasons.get(i),
            ci_rel[i],
            partners[i],
            partner_r[i],
            max_relative_ci,
            max_correlation,
            0.0,
            on_bound,
        )
        verdicts.append(verdict)
        reasons.append(why.replace("0 % CI", "1-JND interval"))
    norms = np.linalg.norm(np.where(np.isfinite(J), J, 0.0), axis=0)
    unit_j = J / np.where(norms > 0, norms, 1.0)
    return Identifiability(
        names=names,
        units=[model.params[n].unit for n in names],
        x=x.copy(),
        lower=problem.lower.copy(),
        upper=problem.upper.copy(),
        se=se,
        ci_half=se,
        ci_rel=ci_rel,
        correlation=cov.correlation,
        cosine=unit_j.T @ unit_j,
        sensitivity=norms * np.abs(x),
        sensitivity_range=norms * width,
        verdicts=verdicts,
        reasons=reasons,
        partners=partners,
        partner_r=partner_r,
        trial_ids=[],
        tau=np.zeros(0),
        n_samples=int(r.size),
        n_effective=float(r.size),
        ssr=float(r @ r),
        rms=math.sqrt(float(r @ r)),
        sigma2=1.0,
        dof=float(r.size - len(keep)),
        condition=cov.condition,
        step=float(step),
        step_agreement=math.nan,
        channel="feel",
        channel_unit="JND",
        objective={"kind": problem.objective.kind, "derivative": 0, "combine": "sum"},
        settings={
            "max_correlation": max_correlation,
            "max_relative_ci": max_relative_ci,
            "interval": "one JND",
        },
        note="intervals: the change that moves the feel by one JND (the objective by 1)",
        seconds=time.perf_counter() - t0,
    )


def _jacobian(residual, x, lower, upper, steps, n: int) -> np.ndarray:
    """Central differences of ``residual`` at ``x`` (one-sided where a bound is near)."""
    J = np.empty((n, x.size))
    for j in range(x.size):
        lo, hi = x.copy(), x.copy()
        lo[j] = max(lower[j], x[j] - steps[j])
        hi[j] = min(upper[j], x[j] + steps[j])
        J[:, j] = (residual(hi) - residual(lo)) / (hi[j] - lo[j])
    return J
