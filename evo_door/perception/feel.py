"""A feel as data, and the perceptual check of one feel against another.

A :class:`FeelCurve` is the force-angle curve of both strokes: the user force (N, +
toward closing) that moves the door slowly toward open (``opening``) and toward closed
(``closing``), against the angle. It comes from a model and its parameters
(:func:`model_curve`, the Coulomb curve of ``evo-door curve``, latch peaks resolved) or
from a CSV file in the columns that ``evo-door curve`` writes (:func:`read_curve_csv`),
so that a curve measured on a reference product, or drawn, is a feel too.

:func:`perceptual_check` says where a mechanism's curve differs from the chosen one by
more than a force JND (:class:`~evo_door.perception.jnd.JND`); :func:`check_verdict`
condenses it into what ``show --json`` prints.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evo_door.errors import UserError
from evo_door.perception.jnd import JND

DIRECTIONS = ("opening", "closing")
#: the columns of a curve file (``evo-door curve``'s CSV)
CURVE_COLUMNS = ("theta", "force", "direction", "speed")
#: a share of the stroke within the JND at or above this passes the check
PASS_FRACTION = 0.95
#: rad before closed where the latch is, judged by its peaks (3 deg)
LATCH_ZONE = math.radians(3.0)


@dataclass
class FeelCurve:
    """Force-angle curves of both strokes on one rising grid of angles (rad)."""

    theta: np.ndarray
    opening: np.ndarray
    closing: np.ndarray
    source: str = ""
    #: where it came from, for the results file: {"kind": "model"|"file", ...}
    origin: dict = field(default_factory=dict)

    def __post_init__(self):
        self.theta = np.asarray(self.theta, dtype=np.float64)
        self.opening = np.asarray(self.opening, dtype=np.float64)
        self.closing = np.asarray(self.closing, dtype=np.float64)
        n = self.theta.size
        if n < 2 or self.opening.shape != (n,) or self.closing.shape != (n,):
            raise UserError(
                f"{self.source or 'feel curve'}: needs at least 2 angles with a force for "
                "each stroke"
            )
        if not np.all(np.diff(self.theta) > 0):
            raise UserError(f"{self.source or 'feel curve'}: the angles must rise")
        for d in DIRECTIONS:
            f = getattr(self, d)
            if not np.all(np.isfinite(f)):
                raise UserError(f"{self.source or 'feel curve'}: a {d} force is not finite")

    def force(self, direction: str, theta) -> np.ndarray:
        """The curve's force (N) of ``direction`` at ``theta``, linear between its points."""
        return np.interp(theta, self.theta, getattr(self, direction))

    def as_dict(self) -> dict:
        return {"theta": self.theta, "opening": self.opening, "closing": self.closing}


def model_curve(model, params, source: str = "") -> FeelCurve:
    """The Coulomb force-angle curve of ``model`` with ``params`` (a ParamSet or vector)."""
    from evo_door.sim.simulate import force_angle_curve

    c = force_angle_curve(model, params)
    return FeelCurve(
        c["theta"],
        c["opening"],
        c["closing"],
        source=source or f"{model.name} model",
        origin={"kind": "model", "model": model.name},
    )


