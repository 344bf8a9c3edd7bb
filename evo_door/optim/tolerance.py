"""Tolerances a supplier can build to: how far each specification may stray from its value
before the door no longer feels like the chosen one.

A specification stage ends with one door that feels like the chosen feel (the
perceptual objective, :class:`~evo_door.perception.FeelTarget`). A supplier cannot
build one value; it builds within a band. Two bands per specification, both
symmetric, ``value +- b`` in the specification's unit:

- **alone**: the widest band such that the door with only that specification moved
  anywhere within it (the others at their values) still passes the perceptual check
  (:func:`~evo_door.perception.perceptual_check` and
  :func:`~evo_door.perception.check_verdict`: at least 95 % of each stroke within the
  force JND). Found by a rising scan (``cap / 2^10``, ``cap / 2^9`` ... ``cap``) to the
  first band whose ends fail, then a bisection between the last band that passed and
  that one, so that every scanned band below the answer passed too.
- **together**: the alone bands scaled down by one common factor until doors built
  with every specification anywhere within its band at once (a Monte-Carlo: ``samples``
  doors, each specification uniform in its band, drawn with the generator
  ``numpy.random.default_rng(seed)``) pass the check often enough: the one-sided
  Wilson lower bound of the pass rate at ``confidence`` is at least ``target`` (95 %
  of doors pass, and a second sample of as many doors agrees). The factor is found by
  bisection on one set of draws (common random numbers), largest first.

Each band is capped at the specification's search range, ``cap``: 100 % of its value
(half its declared range for a value of 0), and never beyond its declared bounds (a
moved value is clipped to them: a friction is not built negative). A band at its cap
(``capped``) is one the feel does not limit: a specification the feel does not
determine (not identifiable, or kept from the product) gets a band too, and usually
this one.

The check is made on one fixed grid of angles (the chosen curve's points, the
perceptual objective's stroke and every fourth point of its latch zone) with the
compiled Coulomb forces of many doors at once
(:func:`~evo_door.sim.simulate.hold_forces_rows`), a millisecond or two a door, where
:func:`~evo_door.perception.model_curve`'s adaptive grid takes a quarter of a second;
tests compare the two at the bands' edges. The felt inertia and damping are not part
of the check (it compares force-angle curves).
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from evo_door.errors import UserError
from evo_door.files import ATTRS
from evo_door.perception import FeelTarget
from evo_door.perception.feel import DIRECTIONS, LATCH_ZONE, PASS_FRACTION, fraction_beyond
from evo_door.sim.simulate import COULOMB_SPEED, coulomb_vector, hold_forces, hold_forces_rows

#: Monte-Carlo doors per factor tried
SAMPLES = 200
#: the Monte-Carlo's generator seed
SEED = 1
#: share of the sampled doors that must pass
TARGET = 0.95
#: confidence of the one-sided Wilson lower bound of the pass rate
CONFIDENCE = 0.95
#: rising scan of the alone bands: cap / 2^SCAN_STEPS first
SCAN_STEPS = 10
#: bisection steps of an alone band (a bracket of a factor 2 to 2^-8 of it)
BISECTIONS = 8
#: bisection steps of the common factor (to 2^-8)
FACTOR_BISECTIONS = 8
#: every LATCH_THIN-th point of the perceptual objective's latch grid (2e-5 rad): the
#: latch zone is 3 deg of 90, too little of a stroke to decide a check alone
LATCH_THIN = 4
#: doors from which a batch is spread across threads
ROWS_IN_THREADS = 8
#: Monte-Carlo doors computed at once (the count stops once too many fail)
BATCH = 50


class FeelCheck:
    """The perceptual check of doors against a chosen feel, on one fixed grid.

    :meth:`judge` takes one door a row of a kernel matrix and says which pass (as
    :func:`check_verdict`'s ``passes`` would: at most ``1 - pass_fraction`` of each
    stroke beyond the force JND, by :func:`fraction_beyond`, and each latch peak within
    its JND), with their Coulomb curves
    on :attr:`theta`; the doors are computed in one compiled call, across threads.
    """

    def __init__(self, model, feel: FeelTarget, pass_fraction: float = PASS_FRACTION):
        self.model = model
        self.feel = feel
        self.pass_fraction = pass_fraction
        latch = feel.latch[::LATCH_THIN]
        self.theta = np.union1d(np.union1d(feel.stroke, latch), feel.curve.theta)
        self.chosen = {d: feel.curve.force(d, self.theta) for d in DIRECTIONS}
        self.threshold = {d: feel.jnd.force_threshold(self.chosen[d]) for d in DIRECTIONS}
        # the latch peaks, judged as perceptual_check judges them (on this grid)
        self.latch = self.theta >= feel.curve.theta[-1] - LATCH_ZONE
        self.evaluations = 0

    def judge(self, P) -> tuple[np.ndarray, dict]:
        """Whether each door (row of ``P``) passes, and its forces (N) per stroke."""
        P = np.atleast_2d(np.asarray(P, dtype=np.float64))
        Q = np.array([coulomb_vector(self.model, p) for p in P])
        self.evaluations += len(P)
        ok = np.ones(len(P), dtype=bool)
        forces = {}
        for d, sign in zip(DIRECTIONS, (-1.0, 1.0)):
            f = self._forces(Q, sign * COULOMB_SPEED)
            finite = np.all(np.isfinite(f), axis=1)
            fails = ~(np.abs(f - self.chosen[d]) <= self.threshold[d])
            ok &= finite & (fraction_beyond(self.theta, fails) <= 1.0 - self.pass_fraction)
            if self.latch.any():
                pick = np.min if d == "opening" else np.max
                peak = pick(f[:, self.latch], axis=1)
                ok &= ~(np.abs(peak - self.feel.peaks[d]) > self.feel.peak_threshold[d])
            forces[d] = f
        return ok, forces

    def _forces(self, Q, speed) -> np.ndarray:
        if len(Q) < ROWS_IN_THREADS:  # a few doors: threads cost more than they give
            return np.array([hold_forces(self.model, q, self.theta, speed) for q in Q])
        return hold_forces_rows(self.model, Q, self.theta, speed)

    def passes(self, p) -> bool:
        """Whether the one door ``p`` passes."""
        return bool(self.judge(p)[0][0])


@dataclass
class Tolerances:
    """The bands of a set of specifications (module docstring); every band in its unit."""

    names: list[str]
    units: list[str]
    value: np.ndarray
    alone: np.ndarray  # +- half-width, alone
    together: np.ndarray  # +- half-width, all at once
    cap: np.ndarray  # the search range of each band
    capped: np.ndarray  # bool: the alone band reached its cap
    factor: float  # together = factor * alone
    samples: int
    seed: int
    passed: int  # doors of the Monte-Carlo at ``factor`` that pass
    target: float
    confidence: float
    nominal_passes: bool
    evaluations: int = 0
    seconds: float = 0.0
    note: str = ""
    #: the force-angle band of the sampled doors against the chosen feel's JND band
    #: (theta rad; chosen, jnd, low, high per stroke, N)
    curves: dict = field(default_factory=dict)

    @property
    def pass_rate(self) -> float:
        return self.passed / self.samples if self.samples else math.nan

    @property
    def lower_bound(self) -> float:
        return wilson_lower(self.passed, self.samples, self.confidence)

    def relative(self, which: str = "alone") -> np.ndarray:
        """A band as a fraction of its value (inf for a value of 0)."""
        band = getattr(self, which)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.value != 0.0, band / np.abs(self.value), math.inf)

    def row(self, name: str) -> dict:
        i = self.names.index(name)
        return {
            "unit": self.units[i],
            "value": float(self.value[i]),
            "alone": float(self.alone[i]),
            "together": float(self.together[i]),
            "cap": float(self.cap[i]),
            "capped": bool(self.capped[i]),
        }

    def as_dict(self) -> dict:
        """What ``show --json`` prints (JSON-able)."""
        return {
            "specifications": {n: self.row(n) for n in self.names},
            "factor": self.factor,
            "monte_carlo": {
                "samples": self.samples,
                "seed": self.seed,
                "passed": self.passed,
                "pass_rate": self.pass_rate,
                "lower_bound": self.lower_bound,
                "target": self.target,
                "confidence": self.confidence,
            },
            "nominal_passes": self.nominal_passes,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "note": self.note,
        }

    def format(self) -> str:
        """A few lines for a person: each band alone and together, and the Monte-Carlo."""
        lines = [
            "tolerances (+- band within which the door still feels like the chosen one):",
            f"{'parameter':<22} {'value':>12}  {'alone':>22}  {'together':>22}",
        ]
        rel_a, rel_t = self.relative("alone"), self.relative("together")
        for i, n in enumerate(self.names):
            u = self.units[i]
            cap = " (cap)" if self.capped[i] else ""
            lines.append(
                f"{n:<22} {self.value[i]:>12.6g}  "
                f"{band_text(self.alone[i], u, rel_a[i]) + cap:>22}  "
                f"{band_text(self.together[i], u, rel_t[i]):>22}"
            )
        lines.append(
            f"together = {self.factor:.3g} x alone: {self.passed}/{self.samples} sampled doors "
            f"pass ({100 * self.pass_rate:.1f} %, lower bound {100 * self.lower_bound:.1f} % at "
            f"{100 * self.confidence:.0f} % confidence), seed {self.seed}; "
            f"{self.evaluations} doors checked in {self.seconds:.1f} s"
        )
        if self.note:
            lines.append(f"note: {self.note}")
        return "\n".join(lines)

    def to_tree(self) -> dict:
        attrs = {
            "names": list(self.names),
            "units": list(self.units),
            "factor": float(self.factor),
            "samples": int(self.samples),
            "seed": int(self.seed),
            "passed": int(self.passed),
            "target": float(self.target),
            "confidence": float(self.confidence),
            "nominal_passes": bool(self.nominal_passes),
            "evaluations": int(self.evaluations),
            "seconds": float(self.seconds),
            "note": self.note,
        }
        tree = {
            ATTRS: attrs,
            "value": np.asarray(self.value, dtype=np.float64),
            "alone": np.asarray(self.alone, dtype=np.float64),
            "together": np.asarray(self.together, dtype=np.float64),
            "cap": np.asarray(self.cap, dtype=np.float64),
            "capped": np.asarray(self.capped, dtype=np.int8),
        }
        if self.curves:
            tree["curves"] = {k: np.asarray(v, dtype=np.float64) for k, v in self.curves.items()}
        return tree

    @classmethod
    def from_tree(cls, node: dict) -> Tolerances:
        a = node[ATTRS]
        curves = node.get("curves") or {}
        return cls(
            names=list(a["names"]),
            units=list(a["units"]),
            value=np.asarray(node["value"], dtype=np.float64),
            alone=np.asarray(node["alone"], dtype=np.float64),
            together=np.asarray(node["together"], dtype=np.float64),
            cap=np.asarray(node["cap"], dtype=np.float64),
            capped=np.asarray(node["capped"]).astype(bool),
            factor=float(a["factor"]),
            samples=int(a["samples"]),
            seed=int(a["seed"]),
            passed=int(a["passed"]),
            target=float(a["target"]),
            confidence=float(a["confidence"]),
            nominal_passes=bool(a["nominal_passes"]),
            evaluations=int(a.get("evaluations", 0)),
            seconds=float(a.get("seconds", 0.0)),
            note=str(a.get("note", "")),
            curves={k: np.asarray(v) for k, v in curves.items() if k != ATTRS},
        )


def band_text(band: float, unit: str, relative: float) -> str:
    """``+-12.3 N/m (3.5 %)``: a band in its unit and as a share of its value."""
    unit = "" if unit == "1" else f" {unit}"
    share = f" ({100 * relative:.3g} %)" if math.isfinite(relative) else ""
    return f"+-{band:.3g}{unit}{share}"


def wilson_lower(passed: int, n: int, confidence: float) -> float:
    """The one-sided Wilson score lower bound of a pass rate of ``passed`` in ``n``.

    >>> round(wilson_lower(200, 200, 0.95), 4), round(wilson_lower(190, 200, 0.95), 4)
    (0.9867, 0.9181)
    """
    if n <= 0:
        return math.nan
    from statistics import NormalDist

    z = NormalDist().inv_cdf(confidence)
    p = passed / n
    centre = p + z * z / (2 * n)
    spread = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return (centre - spread) / (1 + z * z / n)


def allowed_failures(n: int, target: float, confidence: float) -> int:
    """The most failing doors of ``n`` at which the Wilson lower bound still reaches
    ``target`` (-1: none, ``n`` too small for the target)."""
    k = -1
    while k + 1 <= n and wilson_lower(n - (k + 1), n, confidence) >= target:
        k += 1
    return k


def _caps(model, names: list[str], p0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each band's search range (module docstring) and the declared bounds."""
    idx = np.array([model.params.index(n) for n in names], dtype=np.int64)
    lo = np.array([model.params[n].lower for n in names], dtype=np.float64)
    hi = np.array([model.params[n].upper for n in names], dtype=np.float64)
    v = p0[idx]
    cap = np.where(v != 0.0, np.abs(v), 0.5 * (hi - lo))
    cap = np.minimum(cap, np.maximum(hi - v, v - lo))
    return cap, lo, hi


