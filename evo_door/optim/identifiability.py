"""Identifiability of a fit: how well the data pin down each free parameter at the optimum.

The seed notes that its fits "can refer to an equivalent system": two parameters that
change the response in the same way can trade against each other with no loss of fit.
:func:`identifiability` linearises the fit at its optimum ``x`` and says, for each free
parameter, how large that trade is.

The check has three steps, one module each: the residual at ``x`` and its
sensitivity to each parameter (:mod:`evo_door.optim.sensitivity`: how the residual is
weighted, the finite differences), the effective sample count and the covariance they
give (:mod:`evo_door.optim.covariance`: what a coloured residual and a singular
``J^T J`` do), and here the verdicts, which are the thresholds below applied to the
confidence intervals and correlations.

Verdicts (thresholds are arguments, these are the defaults)
    ``not identifiable``: no sensitivity, singular, or a relative 95 % half-width above
    10 % of the value; ``correlated``: the half-width is narrow but ``|corr| > 0.95``
    with a named other parameter (the data determine a combination better than each);
    ``identifiable`` otherwise. A parameter on a bound of its search range is noted in
    its reason (the local theory assumes an interior optimum).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from evo_door.channels import RESPONSE_CHANNELS, unit
from evo_door.errors import UserError
from evo_door.files import ATTRS
from evo_door.optim.bounds import BOUND_TOLERANCE
from evo_door.optim.covariance import (
    MAX_CONDITION,
    MIN_SENSITIVITY,
    autocorrelation_time,
    covariance,
)
from evo_door.optim.sensitivity import STEP, check_estimate, jacobians, sample_weights

IDENTIFIABLE = "identifiable"
CORRELATED = "correlated"
NOT_IDENTIFIABLE = "not identifiable"
VERDICTS = (IDENTIFIABLE, CORRELATED, NOT_IDENTIFIABLE)

#: Verdict thresholds: |correlation|, relative 95 % half-width (cond(J^T J) and the
#: smallest sensitivity that counts: MAX_CONDITION, MIN_SENSITIVITY of .covariance).
MAX_CORRELATION = 0.95
MAX_RELATIVE_CI = 0.10
CONFIDENCE = 0.95

_ARRAYS = (
    "x",
    "lower",
    "upper",
    "se",
    "ci_half",
    "ci_rel",
    "correlation",
    "cosine",
    "sensitivity",
    "sensitivity_range",
    "tau",
    "partner_r",
)


# -- the result ---------------------------------------------------------------------------
@dataclass
class Identifiability:
    """Identifiability of one fit at its optimum (module docstring); arrays per parameter."""

    names: list[str]
    units: list[str]
    x: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    se: np.ndarray  # standard error, parameter unit (inf: not determined)
    ci_half: np.ndarray  # half-width of the confidence interval, parameter unit
    ci_rel: np.ndarray  # ci_half / |x|
    correlation: np.ndarray  # (p, p)
    cosine: np.ndarray  # (p, p) cosine between sensitivity columns
    sensitivity: np.ndarray  # || x_j dr/dx_j ||, residual unit
    sensitivity_range: np.ndarray  # || (hi_j - lo_j) dr/dx_j ||, residual unit
    verdicts: list[str]
    reasons: list[str]
    partners: list[str]  # most correlated other parameter ("" if none)
    partner_r: np.ndarray  # its correlation
    trial_ids: list[str]
    tau: np.ndarray  # autocorrelation time per trial, samples
    n_samples: int
    n_effective: float
    ssr: float  # sum of squared residuals: the summed ISE, (channel unit)^2 s
    rms: float  # sqrt(SSR / counted time): RMS error on the channel, channel unit
    sigma2: float
    dof: float
    condition: float
    step: float
    step_agreement: float
    channel: str
    channel_unit: str
    objective: dict
    settings: dict
    note: str = ""
    seconds: float = 0.0

    @property
    def residual_unit(self) -> str:
        return f"{self.channel_unit} s^0.5"

    def verdict(self, name: str) -> str:
        return self.verdicts[self.names.index(name)]

    def as_dict(self) -> dict:
        """Parameter name -> its numbers and verdict (JSON-able)."""
        out = {}
        for i, n in enumerate(self.names):
            out[n] = {
                "value": float(self.x[i]),
                "unit": self.units[i],
                "se": float(self.se[i]),
                "ci_half": float(self.ci_half[i]),
                "ci_rel": float(self.ci_rel[i]),
                "verdict": self.verdicts[i],
                "reason": self.reasons[i],
                "partner": self.partners[i],
                "partner_r": float(self.partner_r[i]),
            }
        return out

    def to_tree(self) -> dict:
        """A tree for :func:`evo_door.files.write_h5`: arrays as datasets, the rest attributes."""
        attrs = {
            k: v
            for k, v in vars(self).items()
            if k not in _ARRAYS and not isinstance(v, np.ndarray)
        }
        attrs["format"] = "evo-door identifiability"
        tree = {ATTRS: attrs}
        for k in _ARRAYS:
            tree[k] = np.asarray(getattr(self, k), dtype=np.float64)
        return tree

    @classmethod
    def from_tree(cls, tree: dict) -> Identifiability:
        """The inverse of :meth:`to_tree` (from a tree read back by ``read_group``)."""
        attrs = dict(tree[ATTRS])
        attrs.pop("format", None)
        values = {k: np.asarray(tree[k], dtype=np.float64) for k in _ARRAYS}
        for k in ("names", "units", "verdicts", "reasons", "partners", "trial_ids"):
            values[k] = list(attrs.pop(k))
        values.update(attrs)
        values["n_samples"] = int(values["n_samples"])
        return cls(**values)

    def format(self) -> str:
        """A compact table with units: value, SE, 95 % CI, verdict, most correlated partner."""
        level = f"{100 * self.settings.get('confidence', CONFIDENCE):g} %"
        head = (
            f"identifiability at the estimate: {self.channel} residual over "
            f"{len(self.trial_ids)} trials, {self.n_samples} samples, "
            f"{self.n_effective:.3g} effective (residual correlation time "
            f"{_range(self.tau)} samples), RMS error {self.rms:.3g} {self.channel_unit}, "
            f"cond(J^T J) {self.condition:.3g}"
        )
        header = ["parameter", "value", "unit", "SE", f"{level} CI", "verdict", "most correlated"]
        rows = []
        for i, n in enumerate(self.names):
            partner = f"{self.partners[i]} {self.partner_r[i]:+.3f}" if self.partners[i] else "-"
            ci = f"+-{100 * self.ci_rel[i]:.3g} %" if math.isfinite(self.ci_rel[i]) else "inf"
            rows.append(
                [
                    n,
                    f"{self.x[i]:.6g}",
                    self.units[i],
                    f"{self.se[i]:.3g}",
                    ci,
                    self.verdicts[i],
                    partner,
                ]
            )
        widths = [max(len(r[k]) for r in [header, *rows]) for k in range(len(header))]
        lines = [head, "  ".join(h.ljust(w) for h, w in zip(header, widths)).rstrip()]
        lines.append("  ".join("-" * w for w in widths))
        lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
        lines += [
            f"{n}: {why}"
            for n, v, why in zip(self.names, self.verdicts, self.reasons)
            if v != IDENTIFIABLE
        ]
        if self.note:
            lines.append(f"note: {self.note}")
        return "\n".join(lines)


def _range(values) -> str:
    values = np.asarray(values)
    if values.size == 0:
        return "-"
    lo, hi = float(values.min()), float(values.max())
    return f"{lo:.3g}" if np.isclose(lo, hi) else f"{lo:.3g}..{hi:.3g}"


# -- the steps ----------------------------------------------------------------------------
def _check_settings(step: float, confidence: float) -> None:
    """The finite-difference step and the confidence level are usable, else one line."""
    if not (0.0 < step < 0.25):
        raise UserError(f"finite-difference step {step!r} must be in (0, 0.25) of the range")
    if not (0.0 < confidence < 1.0):
        raise UserError(f"confidence {confidence!r} must be between 0 and 1")


def _effective_samples(r, pack, effective: bool) -> tuple[np.ndarray, float]:
    """Each trial's residual correlation time (samples) and the effective sample count.

    ``r`` stacks the trials' counted samples in order; ``N_eff = sum n / tau``
    (:mod:`evo_door.optim.covariance`). Without ``effective`` every ``tau`` is 1: each
    sample counts as independent.
    """
    counted = [int(pack.mask[a:b].sum()) for a, b in zip(pack.offsets[:-1], pack.offsets[1:])]
    bounds = np.cumsum([0, *counted])
    tau = np.array(
        [
            autocorrelation_time(r[a:b]) if effective else 1.0
            for a, b in zip(bounds[:-1], bounds[1:])
        ]
    )
    n_eff = float(sum(c / t for c, t in zip(counted, tau)))
    return tau, n_eff


def _confidence_intervals(cov, x, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """Half-widths of the ``confidence`` intervals (Student's t on the fit's degrees of
    freedom) in the parameters' units, and relative to ``|x|`` (inf where x is 0 or the
    error is not determined)."""
    from scipy.special import stdtrit  # Student's t quantile (lighter than scipy.stats)

    dof = cov.dof
    quantile = float(stdtrit(dof, 0.5 + confidence / 2.0)) if dof > 0 else math.inf
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        ci_half = quantile * cov.se
        ci_rel = np.where(x != 0.0, ci_half / np.abs(x), math.inf)
    ci_rel = np.where(np.isnan(ci_rel), math.inf, ci_rel)
    return ci_half, ci_rel


def _sensitivity_columns(J, J2) -> tuple[np.ndarray, np.ndarray, float]:
    """The Jacobian's column norms, the cosines between its columns, and how much the
    columns change from step ``h`` (``J``) to ``2 h`` (``J2``): the largest relative
    change (``step_agreement``). A column that blew up counts as zero."""
    finite = np.all(np.isfinite(J), axis=0)
    Jf = np.where(finite, J, 0.0)
    norms = np.linalg.norm(Jf, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = (Jf.T @ Jf) / np.outer(norms, norms)
        change = np.linalg.norm(np.where(finite, J - J2, 0.0), axis=0) / norms
    cosine[~np.isfinite(cosine)] = math.nan
    agreement = float(np.max(change[np.isfinite(change)], initial=0.0))
    return norms, cosine, agreement


def _partners(correlation, names) -> tuple[list[str], np.ndarray]:
    """Each parameter's most correlated other one (``""`` if none) and that correlation."""
    p = len(names)
    partners, partner_r = [], np.full(p, math.nan)
    for i in range(p):
        row = np.abs(np.where(np.arange(p) == i, math.nan, correlation[i]))
        k = int(np.nanargmax(row)) if np.any(np.isfinite(row)) else -1
        partners.append(names[k] if k >= 0 else "")
        partner_r[i] = correlation[i, k] if k >= 0 else math.nan
    return partners, partner_r