def read_curve_csv(path) -> FeelCurve:
    """A feel from a CSV file with the columns of ``evo-door curve``.

    ``theta`` (rad), ``force`` (N, + toward closing), ``direction`` (``opening`` or
    ``closing``), ``speed`` (rad/s; 0 for the Coulomb curve, as written). Both
    directions are needed; each may have its own angles (they are put on the union of
    both, linearly). Every bad row is refused with its line number.
    """
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such curve file")
    rows: dict[str, list[tuple[float, float]]] = {d: [] for d in DIRECTIONS}
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise UserError(f"{path}: empty; expected the header {','.join(CURVE_COLUMNS)}")
        header = [h.strip() for h in header]
        missing = [c for c in CURVE_COLUMNS[:3] if c not in header]
        if missing:
            raise UserError(
                f"{path}:1: missing column(s) {', '.join(missing)}; expected "
                f"{','.join(CURVE_COLUMNS)} (the columns evo-door curve writes)"
            )
        col = {c: header.index(c) for c in CURVE_COLUMNS if c in header}
        for line, row in enumerate(reader, start=2):
            if not row or all(not x.strip() for x in row):
                continue
            try:
                theta = float(row[col["theta"]])
                force = float(row[col["force"]])
                direction = row[col["direction"]].strip()
            except (ValueError, IndexError):
                raise UserError(f"{path}:{line}: expected theta,force,direction numbers") from None
            if direction not in rows:
                raise UserError(
                    f"{path}:{line}: direction {direction!r}: expected opening or closing"
                )
            if not (math.isfinite(theta) and math.isfinite(force)):
                raise UserError(f"{path}:{line}: theta and force must be finite")
            rows[direction].append((theta, force))
    for d, r in rows.items():
        if len(r) < 2:
            raise UserError(f"{path}: needs at least 2 {d} rows, has {len(r)}")
    arrays = {}
    for d, r in rows.items():
        a = np.array(sorted(r))
        if np.any(np.diff(a[:, 0]) <= 0):
            raise UserError(f"{path}: two {d} rows at one angle")
        arrays[d] = a
    grid = np.union1d(arrays["opening"][:, 0], arrays["closing"][:, 0])
    forces = {d: np.interp(grid, a[:, 0], a[:, 1]) for d, a in arrays.items()}
    return FeelCurve(
        grid,
        forces["opening"],
        forces["closing"],
        source=str(path),
        origin={"kind": "file", "path": str(path)},
    )


def perceptual_check(mechanism: FeelCurve | dict, chosen: FeelCurve | dict, jnd: JND) -> dict:
    """Where ``mechanism``'s curve differs from ``chosen``'s by more than a force JND.

    Both on the union of their grids (each linear between its points). Returns per
    direction (``opening``, ``closing``): ``theta`` (rad), ``mechanism``, ``chosen``,
    ``threshold`` (N, :meth:`JND.force_threshold` of the chosen force), ``fails`` (bool
    per point), ``fraction`` (share of the stroke's angle range beyond the JND),
    ``worst`` (angle rad, difference N, threshold N), ``bands`` (failing intervals) and
    ``peak``: the latch's peak of the stroke (the largest pull opening, the largest push
    closing, in the last :data:`LATCH_ZONE` rad of the chosen curve, each curve on its
    own points) as ``(mechanism N, chosen N, threshold N)``. A latch is felt as one event:
    a peak beyond its JND is noticeable however little of the stroke it spans.

    >>> import numpy as np
    >>> th = np.linspace(0.0, 1.5, 151)
    >>> chosen = FeelCurve(th, -10.0 + 0 * th, 2.0 + 0 * th)
    >>> mech = FeelCurve(th, -10.5 + 0 * th, np.where(th < 0.75, 2.0, 3.0))
    >>> c = perceptual_check(mech, chosen, JND())
    >>> round(c["opening"]["fraction"], 3), round(c["closing"]["fraction"], 3)
    (0.0, 0.5)
    """
    m = mechanism if isinstance(mechanism, FeelCurve) else FeelCurve(**_arrays(mechanism))
    c = chosen if isinstance(chosen, FeelCurve) else FeelCurve(**_arrays(chosen))
    theta = np.union1d(m.theta, c.theta)
    out = {}
    for d in DIRECTIONS:
        fm = m.force(d, theta)
        fc = c.force(d, theta)
        threshold = jnd.force_threshold(fc)
        diff = fm - fc
        fails = np.abs(diff) > threshold
        k = int(np.argmax(np.abs(diff) / threshold))
        out[d] = {
            "theta": theta,
            "mechanism": fm,
            "chosen": fc,
            "threshold": threshold,
            "fails": fails,
            "fraction": float(fraction_beyond(theta, fails)),
            "worst": (float(theta[k]), float(diff[k]), float(threshold[k])),
            "bands": _bands(theta, fails),
            "peak": _peak(m, c, d, jnd),
        }
    return out


