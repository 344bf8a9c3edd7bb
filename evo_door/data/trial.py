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

from dataclasses import dataclass, field

import numpy as np

from evo_door.channels import RESPONSE_CHANNELS, UNITS
from evo_door.errors import UserError

__all__ = ["RESPONSE_CHANNELS", "UNITS", "Trial"]


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
        self.validate()

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
        step = np.diff(self.t)
        if np.any(step <= 0):
            raise UserError(
                f"{where}: channel 't' is not increasing at row "
                f"{int(np.flatnonzero(step <= 0)[0]) + 1}"
            )
        if np.ptp(step) > 1e-6 * step.mean() + 1e-12:
            row = int(np.argmax(np.abs(step - step[0]))) + 1
            raise UserError(
                f"{where}: channel 't' is not uniformly sampled (row {row}: "
                f"step {step[row - 1]:.6g} s, first step {step[0]:.6g} s)"
            )