def _verdict(
    undetermined: str | None,
    ci_rel: float,
    partner: str,
    r: float,
    max_relative_ci: float,
    max_correlation: float,
    confidence: float,
) -> tuple[str, str]:
    """One parameter's verdict and its reason (module docstring, "Verdicts").

    ``undetermined`` is why the covariance could not determine it (None if it could);
    ``partner`` its most correlated other parameter and ``r`` their correlation.
    """
    correlated = bool(partner) and abs(r) > max_correlation
    if undetermined is not None:
        return NOT_IDENTIFIABLE, undetermined
    if ci_rel > max_relative_ci:
        why = f"{100 * confidence:g} % CI +-{100 * ci_rel:.3g} % > {100 * max_relative_ci:g} %"
        if correlated:
            why += f", correlation {r:+.3f} with {partner}"
        return NOT_IDENTIFIABLE, why
    if correlated:
        return CORRELATED, f"correlation {r:+.3f} with {partner} (|r| > {max_correlation:g})"
    return IDENTIFIABLE, f"{100 * confidence:g} % CI +-{100 * ci_rel:.3g} %"


def _bound_note(x: float, lower: float, upper: float) -> str:
    """What a reason adds for an estimate on a bound of its search range (else ``""``):
    the local theory assumes an interior optimum."""
    slack = BOUND_TOLERANCE * (upper - lower)
    if x - lower <= slack or upper - x <= slack:
        side = "lower" if x - lower <= slack else "upper"
        return f"; on the {side} bound of its search range: the local theory does not hold"
    return ""


