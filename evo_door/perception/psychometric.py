"""The psychometric function of a two-interval forced choice, and its fit to answers.

In a two-interval forced choice (2IFC) trial a participant feels a reference and a
comparison, in random order, and says which felt stronger. The comparison differs by
a relative **step** ``x`` (0.1: 10 % more). The probability of a correct answer is

    P(x) = 1/2 + (1/2 - lapse) * Phi((ln x - ln weber) / slope)

- ``1/2``: the guess rate of two intervals;
- ``weber``: the **Weber fraction**, the step a participant who never lapses tells
  apart 75 % of the time (the usual criterion of a 2IFC JND); Phi is 1/2 there;
- ``slope``: the spread of the function in natural-log units of the step (smaller is
  steeper: 0.4 takes P from 60 % to 90 % over a factor of about 3 in the step);
- ``lapse``: the rate of answers given at random-wrong regardless of the step (an
  inattentive trial), which keeps one wrong answer at a large step from pulling the
  fit.

:func:`fit_psychometric` is a maximum-likelihood fit of ``weber``, ``slope`` and
``lapse`` to the answers. The likelihood is first computed on a grid (vectorised over
every candidate at once: it never misses the global maximum the way a single local
search from a poor start can), then refined with scipy's bounded minimiser. The 95 %
interval of ``weber`` is the central 95 % of the likelihood integrated over slope and
lapse (flat priors on the grid's ln weber, ln slope and lapse), as psignifit computes
its credible intervals: a profile-likelihood interval, which takes the best slope at
each Weber fraction, covered the truth in only 73 % of simulated QUEST sessions
(whose trials crowd at one step and leave the slope free), the integrated one in
95 % (``tests/test_jnd.py`` holds the coverage).

>>> f = Psychometric(weber=0.1, slope=0.4, lapse=0.0)
>>> round(float(f.p_correct(0.1)), 3), round(float(f.p_correct(1.0)), 3)
(0.75, 1.0)
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from evo_door.errors import UserError

#: the guess rate of a two-interval forced choice
GUESS = 0.5
#: the search ranges of the fit: Weber fraction, slope (ln units), lapse rate
WEBER_RANGE = (1e-3, 10.0)
SLOPE_RANGE = (0.05, 2.0)
LAPSE_RANGE = (0.0, 0.06)
#: the chi-square(1) 95 % point: twice a log-likelihood ratio at a 95 % bound
_CHI2_95 = 3.841458820694124


@dataclass(frozen=True)
class Psychometric:
    """A 2IFC psychometric function (see the module docstring).

    Attributes
    ----------
    weber : float
        Weber fraction (1): the step told apart 75 % of the time, lapses aside.
    slope : float
        spread in natural-log units of the step (1); smaller is steeper.
    lapse : float
        lapse rate (1), 0 to 0.5.
    """

    weber: float
    slope: float = 0.4
    lapse: float = 0.02

    def __post_init__(self):
        if not (math.isfinite(self.weber) and self.weber > 0.0):
            raise UserError(f"Weber fraction {self.weber!r}: must be a number above 0")
        if not (math.isfinite(self.slope) and self.slope > 0.0):
            raise UserError(f"slope {self.slope!r}: must be a number above 0")
        if not (0.0 <= self.lapse < 0.5):
            raise UserError(f"lapse rate {self.lapse!r}: must be in [0, 0.5)")

    def p_correct(self, step):
        """The probability of a correct answer at relative ``step`` (>= 0; 0: chance)."""
        return p_correct(np.asarray(step, dtype=float), self.weber, self.slope, self.lapse)

    def step_at(self, p: float) -> float:
        """The step answered correctly with probability ``p`` (between 1/2 and 1 - lapse)."""
        top = 1.0 - self.lapse
        if not GUESS < p < top:
            raise UserError(f"probability {p:g}: must be between {GUESS:g} and {top:g}")
        from scipy import special  # imported where used, not at every command's start

        z = special.ndtri((p - GUESS) / (top - GUESS))
        return float(self.weber * math.exp(self.slope * z))

    def as_dict(self) -> dict:
        return asdict(self)


def p_correct(step, weber, slope, lapse):
    """P(correct) at ``step`` for the function (``weber``, ``slope``, ``lapse``),
    broadcasting over every argument (the fit evaluates a grid of candidates at once)."""
    from scipy import special  # imported where used, not at every command's start

    with np.errstate(divide="ignore"):
        z = (np.log(step) - np.log(weber)) / slope
    return GUESS + (1.0 - GUESS - lapse) * special.ndtr(z)


@dataclass(frozen=True)
class Fit:
    """A maximum-likelihood fit of the psychometric function to a session's answers.

    Attributes
    ----------
    weber, slope, lapse : float
        the estimates (1).
    ci95 : tuple[float, float]
        95 % interval of ``weber`` (1): the likelihood integrated over slope and lapse.
    open_ended : tuple[bool, bool]
        whether each end of the interval reached the edge of the search range
        (:data:`WEBER_RANGE`): the answers do not bound the Weber fraction there.
    trials : int
        the number of answers fitted.
    log_likelihood : float
        at the estimate.
    """

    weber: float
    slope: float
    lapse: float
    ci95: tuple[float, float]
    open_ended: tuple[bool, bool]
    trials: int
    log_likelihood: float

    @property
    def function(self) -> Psychometric:
        return Psychometric(self.weber, self.slope, self.lapse)

    def covers(self, weber: float) -> bool:
        return self.ci95[0] <= weber <= self.ci95[1]

    def as_dict(self) -> dict:
        d = asdict(self)
        d["ci95"] = list(self.ci95)
        d["open_ended"] = list(self.open_ended)
        return d


def _counts(steps, correct):
    """Unique steps with their numbers of trials and of correct answers."""
    steps = np.asarray(steps, dtype=float)
    correct = np.asarray(correct, dtype=bool)
    if steps.ndim != 1 or steps.shape != correct.shape:
        raise UserError("steps and answers: two sequences of one length expected")
    if steps.size == 0:
        raise UserError("no answers to fit: a session of at least one trial is needed")
    if not np.all(np.isfinite(steps) & (steps > 0.0)):
        raise UserError("steps: every step must be a number above 0")
    levels, inverse = np.unique(steps, return_inverse=True)
    n = np.bincount(inverse).astype(float)
    k = np.bincount(inverse, weights=correct.astype(float))
    return levels, n, k


def _log_likelihood(levels, n, k, weber, slope, lapse):
    """The binomial log-likelihood, summed over the last axis (the levels)."""
    p = p_correct(levels, weber, slope, lapse)
    p = np.clip(p, 1e-12, 1.0 - 1e-12)
    return np.sum(k * np.log(p) + (n - k) * np.log1p(-p), axis=-1)


def fit_psychometric(steps, correct, grid: int = 241) -> Fit:
    """The maximum-likelihood fit of a 2IFC psychometric function to the answers.

    ``steps`` are the trials' relative steps (> 0), ``correct`` whether each answer
    was right. ``grid`` is the number of Weber fractions of the grid over
    :data:`WEBER_RANGE` (log-spaced; the interval's ends are interpolated on it).
    """
    levels, n, k = _counts(steps, correct)
    lw = np.linspace(math.log(WEBER_RANGE[0]), math.log(WEBER_RANGE[1]), grid)
    ls = np.linspace(math.log(SLOPE_RANGE[0]), math.log(SLOPE_RANGE[1]), 15)
    la = np.linspace(LAPSE_RANGE[0], LAPSE_RANGE[1], 4)
    W, S, A = np.meshgrid(np.exp(lw), np.exp(ls), la, indexing="ij")
    ll = _log_likelihood(levels, n, k, W[..., None], S[..., None], A[..., None])
    best = np.unravel_index(np.argmax(ll), ll.shape)
    x0 = np.array([lw[best[0]], ls[best[1]], la[best[2]]])
    bounds = [(lw[0], lw[-1]), (ls[0], ls[-1]), LAPSE_RANGE]

    def nll(x):
        return -float(_log_likelihood(levels, n, k, math.exp(x[0]), math.exp(x[1]), x[2]))

    from scipy import optimize  # here: a reader of JND files (``show``) never fits

    res = optimize.minimize(nll, x0, method="L-BFGS-B", bounds=bounds)
    x = res.x if res.fun <= nll(x0) else x0
    ll_max = -min(res.fun, nll(x0))

    # the interval: the likelihood integrated over slope and lapse (flat priors on the
    # grid: ln weber, ln slope, lapse), its central 95 % in ln weber
    post = np.exp(ll - ll.max()).sum(axis=(1, 2))
    cdf = np.cumsum(post) / post.sum()
    lo, hi = (math.exp(float(np.interp(q, cdf, lw))) for q in (0.025, 0.975))
    # an end is open where the search's edge is still as likely as the 95 % region's
    # (likelihood ratio, chi-square(1) 95 % point 3.84): the answers do not bound it
    prof = ll.max(axis=(1, 2))
    lo_open, hi_open = (bool(prof[i] > ll_max - _CHI2_95 / 2.0) for i in (0, -1))
    weber = math.exp(x[0])
    return Fit(
        weber=weber,
        slope=math.exp(x[1]),
        lapse=float(x[2]),
        ci95=(min(lo, weber), max(hi, weber)),
        open_ended=(bool(lo_open), bool(hi_open)),  # not numpy booleans: JSON takes these
        trials=int(n.sum()),
        log_likelihood=float(ll_max),
    )
