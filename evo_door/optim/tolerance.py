"""A specification a supplier can build: nominal values that doors made to the supplier's
tolerances feel like the chosen feel, and how many of them will.

A specification stage ends with one door that feels like the chosen feel (the
perceptual objective, :class:`~evo_door.perception.FeelTarget`). A supplier cannot
build one value; it builds within the tolerances of its process (a spring's rate to
+-10 %, a friction to +-25 %: :mod:`evo_door.optim.process`). What the supplier needs
is a nominal that most doors built to those tolerances still pass the perceptual check
with, and the share that will: the **yield**.

:func:`specify` does it in five steps:

1. **The check, for many doors at once** (:class:`FeelCheck`): every door's margins,
   its differences from the chosen feel in units of their JNDs, signed: each point of
   both strokes outside the latch zone, both latch peaks, both peaks' angles, and the
   felt inertia and damping where the chosen feel has dynamics. A door passes when
   every margin is within +-1, as :func:`~evo_door.perception.check_verdict` judges one
   door (tests compare the two). One compiled call a batch of doors, across threads.
2. **Sensitivities**: each specification's secant slope of every margin over its own
   tolerance (JND per unit of the specification): a specification the check does not
   see has none, and the table says "not judged" instead of giving it a band.
3. **Design centring**: the free specifications' nominal that maximises the yield,
   not the one on the boundary of the check. The doors are the margins' secant model
   about the nominal with one set of standardised draws (common random numbers,
   ``design_seed``), the yield smoothed, maximised by Nelder-Mead within a trust box of
   a few tolerances, the model made again at the new nominal, twice. The centred
   nominal is kept where the *model itself* (the compiled check of those doors) gives it
   a higher yield than the smallest-change door the stage started from; that door stays
   in the results as the alternative, with its own yield.
4. **The yield**: a fresh sample of doors drawn after the design is fixed, with a seed
   of its own (``yield_seed``), at least 2000 doors, each through the compiled check:
   the share that passes with its 95 % Clopper-Pearson interval. Each specification's
   **contribution to the yield loss** is the yield the sample would gain were that
   specification built exactly (its deviation taken off every door's margins through
   its secant slopes).
5. **Reachable or not**: where the yield is below the target (95 %), the stage says so
   and gives the **allocation**: the fewest tolerances, tightened by the least common
   factor, that reach the target (searched on the yield sample's margins, verified on
   another fresh sample, ``allocation_seed``).

Everything is in the specifications' own units; margins are in JND.
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from evo_door.errors import UserError
from evo_door.files import ATTRS
from evo_door.perception import FeelTarget
from evo_door.perception.feel import DIRECTIONS, LATCH_ZONE
from evo_door.sim.simulate import (
    COULOMB_SPEED,
    coulomb_vector,
    hold_forces_rows,
    inertia_rows,
)

#: doors of the yield's fresh sample (the issue's floor: 2000)
SAMPLES = 2000
#: doors of the common-random-number sample the nominal is centred on
DESIGN_SAMPLES = 400
#: the seeds: the centring's draws, the yield's fresh sample, the allocation's check
DESIGN_SEED = 1
YIELD_SEED = 2
ALLOCATION_SEED = 3
#: the yield a specification must reach to be called reachable
TARGET = 0.95
#: every LATCH_THIN-th point of the perceptual objective's latch grid (2e-5 rad): 1.6e-4
#: rad, 0.009 deg, a fiftieth of the position JND's angle at the handle (a latch's peak
#: is a plateau of its hold, some 6e-3 rad long)
LATCH_THIN = 8
#: doors computed at once
BATCH = 250
#: centring: rounds of (secant model, Nelder-Mead), the trust box in tolerances, the
#: smoothing of the yield (JND) and the Nelder-Mead's evaluations per free parameter
ROUNDS = 2
TRUST = 2.0
SMOOTHING = 0.05
EVALUATIONS_PER_FREE = 60
#: allocation: every subset of up to this many of the largest contributors is tried
#: (more are added one at a time, largest first); a tightened tolerance is never below
#: this share of the process's
CANDIDATES = 6
LEAST_SHARE = 0.05
#: margins of a door whose curve is not finite (it fails)
BLOWN = 1e6


@dataclass
class Reference:
    """What a feel is judged by on a :class:`FeelCheck`'s grid: its force (N) and force
    JND (N) per stroke at every angle, its latch peaks (N) and their JNDs, their angles
    (rad) and the position JND's angle, and its felt dynamics with their JNDs (None
    for a bare curve)."""

    chosen: dict
    threshold: dict
    peaks: dict
    peak_threshold: dict
    peak_angles: dict
    angle_threshold: float
    dynamics: tuple | None = None  # ((inertia, jnd), (damping, jnd))


class FeelCheck:
    """The perceptual check of many doors against a chosen feel, on one fixed grid.

    :meth:`margins` gives every door (a row of a kernel matrix) its signed differences
    from the chosen feel in JND (module docstring, step 1), in the columns
    :attr:`labels` names; :meth:`judge` says which pass (every margin within +-1).
    :meth:`measure` gives the doors' own quantities, which :meth:`against` judges
    against any feel (:meth:`reference_of`).
    """

    def __init__(self, model, feel: FeelTarget):
        self.model = model
        self.feel = feel
        latch = feel.latch[::LATCH_THIN]
        self.theta = np.union1d(np.union1d(feel.stroke, latch), feel.curve.theta)
        self.stroke = self.theta < feel.curve.theta[-1] - LATCH_ZONE
        self.latch = ~self.stroke
        if self.stroke.sum() < 2 or not self.latch.any():
            raise UserError(f"{feel.curve.source}: the chosen feel's curve has no latch zone")
        chosen = {d: feel.curve.force(d, self.theta) for d in DIRECTIONS}
        dynamics = None
        if feel.dynamics is not None:
            ti, tc = feel.dynamics
            jnd = feel.jnd
            dynamics = ((ti, jnd.inertia_threshold(ti)), (tc, jnd.damping_threshold(tc)))
        self.reference = Reference(
            chosen,
            {d: feel.jnd.force_threshold(chosen[d]) for d in DIRECTIONS},
            dict(feel.peaks),
            dict(feel.peak_threshold),
            dict(feel.peak_angles),
            feel.angle_threshold,
            dynamics,
        )
        self.chosen, self.threshold = self.reference.chosen, self.reference.threshold
        self.dyn_theta = feel.dyn_grid
        deg = np.degrees(self.theta[self.stroke])
        self.labels = [f"{d} stroke at {a:.2f} deg" for d in DIRECTIONS for a in deg]
        self.labels += ["unlock peak force", "lock peak force"]
        self.labels += ["unlock peak's angle", "lock peak's angle"]
        if feel.dynamics is not None:
            self.labels += ["felt inertia", "felt damping"]
        self.evaluations = 0

    @property
    def columns(self) -> int:
        return len(self.labels)

    def margins(self, P, forces: dict | None = None, measured: list | None = None):
        """The signed margins (JND) of every door, a row of ``P`` (full kernel vectors):
        an array (doors, :attr:`columns`). ``forces``, a dict, receives each stroke's
        Coulomb forces (N, doors x :attr:`theta`); ``measured``, a list, each batch's
        :meth:`measure`."""
        P = np.ascontiguousarray(np.atleast_2d(P), dtype=np.float64)
        out = np.empty((len(P), self.columns))
        for start in range(0, len(P), BATCH):
            rows = slice(start, start + BATCH)
            got = self.measure(P[rows])
            out[rows] = self.against(got, self.reference)
            if forces is not None:
                for d in DIRECTIONS:
                    forces.setdefault(d, []).append(got[d])
            if measured is not None:
                measured.append(got)
        self.evaluations += len(P)
        return out

    def measure(self, P) -> dict:
        """The doors' own quantities: Coulomb forces (N) per stroke on :attr:`theta`,
        latch peaks (N) and their angles (rad) per stroke, felt inertia and damping."""
        Q = np.array([coulomb_vector(self.model, p) for p in P])
        zone = self.theta[self.latch]
        out: dict = {"peaks": {}, "angles": {}}
        for d, sign in zip(DIRECTIONS, (-1.0, 1.0)):
            f = hold_forces_rows(self.model, Q, self.theta, sign * COULOMB_SPEED)
            fl = f[:, self.latch]
            k = np.argmin(fl, axis=1) if d == "opening" else np.argmax(fl, axis=1)
            out[d] = f
            out["peaks"][d] = fl[np.arange(len(P)), k]
            out["angles"][d] = zone[k]
        if self.feel.dynamics is not None:
            out["dynamics"] = self._dynamics(P)
        return out

    def against(self, got: dict, ref: Reference) -> np.ndarray:
        """The margins (JND) of measured doors (:meth:`measure`) against ``ref``."""
        parts = [((got[d] - ref.chosen[d]) / ref.threshold[d])[:, self.stroke] for d in DIRECTIONS]
        parts.append(
            np.array(
                [(got["peaks"][d] - ref.peaks[d]) / ref.peak_threshold[d] for d in DIRECTIONS]
            ).T
        )
        parts.append(
            np.array(
                [(got["angles"][d] - ref.peak_angles[d]) / ref.angle_threshold for d in DIRECTIONS]
            ).T
        )
        if "dynamics" in got:
            (ti, ji), (tc, jc) = ref.dynamics
            parts.append(
                np.c_[(got["dynamics"][:, 0] - ti) / ji, (got["dynamics"][:, 1] - tc) / jc]
            )
        out = np.concatenate(parts, axis=1)
        return np.where(np.isfinite(out), out, BLOWN)

    def reference_of(self, model, p) -> Reference:
        """The :class:`Reference` of the feel of ``model`` at ``p`` (a haptic set, say),
        on this grid, under the chosen feel's JNDs."""
        jnd = self.feel.jnd
        pc = coulomb_vector(model, p)
        zone = self.theta[self.latch]
        chosen, peaks, angles = {}, {}, {}
        for d, sign in zip(DIRECTIONS, (-1.0, 1.0)):
            f = hold_forces_rows(model, pc[None, :], self.theta, sign * COULOMB_SPEED)[0]
            fl = f[self.latch]
            k = int(np.argmin(fl) if d == "opening" else np.argmax(fl))
            chosen[d], peaks[d], angles[d] = f, float(fl[k]), float(zone[k])
        dynamics = None
        if self.feel.dynamics is not None:
            ti, tc = self.feel.felt_dynamics(model, np.asarray(p, dtype=np.float64))
            dynamics = ((ti, jnd.inertia_threshold(ti)), (tc, jnd.damping_threshold(tc)))
        return Reference(
            chosen,
            {d: jnd.force_threshold(chosen[d]) for d in DIRECTIONS},
            peaks,
            {d: jnd.force_threshold(v) for d, v in peaks.items()},
            angles,
            jnd.angle_threshold(),
            dynamics,
        )

    def _dynamics(self, P) -> np.ndarray:
        """Felt inertia (kg m) and damping (N s/rad), as :meth:`FeelTarget.felt_dynamics`."""
        theta, v = self.dyn_theta, self.feel.jnd.speed
        inertia = inertia_rows(self.model, P, theta, -0.5 * v).mean(axis=1)
        damping = np.zeros(len(P))
        for s in (-1.0, 1.0):
            half = hold_forces_rows(self.model, P, theta, 0.5 * s * v)
            full = hold_forces_rows(self.model, P, theta, s * v)
            damping += np.mean((full - half) / (0.5 * s * v), axis=1)
        return np.c_[inertia, 0.5 * damping]

    def judge(self, P) -> np.ndarray:
        """Whether each door (row of ``P``) passes the check."""
        return passing(self.margins(P))

    def passes(self, p) -> bool:
        return bool(self.judge(p)[0])


