"""The chosen feel as a fitting target: the perceptual objective.

A mechanism's parameters are scored by how far its feel is from the chosen one, in
units of the just-noticeable difference (JND), as a user would judge it:

- **the stroke**: on a grid of the angles below the latch zone, the difference of the
  force-angle curves (Coulomb level, :func:`~evo_door.sim.simulate.hold_forces`) of
  each stroke divided by the force JND of the chosen force, squared, averaged over the
  angle range and over both strokes;
- **the worst of the stroke**: every point of a stroke beyond its force JND adds the
  square of how far beyond (JND), times ``excess_weight``: the check judges every
  point, so a fit may not buy a small mean with one stretch beyond the JND;
- **the latch peaks**: in the latch zone (the last ``latch_zone`` rad before closed,
  sampled densely enough to resolve a catch a few thousandths of a radian wide), the
  largest pull of the opening stroke and the largest push of the closing stroke,
  each against its own force JND, and the angle of each against the position JND at
  the handle (:meth:`JND.angle_threshold`), squared, times ``peak_weight``;
- **the dynamics**, where the chosen feel has them (a model, not a bare curve): the
  mean felt inertia (the force per angular acceleration at the handle) and viscous
  damping (the force per angular speed beyond the dry friction, between half and the
  whole of :attr:`JND.speed`) over the stroke, each against its JND, squared.

The objective is the sum: 0 is the chosen feel, 1 is a difference of one JND
everywhere. :meth:`FeelTarget.residuals` gives the terms as a vector whose squares sum
to it (for the identifiability check and for local polish).

Every door is measured one way, compiled and many at once: :func:`measured_feel` (the
Coulomb forces of both strokes, the latch peaks and their angles) and
:func:`felt_dynamics_rows` (the felt inertia and damping). One candidate is a batch of
one row; :class:`~evo_door.optim.feel_doors.BatchFeelCheck`, the check of the doors a
supplier builds, measures on the same two. The objective itself searches the latch
zone's fine grid coarse to fine where the plant allows it (:func:`stroke_and_peaks`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from evo_door.errors import UserError
from evo_door.perception.feel import DIRECTIONS, LATCH_ZONE, FeelCurve
from evo_door.perception.jnd import JND

#: spacing of the latch zone's grid (rad): a catch rises over about 1e-3 rad
LATCH_SPACING = 2e-5
#: points of the stroke's grid below the latch zone
STROKE_POINTS = 361
#: points of the stroke at which the felt inertia and damping are averaged
DYNAMICS_POINTS = 33
#: weight of each latch peak's squared JND difference: a peak one JND off counts as the
#: whole stroke one JND off (a latch is felt as one event)
PEAK_WEIGHT = 1.0
#: weight of each stroke point's squared excess beyond its JND (JND^2 a point): ten
#: points 0.1 JND beyond add 1, as much as the whole stroke one JND off
EXCESS_WEIGHT = 10.0


#: rows measured at once (the memory of a batch: rows x angles x 2 strokes)
ROWS = 256
#: the latch zone's grid is searched for each peak coarse to fine (stroke_and_peaks):
#: every LATCH_COARSE-th angle, then every angle within LATCH_WINDOW coarse steps of the
#: coarse peak. A catch rises over some 50 points of the grid and its peak is a plateau
#: some 300 long, so the peak is among them (tests/test_perception.py compares the two
#: searches door by door); an eighth of the zone's angles
LATCH_COARSE = 8
LATCH_WINDOW = 2


def coulomb_rows(model, P) -> np.ndarray:
    """The Coulomb kernel vector (:func:`~evo_door.sim.simulate.coulomb_vector`) of
    every row of the kernel matrix ``P``."""
    from evo_door.sim.simulate import coulomb_vector

    return np.array([coulomb_vector(model, p) for p in P])


def measured_feel(model, Q, theta, latch) -> dict:
    """What a door's feel is judged by, for every row of the Coulomb kernel matrix ``Q``
    (:func:`coulomb_rows`) on the angles ``theta`` (rad), in one compiled call a stroke:
    ``{"opening": forces, "closing": forces}`` (N, rows x angles) and, in the latch zone
    (``latch``, a mask of ``theta``), ``"peaks"`` (the largest pull opening, the largest
    push closing, N) and their ``"angles"`` (rad), each per stroke a value a row."""
    from evo_door.sim.simulate import COULOMB_SPEED, hold_forces_rows

    zone = theta[latch]
    out: dict = {"peaks": {}, "angles": {}}
    for d, sign in zip(DIRECTIONS, (-1.0, 1.0)):
        f = hold_forces_rows(model, Q, theta, sign * COULOMB_SPEED)
        fl = f[:, latch]
        k = np.argmin(fl, axis=1) if d == "opening" else np.argmax(fl, axis=1)
        out[d] = f
        out["peaks"][d] = fl[np.arange(len(Q)), k]
        out["angles"][d] = zone[k]
    return out


def stroke_and_peaks(model, Q, stroke, zone) -> dict:
    """:func:`measured_feel` with the forces on the angles ``stroke`` (rad) and the
    peaks searched on the latch zone's grid ``zone`` (rad) coarse to fine, for a plant
    whose force at an angle depends on that angle alone (``hold_forces_at``: a model
    given by ``accel``): every :data:`LATCH_COARSE`-th angle first, then every angle
    within :data:`LATCH_WINDOW` coarse steps of the coarse peak. The same peaks and
    angles as on every angle of ``zone`` unless a spike narrower than a coarse step
    stands higher than the coarse peak's surroundings (as where a catch lets go: a
    sample or two of the whole grid may land on its edge; the peak's force then
    differs by a fraction of a per cent, its angle by up to the plateau's length).
    Other plants (a state vector's hold starts from the last angle's equilibrium) are
    measured on every angle."""
    from evo_door.sim.simulate import COULOMB_SPEED, hold_forces_rows

    at = getattr(model.plant, "hold_forces_at", None)
    if at is None:
        theta = np.concatenate([stroke, zone])
        got = measured_feel(model, Q, theta, np.arange(theta.size) >= stroke.size)
        return {**got, **{d: got[d][:, : stroke.size] for d in DIRECTIONS}}
    rows, n = np.arange(len(Q)), stroke.size
    coarse = np.arange(0, zone.size, LATCH_COARSE)
    reach = LATCH_WINDOW * LATCH_COARSE
    width = min(zone.size, 2 * reach + 1)
    theta = np.concatenate([stroke, zone[coarse]])  # the stroke, then the coarse zone
    out: dict = {"peaks": {}, "angles": {}}
    for d, sign in zip(DIRECTIONS, (-1.0, 1.0)):
        speed = sign * COULOMB_SPEED
        f = hold_forces_rows(model, Q, theta, speed)
        out[d] = f[:, :n]
        # the largest push closing, the largest pull (the least force) opening: the
        # first largest of sign x force, as np.argmax takes it on the whole grid
        g = sign * f[:, n:]
        start = np.clip(coarse[np.argmax(g, axis=1)] - reach, 0, zone.size - width)
        window = start[:, None] + np.arange(width)
        f = at(Q, zone[window], speed)
        k = np.argmax(sign * f, axis=1)
        out["peaks"][d] = f[rows, k]
        out["angles"][d] = zone[window[rows, k]]
    return out


def felt_dynamics_rows(model, P, theta, speed: float) -> np.ndarray:
    """Mean felt inertia (kg m) and viscous damping (N s/rad) of every row of the
    kernel matrix ``P`` over the angles ``theta`` (module docstring, the dynamics;
    ``speed``: :attr:`JND.speed`): an array (rows, 2)."""
    from evo_door.sim.simulate import hold_forces_rows, inertia_rows

    inertia = inertia_rows(model, P, theta, -0.5 * speed).mean(axis=1)
    damping = np.zeros(len(P))
    for s in (-1.0, 1.0):
        half = hold_forces_rows(model, P, theta, 0.5 * s * speed)
        full = hold_forces_rows(model, P, theta, s * speed)
        damping += np.mean((full - half) / (0.5 * s * speed), axis=1)
    return np.c_[inertia, 0.5 * damping]


@dataclass
class FeelTarget:
    """A chosen feel and how a mechanism is scored against it (module docstring)."""

    curve: FeelCurve
    jnd: JND = field(default_factory=JND)
    #: (inertia kg m, damping N s/rad) felt on the chosen feel, None for a bare curve
    dynamics: tuple[float, float] | None = None
    closed: float = 0.5 * math.pi
    latch_zone: float = LATCH_ZONE
    peak_weight: float = PEAK_WEIGHT
    excess_weight: float = EXCESS_WEIGHT
    #: weight of each peak's squared angle difference (JND^2), as a peak force's
    angle_weight: float = PEAK_WEIGHT

    def __post_init__(self):
        lo = float(self.curve.theta[0])
        edge = self.closed - self.latch_zone
        if edge <= lo:
            raise UserError(
                f"{self.curve.source}: the curve must reach below {math.degrees(edge):.1f} deg"
            )
        stroke = np.linspace(lo, edge, STROKE_POINTS)
        self.stroke = np.union1d(stroke, self.curve.theta[(self.curve.theta < edge)])
        w = np.zeros(self.stroke.size)
        h = np.diff(self.stroke)
        w[:-1] += h / 2
        w[1:] += h / 2
        self.weights = w / (self.stroke[-1] - self.stroke[0])
        hi = min(self.closed, float(self.curve.theta[-1]))
        n = max(2, int(math.ceil((hi - edge) / LATCH_SPACING)) + 1)
        self.latch = np.union1d(
            np.linspace(edge, hi, n), self.curve.theta[self.curve.theta >= edge]
        )
        self.dyn_grid = np.linspace(lo, edge, DYNAMICS_POINTS)
        self.chosen = {d: self.curve.force(d, self.stroke) for d in DIRECTIONS}
        self.threshold = {d: self.jnd.force_threshold(self.chosen[d]) for d in DIRECTIONS}
        latch = {d: self.curve.force(d, self.latch) for d in DIRECTIONS}
        at = {"opening": int(latch["opening"].argmin()), "closing": int(latch["closing"].argmax())}
        self.peaks = {d: float(latch[d][k]) for d, k in at.items()}
        #: the angle (rad) of each latch peak, and the JND it is judged by
        self.peak_angles = {d: float(self.latch[k]) for d, k in at.items()}
        self.angle_threshold = self.jnd.angle_threshold()
        self.peak_threshold = {d: self.jnd.force_threshold(v) for d, v in self.peaks.items()}

    # -- from a model ----------------------------------------------------------------
    @classmethod
    def from_model(
        cls, model, params, jnd: JND | None = None, source: str = "", closed: float | None = None
    ) -> FeelTarget:
        """The feel of ``model`` with ``params``: its Coulomb curve and its dynamics.
        ``closed`` (rad): where the latch zone ends, default the model's closed angle."""
        from evo_door.params import param_vector
        from evo_door.perception.feel import model_curve

        jnd = jnd or JND()
        closed = float(model.theta_range[1]) if closed is None else closed
        curve = model_curve(model, params, source)
        probe = cls(curve, jnd, closed=closed)
        p = param_vector(params, model.params)
        return cls(curve, jnd, dynamics=probe.felt_dynamics(model, p), closed=closed)

    # -- the mechanism's side ----------------------------------------------------------
    def felt_dynamics(self, model, p) -> tuple[float, float]:
        """Mean felt inertia (kg m) and viscous damping (N s/rad) of ``model`` at ``p``
        over the stroke (module docstring): :func:`felt_dynamics_rows` of one row."""
        inertia, damping = felt_dynamics_rows(
            model, np.atleast_2d(p), self.dyn_grid, self.jnd.speed
        )[0]
        return float(inertia), float(damping)

    def residuals(self, model, p) -> np.ndarray:
        """The objective's terms as a vector whose squares sum to :meth:`value`."""
        return self.residual_rows(model, p)[0]

    def residual_rows(self, model, P) -> np.ndarray:
        """:meth:`residuals` of every row of the full parameter matrix ``P``: an array
        (rows, terms), each door measured with the others (:func:`stroke_and_peaks`)."""
        P = np.ascontiguousarray(np.atleast_2d(P), dtype=np.float64)
        n = self.stroke.size
        got = stroke_and_peaks(model, coulomb_rows(model, P), self.stroke, self.latch)
        parts = []
        excess = math.sqrt(self.excess_weight)
        for d in DIRECTIONS:
            r = (got[d][:, :n] - self.chosen[d]) / self.threshold[d]
            parts.append(np.sqrt(0.5 * self.weights) * r)
            if excess > 0.0:
                parts.append(excess * np.sign(r) * np.maximum(np.abs(r) - 1.0, 0.0))
        w, wa = math.sqrt(self.peak_weight), math.sqrt(self.angle_weight)
        for d in DIRECTIONS:
            parts.append((w * (got["peaks"][d] - self.peaks[d]) / self.peak_threshold[d])[:, None])
            if wa > 0.0:
                angle = (got["angles"][d] - self.peak_angles[d]) / self.angle_threshold
                parts.append((wa * angle)[:, None])
        if self.dynamics is not None:
            felt = felt_dynamics_rows(model, P, self.dyn_grid, self.jnd.speed)
            ti, tc = self.dynamics
            parts.append(
                np.c_[
                    (felt[:, 0] - ti) / self.jnd.inertia_threshold(ti),
                    (felt[:, 1] - tc) / self.jnd.damping_threshold(tc),
                ]
            )
        r = np.concatenate(parts, axis=1)
        return np.where(np.isfinite(r), r, 1e6)

    def mechanism_curve(self, model, p) -> FeelCurve:
        """The Coulomb force-angle curve of ``model`` at ``p`` where the objective
        samples it (the stroke's grid and the latch zone's, which hold every angle of
        the chosen curve): what :func:`~evo_door.perception.perceptual_check` needs,
        a few milliseconds instead of a full ``model_curve``'s refinement."""
        from evo_door.sim.simulate import COULOMB_SPEED, coulomb_vector, hold_forces

        pc = coulomb_vector(model, np.asarray(p, dtype=np.float64))
        theta = np.union1d(self.stroke, self.latch)
        forces = {
            d: hold_forces(model, pc, theta, s * COULOMB_SPEED)
            for d, s in zip(DIRECTIONS, (-1.0, 1.0))
        }
        return FeelCurve(
            theta,
            np.where(np.isfinite(forces["opening"]), forces["opening"], 1e6),
            np.where(np.isfinite(forces["closing"]), forces["closing"], 1e6),
            source=f"{model.name} model",
            origin={"kind": "model", "model": model.name},
        )

    def dynamics_check(self, model, p) -> dict | None:
        """The felt inertia and damping of ``model`` at ``p`` against the chosen feel's,
        as :func:`~evo_door.perception.check_verdict` takes them (None for a bare curve)."""
        if self.dynamics is None:
            return None
        inertia, damping = self.felt_dynamics(model, np.asarray(p, dtype=np.float64))
        ti, tc = self.dynamics
        return {
            "inertia": (inertia, ti, self.jnd.inertia_threshold(ti)),
            "damping": (damping, tc, self.jnd.damping_threshold(tc)),
        }

    def verdict(self, model, p, jnd: JND | None = None) -> dict:
        """The perceptual check of ``model`` at ``p`` against the chosen feel, judged
        (:func:`~evo_door.perception.check_verdict`), under ``jnd`` (default its own)."""
        from evo_door.perception.feel import check_verdict, perceptual_check

        jnd = jnd or self.jnd
        curve = self.mechanism_curve(model, p)
        dynamics = self.dynamics_check(model, p)
        if dynamics is not None and self.dynamics is not None and jnd is not self.jnd:
            ti, tc = self.dynamics
            dynamics["inertia"] = (*dynamics["inertia"][:2], jnd.inertia_threshold(ti))
            dynamics["damping"] = (*dynamics["damping"][:2], jnd.damping_threshold(tc))
        return check_verdict(perceptual_check(curve, self.curve, jnd), jnd, dynamics)

    def value(self, model, p) -> float:
        """The perceptual objective of one parameter vector (JND units, squared)."""
        r = self.residuals(model, p)
        return float(np.dot(r, r))

    def evaluate(self, model, P) -> np.ndarray:
        """:meth:`value` of every row of the full parameter matrix ``P``, :data:`ROWS`
        rows measured at once."""
        P = np.atleast_2d(np.asarray(P, dtype=np.float64))
        out = np.empty(len(P))
        for start in range(0, len(P), ROWS):
            for k, r in enumerate(self.residual_rows(model, P[start : start + ROWS])):
                out[start + k] = float(np.dot(r, r))
        return out

    def describe(self) -> dict:
        """What a results file keeps of it (the chosen curve, the settings)."""
        out = {
            "source": self.curve.source,
            "origin": dict(self.curve.origin),
            "jnd": self.jnd.as_dict(),
            "latch_zone_rad": self.latch_zone,
            "peak_weight": self.peak_weight,
            "excess_weight": self.excess_weight,
            "angle_weight": self.angle_weight,
            "peaks_N": dict(self.peaks),
            "peak_angles_rad": dict(self.peak_angles),
        }
        if self.dynamics is not None:
            out["inertia_kg_m"], out["damping_N_s_per_rad"] = self.dynamics
        return out
