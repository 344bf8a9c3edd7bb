"""Transmissions: a kinematic map from a body's coordinate ``q`` to an output ``s(q)``.

A mechanism file's ``transmissions:`` names each map (``docs/blocks.md``); an element
``on:`` a transmission acts on its output: its law sees ``s`` and
``ds/dt = (ds/dq) dq/dt``, and its force ``F`` on ``s`` acts on the body as
``F ds/dq`` (virtual work through a massless linkage). The maps are the compiled
kernels of :mod:`evo_door.models.blocks.kinematics`, in closed form with their ratio.

Each kind declares its parameters as :class:`~evo_door.models.blocks.components.Spec`
(units: the linear unit is that of a linear output or a length, the rotary one of an
angle), its input kinds and its output kind. :func:`check_fold` evaluates the map over
the body's range at the file's values and refuses one that folds: the rod of a
slider-crank that cannot reach, a four-bar that cannot close, a ratio that vanishes or
changes sign (a dead point), a table whose points are not monotone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from evo_door.models.blocks.components import LINEAR, ROTARY, Spec

#: points of the range the fold check evaluates the map at
FOLD_GRID = 4001
#: a ratio smaller than this fraction of the largest over the range counts as vanishing
DEAD_RATIO = 1e-6


@dataclass(frozen=True)
class TransmissionKind:
    kind: str
    title: str
    inputs: tuple[str, ...]  # body kinds it takes
    output: str | None  # the output's kind; None: the word ``output`` says
    specs: tuple[Spec, ...]
    words: dict[str, tuple[str, ...]]
    fold: str  # what it means when the map cannot be evaluated


_LENGTH = "m"
TRANSMISSIONS: dict[str, TransmissionKind] = {
    t.kind: t
    for t in (
        TransmissionKind(
            "slider_crank", "slider-crank: crank angle to slider position", (ROTARY,), LINEAR,
            (
                Spec("radius", _LENGTH, _LENGTH, None, 1e-6, 10.0, "geometry", "crank radius"),
                Spec("rod", _LENGTH, _LENGTH, None, 1e-6, 10.0, "geometry", "rod length"),
                Spec("offset", _LENGTH, _LENGTH, 0.0, -10.0, 10.0, "geometry",
                     "distance of the slider's line from the crank's axis"),
                Spec("phase", "rad", "rad", 0.0, -10.0, 10.0, "geometry",
                     "crank angle from the slider's line at q = 0"),
            ),
            {}, "the rod cannot reach the slider's line",
        ),
        TransmissionKind(
            "four_bar", "four-bar: crank angle to rocker angle", (ROTARY,), ROTARY,
            (
                Spec("crank", _LENGTH, _LENGTH, None, 1e-6, 10.0, "geometry",
                     "input crank, on the body"),
                Spec("coupler", _LENGTH, _LENGTH, None, 1e-6, 10.0, "geometry", "coupler"),
                Spec("rocker", _LENGTH, _LENGTH, None, 1e-6, 10.0, "geometry",
                     "output rocker"),
                Spec("ground", _LENGTH, _LENGTH, None, 1e-6, 10.0, "geometry",
                     "distance between the two fixed pivots"),
                Spec("phase", "rad", "rad", 0.0, -10.0, 10.0, "geometry",
                     "crank angle from the ground link at q = 0"),
            ),
            {"branch": ("open", "crossed")}, "the four-bar cannot close",
        ),
        TransmissionKind(
            "table", "table: output over the body's coordinate, monotone cubic", (LINEAR, ROTARY),
            None, (), {"output": (LINEAR, ROTARY)}, "",
        ),
    )
}  # fmt: skip
#: the most points a table holds
TABLE_POINTS = 64


@dataclass
class Transmission:
    name: str
    kind: str
    body: str
    values: dict[str, float]  # parameter -> value (a table's: q_0.., s_0..)
    words: dict[str, str]
    input: str  # the body's kind
    output: str  # the output's kind

    @property
    def points(self) -> int:
        """A table's number of points (0 for another kind)."""
        return sum(1 for k in self.values if k.startswith("q_")) if self.kind == "table" else 0

    def unit(self, parameter: str) -> str:
        """The unit of one of its parameters."""
        if self.kind == "table":
            kind = self.input if parameter.startswith("q_") else self.output
            return "m" if kind == LINEAR else "rad"
        spec = next(s for s in TRANSMISSIONS[self.kind].specs if s.name == parameter)
        return spec.linear_unit

    def call(self, q: str, p: dict[str, str], vector: str = "p") -> str:
        """Source of the kernel's call: ``(s, ds/dq)`` at the coordinate ``q``;
        ``p`` maps the parameters to their source (``p[3]``)."""
        if self.kind == "slider_crank":
            args = ", ".join(p[k] for k in ("radius", "rod", "offset", "phase"))
            return f"slider_crank({q}, {args})"
        if self.kind == "four_bar":
            args = ", ".join(p[k] for k in ("crank", "coupler", "rocker", "ground", "phase"))
            branch = "1.0" if self.words["branch"] == "open" else "-1.0"
            return f"four_bar({q}, {args}, {branch})"
        first = int(p["q_0"].removeprefix(f"{vector}[").removesuffix("]"))
        return f"pchip({q}, {vector}, {first}, {self.points})"

    def evaluate(self, q: float) -> tuple[float, float]:
        """``(s, ds/dq)`` at ``q`` and the file's values (the compiled kernel)."""
        from evo_door.models.blocks import kinematics

        v = self.values
        if self.kind == "slider_crank":
            return kinematics.slider_crank(q, v["radius"], v["rod"], v["offset"], v["phase"])
        if self.kind == "four_bar":
            branch = 1.0 if self.words["branch"] == "open" else -1.0
            args = (v["crank"], v["coupler"], v["rocker"], v["ground"], v["phase"])
            return kinematics.four_bar(q, *args, branch)
        return kinematics.pchip(q, self.table(), 0, self.points)

    def curve(self, qs) -> np.ndarray:
        """``(s, ds/dq)`` at each coordinate of ``qs``, a row each, as :meth:`evaluate`
        gives them (a table's points gathered once, not once a coordinate: the check of
        a fold evaluates thousands, at every command that reads the file)."""
        if self.kind != "table":
            return np.array([self.evaluate(float(q)) for q in qs])
        from evo_door.models.blocks import kinematics

        data, n = self.table(), self.points
        return np.array([kinematics.pchip(float(q), data, 0, n) for q in qs])

    def table(self) -> np.ndarray:
        """A table's points as its kernel reads them: ``q_0..q_{n-1}``, then ``s_0..``."""
        v, n = self.values, self.points
        return np.array([v[f"q_{i}"] for i in range(n)] + [v[f"s_{i}"] for i in range(n)])

    @property
    def imports(self) -> str:
        """The import line its kernel needs."""
        kernel = "pchip" if self.kind == "table" else self.kind
        return f"from evo_door.models.blocks.kinematics import {kernel}"