def band_text(band: float, unit: str, relative: float) -> str:
    """``+-12.3 N/m (3.5 %)``: a band in its unit and as a share of its value.

    >>> band_text(12.3, "N/m", 0.035), band_text(0.1, "1", float("inf"))
    ('+-12.3 N/m (3.5 %)', '+-0.1')
    """
    unit = "" if unit == "1" else f" {unit}"
    share = f" ({100 * relative:.3g} %)" if math.isfinite(relative) else ""
    return f"+-{band:.3g}{unit}{share}"


def soft_yield(margins, smoothing: float = SMOOTHING) -> float:
    """The share of doors that pass, smoothed: each door counts
    ``1 / (1 + exp((worst - 1) / smoothing))`` by its worst margin (JND)."""
    worst = np.max(np.abs(np.atleast_2d(margins)), axis=1)
    return float(np.mean(1.0 / (1.0 + np.exp(np.clip((worst - 1.0) / smoothing, -50, 50)))))


def passing(margins) -> np.ndarray:
    """Whether each row of margins passes: every one within +-1 JND."""
    return np.all(np.abs(margins) <= 1.0, axis=-1)


# -- the result -----------------------------------------------------------------------
@dataclass
class YieldEstimate:
    """The share of a fresh sample of doors that passes, with its 95 % interval."""

    passed: int
    samples: int
    seed: int

    @property
    def estimate(self) -> float:
        return self.passed / self.samples if self.samples else math.nan

    @property
    def ci95(self) -> tuple[float, float]:
        return clopper_pearson(self.passed, self.samples)

    def as_dict(self) -> dict:
        lo, hi = self.ci95
        return {
            "estimate": self.estimate,
            "ci95": [lo, hi],
            "samples": self.samples,
            "seed": self.seed,
            "passed": self.passed,
        }

    def text(self) -> str:
        lo, hi = self.ci95
        return (
            f"{100 * self.estimate:.1f} % (95 % interval {100 * lo:.1f}-{100 * hi:.1f} %, "
            f"{self.passed} of {self.samples} doors, seed {self.seed})"
        )

    @classmethod
    def from_dict(cls, d: dict) -> YieldEstimate:
        return cls(int(d["passed"]), int(d["samples"]), int(d["seed"]))


