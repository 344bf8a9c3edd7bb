"""The perceptual check of many doors at once, compiled: what a yield is counted with.

:class:`BatchFeelCheck` gives every door (a row of full kernel vectors) its signed
differences from a chosen feel in units of their JNDs (its *margins*): each point of
both strokes outside the latch zone, both latch peaks, both peaks' angles, and the
felt inertia and damping where the chosen feel has dynamics. A door passes when every
margin is within +-1, as :func:`~evo_door.perception.check_verdict` judges one door
(``tests/test_specification_yield.py`` compares the two door by door). The doors are
measured as a candidate of the perceptual objective is, by
:func:`~evo_door.perception.target.measured_feel` and
:func:`~evo_door.perception.target.felt_dynamics_rows`. The doors' own quantities
(:meth:`BatchFeelCheck.measure`) can be judged against another feel (:meth:`BatchFeelCheck.against`,
:meth:`BatchFeelCheck.reference_of`): the nearest feel a process can hold is searched so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from evo_door.errors import UserError
from evo_door.perception import FeelTarget
from evo_door.perception.feel import DIRECTIONS, LATCH_ZONE
from evo_door.perception.target import coulomb_rows, felt_dynamics_rows, measured_feel

#: every LATCH_THIN-th point of the perceptual objective's latch grid (2e-5 rad): 1.6e-4
#: rad, 0.009 deg, a fiftieth of the position JND's angle at the handle (a latch's peak
#: is a plateau of its hold, some 6e-3 rad long)
LATCH_THIN = 8
#: doors computed at once
BATCH = 250
#: the smoothing of the yield (JND) where an optimiser needs a slope
SMOOTHING = 0.05
#: margins of a door whose curve is not finite (it fails)
BLOWN = 1e6


@dataclass
class Reference:
    """What a feel is judged by on a :class:`BatchFeelCheck`'s grid: its force (N) and force
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


class BatchFeelCheck:
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
        #: the stroke's angles: the first of :attr:`theta` (ascending), a slice of its columns
        self.n_stroke = int(self.stroke.sum())
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
        latch peaks (N) and their angles (rad) per stroke, felt inertia and damping
        (:func:`~evo_door.perception.target.measured_feel`, as a candidate's)."""
        out = measured_feel(self.model, coulomb_rows(self.model, P), self.theta, self.latch)
        if self.feel.dynamics is not None:
            out["dynamics"] = felt_dynamics_rows(self.model, P, self.dyn_theta, self.feel.jnd.speed)
        return out

    def against(self, got: dict, ref: Reference) -> np.ndarray:
        """The margins (JND) of measured doors (:meth:`measure`) against ``ref``: each
        column written in place (a batch is hundreds of doors by some 1500 angles, and
        the check runs for every candidate of a tolerance search)."""
        n = self.n_stroke
        rows = got[DIRECTIONS[0]].shape[0]
        dynamics = ref.dynamics if "dynamics" in got else None
        out = np.empty((rows, 2 * n + 4 + (2 if dynamics is not None else 0)))
        for i, d in enumerate(DIRECTIONS):
            part = out[:, i * n : (i + 1) * n]
            np.subtract(got[d][:, :n], ref.chosen[d][:n], out=part)
            np.divide(part, ref.threshold[d][:n], out=part)
            out[:, 2 * n + i] = (got["peaks"][d] - ref.peaks[d]) / ref.peak_threshold[d]
            out[:, 2 * n + 2 + i] = (got["angles"][d] - ref.peak_angles[d]) / ref.angle_threshold
        if dynamics is not None:
            (ti, ji), (tc, jc) = dynamics
            out[:, 2 * n + 4] = (got["dynamics"][:, 0] - ti) / ji
            out[:, 2 * n + 5] = (got["dynamics"][:, 1] - tc) / jc
        np.copyto(out, BLOWN, where=~np.isfinite(out))
        return out

    def reference_of(self, model, p) -> Reference:
        """The :class:`Reference` of the feel of ``model`` at ``p`` (a haptic set, say),
        on this grid, under the chosen feel's JNDs."""
        jnd = self.feel.jnd
        got = measured_feel(model, coulomb_rows(model, [p]), self.theta, self.latch)
        chosen = {d: got[d][0] for d in DIRECTIONS}
        peaks = {d: float(got["peaks"][d][0]) for d in DIRECTIONS}
        angles = {d: float(got["angles"][d][0]) for d in DIRECTIONS}
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
    return smoothed_share(np.max(np.abs(np.atleast_2d(margins)), axis=1), smoothing)


def smoothed_share(worst, smoothing: float = SMOOTHING) -> float:
    """:func:`soft_yield` of doors whose worst margins (JND) are ``worst``."""
    return float(np.mean(1.0 / (1.0 + np.exp(np.clip((worst - 1.0) / smoothing, -50, 50)))))


def passing(margins) -> np.ndarray:
    """Whether each row of margins passes: every one within +-1 JND (a compiled loop for
    a matrix of doubles, :func:`~evo_door.optim.yield_kernel.rows_within`)."""
    if isinstance(margins, np.ndarray) and margins.ndim == 2 and margins.dtype == np.float64:
        return passing_moved(margins, np.zeros(len(margins)), np.zeros(margins.shape[1]))
    return np.all(np.abs(margins) <= 1.0, axis=-1)


def passing_moved(M, a, b) -> np.ndarray:
    """:func:`passing` of the margins ``M - np.outer(a, b)`` (doors x margins, JND): each
    door's margins moved by ``a[i] b``, without forming them (a compiled loop)."""
    from evo_door.optim.yield_kernel import rows_within  # numba, when the check runs

    return rows_within(*(np.ascontiguousarray(x, dtype=np.float64) for x in (M, a, b)))