def check_fold(t: Transmission, lo: float, hi: float) -> str | None:
    """Why ``t`` folds over ``[lo, hi]`` of its body's coordinate, naming where (None: it
    does not)."""
    unit = "m" if t.input == LINEAR else "rad"
    if t.kind == "table":
        n = t.points
        qs = [t.values[f"q_{i}"] for i in range(n)]
        ss = [t.values[f"s_{i}"] for i in range(n)]
        for i in range(1, n):
            if not qs[i] > qs[i - 1]:
                return f"its q points must rise; q_{i} = {qs[i]:g} {unit} does not"
        rising = ss[1] > ss[0]
        for i in range(1, n):
            if (ss[i] > ss[i - 1]) != rising or ss[i] == ss[i - 1]:
                return f"it is not monotone: s turns at q = {qs[i - 1]:g} {unit} (point {i - 1})"
    q = np.linspace(lo, hi, FOLD_GRID)
    sr = t.curve(q)
    bad = ~np.isfinite(sr).all(axis=1)
    if bad.any():
        j = int(np.argmax(bad))
        at = q[j] if j == 0 else _edge(t, q[j - 1], q[j], lambda v: math.isfinite(t.evaluate(v)[0]))
        return f"it folds at q = {at:.6g} {unit}: {TRANSMISSIONS[t.kind].fold}"
    r = sr[:, 1]
    big = float(np.max(np.abs(r)))
    dead = (np.abs(r) <= DEAD_RATIO * big) | (np.sign(r) != np.sign(r[0]))
    if big == 0.0 or dead.any():
        j = int(np.argmax(dead))
        sign = np.sign(r[0])
        at = q[j] if j == 0 else _edge(t, q[j - 1], q[j], lambda v: sign * t.evaluate(v)[1] > 0)
        return f"it passes a dead point at q = {at:.6g} {unit} (ds/dq vanishes or changes sign)"
    return None


def _edge(t: Transmission, good: float, bad: float, ok) -> float:
    """Where ``ok`` stops holding between ``good`` and ``bad`` (bisection)."""
    for _ in range(60):
        mid = 0.5 * (good + bad)
        if ok(mid):
            good = mid
        else:
            bad = mid
    return 0.5 * (good + bad)
