"""An independent statement of the perceptual check, for tests: plain numpy on two feel
curves, written from the rule (docs/perception.md), not from ``perceptual_check`` or
``check_verdict``.

A door feels like the chosen feel when

- outside the latch zone (angles below the chosen curve's last angle minus 3 deg),
  every point of both strokes, on the union of both curves' angles (each curve linear
  between its points), is within the force JND of the chosen force:
  ``max(force |F_chosen|, force_floor)``;
- in the latch zone, each curve on its own points, the latch peak of each stroke (the
  largest pull opening: the least force; the largest push closing: the largest force)
  is within the force JND of the chosen peak, and the peak's angle within
  ``position / handle_radius`` rad of the chosen peak's angle;
- where dynamics are given (``{"inertia": (mechanism, chosen, jnd), ...}``), each
  within its JND.

:func:`reference_passes` gives whether it passes and the worst difference in JND units.
"""

from __future__ import annotations

import math

import numpy as np

#: the latch zone: the last 3 deg before the chosen curve's last angle (closed)
LATCH_ZONE_DEG = 3.0


def _force_jnd(jnd, chosen):
    return np.maximum(jnd.force * np.abs(chosen), jnd.force_floor)


def reference_margins(mechanism, chosen, jnd, dynamics: dict | None = None) -> dict[str, float]:
    """Every judged difference of ``mechanism`` from ``chosen`` in JND units (>= 0), by
    kind: ``"<direction> stroke"`` (the stroke's worst point), ``"<direction> peak
    force"``, ``"<direction> peak angle"`` and each dynamics' name."""
    edge = float(chosen.theta[-1]) - math.radians(LATCH_ZONE_DEG)
    theta = np.union1d(mechanism.theta, chosen.theta)
    stroke = theta[theta < edge]
    out: dict[str, float] = {}
    for d in ("opening", "closing"):
        fm = np.interp(stroke, mechanism.theta, getattr(mechanism, d))
        fc = np.interp(stroke, chosen.theta, getattr(chosen, d))
        out[f"{d} stroke"] = float(np.max(np.abs(fm - fc) / _force_jnd(jnd, fc)))
        pick = np.argmin if d == "opening" else np.argmax
        peaks = []
        for curve in (mechanism, chosen):
            zone = curve.theta >= edge
            forces = getattr(curve, d)[zone]
            k = int(pick(forces))
            peaks.append((float(forces[k]), float(curve.theta[zone][k])))
        (pm, am), (pc, ac) = peaks
        out[f"{d} peak force"] = abs(pm - pc) / float(_force_jnd(jnd, pc))
        out[f"{d} peak angle"] = abs(am - ac) / (jnd.position / jnd.handle_radius)
    for name, (m, c, limit) in (dynamics or {}).items():
        out[name] = abs(m - c) / limit
    return out


def reference_passes(mechanism, chosen, jnd, dynamics: dict | None = None) -> tuple[bool, float]:
    """Whether ``mechanism`` (a FeelCurve) feels like ``chosen`` under ``jnd`` (a JND),
    with the felt ``dynamics`` where given, and its worst difference in JND units."""
    worst = max(reference_margins(mechanism, chosen, jnd, dynamics).values())
    return worst <= 1.0, worst
