"""The spread of per-trial fits as a floor for a pooled fit's intervals.

Part of the identifiability check (:mod:`evo_door.optim.identifiability`, "Intervals
that own up to model mismatch"): a ``per_trial`` run fits each trial alone and, with
``pooled``, all of them at once. Trials made under other conditions (speed, user,
start) that disagree beyond the pooled fit's local interval show an error the pooled
curvature hides, so their standard error is a floor for the pooled one.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from evo_door.optim.bounds import bound_side
from evo_door.optim.identifiability import (
    CONFIDENCE,
    MAX_CORRELATION,
    MAX_RELATIVE_CI,
    Identifiability,
    _bound_reason,
    _verdict,
    relative_half_widths,
)


def with_trial_spread(ident: Identifiability, estimates, usable=None) -> Identifiability:
    """``ident`` (of a pooled fit) with the spread of per-trial fits as a floor.

    Parameters
    ----------
    ident : Identifiability
        The pooled fit's, at its estimate.
    estimates : (n, p) array
        One row per trial: that trial's own fit, in ``ident``'s parameter order.
    usable : (n, p) bool array, optional
        Which per-trial estimates count (default all): a trial whose own fit left a
        parameter undetermined or on a bound says nothing about it.

    For a parameter with at least two usable estimates of standard deviation ``s``,
    the standard error is at least ``s / sqrt(n)`` and the half-width at least
    ``t(0.5 + confidence / 2, n - 1) s / sqrt(n)`` (module docstring); the verdicts
    follow the widened intervals. A parameter the pooled fit could not determine keeps
    its verdict.
    """
    from scipy.special import stdtrit

    X = np.atleast_2d(np.asarray(estimates, dtype=np.float64))
    p = len(ident.names)
    if X.shape[1] != p:
        raise ValueError(f"estimates need {p} columns, got {X.shape[1]}")
    ok = np.isfinite(X) if usable is None else np.asarray(usable, dtype=bool) & np.isfinite(X)
    level = float(ident.settings.get("confidence", CONFIDENCE))
    se, ci_half = ident.se.copy(), ident.ci_half.copy()
    trial_se = np.full(p, math.nan)
    for j in range(p):
        values = X[ok[:, j], j]
        if values.size < 2 or not math.isfinite(ident.se_local[j]):
            continue
        trial_se[j] = float(np.std(values, ddof=1)) / math.sqrt(values.size)
        se[j] = max(se[j], trial_se[j])
        ci_half[j] = max(ci_half[j], float(stdtrit(values.size - 1, 0.5 + level / 2)) * trial_se[j])
    ci_rel = relative_half_widths(ci_half, ident.x)
    verdicts, reasons = list(ident.verdicts), list(ident.reasons)
    s = ident.settings
    thresholds = (
        s.get("max_relative_ci", MAX_RELATIVE_CI),
        s.get("max_correlation", MAX_CORRELATION),
        level,
    )
    for j in range(p):
        if not math.isfinite(trial_se[j]):
            continue
        on_bound = _bound_reason(
            ident.names[j], ident.units[j], ident.x[j], ident.lower[j], ident.upper[j]
        )
        verdicts[j], reasons[j] = _verdict(
            None, ci_rel[j], ident.partners[j], ident.partner_r[j], *thresholds, on_bound
        )
    out = replace(ident, verdicts=verdicts, reasons=reasons)
    out.se, out.ci_half, out.ci_rel, out.trial_se = se, ci_half, ci_rel, trial_se
    return out


def trial_estimates(idents) -> tuple[np.ndarray, np.ndarray]:
    """``(estimates, usable)`` for :func:`with_trial_spread` from per-trial results.

    ``idents`` holds each trial's own :class:`Identifiability` (None where its check
    could not be made: that row is NaN). An estimate is usable where its own fit
    determined it (a finite statistical standard error) off its search bounds.
    """
    rows = [i for i in idents if i is not None]
    p = len(rows[0].names) if rows else 0
    X = np.full((len(idents), p), math.nan)
    usable = np.zeros((len(idents), p), dtype=bool)
    for k, ident in enumerate(idents):
        if ident is None:
            continue
        X[k] = ident.x
        for j in range(p):
            usable[k, j] = math.isfinite(ident.se_local[j]) and not bound_side(
                ident.x[j], ident.lower[j], ident.upper[j]
            )
    return X, usable
