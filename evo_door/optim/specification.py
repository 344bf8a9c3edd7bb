"""What a specification stage states, as data: the yield, the specification, the
nearest feel; stored in a results file's ``tolerance/`` group and read back
(:mod:`evo_door.optim.tolerance` computes them)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from evo_door.files import ATTRS

#: the groups a specification table lists (besides the free parameters)
SPEC_GROUPS = ("specification", "sensation")


def spec_names(model, free) -> list[str]:
    """The parameters a specification table lists: the model's ``specification`` and
    ``sensation`` groups and the free ones, in declaration order."""
    return [p.name for p in model.params if p.group in SPEC_GROUPS or p.name in free]


#: the seed of the centring's draws (what a file written without one used)
DESIGN_SEED = 1


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
        """The inverse of :meth:`as_dict`; counts checked (a results file is data)."""
        from evo_door.files import DamagedFile, fields

        d = fields.as_mapping(d, fields.node_place(d))
        out = cls(
            fields.integer(d, "passed", lo=0),
            fields.integer(d, "samples", lo=0),
            fields.integer(d, "seed"),
        )
        if out.passed > out.samples:
            raise DamagedFile(f"{fields.node_place(d)}: more doors passed than sampled")
        return out


def clopper_pearson(passed: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """The two-sided Clopper-Pearson interval of a share of ``passed`` in ``n``.

    >>> [round(x, 4) for x in clopper_pearson(1900, 2000)]
    [0.9395, 0.9591]
    """
    if n <= 0:
        return (math.nan, math.nan)
    # the beta distribution's quantiles, as scipy.stats.beta.ppf computes them (the same
    # function), without importing scipy.stats: much of the start of a command that shows one
    from scipy.special import betaincinv

    a = 1.0 - confidence
    lo = 0.0 if passed == 0 else float(betaincinv(passed, n - passed + 1, a / 2))
    hi = 1.0 if passed == n else float(betaincinv(passed + 1, n - passed, 1 - a / 2))
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
        from evo_door.files import fields

        a = node[ATTRS]
        names = fields.texts(a, "names")
        values = fields.array(node, "values", shape=(len(names),))
        return cls(
            model=fields.text(a, "model"),
            values=dict(zip(names, map(float, values))),
            moved=fields.texts(a, "moved"),
            distance=fields.number(a, "distance_jnd"),
            yield_=_yield_attr(a, "yield"),
            target=fields.number(a, "target"),
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
        from evo_door.files import Node, fields

        a = node[ATTRS]
        if fields.integer(a, "format", 1) < 2:
            return None
        names = fields.texts(a, "names")
        n = len(names)
        alt = fields.json_value(a, "alternative", None) or {}
        if alt:
            alt = Node(
                fields.as_mapping(alt, fields.place_of(a, "alternative")),
                place=fields.place_of(a, "alternative") + ":",
                style="key",
            )
            alt = {
                "design": fields.text(alt, "design"),
                "nominal": fields.array(alt, "nominal", shape=(n,)),
                "yield": YieldEstimate.from_dict(fields.group(alt, "yield")),
            }
        ay = fields.json_value(a, "allocation_yield", None)
        curves = fields.group(node, "curves", {})
        allocation = fields.as_mapping(
            fields.json_value(a, "allocation", None) or {},
            fields.place_of(a, "allocation"),
            fields.as_number,
        )
        return fields.stored(
            cls,
            a,
            node,
            shapes={
                k: (n,)
                for k in (
                    "units",
                    "nominal",
                    "asis",
                    "half_width",
                    "distribution",
                    "source",
                    "sensitivity",
                    "loss",
                    "allocation_nominal",
                )
            },
            yield_=_yield_attr(a, "yield"),
            alternative=alt,
            allocation=allocation,
            allocation_yield=YieldEstimate.from_dict(ay) if ay else None,
            nearest=NearestFeel.from_tree(fields.group(node, "nearest_feel"))
            if "nearest_feel" in node
            else None,
            curves={k: fields.array(curves, k) for k in curves if k != ATTRS},
        )


def _yield_attr(a, key) -> YieldEstimate:
    from evo_door.files import Node, fields

    where = fields.place_of(a, key)
    d = fields.as_mapping(fields.json_value(a, key, None), where)
    return YieldEstimate.from_dict(Node(d, place=where + ":", style="key"))


def _plain_alternative(alt: dict) -> dict:
    if not alt:
        return {}
    return {
        "design": alt["design"],
        "nominal": [float(v) for v in alt["nominal"]],
        "yield": alt["yield"].as_dict(),
    }
