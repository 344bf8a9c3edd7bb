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
#: the units of the felt dynamics a check judges
DYNAMICS_UNITS = {"inertia": "kg m", "damping": "N s/rad"}
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
    """Where ``mechanism``'s curve differs from ``chosen``'s by more than its JND.

    Both on the union of their grids (each linear between its points). The stroke, the
    angles below the latch zone (the last :data:`LATCH_ZONE` rad of the chosen curve),
    is judged at every point against the force JND of the chosen force; the latch zone
    by its two events, each curve on its own points: the peak force (the largest pull
    opening, the largest push closing) against the force JND of the chosen peak, and
    the angle of that peak against the position JND at the handle
    (:meth:`JND.angle_threshold`). A latch is felt as one event: its peak and where it
    catches, however little of the stroke it spans.

    Returns per direction (``opening``, ``closing``): ``theta`` (rad), ``mechanism``,
    ``chosen``, ``threshold`` (N), ``stroke`` (bool per point: below the latch zone),
    ``ratio`` (|difference| / threshold, JND), ``fails`` (bool per point: a stroke point
    beyond its JND), ``fraction`` (share of the stroke's angle range beyond it),
    ``worst`` (angle rad, difference N, threshold N of the stroke's largest ratio),
    ``bands`` (failing intervals), ``peak`` ``(mechanism N, chosen N, threshold N)`` and
    ``peak_angle`` ``(mechanism rad, chosen rad, threshold rad)``.

    >>> import numpy as np
    >>> th = np.linspace(0.0, 1.5, 151)
    >>> chosen = FeelCurve(th, -10.0 + 0 * th, 2.0 + 0 * th)
    >>> mech = FeelCurve(th, -10.5 + 0 * th, np.where(th < 0.75, 2.0, 3.0))
    >>> c = perceptual_check(mech, chosen, JND())
    >>> round(c["opening"]["fraction"], 3), round(c["closing"]["fraction"], 3)
    (0.0, 0.479)
    """
    m = mechanism if isinstance(mechanism, FeelCurve) else FeelCurve(**_arrays(mechanism))
    c = chosen if isinstance(chosen, FeelCurve) else FeelCurve(**_arrays(chosen))
    theta = np.union1d(m.theta, c.theta)
    stroke = theta < c.theta[-1] - LATCH_ZONE
    if stroke.sum() < 2:
        stroke = np.ones(theta.size, dtype=bool)  # a curve that is all latch zone
    out = {}
    for d in DIRECTIONS:
        fm = m.force(d, theta)
        fc = c.force(d, theta)
        threshold = jnd.force_threshold(fc)
        diff = fm - fc
        ratio = np.abs(diff) / threshold
        fails = (ratio > 1.0) & stroke
        k = int(np.argmax(np.where(stroke, ratio, -1.0)))
        peak, angle = _peak(m, c, d, jnd)
        out[d] = {
            "theta": theta,
            "mechanism": fm,
            "chosen": fc,
            "threshold": threshold,
            "stroke": stroke,
            "ratio": ratio,
            "fails": fails,
            "fraction": float(fraction_beyond(theta[stroke], fails[stroke])),
            "worst": (float(theta[k]), float(diff[k]), float(threshold[k])),
            "bands": _bands(theta, fails),
            "peak": peak,
            "peak_angle": angle,
        }
    return out


def _peak(m: FeelCurve, c: FeelCurve, direction: str, jnd: JND) -> tuple[tuple, tuple]:
    """``(mechanism, chosen, threshold)`` of the latch peak of ``direction``: its force
    (N) and its angle (rad)."""
    edge = c.theta[-1] - LATCH_ZONE
    pick = np.argmin if direction == "opening" else np.argmax
    zone_m, zone_c = m.theta >= edge, c.theta >= edge
    if not zone_m.any() or not zone_c.any():
        nan = (math.nan, math.nan, math.nan)
        return nan, nan
    fm, fc = getattr(m, direction)[zone_m], getattr(c, direction)[zone_c]
    km, kc = int(pick(fm)), int(pick(fc))
    chosen = float(fc[kc])
    force = (float(fm[km]), chosen, float(jnd.force_threshold(chosen)))
    angle = (float(m.theta[zone_m][km]), float(c.theta[zone_c][kc]), jnd.angle_threshold())
    return force, angle


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