def tolerances(
    model,
    p0,
    feel: FeelTarget,
    names: list[str],
    samples: int = SAMPLES,
    seed: int = SEED,
    target: float = TARGET,
    confidence: float = CONFIDENCE,
    progress: bool = False,
) -> Tolerances:
    """The alone and together bands of ``names`` about the door ``p0`` (a full kernel
    vector of ``model``) against the chosen feel ``feel`` (module docstring)."""
    t0 = time.perf_counter()
    p0 = _check_inputs(model, p0, feel, names, samples, target, confidence)
    idx = np.array([model.params.index(n) for n in names], dtype=np.int64)
    cap, lo, hi = _caps(model, names, p0)
    check = FeelCheck(model, feel)
    bar = _bar(len(names) + FACTOR_BISECTIONS + 1, progress)
    nominal = check.passes(p0)
    alone = np.zeros(len(names))
    capped = np.zeros(len(names), dtype=bool)
    note = ""
    for i in range(len(names)):
        if nominal:
            alone[i], capped[i] = _alone_band(check, p0, idx[i], cap[i], lo[i], hi[i])
        bar.update(1)
    if not nominal:
        note = "the fitted door itself does not pass the perceptual check: no band"
    factor, passed, curves = _together(
        check, p0, idx, alone, lo, hi, samples, seed, target, confidence, bar
    )
    bar.close()
    return Tolerances(
        names=list(names),
        units=[model.params[n].unit for n in names],
        value=p0[idx].copy(),
        alone=alone,
        together=factor * alone,
        cap=cap,
        capped=capped,
        factor=factor,
        samples=samples,
        seed=seed,
        passed=passed,
        target=target,
        confidence=confidence,
        nominal_passes=nominal,
        evaluations=check.evaluations,
        seconds=time.perf_counter() - t0,
        note=note,
        curves=curves,
    )


