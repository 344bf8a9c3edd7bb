"""How uncertain a least-squares estimate is: effective samples and covariance.

The second half of the identifiability check (:mod:`evo_door.optim.identifiability`),
from a residual ``r`` and its Jacobian ``J`` (:mod:`evo_door.optim.sensitivity`); nothing
here knows about models or trials.

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
Noise level and mismatch
    :func:`noise_level` estimates the measurement noise from the residual's
    sample-to-sample differences: white noise of standard deviation ``s`` gives
    differences of variance ``2 s^2``, while a model error, smooth over a sample (a lag,
    a friction law of another shape), hardly shows in them. The *mismatch ratio* is the
    residual's RMS over that level: about 1 when the model matches the data but for
    noise (1.1-2.0 measured on the rig's own impulse trials, where the load cell's noise
    integrated by the door adds a slow part), 8-200 on the rig's richer truth
    (``docs/model-mismatch.md``). :mod:`evo_door.optim.identifiability` widens the
    intervals by it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: Thresholds of a determined parameter: cond(J^T J), and the smallest range-scaled
#: sensitivity (relative to the largest) that counts as one.
MAX_CONDITION = 1e10
MIN_SENSITIVITY = 1e-6


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


def noise_level(parts) -> tuple[float, float]:
    """``(noise, ratio)``: the residual's white-noise level and its RMS over that level.

    ``parts`` are the trials' residuals (each in sample order); the level is
    ``sqrt(sum diff(r)^2 / (2 sum (n - 1)))`` over every trial (module docstring), the
    ratio ``sqrt(mean r^2) / noise`` (NaN when either is zero or undefined).

    >>> rng = np.random.default_rng(1)
    >>> noise, ratio = noise_level([rng.normal(0.0, 0.1, 4000)])
    >>> round(noise, 2), round(ratio, 1)
    (0.1, 1.0)
    >>> noise_level([0.1 * rng.normal(size=4000) + np.sin(np.linspace(0, 3, 4000))])[1] > 5
    True
    """
    parts = [np.asarray(r, dtype=np.float64) for r in parts]
    diffs = sum(float(np.sum(np.diff(r) ** 2)) for r in parts)
    pairs = sum(max(r.size - 1, 0) for r in parts)
    count = sum(r.size for r in parts)
    if pairs == 0 or not diffs > 0.0:
        return 0.0, math.nan
    noise = math.sqrt(diffs / (2.0 * pairs))
    rms = math.sqrt(sum(float(r @ r) for r in parts) / count)
    return noise, rms / noise


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
    reasons, norms = _without_sensitivity(J, scale, relative, min_sensitivity)
    keep = [j for j in range(p) if j not in reasons]
    condition, _ = _condition(J, norms, keep)
    _drop_singular(J, norms, keep, names, max_condition, reasons)
    ssr = float(r @ r)
    dof = n_eff - len(keep)
    sigma2 = ssr / dof if dof > 0 else math.inf
    se, corr = _errors(J, norms, keep, sigma2, n_eff, reasons)
    return Covariance(se, corr, sigma2, dof, condition, reasons)


def _without_sensitivity(J, scale, relative: bool, min_sensitivity: float):
    """``(reasons, norms)``: why each column that cannot be determined cannot (a blown
    simulation, no sensitivity), and the columns' norms (0 where blown up)."""
    p = J.shape[1]
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
    return reasons, norms


def _condition(J, norms, cols) -> tuple[float, np.ndarray]:
    """cond(J^T J) of the unit-length columns ``cols``, and their right singular vectors."""
    if not cols:
        return 1.0, np.zeros((0, 0))
    _, s, vt = np.linalg.svd(J[:, cols] / norms[cols], full_matrices=False)
    c = math.inf if s[-1] == 0.0 else float((s[0] / s[-1]) ** 2)
    return c, vt


def _drop_singular(J, norms, keep: list, names, max_condition: float, reasons: dict) -> None:
    """Take out of ``keep``, one at a time, the parameter that weighs most in the
    weakest direction, until cond(J^T J) is at most ``max_condition``; each gets its
    reason, naming those it trades with."""
    while True:
        c, vt = _condition(J, norms, keep)
        if c <= max_condition:
            break
        v = np.abs(vt[-1])
        worst = keep[int(np.argmax(v))]
        partners = [names[keep[i]] for i in np.argsort(-v) if keep[i] != worst and v[i] > 0.1]
        reasons[worst] = f"singular: cond(J^T J) {c:.2g} > {max_condition:.2g}" + (
            f", trades with {', '.join(partners)}" if partners else ""
        )
        keep.remove(worst)


def _errors(J, norms, keep: list, sigma2: float, n_eff: float, reasons: dict):
    """``(standard errors, correlation)`` of the parameters in ``keep`` (inf and NaN for
    the others; also for ``keep`` when too few effective samples leave sigma2 infinite,
    with that reason)."""
    p = J.shape[1]
    se = np.full(p, math.inf)
    corr = np.full((p, p), math.nan)
    if not keep:
        return se, corr
    A = J[:, keep] / norms[keep]
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    inv = (vt.T / s**2) @ vt  # (A^T A)^-1, A = J D with D = diag(1 / norms)
    d = 1.0 / norms[keep]
    if not math.isfinite(sigma2):
        for j in keep:
            reasons[j] = f"{n_eff:.3g} effective samples for {len(keep)} parameters"
        return se, corr
    cov = sigma2 * inv * np.outer(d, d)
    se[keep] = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        c = inv / np.sqrt(np.outer(np.diag(inv), np.diag(inv)))
    corr[np.ix_(keep, keep)] = np.clip(c, -1.0, 1.0)
    return se, corr