def check_verdict(check: dict, jnd: JND, dynamics: dict | None = None) -> dict:
    """What ``show --json`` prints of a :func:`perceptual_check`, per direction, and its
    verdict.

    A door feels like the chosen feel when every point of both strokes is within the
    force JND, each latch peak within its force JND and each peak's angle within the
    position JND at the handle, and, where the chosen feel has dynamics (``dynamics``:
    ``{"inertia": (mechanism, chosen, jnd), "damping": (...)}``, kg m and N s/rad at the
    handle), the felt inertia and damping within theirs. No share of the stroke is
    allowed beyond.

    Per direction: ``worst`` (the stroke's largest difference: ``angle_deg``,
    ``difference_N``, ``jnd_N``, ``jnd_units``), ``latch_peak`` (``mechanism_N``,
    ``chosen_N``, ``jnd_N``, ``jnd_units``), ``peak_angle`` (``mechanism_deg``,
    ``chosen_deg``, ``jnd_deg``, ``jnd_units``), ``fraction_beyond_jnd`` (share of the
    stroke), ``bands_deg``, ``worst_jnd`` (the largest of the three in JND units),
    ``worst_at`` (which it is, in words) and ``verdict``: ``"within the JND"`` or
    ``"noticeable"``. Beside them: ``dynamics`` (where given), ``worst_jnd`` and
    ``worst`` (the worst of everything, in words), ``passes`` and ``jnd``.
    """
    out: dict = {}
    items = []  # (JND units, words)
    for d in DIRECTIONS:
        c = check[d]
        angle, diff, thr = c["worst"]
        mech, chosen, limit = c.get("peak", (math.nan,) * 3)
        am, ac, alim = c.get("peak_angle", (math.nan,) * 3)
        stroke = abs(diff) / thr
        peak = abs(mech - chosen) / limit  # (nan: no latch zone, nothing to judge)
        at = abs(am - ac) / alim
        latch = "unlock" if d == "opening" else "lock"
        mine = [
            (stroke, f"{d} stroke at {math.degrees(angle):.2f} deg"),
            (peak, f"{latch} peak force"),
            (at, f"{latch} peak's angle"),
        ]
        mine = [(v, w) for v, w in mine if math.isfinite(v)]
        worst_jnd, worst_at = max(mine) if mine else (0.0, "")
        items += mine
        out[d] = {
            "fraction_beyond_jnd": c["fraction"],
            "worst": {
                "angle_deg": math.degrees(angle),
                "difference_N": diff,
                "jnd_N": thr,
                "jnd_units": stroke,
            },
            "latch_peak": {
                "mechanism_N": mech,
                "chosen_N": chosen,
                "jnd_N": limit,
                "jnd_units": peak,
            },
            "peak_angle": {
                "mechanism_deg": math.degrees(am),
                "chosen_deg": math.degrees(ac),
                "jnd_deg": math.degrees(alim),
                "jnd_units": at,
            },
            "bands_deg": [(math.degrees(a), math.degrees(b)) for a, b in c["bands"]],
            "worst_jnd": worst_jnd,
            "worst_at": worst_at,
            "verdict": "within the JND" if worst_jnd <= 1.0 else "noticeable",
        }
    if dynamics:
        out["dynamics"] = {}
        for name, (mech, chosen, limit) in dynamics.items():
            units = abs(mech - chosen) / limit
            items.append((units, f"felt {name}"))
            out["dynamics"][name] = {
                "mechanism": mech,
                "chosen": chosen,
                "jnd": limit,
                "unit": DYNAMICS_UNITS[name],
                "jnd_units": units,
                "verdict": "within the JND" if units <= 1.0 else "noticeable",
            }
    worst_jnd, worst = max(items) if items else (0.0, "")
    out["worst_jnd"] = worst_jnd
    out["worst"] = worst
    out["jnd"] = jnd.as_dict()
    out["passes"] = worst_jnd <= 1.0
    return out


def verdict_text(verdict: dict) -> str:
    """One line for a person: the verdict with its worst point in JND units.

    >>> verdict_text({"passes": False, "worst_jnd": 1.5, "worst": "unlock peak force"})
    'noticeable: unlock peak force off by 1.5 JND'
    >>> verdict_text({"passes": True, "worst_jnd": 0.42, "worst": "opening stroke at 30 deg"})
    'within the JND: at most 0.42 JND (opening stroke at 30 deg)'
    """
    w, at = verdict["worst_jnd"], verdict["worst"]
    if verdict["passes"]:
        return f"within the JND: at most {w:.2g} JND ({at})"
    return f"noticeable: {at} off by {w:.3g} JND"