def _peak(m: FeelCurve, c: FeelCurve, direction: str, jnd: JND) -> tuple[float, float, float]:
    """``(mechanism, chosen, threshold)`` (N) of the latch peak of ``direction``."""
    edge = c.theta[-1] - LATCH_ZONE
    pick = np.min if direction == "opening" else np.max
    fm = getattr(m, direction)[m.theta >= edge]
    fc = getattr(c, direction)[c.theta >= edge]
    if fm.size == 0 or fc.size == 0:
        return (math.nan, math.nan, math.nan)
    chosen = float(pick(fc))
    return (float(pick(fm)), chosen, float(jnd.force_threshold(chosen)))


def fraction_beyond(theta, fails):
    """The share of the angle range of ``theta`` (rising) that is beyond the JND: the
    intervals whose both ends fail. ``fails`` may hold one row per curve (last axis along
    ``theta``); a row's share each.

    >>> float(fraction_beyond([0.0, 1.0, 2.0, 4.0], [False, True, True, True]))
    0.75
    """
    theta = np.asarray(theta, dtype=np.float64)
    fails = np.asarray(fails, dtype=bool)
    both = fails[..., :-1] & fails[..., 1:]
    return np.sum(np.diff(theta) * both, axis=-1) / (theta[-1] - theta[0])


def _arrays(curve: dict) -> dict:
    return {d: curve[d] for d in ("theta", *DIRECTIONS)}


def _bands(theta, fails) -> list[tuple[float, float]]:
    """The runs of consecutive failing points as (first, last) angle intervals."""
    f = np.concatenate([[False], np.asarray(fails, dtype=bool), [False]])
    starts = np.flatnonzero(f[1:] & ~f[:-1])
    ends = np.flatnonzero(~f[1:] & f[:-1]) - 1
    return [(float(theta[a]), float(theta[b])) for a, b in zip(starts, ends)]


def check_verdict(check: dict, jnd: JND, pass_fraction: float = PASS_FRACTION) -> dict:
    """What ``show --json`` prints of a :func:`perceptual_check`, per direction.

    ``fraction_beyond_jnd`` of the stroke, the ``worst`` difference (``angle_deg``,
    ``difference_N``, ``jnd_N``) and a ``verdict``: ``"within the JND"`` where no point
    of the stroke is beyond it, ``"passes"`` where at least ``pass_fraction`` of the
    stroke is within it and its latch peak within its JND (``latch_peak``: mechanism,
    chosen, JND in N), ``"noticeable"`` otherwise. ``jnd`` is recorded beside it.
    """
    out: dict = {}
    for d in DIRECTIONS:
        c = check[d]
        angle, diff, thr = c["worst"]
        fraction = c["fraction"]
        mech, chosen, limit = c.get("peak", (math.nan, math.nan, math.nan))
        peak_ok = not (abs(mech - chosen) > limit)  # (nan: no latch zone, nothing to judge)
        if not c["fails"].any():
            verdict = "within the JND"
        elif fraction <= 1.0 - pass_fraction and peak_ok:
            verdict = "passes"
        else:
            verdict = "noticeable"
        out[d] = {
            "fraction_beyond_jnd": fraction,
            "worst": {"angle_deg": math.degrees(angle), "difference_N": diff, "jnd_N": thr},
            "verdict": verdict,
            "bands_deg": [(math.degrees(a), math.degrees(b)) for a, b in c["bands"]],
            "latch_peak": {"mechanism_N": mech, "chosen_N": chosen, "jnd_N": limit},
        }
    out["pass_fraction"] = pass_fraction
    out["jnd"] = jnd.as_dict()
    out["passes"] = all(out[d]["verdict"] != "noticeable" for d in DIRECTIONS)
    return out
