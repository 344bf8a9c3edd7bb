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

Intervals that own up to model mismatch
    The covariance of :mod:`evo_door.optim.covariance` is that of an estimate whose
    residual is measurement noise: it shrinks with every effective sample. When the
    model cannot match the data (a real door; the rig's ``--truth rich``), most of the
    residual is model error, the same shape in every trial, which no number of samples
    averages out, and the estimate carries a bias the curvature knows nothing of (on
    the rig's rich truth: F_atD 43 % and unlock_force 5 % off with +-0.1 % intervals).
    The data cannot measure that bias (the part of the model error the parameters
    absorbed leaves no residual), so the intervals are widened by two measurable
    signs of it, and the widening is reported:

    * **the mismatch ratio** ``m`` (:func:`~evo_door.optim.covariance.noise_level`):
      the residual's RMS over its sample-to-sample noise level. Every standard error is
      multiplied by ``max(1, m)``: a model that matches the data (``m`` about 1) keeps
      its statistical intervals, one whose residual is ``m`` times the noise has
      intervals ``m`` times wider. This is a rule of thumb, not a theorem: it is
      calibrated on the rig, where it makes every interval of the physical stage on the
      rich truth cover the truth or say ``not identifiable`` and leaves the model-truth
      fits within their 5 % (``tests/test_identifiability_mismatch.py``);
    * **the spread of per-trial fits** (:func:`evo_door.optim.spread.with_trial_spread`,
      for a ``per_trial``
      run with a pooled answer): each trial alone gives an estimate; their standard
      error ``s / sqrt(n)`` (n trials whose own fit determined the parameter off its
      bounds) is a floor for the pooled estimate's, and ``t(0.975, n - 1) s / sqrt(n)``
      one for its half-width: trials made under other conditions (speed, user) that
      disagree beyond the local interval show a model error the pooled curvature hides.

    ``se_local`` keeps the purely statistical standard errors, ``mismatch`` the ratio,
    ``trial_se`` the per-trial floor (NaN where none applied).

Verdicts (thresholds are arguments, these are the defaults)
    ``not identifiable``: on a bound of its search range (within
    :data:`~evo_door.optim.bounds.BOUND_TOLERANCE`, 1 % of the range: the bound, not the
    data, decided it; the reason says which bound and to widen ``free:``), no
    sensitivity, singular, or a relative 95 % half-width above 10 % of the value;
    ``correlated``: the half-width is narrow but ``|corr| > 0.95`` with a named other
    parameter (the data determine a combination better than each); ``identifiable``
    otherwise.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from evo_door.channels import RESPONSE_CHANNELS, unit
from evo_door.errors import UserError
from evo_door.files import ATTRS
from evo_door.optim.bounds import BOUND_TOLERANCE, bound_side
from evo_door.optim.covariance import (
    MAX_CONDITION,
    MIN_SENSITIVITY,
    autocorrelation_time,
    covariance,
    noise_level,
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
    "se_local",
    "trial_se",
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
    # statistical standard error before any widening; per-trial fits' s / sqrt(n) (NaN:
    # none applied); the residual's noise level (residual unit); residual RMS / noise
    se_local: np.ndarray = field(default_factory=lambda: np.zeros(0))
    trial_se: np.ndarray = field(default_factory=lambda: np.zeros(0))
    noise: float = math.nan
    mismatch: float = math.nan

    def __post_init__(self):
        p = len(self.names)
        if self.se_local.size != p:  # a file written before the widening existed
            self.se_local = np.asarray(self.se, dtype=np.float64).copy()
        if self.trial_se.size != p:
            self.trial_se = np.full(p, math.nan)

    def _widening(self) -> str:
        return _widening_text(self)

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
        from evo_door.files import fields

        attrs = tree[ATTRS]
        settings = fields.mapping(attrs, "settings")
        fields.number(settings, "confidence", None, lo=0.0, hi=1.0)
        fields.flag(settings, "mismatch", True)
        per: tuple = ("p",)
        shapes = {k: per for k in (*_ARRAYS, "names", "units", "verdicts", "reasons", "partners")}
        shapes.update(
            correlation=("p", "p"),
            cosine=("p", "p"),
            tau=("t",),
            trial_ids=("t",),
            se_local=(None,),
            trial_se=(None,),
        )
        return fields.stored(
            cls,
            attrs,
            tree,
            shapes=shapes,
            sizes={"p": "names", "t": "trial_ids"},
            settings=settings,
        )

    def format(self) -> str:
        """A compact table with units: value, SE, 95 % CI, verdict, most correlated partner."""
        level = f"{100 * self.settings.get('confidence', CONFIDENCE):g} %"
        head = (
            f"identifiability at the estimate: {self.channel} residual over "
            f"{len(self.trial_ids)} trials, {self.n_samples} samples, "
            f"{self.n_effective:.3g} effective (residual correlation time "
            f"{_range(self.tau)} samples), RMS error {self.rms:.3g} {self.channel_unit}, "
            f"cond(J^T J) {self.condition:.3g}"
        ) + self._widening()
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


def _widening_text(ident: Identifiability) -> str:
    """What :meth:`Identifiability.format`'s head adds on the widened intervals."""
    out = ""
    if math.isfinite(ident.mismatch):
        out += (
            f"; residual {ident.mismatch:.3g} times its noise level "
            f"({ident.noise:.3g} {ident.residual_unit})"
        )
        if ident.mismatch > 1.0 and ident.settings.get("mismatch", True):
            out += f": intervals x{ident.mismatch:.3g} for model mismatch"
        elif ident.mismatch > 1.0:
            out += ": intervals not widened for it"
    floors = [n for n, t in zip(ident.names, ident.trial_se) if math.isfinite(t)]
    if floors:
        out += f"; per-trial spread a floor for {', '.join(floors)}"
    return out


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
    parts = _per_trial(r, pack)
    tau = np.array([autocorrelation_time(part) if effective else 1.0 for part in parts])
    n_eff = float(sum(part.size / t for part, t in zip(parts, tau)))
    return tau, n_eff


def _confidence_intervals(cov, x, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """Half-widths of the ``confidence`` intervals (Student's t on the fit's degrees of
    freedom) in the parameters' units, and relative to ``|x|`` (inf where x is 0 or the
    error is not determined)."""
    from scipy.special import stdtrit  # Student's t quantile (lighter than scipy.stats)

    dof = cov.dof
    quantile = float(stdtrit(dof, 0.5 + confidence / 2.0)) if dof > 0 else math.inf
    with np.errstate(invalid="ignore", over="ignore"):
        ci_half = quantile * cov.se
    return ci_half, relative_half_widths(ci_half, x)


def relative_half_widths(ci_half, x) -> np.ndarray:
    """``ci_half / |x|``, inf where ``x`` is 0 or the half-width is not determined."""
    with np.errstate(invalid="ignore", divide="ignore"):
        ci_rel = np.where(x != 0.0, ci_half / np.abs(x), math.inf)
    return np.where(np.isnan(ci_rel), math.inf, ci_rel)


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
    on_bound: str = "",
) -> tuple[str, str]:
    """One parameter's verdict and its reason (module docstring, "Verdicts").

    ``undetermined`` is why the covariance could not determine it (None if it could);
    ``partner`` its most correlated other parameter and ``r`` their correlation;
    ``on_bound`` what :func:`_bound_reason` says (``""``: off its bounds).
    """
    if on_bound:
        _, why = _verdict(
            undetermined, ci_rel, partner, r, max_relative_ci, max_correlation, confidence
        )
        return NOT_IDENTIFIABLE, f"{on_bound}; {why}"
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


def _bound_reason(name: str, unit_: str, x: float, lower: float, upper: float) -> str:
    """Why an estimate on a bound of its search range (within ``BOUND_TOLERANCE`` of it)
    is not identifiable, else ``""``.

    >>> _bound_reason("friction_opening", "N", 29.96, 0.0, 30.0)
    'on the upper bound of its search range (29.96 N, bound 30 N): widen free: friction_opening'
    """
    side = bound_side(x, lower, upper, BOUND_TOLERANCE)
    if not side:
        return ""
    bound = upper if side == "upper" else lower
    u = "" if unit_ == "1" else f" {unit_}"
    return f"on the {side} bound of its search range ({x:.4g}{u}, bound {bound:g}{u}): widen free: {name}"


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


def _per_trial(r, pack) -> list[np.ndarray]:
    """``r`` (every trial's counted samples, stacked) cut back into its trials."""
    counted = [int(pack.mask[a:b].sum()) for a, b in zip(pack.offsets[:-1], pack.offsets[1:])]
    return np.split(r, np.cumsum(counted)[:-1])


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
    mismatch: bool = True,
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
    mismatch : bool
        Widen the standard errors by the mismatch ratio (default; module docstring);
        False keeps the statistical ones of the noise alone.
    """
    t0 = time.perf_counter()
    _check_settings(step, confidence)
    x = check_estimate(problem, x)
    names = list(problem.free)
    width = problem.upper - problem.lower
    r, (J, J2), _ = jacobians(problem, x, (step, 2.0 * step))
    tau, n_eff = _effective_samples(r, problem.fit, effective)
    cov = covariance(J, r, n_eff, width, max_condition, min_sensitivity, names)
    se_local = cov.se.copy()
    noise, ratio = noise_level(_per_trial(r, problem.fit))
    if mismatch and math.isfinite(ratio) and ratio > 1.0:
        cov.se = cov.se * ratio
    ci_half, ci_rel = _confidence_intervals(cov, x, confidence)
    norms, cosine, agreement = _sensitivity_columns(J, J2)
    partners, partner_r = _partners(cov.correlation, names)
    units = [problem.model.params[n].unit for n in names]
    thresholds = (max_relative_ci, max_correlation, confidence)
    verdicts, reasons = [], []
    for i in range(len(names)):
        on_bound = _bound_reason(names[i], units[i], x[i], problem.lower[i], problem.upper[i])
        verdict, why = _verdict(
            cov.reasons.get(i), ci_rel[i], partners[i], partner_r[i], *thresholds, on_bound
        )
        verdicts.append(verdict)
        reasons.append(why)
    objective = problem.objective
    channel = RESPONSE_CHANNELS[objective.derivative]
    # the result's fields, one a line: what makes this function long
    return Identifiability(
        names=names,
        units=units,
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
            "mismatch": mismatch,
        },
        note=_note(objective, r),
        seconds=time.perf_counter() - t0,
        se_local=se_local,
        noise=noise,
        mismatch=ratio,
    )