def _check_inputs(model, p0, feel, names, samples, target, confidence) -> np.ndarray:
    """``p0`` as a kernel vector; every bad argument a one-line error."""
    if not isinstance(feel, FeelTarget):
        raise UserError("tolerances: need a chosen feel (a run with the perceptual objective)")
    p0 = np.array(p0, dtype=np.float64).ravel()
    if p0.shape != (len(model.params),) or not np.all(np.isfinite(p0)):
        raise UserError(
            f"tolerances: the door needs {len(model.params)} finite values of model "
            f"{model.name!r}, got shape {p0.shape}"
        )
    if not names:
        raise UserError("tolerances: no specification to give a band to")
    for n in names:
        if n not in model.params.names:
            model.params[n]  # the declaration's own did-you-mean error
    if len(set(names)) != len(names):
        raise UserError("tolerances: a specification is named twice")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 20:
        raise UserError(f"tolerances: samples {samples!r}: a whole number of doors, at least 20")
    for what, v in (("target", target), ("confidence", confidence)):
        if not (isinstance(v, (int, float)) and 0.5 <= v < 1.0):
            raise UserError(f"tolerances: {what} {v!r}: a share in [0.5, 1) (0.95 is 95 %)")
    if allowed_failures(samples, target, confidence) < 0:
        raise UserError(
            f"tolerances: {samples} doors cannot show a pass rate of {100 * target:g} % at "
            f"{100 * confidence:g} % confidence; sample more"
        )
    return p0


