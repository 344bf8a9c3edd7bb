"""The in-memory form of one trial (measured, rig-generated or simulated).

A trial is a uniformly sampled record of the user's force at the handle and the
door's response. SI units and the project's sign conventions throughout:

========  =======  ===========================================================
field     unit     meaning
========  =======  ===========================================================
t         s        sample instants, uniform, increasing
force     N        user force at the handle, tangential, + toward closing
theta     rad      door angle, 0 fully open, pi/2 closed (optional)
dtheta    rad/s    angular speed, opening is negative (optional)
ddtheta   rad/s^2  angular acceleration (optional)
========  =======  ===========================================================

At least one of ``theta`` / ``dtheta`` must be present for a trial to be a fitting
target; ``force`` alone is enough to drive a simulation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from evo_door.channels import RESPONSE_CHANNELS, UNITS
from evo_door.errors import UserError

__all__ = [
    "RESPONSE_CHANNELS",
    "STEP_TOLERANCE",
    "UNITS",
    "Trial",
    "check_theta0",
    "time_axis_problem",
]

#: How far, as a fraction of the sampling step, time stamps may stray from a uniform
#: grid and still count as uniformly sampled: each step within this fraction of the
#: median step, each stamp within this fraction of a step of the grid
#: ``t0 + k * mean step``. Time stamps printed with 6 decimals are off by at most
#: 0.5e-6 s, so their steps by 1e-6 s: 0.1 % of a 1024 Hz step (0.8 % at 8192 Hz). A
#: dropped sample (100 %), a rate change or a drifting clock is far beyond it. Within
#: it the stamps are replaced by the grid, so that every step, and the ``dt`` of the
#: integrators, is exact; ``meta["time_axis"]`` says so.
STEP_TOLERANCE = 0.01


def time_axis_problem(t: np.ndarray) -> tuple[int, str, str] | None:
    """The first reason the 1-D array ``t`` is not a uniform time axis, or None.

    Returns ``(row, problem, detail)``: the data row at fault (0-based), what is wrong
    (``"is not increasing"``, ``"is not uniformly sampled"``, ``"drifts from a uniform
    time grid"``) and the numbers that show it, for a message
    ``f"channel 't' {problem} at row {row}: {detail}"``. Steps within
    :data:`STEP_TOLERANCE` pass (see there).

    >>> time_axis_problem(np.round(np.arange(8) / 1024, 6)) is None
    True
    >>> time_axis_problem(np.array([0.0, 0.001, 0.002, 0.004, 0.005]))[:2]
    (3, 'is not uniformly sampled')
    """
    step = np.diff(t)
    if np.any(step <= 0):
        row = int(np.flatnonzero(step <= 0)[0]) + 1
        return row, "is not increasing", f"{float(t[row - 1])!r} then {float(t[row])!r} s"
    median = float(np.median(step))
    off = np.abs(step - median) > STEP_TOLERANCE * median
    if off.any():
        row = int(np.flatnonzero(off)[0]) + 1
        return (
            row,
            "is not uniformly sampled",
            f"step {step[row - 1]:.6g} s, typical {median:.6g} s",
        )
    shift = t - uniform_grid(t)
    dt = (t[-1] - t[0]) / (t.size - 1)
    if np.max(np.abs(shift)) > STEP_TOLERANCE * dt:
        row = int(np.argmax(np.abs(shift)))
        return (
            row,
            "drifts from a uniform time grid",
            f"{float(t[row])!r} s, {abs(shift[row]) / dt:.2g} step(s) from the grid "
            f"t0 + k * {dt:.6g} s",
        )
    return None


#: An initial angle may pass an end of the coordinate range by this fraction of the
#: range: a door closed at pi/2 is often typed 1.5708.
THETA0_MARGIN = 1e-3


def check_theta0(
    value, theta_range=(0.0, 0.5 * math.pi), unit: str = "rad", name: str = "--theta0"
) -> float:
    """``value`` as a float if it lies in ``theta_range`` (open, closed), else a UserError.

    The message names ``name`` (an option, or a file and field) and the range; a value
    in degrees where radians are expected is pointed out.

    >>> check_theta0(1.5708)
    1.5708
    >>> check_theta0(90.0)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    evo_door.errors.UserError: --theta0 90: outside ... 0..1.5708 rad ...; in degrees? 90 deg is 1.5708 rad
    """
    lo, hi = (float(v) for v in theta_range)
    value = float(value)
    margin = THETA0_MARGIN * (hi - lo)
    if lo - margin <= value <= hi + margin:
        return value
    hint = ""
    if unit == "rad" and lo - margin <= math.radians(value) <= hi + margin:
        hint = f"; in degrees? {value:g} deg is {math.radians(value):.6g} rad"
    raise UserError(
        f"{name} {value:g}: outside the coordinate range {lo:.6g}..{hi:.6g} {unit} "
        f"({lo:.6g} fully open, {hi:.6g} closed){hint}"
    )


def uniform_grid(t: np.ndarray) -> np.ndarray:
    """``t[0] + k * mean step``: the uniform grid through the first and last stamps."""
    n = t.size
    return t[0] + (t[-1] - t[0]) / (n - 1) * np.arange(n)


@dataclass
class Trial:
    """One trial; see the module docstring for fields and units.

    Attributes beyond the signals
    -----------------------------
    trial_id, user_id : str
        Identifiers (the seed had ten trials from three users).
    kind : str
        What the user did: ``unlock``, ``lock``, ``impulse``, ``free`` or ``""``.
    theta0, dtheta0 : float or None
        Initial state for simulation; default the first sample of theta / dtheta.
    sensors : dict
        Sensor metadata (range, resolution, noise, model), free-form, JSON-able.
    truth : dict or None
        For generated trials: ``{"model": name, "params": {name: value}}``, so that
        parameter recovery can be scored.
    source : str
        Where the trial came from (file path and group), for messages.
    meta : dict
        Free-form, JSON-able provenance: rig settings and the virtual user's traits,
        the import mapping, the original file...
    """

    t: np.ndarray
    force: np.ndarray
    theta: np.ndarray | None = None
    dtheta: np.ndarray | None = None
    ddtheta: np.ndarray | None = None
    trial_id: str = ""
    user_id: str = ""
    kind: str = ""
    theta0: float | None = None
    dtheta0: float | None = None
    sensors: dict = field(default_factory=dict)
    truth: dict | None = None
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.t = np.ascontiguousarray(self.t, dtype=np.float64)
        self.force = np.ascontiguousarray(self.force, dtype=np.float64)
        for name in RESPONSE_CHANNELS:
            value = getattr(self, name)
            if value is not None:
                setattr(self, name, np.ascontiguousarray(value, dtype=np.float64))
        self._make_time_uniform()
        self.validate()

    def digest(self) -> str:
        """A checksum of the trial's signals (BLAKE2b of their float64 bytes): stored
        beside them in trial, results and log files, and checked when they are read
        back, so that a copy is known to hold the numbers of its source."""
        import hashlib

        h = hashlib.blake2b(digest_size=16)
        for name in ("t", "force", *RESPONSE_CHANNELS):
            value = getattr(self, name)
            if value is not None:
                h.update(name.encode() + b"\0" + value.tobytes())
        return "blake2b:" + h.hexdigest()

    def _make_time_uniform(self) -> None:
        """Rounded time stamps (within :data:`STEP_TOLERANCE`) onto the exact grid, noted."""
        t = self.t
        if t.ndim != 1 or t.size < 3 or not np.all(np.isfinite(t)):
            return  # validate() says what is wrong
        step = np.diff(t)
        # uniform to floating-point precision already: keep the stamps as they are
        if np.all(step > 0) and np.ptp(step) <= 1e-6 * step.mean():
            return
        if time_axis_problem(t) is not None:
            return  # validate() refuses it
        grid = uniform_grid(t)
        self.t = grid
        self.meta = {
            **self.meta,
            "time_axis": {
                "uniform_grid": "t0 + k * step",
                "t0": float(grid[0]),
                "step": float((grid[-1] - grid[0]) / (grid.size - 1)),
                "max_shift": float(np.max(np.abs(t - grid))),
                "unit": "s",
            },
        }

    # -- derived ---------------------------------------------------------------
    @property
    def n(self) -> int:
        return int(self.t.size)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def rate(self) -> float:
        """Sampling rate in Hz."""
        return 1.0 / self.dt

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    @property
    def channels(self) -> tuple[str, ...]:
        """Response channels present."""
        return tuple(c for c in RESPONSE_CHANNELS if getattr(self, c) is not None)

    def initial_state(self, default_theta0: float | None = None) -> tuple[float, float]:
        """(theta0, dtheta0) for simulation, from the fields or the first samples.

        Without ``theta0`` and a ``theta`` channel the angle is ``default_theta0`` (a
        model's rest angle, for a bare force record), else unknown: an error.
        """
        theta0 = (
            self.theta0
            if self.theta0 is not None
            else (float(self.theta[0]) if self.theta is not None else default_theta0)
        )
        if theta0 is None:
            raise UserError(
                f"{self.label}: no theta channel and no theta0: the initial angle is unknown"
            )
        dtheta0 = (
            self.dtheta0
            if self.dtheta0 is not None
            else (float(self.dtheta[0]) if self.dtheta is not None else 0.0)
        )
        return float(theta0), float(dtheta0)

    def channel(self, derivative: int) -> np.ndarray | None:
        """The response of derivative order 0, 1 or 2 (None if absent)."""
        return getattr(self, RESPONSE_CHANNELS[derivative])

    def require(self, derivative: int) -> np.ndarray:
        """The response of derivative order 0, 1 or 2, or a one-line error naming the trial."""
        values = self.channel(derivative)
        if values is None:
            raise UserError(
                f"trial {self.trial_id!r} has no {RESPONSE_CHANNELS[derivative]!r} "
                f"channel (it has {', '.join(self.channels) or 'none'})"
            )
        return values

    @property
    def label(self) -> str:
        return self.source or self.trial_id or "trial"

    def sensor(self, name: str) -> dict:
        """Metadata of the sensor behind channel ``name`` (empty dict if unknown)."""
        info = self.sensors.get(name)
        return info if isinstance(info, dict) else {}

    def unsaturated(self, name: str) -> np.ndarray:
        """Boolean mask of the samples of channel ``name`` strictly inside its sensor range.

        A saturated sample (the sensor pinned at an end of ``sensors[name]["range"]``)
        says only that the true value is beyond the range: objectives should skip it.
        All True when the channel has no declared range.
        """
        values = getattr(self, name)
        if values is None:
            raise UserError(f"{self.label}: no channel {name!r}")
        rng = self.sensor(name).get("range")
        if not rng:
            return np.ones(values.shape, dtype=bool)
        lo, hi = float(rng[0]), float(rng[1])
        tol = 1e-9 * max(1.0, abs(lo), abs(hi))
        return (values > lo + tol) & (values < hi - tol)

    def replace(self, **changes) -> Trial:
        """A validated copy with some fields changed (dicts are copied, arrays shared)."""
        import copy
        import dataclasses

        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for key in ("sensors", "truth", "meta"):
            fields[key] = copy.deepcopy(fields[key])
        fields.update(changes)
        return Trial(**fields)

    # -- checks ----------------------------------------------------------------
    def validate(self) -> None:
        """Raise :class:`UserError` naming the trial, channel and row of the first problem."""
        where = self.label
        if self.t.ndim != 1 or self.t.size < 2:
            raise UserError(f"{where}: channel 't' needs at least two samples")
        for name in ("t", "force", *RESPONSE_CHANNELS):
            value = getattr(self, name)
            if value is None:
                continue
            if value.shape != self.t.shape:
                raise UserError(
                    f"{where}: channel {name!r} has {value.size} samples, 't' has {self.t.size}"
                )
            bad = ~np.isfinite(value)
            if bad.any():
                raise UserError(
                    f"{where}: channel {name!r} is not finite at row {int(np.flatnonzero(bad)[0])}"
                )
        problem = time_axis_problem(self.t)
        if problem is not None:
            row, what, detail = problem
            raise UserError(f"{where}: channel 't' {what} at row {row}: {detail}")
        _check_fields(self, where)


def _check_fields(trial: Trial, where: str) -> None:
    """The trial's fields beyond its signals have the types the code reads them as (a
    trial read from a file is data): texts, finite initial states, the sensors' metadata
    and the truth as mappings, a sensor's range two rising numbers; else one line."""
    from evo_door.files.fields import as_mapping, as_number, as_text

    for key in ("trial_id", "user_id", "kind", "source"):
        as_text(getattr(trial, key), f"{where}: {key}")
    for key in ("theta0", "dtheta0"):
        if getattr(trial, key) is not None:
            as_number(getattr(trial, key), f"{where}: {key}", finite=True)
    as_mapping(trial.meta, f"{where}: meta")
    for channel, info in as_mapping(trial.sensors, f"{where}: sensors").items():
        if not isinstance(info, dict):
            continue  # not a sensor's record: Trial.sensor reads it as none
        span = info.get("range")
        if span is None:
            continue
        what = f"{where}: sensors.{channel}.range"
        if not isinstance(span, (list, tuple)) or len(span) != 2:
            raise UserError(f"{what}: expected [low, high], got {str(span)[:40]}")
        lo, hi = (as_number(v, what, finite=True) for v in span)
        if not lo < hi:
            raise UserError(f"{what}: expected low < high, got [{lo:g}, {hi:g}]")
    if trial.truth is not None:
        truth = as_mapping(trial.truth, f"{where}: truth")
        _check_truth(truth, f"{where}: truth")
        if "params" in truth:
            as_mapping(truth["params"], f"{where}: truth.params", as_number)
        for key in ("model", "params_source"):
            if key in truth:
                as_text(truth[key], f"{where}: truth.{key}")


def _check_truth(tree: dict, where: str, depth: int = 0) -> None:
    """The truth can be written as it is (as groups of attributes): every key names a
    group or an attribute (not empty, no '/'), every text is one a file holds, every
    whole number fits 64 bits; at most 8 levels deep."""
    from evo_door.errors import plain_text

    if depth > 8:
        raise UserError(f"{where}: nested more than 8 levels deep")
    for key, value in tree.items():
        if not key or "/" in key or key in (".", ".."):
            raise UserError(f"{where}: {key!r} cannot name a stored value")
        plain_text(key, where)
        at = f"{where}.{key}"
        if isinstance(value, dict):
            _check_truth(value, at, depth + 1)
        for v in value if isinstance(value, list) else [value]:
            if isinstance(v, str):
                plain_text(v, at)
            elif isinstance(v, int) and not -(2**63) <= v < 2**63:
                raise UserError(f"{at}: a whole number beyond 64 bits")