def clopper_pearson(passed: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """The two-sided Clopper-Pearson interval of a share of ``passed`` in ``n``.

    >>> [round(x, 4) for x in clopper_pearson(1900, 2000)]
    [0.9397, 0.9591]
    """
    if n <= 0:
        return (math.nan, math.nan)
    from scipy.stats import beta

    a = 1.0 - confidence
    lo = 0.0 if passed == 0 else float(beta.ppf(a / 2, passed, n - passed + 1))
    hi = 1.0 if passed == n else float(beta.ppf(1 - a / 2, passed + 1, n - passed))
    return (lo, hi)


@dataclass
class NearestFeel:
    """The feel nearest the chosen one that doors built to the process hold: a set of
    the chosen feel's model (``values``: every parameter), how far it is from the
    chosen feel (``distance``, the perceptual objective's RMS in JND), the sensations
    moved, and its yield on the specification's sample of doors."""

    model: str
    values: dict
    moved: list
    distance: float
    yield_: YieldEstimate
    target: float

    @property
    def holds(self) -> bool:
        return self.yield_.estimate >= self.target

    def as_dict(self) -> dict:
        return {
            "model": self.model,
            "values": dict(self.values),
            "moved": list(self.moved),
            "distance_jnd": self.distance,
            "yield": self.yield_.as_dict(),
            "holds": self.holds,
        }

    def to_tree(self) -> dict:
        import json

        return {
            ATTRS: {
                "model": self.model,
                "names": list(self.values),
                "moved": list(self.moved),
                "distance_jnd": float(self.distance),
                "yield": json.dumps(self.yield_.as_dict()),
                "target": float(self.target),
            },
            "values": np.array(list(self.values.values()), dtype=np.float64),
        }

    @classmethod
    def from_tree(cls, node: dict) -> NearestFeel:
        import json

        a = node[ATTRS]
        return cls(
            model=str(a["model"]),
            values=dict(zip(list(a["names"]), map(float, np.asarray(node["values"])))),
            moved=list(a["moved"]),
            distance=float(a["distance_jnd"]),
            yield_=YieldEstimate.from_dict(json.loads(a["yield"])),
            target=float(a["target"]),
        )

    def text(self) -> str:
        moved = ", ".join(f"{n} {self.values[n]:.4g}" for n in self.moved)
        verdict = "holds" if self.holds else "the nearest it comes: still short of the target"
        return (
            f"nearest feel the process can hold ({self.model} model, {self.distance:.2f} JND "
            f"from the chosen feel; {moved}): yield {self.yield_.text()}; {verdict}"
        )


@dataclass
class Specification:
    """What :func:`specify` decided (module docstring); every value in its unit.

    Per specification (``names``): ``nominal``, ``half_width`` (the process's +-t as
    used), ``distribution``, ``source`` (of the tolerance), ``sensitivity`` (JND per
    unit: the largest secant slope of any margin), ``loss`` (yield points lost to it),
    ``changed`` (from the AS-IS door). ``design``: ``"centred"`` or ``"smallest
    change"``, the nominal chosen; ``alternative`` the other one's nominal and yield.
    """

    names: list[str]
    units: list[str]
    nominal: np.ndarray
    asis: np.ndarray
    half_width: np.ndarray
    distribution: list[str]
    source: list[str]
    sensitivity: np.ndarray
    loss: np.ndarray
    free: list[str]
    design: str
    yield_: YieldEstimate
    target: float
    worst: str  # the margin that fails the most sampled doors
    alternative: dict = field(default_factory=dict)  # {"design", "nominal", "yield"}
    allocation: dict = field(default_factory=dict)  # name -> tightened half-width
    allocation_yield: YieldEstimate | None = None
    #: the nominal the allocation is built to (the robust one), None without allocation
    allocation_nominal: np.ndarray | None = None
    #: where the target is out of reach: the nearest feel the process can hold
    nearest: NearestFeel | None = None
    nominal_margin: float = math.nan  # the nominal door's worst margin, JND
    design_seed: int = DESIGN_SEED
    evaluations: int = 0
    seconds: float = 0.0
    note: str = ""
    #: the force-angle band of the sampled doors against the chosen feel's JND band
    #: (theta rad; chosen, jnd, low, high per stroke, N)
    curves: dict = field(default_factory=dict)

    @property
    def reachable(self) -> bool:
        return self.yield_.estimate >= self.target

    @property
    def changed(self) -> np.ndarray:
        scale = np.maximum(np.abs(self.asis), 1e-300)
        return np.abs(self.nominal - self.asis) > 1e-9 * scale

    @property
    def judged(self) -> np.ndarray:
        """Whether the check sees each specification at all."""
        return self.sensitivity > 0.0

    def row(self, name: str) -> dict:
        i = self.names.index(name)
        return {
            "unit": self.units[i],
            "nominal": float(self.nominal[i]),
            "half_width": float(self.half_width[i]),
            "distribution": self.distribution[i],
            "source": self.source[i],
            "sensitivity_jnd_per_unit": float(self.sensitivity[i]),
            "judged": bool(self.judged[i]),
            "yield_loss": float(self.loss[i]),
            "changed": bool(self.changed[i]),
            "free": name in self.free,
        }

    def as_dict(self) -> dict:
        """What ``show --json`` prints (JSON-able)."""
        return {
            "design": self.design,
            "process": {n: float(t) for n, t in zip(self.names, self.half_width)},
            "distribution": dict(zip(self.names, self.distribution)),
            "yield": self.yield_.as_dict(),
            "target": self.target,
            "reachable": self.reachable,
            "allocation": dict(self.allocation),
            "allocation_yield": (
                self.allocation_yield.as_dict() if self.allocation_yield is not None else None
            ),
            "allocation_nominal": (
                dict(zip(self.names, map(float, self.allocation_nominal)))
                if self.allocation_nominal is not None
                else None
            ),
            "nearest_feel": self.nearest.as_dict() if self.nearest is not None else None,
            "specifications": {n: self.row(n) for n in self.names},
            "alternative": _plain_alternative(self.alternative),
            "worst": self.worst,
            "nominal_margin_jnd": self.nominal_margin,
            "design_seed": self.design_seed,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "note": self.note,
        }

    def summary_lines(self) -> list[str]:
        """The lines under the table: the yield, the design, reachable or not."""
        lines = [
            f"yield: {self.yield_.text()} pass the perceptual check when built to the "
            f"process's tolerances (target {100 * self.target:g} %)",
            f"design: {self.design} nominal (the nominal door's worst difference "
            f"{self.nominal_margin:.2f} JND)",
        ]
        alt = self.alternative
        if alt:
            lines.append(f"alternative: the {alt['design']} nominal, yield {alt['yield'].text()}")
        if self.yield_.passed < self.yield_.samples:
            lines.append(f"most doors fail at: {self.worst}")
        if not self.reachable:
            lines.append(
                f"NOT REACHABLE: the process's tolerances give {100 * self.yield_.estimate:.1f} % "
                f"< {100 * self.target:g} %"
            )
            if self.allocation:
                tight = ", ".join(
                    f"{n} +-{t:.3g} {self.units[self.names.index(n)]}".replace(" 1", "")
                    for n, t in self.allocation.items()
                )
                got = self.allocation_yield.text() if self.allocation_yield else "not verified"
                lines.append(f"  tighten {tight}: yield {got}")
                if self.allocation_nominal is not None:
                    moved = [
                        f"{n} {v:.4g}"
                        for n, v, w in zip(self.names, self.allocation_nominal, self.nominal)
                        if abs(v - w) > 1e-9 * max(abs(w), 1e-300)
                    ]
                    if moved:
                        lines.append(f"  built to the robust nominal: {', '.join(moved)}")
            else:
                lines.append("  no tightening of the tolerances the check sees reaches it")
        if self.nearest is not None:
            lines.append("  " + self.nearest.text())
            lines.append(
                "  (evo-door push RUN.h5 --to HOST:PORT renders it for a participant to confirm)"
            )
        if self.note:
            lines.append(f"note: {self.note}")
        return lines

    def to_tree(self) -> dict:
        import json

        attrs = {
            "format": 2,
            "names": list(self.names),
            "units": list(self.units),
            "distribution": list(self.distribution),
            "source": list(self.source),
            "free": list(self.free),
            "design": self.design,
            "yield": json.dumps(self.yield_.as_dict()),
            "target": float(self.target),
            "worst": self.worst,
            "alternative": json.dumps(_plain_alternative(self.alternative)),
            "allocation": json.dumps(self.allocation),
            "allocation_yield": json.dumps(
                self.allocation_yield.as_dict() if self.allocation_yield is not None else None
            ),
            "nominal_margin": float(self.nominal_margin),
            "design_seed": int(self.design_seed),
            "evaluations": int(self.evaluations),
            "seconds": float(self.seconds),
            "note": self.note,
        }
        tree = {
            ATTRS: attrs,
            "nominal": np.asarray(self.nominal, dtype=np.float64),
            "asis": np.asarray(self.asis, dtype=np.float64),
            "half_width": np.asarray(self.half_width, dtype=np.float64),
            "sensitivity": np.asarray(self.sensitivity, dtype=np.float64),
            "loss": np.asarray(self.loss, dtype=np.float64),
        }
        if self.nearest is not None:
            tree["nearest_feel"] = self.nearest.to_tree()
        if self.allocation_nominal is not None:
            tree["allocation_nominal"] = np.asarray(self.allocation_nominal, dtype=np.float64)
        if self.curves:
            tree["curves"] = {k: np.asarray(v, dtype=np.float64) for k, v in self.curves.items()}
        return tree

    @classmethod
    def from_tree(cls, node: dict) -> Specification | None:
        """Read the group back; None for one written in the old form (bands alone and
        together), which is then computed anew."""
        import json

        a = node[ATTRS]
        if int(a.get("format", 1)) < 2:
            return None
        alt = json.loads(a["alternative"])
        if alt:
            alt = {
                "design": alt["design"],
                "nominal": np.asarray(alt["nominal"], dtype=np.float64),
                "yield": YieldEstimate.from_dict(alt["yield"]),
            }
        ay = json.loads(a["allocation_yield"])
        curves = node.get("curves") or {}
        return cls(
            names=list(a["names"]),
            units=list(a["units"]),
            nominal=np.asarray(node["nominal"], dtype=np.float64),
            asis=np.asarray(node["asis"], dtype=np.float64),
            half_width=np.asarray(node["half_width"], dtype=np.float64),
            distribution=list(a["distribution"]),
            source=list(a["source"]),
            sensitivity=np.asarray(node["sensitivity"], dtype=np.float64),
            loss=np.asarray(node["loss"], dtype=np.float64),
            free=list(a["free"]),
            design=str(a["design"]),
            yield_=YieldEstimate.from_dict(json.loads(a["yield"])),
            target=float(a["target"]),
            worst=str(a["worst"]),
            alternative=alt or {},
            allocation={k: float(v) for k, v in json.loads(a["allocation"]).items()},
            allocation_yield=YieldEstimate.from_dict(ay) if ay else None,
            nearest=NearestFeel.from_tree(node["nearest_feel"]) if "nearest_feel" in node else None,
            allocation_nominal=(
                np.asarray(node["allocation_nominal"], dtype=np.float64)
                if "allocation_nominal" in node
                else None
            ),
            nominal_margin=float(a["nominal_margin"]),
            design_seed=int(a["design_seed"]),
            evaluations=int(a["evaluations"]),
            seconds=float(a["seconds"]),
            note=str(a["note"]),
            curves={k: np.asarray(v) for k, v in curves.items() if k != ATTRS},
        )


def _plain_alternative(alt: dict) -> dict:
    if not alt:
        return {}
    return {
        "design": alt["design"],
        "nominal": [float(v) for v in alt["nominal"]],
        "yield": alt["yield"].as_dict(),
    }


# -- the computation ------------------------------------------------------------------
def standard_draws(distributions: list[str], n: int, rng) -> np.ndarray:
    """Deviations of ``n`` doors in units of each tolerance: normal with 3 sigma = 1, or
    uniform on [-1, 1]; one column per specification, drawn in that order.

    >>> u = standard_draws(["normal", "uniform"], 20000, np.random.default_rng(1))
    >>> round(float(u[:, 0].std()), 2), bool(np.abs(u[:, 1]).max() <= 1.0)
    (0.33, True)
    """
    out = np.empty((n, len(distributions)))
    for j, kind in enumerate(distributions):
        if kind == "uniform":
            out[:, j] = rng.uniform(-1.0, 1.0, n)
        else:
            out[:, j] = rng.standard_normal(n) / 3.0
    return out


def specify(
    model,
    p0,
    feel: FeelTarget,
    names: list[str],
    process,
    free: list[str],
    lower,
    upper,
    asis=None,
    target: float = TARGET,
    samples: int = SAMPLES,
    design_seed: int = DESIGN_SEED,
    yield_seed: int = YIELD_SEED,
    allocation_seed: int = ALLOCATION_SEED,
    centre: bool = True,
    feel_model=None,
    feel_params=None,
    progress: bool = False,
) -> Specification:
    """The specification of ``names`` from the door ``p0`` (a full kernel vector of
    ``model``, the smallest change that reaches the chosen ``feel``), built to
    ``process`` (an :class:`~evo_door.optim.process.Process` of ``names``); ``free``
    are the specifications the nominal may move (within ``lower``..``upper``, their
    search ranges), ``asis`` the AS-IS door's full vector (the "changed" column);
    ``feel_model`` and ``feel_params`` the chosen feel's model and set (a haptic set:
    where the target is out of reach, the nearest feel is one of that model). See the
    module docstring."""
    t0 = time.perf_counter()
    p0 = _check_inputs(model, p0, feel, names, samples, target)
    idx = np.array([model.params.index(n) for n in names], dtype=np.int64)
    lo_decl = np.array([model.params[n].lower for n in names])
    hi_decl = np.array([model.params[n].upper for n in names])
    dist = [process.distribution[process.names.index(n)] for n in names]
    source = [process.source[process.names.index(n)] for n in names]
    check = FeelCheck(model, feel)
    bar = _bar(ROUNDS + 4, progress)

    def widths(p):
        return np.asarray(process.half_widths(p[idx]), dtype=np.float64)

    def doors(p, U, t):
        P = np.repeat(p[None, :], len(U), axis=0)
        P[:, idx] = np.clip(p[idx] + U * t, lo_decl, hi_decl)
        return P

    design_draws = standard_draws(dist, DESIGN_SAMPLES, np.random.default_rng(design_seed))
    cols = np.array([names.index(n) for n in free if n in names], dtype=np.int64)
    search_lo = np.asarray(lower, dtype=np.float64)
    search_hi = np.asarray(upper, dtype=np.float64)
    start = p0.copy()
    p = p0.copy()
    if centre and cols.size:
        for _ in range(ROUNDS):
            p = _centre_round(check, p, idx, cols, widths(p), design_draws, search_lo, search_hi)
            bar.update(1)
    else:
        bar.update(ROUNDS)
    # the centred nominal where the compiled check of the design doors says it is better
    # (their yield, smoothed: it still orders two designs that no door passes)
    y_start = soft_yield(check.margins(doors(start, design_draws, widths(start))))
    y_centred = soft_yield(check.margins(doors(p, design_draws, widths(p))))
    bar.update(1)
    if centre and y_centred > y_start and check.passes(p):
        design, other, other_name = "centred", start, "smallest change"
    else:
        p, design, other, other_name = start, "smallest change", None, ""
    # the yield: a fresh sample, drawn now that the design is fixed
    t = widths(p)
    U = standard_draws(dist, samples, np.random.default_rng(yield_seed))
    forces: dict = {}
    measured: list = []
    M = check.margins(doors(p, U, t), forces, measured)
    ok = passing(M)
    estimate = YieldEstimate(int(ok.sum()), samples, yield_seed)
    bar.update(1)
    J = _secants(check, p, idx, t, lo_decl, hi_decl)
    sensitivity = np.max(np.abs(J), axis=0) if J.size else np.zeros(len(names))
    loss = np.array(
        [
            passing(M - np.outer(U[:, j] * t[j], J[:, j])).mean() - ok.mean() if t[j] else 0.0
            for j in range(len(names))
        ]
    )
    fails = np.abs(M) > 1.0
    worst = check.labels[int(np.argmax(fails.sum(axis=0)))] if fails.any() else ""
    alternative = {}
    if other is not None:
        Ua = standard_draws(dist, samples, np.random.default_rng(yield_seed))
        ya = passing(check.margins(doors(other, Ua, widths(other)))).mean()
        alternative = {
            "design": other_name,
            "nominal": other[idx].copy(),
            "yield": YieldEstimate(int(round(ya * samples)), samples, yield_seed),
        }
    bar.update(1)
    allocation, allocation_yield, allocation_nominal = {}, None, None
    nearest = None
    if estimate.estimate < target and feel_model is not None:
        nearest = nearest_feel(
            check, _joined(measured), feel_model, feel_params, target, yield_seed
        )
    if estimate.estimate < target:
        # tightened tolerances want the door with the most room, not the one centred
        # on the process's spread: the allocation is made about the robust nominal
        robust = _robust_nominal(check, p, idx, cols, search_lo, search_hi)
        tr = widths(robust)
        Jr = _secants(check, robust, idx, tr, lo_decl, hi_decl)
        Ml = check.margins(robust)[0] + (U * tr) @ Jr.T  # the yield's doors, first order
        allocation = _allocate(Ml, U, tr, Jr, names, loss, np.max(np.abs(Jr), axis=0) * tr, target)
        if allocation:
            tightened = tr.copy()
            for n, w in allocation.items():
                tightened[names.index(n)] = w
            Uv = standard_draws(dist, samples, np.random.default_rng(allocation_seed))
            okv = passing(check.margins(doors(robust, Uv, tightened)))
            allocation_yield = YieldEstimate(int(okv.sum()), samples, allocation_seed)
            allocation_nominal = robust[idx].copy()
    bar.update(1)
    bar.close()
    nominal_margin = float(np.max(np.abs(check.margins(p))))
    return Specification(
        names=list(names),
        units=[model.params[n].unit for n in names],
        nominal=p[idx].copy(),
        asis=(np.asarray(asis, dtype=np.float64)[idx] if asis is not None else start[idx]).copy(),
        half_width=t,
        distribution=dist,
        source=source,
        sensitivity=sensitivity,
        loss=loss,
        free=[names[c] for c in cols],
        design=design,
        yield_=estimate,
        target=target,
        worst=worst,
        alternative=alternative,
        allocation=allocation,
        allocation_yield=allocation_yield,
        allocation_nominal=allocation_nominal,
        nearest=nearest,
        nominal_margin=nominal_margin,
        design_seed=design_seed,
        evaluations=check.evaluations,
        seconds=time.perf_counter() - t0,
        curves=_curves(check, forces),
    )


def full_nominal(spec: Specification, model, p0) -> np.ndarray:
    """The full kernel vector ``p0`` with the specification's nominal in it."""
    p = np.array(p0, dtype=np.float64)
    for n, v in zip(spec.names, spec.nominal):
        p[model.params.index(n)] = v
    return p


def _check_inputs(model, p0, feel, names, samples, target) -> np.ndarray:
    """``p0`` as a kernel vector; every bad argument a one-line error."""
    if not isinstance(feel, FeelTarget):
        raise UserError("specification: needs a chosen feel (a run with the perceptual objective)")
    p0 = np.array(p0, dtype=np.float64).ravel()
    if p0.shape != (len(model.params),) or not np.all(np.isfinite(p0)):
        raise UserError(
            f"specification: the door needs {len(model.params)} finite values of model "
            f"{model.name!r}, got shape {p0.shape}"
        )
    if not names:
        raise UserError("specification: no specification to build")
    for n in names:
        if n not in model.params.names:
            model.params[n]  # the declaration's own did-you-mean error
    if len(set(names)) != len(names):
        raise UserError("specification: a specification is named twice")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 100:
        raise UserError(f"specification: samples {samples!r}: a whole number of doors, >= 100")
    if not (isinstance(target, (int, float)) and 0.5 <= target < 1.0):
        raise UserError(f"specification: target {target!r}: a share in [0.5, 1) (0.95 is 95 %)")
    return p0


def _secants(check: FeelCheck, p, idx, t, lo, hi) -> np.ndarray:
    """Each specification's secant slope of every margin over +-its tolerance (JND per
    unit), columns in ``idx``'s order; a step of 1e-6 of its value where the tolerance
    is 0 (a slope is still wanted for centring)."""
    steps = np.where(t > 0.0, t, 1e-6 * np.maximum(np.abs(p[idx]), 1e-6))
    P = np.repeat(p[None, :], 2 * len(idx), axis=0)
    for j, i in enumerate(idx):
        P[2 * j, i] = min(p[i] + steps[j], hi[j])
        P[2 * j + 1, i] = max(p[i] - steps[j], lo[j])
    M = check.margins(P)
    width = P[0::2, idx].diagonal() - P[1::2, idx].diagonal()
    with np.errstate(divide="ignore", invalid="ignore"):
        J = (M[0::2] - M[1::2]).T / np.where(width > 0.0, width, np.inf)
    J[np.abs(J) > 0.1 * BLOWN] = 0.0  # a blown door at an end: no slope to trust
    # a change the check cannot tell from rounding (a millionth of a JND over the step)
    # is no sensitivity: the check does not see that specification there
    J[np.abs(J) * steps[None, :] < 1e-6] = 0.0
    return J


def _centre_round(check, p, idx, cols, t, U, search_lo, search_hi) -> np.ndarray:
    """One round of centring (module docstring, step 3): the free specifications'
    nominal that maximises the smoothed yield of the secant model about ``p``."""
    from scipy.optimize import minimize

    lo = np.array([check.model.params[check.model.params.names[i]].lower for i in idx])
    hi = np.array([check.model.params[check.model.params.names[i]].upper for i in idx])
    J = _secants(check, p, idx, t, lo, hi)
    m0 = check.margins(p)[0]
    D = (U * t) @ J.T  # every design door's deviation of its margins
    Jf = J[:, cols]
    ref = np.maximum(t[cols], 1e-3 * (search_hi - search_lo))
    box_lo = np.maximum(p[idx][cols] - TRUST * ref, search_lo)
    box_hi = np.minimum(p[idx][cols] + TRUST * ref, search_hi)
    if np.any(box_hi <= box_lo):
        return p

    def objective(z):
        return -soft_yield(m0 + Jf @ (z * ref) + D)

    z_lo = (box_lo - p[idx][cols]) / ref
    z_hi = (box_hi - p[idx][cols]) / ref
    res = minimize(
        objective,
        np.zeros(cols.size),
        method="Nelder-Mead",
        bounds=list(zip(z_lo, z_hi)),
        options={"maxfev": EVALUATIONS_PER_FREE * cols.size, "xatol": 1e-3, "fatol": 1e-5},
    )
    out = p.copy()
    out[idx[cols]] = p[idx][cols] + np.clip(res.x, z_lo, z_hi) * ref
    return out


def _joined(measured: list) -> dict:
    """One :meth:`FeelCheck.measure` of the batches of a sample."""
    out: dict = {d: np.concatenate([m[d] for m in measured]) for d in DIRECTIONS}
    for key in ("peaks", "angles"):
        out[key] = {d: np.concatenate([m[key][d] for m in measured]) for d in DIRECTIONS}
    if "dynamics" in measured[0]:
        out["dynamics"] = np.concatenate([m["dynamics"] for m in measured])
    return out


def _subset(got: dict, rows) -> dict:
    out: dict = {d: got[d][rows] for d in DIRECTIONS}
    for key in ("peaks", "angles"):
        out[key] = {d: got[key][d][rows] for d in DIRECTIONS}
    if "dynamics" in got:
        out["dynamics"] = got["dynamics"][rows]
    return out


#: the units of the sensations the nearest feel moves: levels of force, dynamics
LEVEL_UNITS = ("N", "N s/rad", "kg m")
#: doors of the sample the nearest feel is searched on (all of them check it)
NEAREST_DOORS = 500


def nearest_feel(
    check: FeelCheck, got: dict, model, params, target: float, seed: int = YIELD_SEED
) -> NearestFeel:
    """The set of ``model`` (the chosen feel's, at ``params``) nearest the chosen feel
    whose feel the measured doors ``got`` pass at ``target`` (module docstring, step 5).

    The sensations moved are the model's levels (group ``sensation``, a force, a
    damping or an inertia; each within its declared bounds); nearest is the perceptual
    objective of the chosen feel (:meth:`FeelTarget.value`, JND^2); the doors' smoothed
    yield must reach ``target``, a penalty otherwise. Nelder-Mead on the first
    :data:`NEAREST_DOORS` doors, the yield counted on all of them.
    """
    from scipy.optimize import minimize

    p0 = np.array(params, dtype=np.float64)
    cols = [
        i
        for i, q in enumerate(model.params)
        if q.group == "sensation" and q.unit in LEVEL_UNITS and q.lower < q.upper
    ]
    lo = np.array([model.params[model.params.names[i]].lower for i in cols])
    hi = np.array([model.params[model.params.names[i]].upper for i in cols])
    scale = np.maximum(np.abs(p0[cols]), 0.05 * (hi - lo))
    n = min(NEAREST_DOORS, len(got["peaks"]["opening"]))
    some = _subset(got, slice(0, n))
    aim = target + 0.01

    def feel_of(z):
        p = p0.copy()
        p[cols] = np.clip(p0[cols] + z * scale, lo, hi)
        return p

    def cost(z):
        p = feel_of(z)
        shortfall = max(0.0, aim - soft_yield(check.against(some, check.reference_of(model, p))))
        return check.feel.value(model, p) + 1e4 * shortfall**2

    res = minimize(
        cost,
        np.zeros(len(cols)),
        method="Nelder-Mead",
        options={"maxfev": 20 * len(cols), "xatol": 1e-3, "fatol": 1e-4},
    )
    p = feel_of(res.x)
    ok = passing(check.against(got, check.reference_of(model, p)))
    names = model.params.names
    moved = [names[i] for i in cols if abs(p[i] - p0[i]) > 1e-9 * max(abs(p0[i]), 1.0)]
    return NearestFeel(
        model=model.name,
        values={nm: float(v) for nm, v in zip(names, p)},
        moved=moved,
        distance=math.sqrt(max(check.feel.value(model, p), 0.0)),
        yield_=YieldEstimate(int(ok.sum()), len(ok), seed),
        target=target,
    )


def _robust_nominal(check, p, idx, cols, search_lo, search_hi) -> np.ndarray:
    """The free specifications' nominal with the most room: the least worst margin
    (JND) of the door itself, by Nelder-Mead on the compiled check from ``p``."""
    from scipy.optimize import minimize

    if not cols.size:
        return p
    width = search_hi - search_lo

    def door(z):
        q = p.copy()
        q[idx[cols]] = search_lo + np.clip(z, 0.0, 1.0) * width
        return q

    def worst(z):
        return float(np.max(np.abs(check.margins(door(z))[0])))

    z0 = (p[idx][cols] - search_lo) / width
    res = minimize(
        worst,
        z0,
        method="Nelder-Mead",
        bounds=[(0.0, 1.0)] * cols.size,
        options={"maxfev": 40 * cols.size, "xatol": 1e-4, "fatol": 1e-4},
    )
    return door(res.x) if res.fun < worst(z0) else p


def _allocate(M, U, t, J, names, loss, swing, target) -> dict:
    """The fewest tolerances, tightened by the least common factor, whose doors reach
    ``target`` on the sample's margins (first order in each tightened deviation): every
    subset of up to :data:`CANDIDATES` of the largest contributors (yield loss, then
    swing: JND moved at the end of the tolerance), then more of them one at a time;
    {} when even all of them at :data:`LEAST_SHARE` cannot."""
    ranked = sorted(
        (j for j in range(len(names)) if t[j] > 0.0 and swing[j] > 0.0),
        key=lambda j: (-loss[j], -swing[j]),
    )
    aim = target + 0.005  # a little above: the fresh sample that verifies it varies
    if not ranked:
        return {}
    # a margin that no tightening can take beyond 1 JND is left out of the search
    reach_of = np.abs(M) + sum(np.abs(np.outer(U[:, j] * t[j], J[:, j])) for j in ranked)
    keep = np.max(reach_of, axis=0) > 1.0
    M = np.ascontiguousarray(M[:, keep], dtype=np.float32)
    shifts = {j: np.outer(U[:, j] * t[j], J[keep, j]).astype(np.float32) for j in ranked}

    def reach(subset, share):
        m = M.copy()
        for j in subset:
            m -= (1.0 - share) * shifts[j]
        return passing(m).mean()

    def least(subset):
        """The largest share of the process's tolerances kept that reaches ``aim``."""
        if reach(subset, LEAST_SHARE) < aim:
            return None
        lo, hi = LEAST_SHARE, 1.0
        for _ in range(10):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if reach(subset, mid) >= aim else (lo, mid)
        return lo

    top = ranked[:CANDIDATES]
    for k in range(1, len(ranked) + 1):
        subsets = itertools.combinations(top, k) if k <= len(top) else [tuple(ranked[:k])]
        found = [(share, sub) for sub in subsets if (share := least(sub)) is not None]
        if found:
            share, subset = max(found)
            return {names[j]: float(share * t[j]) for j in subset}
    return {}


def _curves(check: FeelCheck, forces: dict) -> dict:
    """The figure's arrays: the chosen curve, its JND, the sampled doors' low and high."""
    if not forces:
        return {}
    out = {"theta": check.theta}
    for d in DIRECTIONS:
        f = np.concatenate(forces[d], axis=0)
        out[f"{d}_chosen"] = check.chosen[d]
        out[f"{d}_jnd"] = check.threshold[d]
        out[f"{d}_low"] = np.percentile(f, 2.5, axis=0)
        out[f"{d}_high"] = np.percentile(f, 97.5, axis=0)
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

    return tqdm(total=total, desc="specification", unit="step", file=sys.stderr, dynamic_ncols=True)