def _note(objective, r) -> str:
    """What the result should say about itself: an objective that is not a sum of
    squares, a zero residual (a noise-free target)."""
    note = ""
    if objective.kind != "ise" or objective.combine == "max":
        note = (
            f"the objective ({objective.kind}, combine {objective.combine}) is not a sum of "
            "squares: computed on the ISE of the same channel at this estimate, which it "
            "need not minimise"
        )
    if not float(r @ r) > 0.0:
        note = "; ".join(
            filter(
                None,
                [
                    note,
                    "the residual is zero (a noise-free target): every standard error is 0, "
                    "only a correlation or a singularity can flag a parameter",
                ],
            )
        )
    return note


def _rms(r, pack) -> float:
    """The RMS error on the channel: ``sqrt(SSR / counted time)``, in the channel's unit."""
    counted_time = float(sum(np.sum(w**2) for w in sample_weights(pack)))
    return math.sqrt(float(r @ r) / counted_time) if counted_time > 0 else math.nan


# -- the entry point ----------------------------------------------------------------------
def identifiability(
    problem,
    x,
    step: float = STEP,
    max_correlation: float = MAX_CORRELATION,
    max_relative_ci: float = MAX_RELATIVE_CI,
    max_condition: float = MAX_CONDITION,
    min_sensitivity: float = MIN_SENSITIVITY,
    confidence: float = CONFIDENCE,
    effective: bool = True,
) -> Identifiability:
    """Identifiability of ``problem``'s free parameters at the estimate ``x``.

    Parameters
    ----------
    problem : Problem
    x : array_like
        The estimate (free parameters in the problem's order, inside the search range).
    step : float
        Finite-difference step as a fraction of each search range.
    max_correlation, max_relative_ci, max_condition, min_sensitivity :
        Verdict thresholds (module docstring).
    confidence : float
        Level of the confidence intervals.
    effective : bool
        Count effective samples from the residual's autocorrelation (default); False
        treats every sample as independent (white residual).
    """
    t0 = time.perf_counter()
    _check_settings(step, confidence)
    x = check_estimate(problem, x)
    names = list(problem.free)
    width = problem.upper - problem.lower
    r, (J, J2), _ = jacobians(problem, x, (step, 2.0 * step))
    tau, n_eff = _effective_samples(r, problem.fit, effective)
    cov = covariance(J, r, n_eff, width, max_condition, min_sensitivity, names)
    ci_half, ci_rel = _confidence_intervals(cov, x, confidence)
    norms, cosine, agreement = _sensitivity_columns(J, J2)
    partners, partner_r = _partners(cov.correlation, names)
    verdicts, reasons = [], []
    for i in range(len(names)):
        verdict, why = _verdict(
            cov.reasons.get(i),
            ci_rel[i],
            partners[i],
            partner_r[i],
            max_relative_ci,
            max_correlation,
            confidence,
        )
        verdicts.append(verdict)
        reasons.append(why + _bound_note(x[i], problem.lower[i], problem.upper[i]))
    objective = problem.objective
    channel = RESPONSE_CHANNELS[objective.derivative]
    # the result's fields, one a line: what makes this function long
    return Identifiability(
        names=names,
        units=[problem.model.params[n].unit for n in names],
        x=x.copy(),
        lower=problem.lower.copy(),
        upper=problem.upper.copy(),
        se=cov.se,
        ci_half=ci_half,
        ci_rel=ci_rel,
        correlation=cov.correlation,
        cosine=cosine,
        sensitivity=norms * np.abs(x),
        sensitivity_range=norms * width,
        verdicts=verdicts,
        reasons=reasons,
        partners=partners,
        partner_r=partner_r,
        trial_ids=list(problem.fit.ids),
        tau=tau,
        n_samples=int(r.size),
        n_effective=n_eff,
        ssr=float(r @ r),
        rms=_rms(r, problem.fit),
        sigma2=cov.sigma2,
        dof=cov.dof,
        condition=cov.condition,
        step=float(step),
        step_agreement=agreement,
        channel=channel,
        channel_unit=unit(channel, getattr(problem.model, "theta_unit", "rad")),
        objective={
            "kind": objective.kind,
            "derivative": objective.derivative,
            "combine": objective.combine,
        },
        settings={
            "max_correlation": max_correlation,
            "max_relative_ci": max_relative_ci,
            "max_condition": max_condition,
            "min_sensitivity": min_sensitivity,
            "confidence": confidence,
            "effective": effective,
        },
        note=_note(objective, r),
        seconds=time.perf_counter() - t0,
    )
