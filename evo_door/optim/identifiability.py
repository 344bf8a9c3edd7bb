"""Identifiability of a fit: how well the data pin down each free parameter at the optimum.

The seed notes that its fits "can refer to an equivalent system": two parameters that
change the response in the same way can trade against each other with no loss of fit.
:func:`identifiability` linearises the fit at its optimum ``x`` and says, for each free
parameter, how large that trade is.

Residuals
    ``r`` stacks, over every fitted trial and every *counted* sample (a saturated
    sensor sample does not count), ``sqrt(w_k dt) (y_s[k] - y_h[k])``: model minus
    target on the objective's channel (``d^n theta``), with the trapezoid weights of the
    ISE kernel (``w = 1/2`` at a trial's first and last sample, else 1). So
    ``sum(r^2)`` is the sum over the trials of their ISE (eq. 5.4), the fitness of an
    ISE objective with ``combine: sum`` (``mean`` divides it by the number of trials,
    which changes neither the minimiser nor the standard errors below). The theory is
    that of least squares, a sum of squares at its minimum. For a **max-square**
    objective (eq. 5.3) or ``combine: max``, which are not sums of squares, the same ISE
    residuals are used at the given ``x``: the numbers then describe the ISE of the same
    channel linearised there, which is the local information the data hold, but ``x`` is
    not its minimiser (the result says so in ``note``).
Sensitivity
    ``J = dr/dx`` by central differences with the step ``h_j = step (hi_j - lo_j)``,
    a fixed fraction of parameter ``j``'s search range (default ``1e-4``): the range is
    what the experiment calls a meaningful variation of the parameter, and unlike
    ``|x_j|`` it is never zero. The responses are smooth in the parameters (fixed-step
    integration, tanh friction laws), so the error is ``O(h^2)`` plus round-off of
    order ``1e-16 / 1e-4``: both far below the statistical spread (the tests compare
    with scipy's ``approx_fprime`` and across steps from 1e-5 to 1e-3). Where ``x_j +-
    2 h_j`` leaves the search range the second-order one-sided difference inward is
    used. ``J`` is evaluated at ``h`` and at ``2 h``; ``step_agreement`` is the largest
    relative change of a column between the two (round-off or a kink shows there).
    Normalised sensitivities, comparable between parameters: ``sensitivity`` is
    ``|| x_j dr/dx_j ||`` (``dr / d ln x``: the residual change for a 100 % change of
    the parameter, linearised) and ``sensitivity_range`` ``|| (hi_j - lo_j) dr/dx_j ||``,
    both in the residual's unit (``rad/s s^0.5`` for ISE on speed); ``cosine`` is the
    cosine between sensitivity columns (``+-1``: the same effect on the response).
Covariance
    ``C = sigma^2 (J^T J)^-1``, ``sigma^2 = SSR / (N_eff - p)``, standard errors
    ``sqrt(diag C)``, 95 % half-widths ``t(0.975, N_eff - p) SE``, correlations
    ``C_ij / sqrt(C_ii C_jj)``.
Effective sample count
    Samples at 1024 Hz are not independent: the residual is coloured (the load cell's
    noise integrated by the door is a slow random error; a sensor bias is constant over
    a trial). With ``N`` samples of correlation time ``tau`` (in samples), the
    covariance of a least-squares estimate is about ``tau`` times the white-noise one
    when the sensitivities vary slowly over ``tau`` (``J^T Sigma J ~ tau sigma_e^2 J^T
    J``), that is the white-noise formula with ``N_eff = N / tau`` independent
    samples in place of ``N``: then ``SSR / N * tau = SSR / N_eff`` and with the
    ``p`` degrees of freedom of the fit ``sigma^2 = SSR / (N_eff - p)`` multiplies
    ``(J^T J)^-1`` of all ``N`` samples. ``tau`` is the integrated autocorrelation time
    of each trial's residual, ``1 + 2 sum_k rho_k`` summed up to the first lag where
    ``rho_k <= 0``, with the *non-centred* autocorrelation ``rho_k = sum r_i r_{i+k} /
    sum r_i^2`` so that a constant offset counts as fully correlated (a pure bias gives
    ``tau = n``: one independent value per trial), and ``N_eff = sum_trials n / tau``.
Singular or ill-conditioned ``J^T J``
    A parameter whose range-scaled column is below ``min_sensitivity`` times the largest
    (a latch parameter on trials that never reach the latch) has no sensitivity: its
    standard error is infinite. Then, on the columns scaled to unit length (so only
    their directions matter), while ``cond(J^T J) > max_condition`` the parameter that
    dominates the smallest singular vector is set aside as undetermined, naming the
    parameters it trades with. The covariance of the others is that of the fit with
    those held at their values (a pseudo-inverse that drops the null directions).
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
from dataclasses import dataclass, field

import numpy as np

from evo_door.channels import RESPONSE_CHANNELS, unit
from evo_door.errors import UserError
from evo_door.files import ATTRS
from evo_door.optim.bounds import BOUND_TOLERANCE
from evo_door.sim.simulate import simulate_batch

IDENTIFIABLE = "identifiable"
CORRELATED = "correlated"
NOT_IDENTIFIABLE = "not identifiable"
VERDICTS = (IDENTIFIABLE, CORRELATED, NOT_IDENTIFIABLE)

#: Finite-difference step, as a fraction of each parameter's search range.
STEP = 1e-4
#: Verdict thresholds: |correlation|, relative 95 % half-width, cond(J^T J), and the
#: smallest range-scaled sensitivity (relative to the largest) that counts as one.
MAX_CORRELATION = 0.95
MAX_RELATIVE_CI = 0.10
MAX_CONDITION = 1e10
MIN_SENSITIVITY = 1e-6
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


# -- residuals and their sensitivity ----------------------------------------------------
def _weights(pack) -> list[np.ndarray]:
    """Per trial, ``sqrt(w_k dt)`` on counted samples, 0 elsewhere (the ISE kernel's)."""
    out = []
    for j, (a, b) in enumerate(zip(pack.offsets[:-1], pack.offsets[1:])):
        w = np.full(b - a, pack.dt[j])
        w[0] *= 0.5
        w[-1] *= 0.5
        out.append(np.sqrt(np.where(pack.mask[a:b], w, 0.0)))
    return out


def _responses(problem, X) -> tuple[list[np.ndarray], np.ndarray]:
    """Weighted residuals of every row of ``X`` on each fitted trial, and which blew up.

    Returns a list (one per trial) of ``(len(X), n_counted)`` arrays and a boolean
    array, True where a row's simulation of some trial blew up.
    """
    pack = problem.fit
    P = problem.full(X)
    derivative = problem.objective.derivative
    blown = np.zeros(len(P), dtype=bool)
    out = []
    for j, sw in enumerate(_weights(pack)):
        a, b = pack.offsets[j], pack.offsets[j + 1]
        sim = simulate_batch(
            problem.model,
            P,
            pack.force[a:b],
            pack.dt[j],
            theta0=pack.theta0[j],
            dtheta0=pack.dtheta0[j],
            method=problem.method,
            substeps=problem.substeps,
        )
        keep = sw > 0.0
        r = (sim[derivative][:, keep] - pack.target[a:b][keep]) * sw[keep]
        blown |= ~sim[3] | ~np.all(np.isfinite(r), axis=1)
        out.append(r)
    return out, blown


def residuals(problem, x) -> list[np.ndarray]:
    """Weighted residuals of ``x`` on each fitted trial (see the module docstring).

    The sum of their squares is the ISE (eq. 5.4) summed over the trials.
    """
    x = _check_x(problem, x)
    r, blown = _responses(problem, x[None, :])
    if blown[0]:
        raise UserError("the model blows up at the estimate: no identifiability to compute")
    return [rj[0] for rj in r]


def _stencils(x, lo, hi, h):
    """Per parameter: offsets (in steps) and weights of a derivative of step ``h``.

    Central ``(f(+1) - f(-1)) / 2`` where ``x +- 2 h`` stays in range, else the
    second-order one-sided difference inward, ``(-3 f(0) + 4 f(1) - f(2)) / 2``.
    """
    out = []
    for v, a, b, s in zip(x, lo, hi, h):
        if v - 2.0 * s >= a and v + 2.0 * s <= b:
            out.append(((-1.0, 1.0), (-0.5, 0.5)))
        else:
            d = 1.0 if v - 2.0 * s < a else -1.0
            out.append(((0.0, d, 2.0 * d), (-1.5 * d, 2.0 * d, -0.5 * d)))
    return out


def jacobians(problem, x, steps=(STEP,)) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """Residual at ``x`` and its Jacobian for each relative step in ``steps``.

    Returns ``(r, [J for each step], blown)``: ``r`` of length N (every trial's counted
    samples, stacked), each ``J`` (N, p) in residual unit per parameter unit, ``blown``
    (p,) True where a finite-difference point blew up (that column is NaN).
    """
    x = _check_x(problem, x)
    width = problem.upper - problem.lower
    rows = [x]
    plan = []  # per step, per parameter: (row indices, weights, h)
    for step in steps:
        h = float(step) * width
        per = []
        for j, (offsets, weights) in enumerate(_stencils(x, problem.lower, problem.upper, h)):
            idx = []
            for o in offsets:
                if o == 0.0:
                    idx.append(0)
                    continue
                xi = x.copy()
                xi[j] = x[j] + o * h[j]
                idx.append(len(rows))
                rows.append(np.clip(xi, problem.lower, problem.upper))
            per.append((idx, np.array(weights), h[j]))
        plan.append(per)
    parts, blown_rows = _responses(problem, np.array(rows))
    if blown_rows[0]:
        raise UserError("the model blows up at the estimate: no identifiability to compute")
    R = np.concatenate(parts, axis=1)  # (rows, N)
    r0 = R[0]
    blown = np.zeros(len(x), dtype=bool)
    out = []
    for per in plan:
        J = np.empty((R.shape[1], len(x)))
        for j, (idx, weights, hj) in enumerate(per):
            if blown_rows[idx].any():
                blown[j] = True
                J[:, j] = np.nan
            else:
                J[:, j] = weights @ R[idx] / hj
        out.append(J)
    return r0, out, blown


# -- the statistics, from a residual and a Jacobian --------------------------------------
def autocorrelation_time(r) -> float:
    """Integrated autocorrelation time (samples) of a residual, non-centred.

    ``1 + 2 sum_k rho_k`` up to the first lag with ``rho_k <= 0``, in ``[1, len(r)]``
    (module docstring). A white residual gives about 1, a constant one ``len(r)``.

    >>> autocorrelation_time(np.ones(100)), autocorrelation_time(np.zeros(5))
    (100.0, 1.0)
    """
    r = np.asarray(r, dtype=np.float64)
    n = r.size
    energy = float(r @ r)
    if n < 2 or not energy > 0.0:
        return 1.0
    size = 1 << (2 * n - 1).bit_length()
    spectrum = np.fft.rfft(r, size)
    acf = np.fft.irfft(spectrum * np.conj(spectrum), size)[:n] / energy
    negative = np.flatnonzero(acf[1:] <= 0.0)
    stop = 1 + (int(negative[0]) if negative.size else n - 1)
    tau = 1.0 + 2.0 * float(np.sum(acf[1:stop]))
    return float(min(max(tau, 1.0), n))


@dataclass
class Covariance:
    """What :func:`covariance` finds from a residual and a Jacobian (module docstring)."""

    se: np.ndarray  # standard errors, inf where not determined
    correlation: np.ndarray  # NaN rows / columns where not determined
    sigma2: float  # SSR / (N_eff - p)
    dof: float  # N_eff - p (of the determined parameters)
    condition: float  # cond(J^T J) of the unit-length columns, all parameters with sensitivity
    reasons: dict = field(default_factory=dict)  # index -> why it is not determined


def covariance(
    J,
    r,
    n_effective: float | None = None,
    scale=None,
    max_condition: float = MAX_CONDITION,
    min_sensitivity: float = MIN_SENSITIVITY,
    names=None,
) -> Covariance:
    """Approximate covariance ``SSR / (N_eff - p) (J^T J)^-1`` of a least-squares fit.

    Parameters
    ----------
    J : (N, p) array
        Jacobian of the residual ``r`` with respect to the parameters.
    r : (N,) array
        Residual at the optimum.
    n_effective : float, optional
        Effective number of independent samples (default ``N``: white residual).
    scale : (p,) array, optional
        Meaningful variation of each parameter (the search range): a column whose
        ``scale``-times norm is below ``min_sensitivity`` times the largest has no
        sensitivity. Without it (units unknown) only an all-zero column has none.
    max_condition, min_sensitivity :
        See the module docstring.
    names : sequence of str, optional
        Parameter names for the reasons (default ``x0, x1...``).
    """
    J = np.asarray(J, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    n, p = J.shape
    names = list(names) if names is not None else [f"x{i}" for i in range(p)]
    relative = scale is not None
    scale = np.ones(p) if scale is None else np.asarray(scale, dtype=np.float64)
    n_eff = float(n if n_effective is None else n_effective)
    reasons: dict[int, str] = {}

    bad = ~np.all(np.isfinite(J), axis=0)
    for j in np.flatnonzero(bad):
        reasons[int(j)] = "the simulation blew up in its finite differences"
    norms = np.where(bad, 0.0, np.linalg.norm(np.where(bad, 0.0, J), axis=0))
    ranged = norms * np.abs(scale)
    top = ranged.max() if p and relative else 0.0
    for j in range(p):
        if j not in reasons and not ranged[j] > min_sensitivity * top:
            reasons[j] = "no sensitivity: the residual does not change with it"

    def unit_columns(cols):
        return J[:, cols] / norms[cols]

    def cond(cols) -> tuple[float, np.ndarray]:
        if not cols:
            return 1.0, np.zeros((0, 0))
        _, s, vt = np.linalg.svd(unit_columns(cols), full_matrices=False)
        c = math.inf if s[-1] == 0.0 else float((s[0] / s[-1]) ** 2)
        return c, vt

    keep = [j for j in range(p) if j not in reasons]
    condition, _ = cond(keep)
    while True:
        c, vt = cond(keep)
        if c <= max_condition:
            break
        v = np.abs(vt[-1])
        worst = keep[int(np.argmax(v))]
        partners = [names[keep[i]] for i in np.argsort(-v) if keep[i] != worst and v[i] > 0.1]
        reasons[worst] = f"singular: cond(J^T J) {c:.2g} > {max_condition:.2g}" + (
            f", trades with {', '.join(partners)}" if partners else ""
        )
        keep.remove(worst)

    se = np.full(p, math.inf)
    corr = np.full((p, p), math.nan)
    ssr = float(r @ r)
    dof = n_eff - len(keep)
    sigma2 = ssr / dof if dof > 0 else math.inf
    if keep:
        A = unit_columns(keep)
        _, s, vt = np.linalg.svd(A, full_matrices=False)
        inv = (vt.T / s**2) @ vt  # (A^T A)^-1, A = J D with D = diag(1 / norms)
        d = 1.0 / norms[keep]
        cov = sigma2 * inv * np.outer(d, d) if math.isfinite(sigma2) else None
        if cov is None:
            for j in keep:
                reasons[j] = f"{n_eff:.3g} effective samples for {len(keep)} parameters"
        else:
            sd = np.sqrt(np.diag(cov))
            se[keep] = sd
            with np.errstate(invalid="ignore", divide="ignore"):
                c = inv / np.sqrt(np.outer(np.diag(inv), np.diag(inv)))
            corr[np.ix_(keep, keep)] = np.clip(c, -1.0, 1.0)
    return Covariance(se, corr, sigma2, dof, condition, reasons)


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


def _check_x(problem, x) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    if x.shape != (problem.n_var,):
        raise UserError(f"the estimate needs {problem.n_var} values ({', '.join(problem.free)})")
    if not np.all(np.isfinite(x)):
        raise UserError("the estimate has a non-finite value")
    outside = (x < problem.lower) | (x > problem.upper)
    if outside.any():
        j = int(np.flatnonzero(outside)[0])
        raise UserError(
            f"the estimate {problem.free[j]} = {x[j]:g} is outside its search range "
            f"[{problem.lower[j]:g}, {problem.upper[j]:g}]"
        )
    return x


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
    from scipy.special import stdtrit  # Student's t quantile (lighter than scipy.stats)

    t0 = time.perf_counter()
    if not (0.0 < step < 0.25):
        raise UserError(f"finite-difference step {step!r} must be in (0, 0.25) of the range")
    if not (0.0 < confidence < 1.0):
        raise UserError(f"confidence {confidence!r} must be between 0 and 1")
    x = _check_x(problem, x)
    names = list(problem.free)
    p = len(names)
    width = problem.upper - problem.lower
    r, (J, J2), blown = jacobians(problem, x, (step, 2.0 * step))

    pack = problem.fit
    counted = [int(pack.mask[a:b].sum()) for a, b in zip(pack.offsets[:-1], pack.offsets[1:])]
    bounds = np.cumsum([0, *counted])
    tau = np.array(
        [
            autocorrelation_time(r[a:b]) if effective else 1.0
            for a, b in zip(bounds[:-1], bounds[1:])
        ]
    )
    n = int(r.size)
    n_eff = float(sum(c / t for c, t in zip(counted, tau)))

    cov = covariance(J, r, n_eff, width, max_condition, min_sensitivity, names)
    dof = cov.dof
    quantile = float(stdtrit(dof, 0.5 + confidence / 2.0)) if dof > 0 else math.inf
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        ci_half = quantile * cov.se
        ci_rel = np.where(x != 0.0, ci_half / np.abs(x), math.inf)
    ci_rel = np.where(np.isnan(ci_rel), math.inf, ci_rel)

    finite = np.all(np.isfinite(J), axis=0)
    Jf = np.where(finite, J, 0.0)
    norms = np.linalg.norm(Jf, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = (Jf.T @ Jf) / np.outer(norms, norms)
        change = np.linalg.norm(np.where(finite, J - J2, 0.0), axis=0) / norms
    cosine[~np.isfinite(cosine)] = math.nan
    agreement = float(np.max(change[np.isfinite(change)], initial=0.0))

    partners, partner_r = [], np.full(p, math.nan)
    verdicts, reasons = [], []
    for i in range(p):
        row = np.abs(np.where(np.arange(p) == i, math.nan, cov.correlation[i]))
        k = int(np.nanargmax(row)) if np.any(np.isfinite(row)) else -1
        partners.append(names[k] if k >= 0 else "")
        partner_r[i] = cov.correlation[i, k] if k >= 0 else math.nan
        if i in cov.reasons:
            verdict, why = NOT_IDENTIFIABLE, cov.reasons[i]
        elif ci_rel[i] > max_relative_ci:
            verdict = NOT_IDENTIFIABLE
            why = (
                f"{100 * confidence:g} % CI +-{100 * ci_rel[i]:.3g} % > {100 * max_relative_ci:g} %"
            )
            if k >= 0 and abs(partner_r[i]) > max_correlation:
                why += f", correlation {partner_r[i]:+.3f} with {names[k]}"
        elif k >= 0 and abs(partner_r[i]) > max_correlation:
            verdict = CORRELATED
            why = f"correlation {partner_r[i]:+.3f} with {names[k]} (|r| > {max_correlation:g})"
        else:
            verdict = IDENTIFIABLE
            why = f"{100 * confidence:g} % CI +-{100 * ci_rel[i]:.3g} %"
        slack = BOUND_TOLERANCE * width[i]
        if x[i] - problem.lower[i] <= slack or problem.upper[i] - x[i] <= slack:
            side = "lower" if x[i] - problem.lower[i] <= slack else "upper"
            why += f"; on the {side} bound of its search range: the local theory does not hold"
        verdicts.append(verdict)
        reasons.append(why)

    objective = problem.objective
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
    counted_time = float(sum(np.sum(w**2) for w in _weights(pack)))
    channel = RESPONSE_CHANNELS[objective.derivative]
    theta_unit = getattr(problem.model, "theta_unit", "rad")
    params = problem.model.params
    return Identifiability(
        names=names,
        units=[params[n].unit for n in names],
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
        trial_ids=list(pack.ids),
        tau=tau,
        n_samples=n,
        n_effective=n_eff,
        ssr=float(r @ r),
        rms=math.sqrt(float(r @ r) / counted_time) if counted_time > 0 else math.nan,
        sigma2=cov.sigma2,
        dof=dof,
        condition=cov.condition,
        step=float(step),
        step_agreement=agreement,
        channel=channel,
        channel_unit=unit(channel, theta_unit),
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
        note=note,
        seconds=time.perf_counter() - t0,
    )