def _moved(p0, i, value, lo, hi) -> np.ndarray:
    p = p0.copy()
    p[i] = min(max(value, lo), hi)
    return p


def _alone_band(check: FeelCheck, p0, i, cap, lo, hi) -> tuple[float, bool]:
    """The widest band ``+-b`` of the specification at index ``i`` alone (module
    docstring); True where it is the cap."""
    v = p0[i]

    def ok(b):
        ends = np.array([_moved(p0, i, v - b, lo, hi), _moved(p0, i, v + b, lo, hi)])
        return bool(np.all(check.judge(ends)[0]))

    if cap <= 0.0:
        return 0.0, True
    good, bad = 0.0, None
    for j in range(SCAN_STEPS, -1, -1):
        b = cap * 2.0**-j
        if ok(b):
            good = b
        else:
            bad = b
            break
    if bad is None:
        return cap, True
    for _ in range(BISECTIONS):
        mid = 0.5 * (good + bad)
        if ok(mid):
            good = mid
        else:
            bad = mid
    return good, False


def _together(check, p0, idx, alone, lo, hi, samples, seed, target, confidence, bar):
    """The common factor of the together bands, the doors that pass at it, and their
    force-angle band (module docstring)."""
    draws = np.random.default_rng(seed).uniform(-1.0, 1.0, (samples, idx.size))
    limit = allowed_failures(samples, target, confidence)

    def trial(s):
        """Doors passing at factor ``s`` and their force-angle band; None once more
        fail than allowed."""
        P = np.repeat(p0[None, :], samples, axis=0)
        P[:, idx] = np.clip(p0[idx] + s * alone * draws, lo, hi)
        fails, env = 0, None
        for start in range(0, samples, BATCH):
            ok, forces = check.judge(P[start : start + BATCH])
            fails += int(np.sum(~ok))
            if fails > limit:
                return None
            env = _envelope(env, forces)
        return samples - fails, env

    got = trial(1.0)
    bar.update(1)
    if got is not None or not np.any(alone > 0.0):  # all pass, or the door alone fails
        bar.update(FACTOR_BISECTIONS)
        passed, env = got if got is not None else (0, None)
        return (1.0 if got is not None else 0.0), passed, _curves(check, env)
    good, bad, best = 0.0, 1.0, None
    for _ in range(FACTOR_BISECTIONS):
        mid = 0.5 * (good + bad)
        got = trial(mid)
        if got is not None:
            good, best = mid, got
        else:
            bad = mid
        bar.update(1)
    if best is None:  # even the smallest factor tried fails: the door alone
        good, best = 0.0, trial(0.0) or (0, None)
    passed, env = best
    return good, passed, _curves(check, env)


def _envelope(env, forces: dict) -> dict:
    low = {d: f.min(axis=0) for d, f in forces.items()}
    high = {d: f.max(axis=0) for d, f in forces.items()}
    if env is None:
        return {d: [low[d], high[d]] for d in forces}
    return {d: [np.minimum(env[d][0], low[d]), np.maximum(env[d][1], high[d])] for d in forces}


def _curves(check: FeelCheck, env) -> dict:
    """The figure's arrays: the chosen curve, its JND, the sampled doors' low and high."""
    if env is None:
        return {}
    out = {"theta": check.theta}
    for d in DIRECTIONS:
        out[f"{d}_chosen"] = check.chosen[d]
        out[f"{d}_jnd"] = check.threshold[d]
        out[f"{d}_low"], out[f"{d}_high"] = env[d]
    return out


class _NoBar:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def _bar(total: int, progress: bool):
    if not progress:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc="tolerances", unit="step", file=sys.stderr, dynamic_ncols=True)
