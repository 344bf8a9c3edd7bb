"""Sensor models of the virtual rig: range (saturation), noise, bias, quantisation, dynamics.

The seed's instruments (section 3.4), all sampled at 1024 Hz by an NI cDAQ-9172:

============  =======================  ==========================  ===================
channel       sensor                   range                       assumed here
============  =======================  ==========================  ===================
force         FUTEK LTH300 load cell   445 N                       +-445 N, 16 bit
theta         Columbia SI-701B         +-10 deg about closed       16 bit
              inclinometer
dtheta        BAE Systems gyroscope    +-100 deg/s                 16 bit, bias drift
============  =======================  ==========================  ===================

The noise levels, the 16-bit quantisation over the full range and the gyroscope's
bias are assumptions (the seed gives only ranges); change them per rig run with
:func:`dataclasses.replace`.

The seed's sensors are ideal in time (:meth:`Sensor.respond` passes the signal as it
is). A :class:`FilteredSensor` adds the dynamics of a real one, a low-pass of order 1
or 2 with a declared bandwidth, before noise, quantisation and saturation; the rig's
rich truth (``evo-door rig generate --truth rich``) measures force and angular speed
that way.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from evo_door.errors import UserError

DEG = math.pi / 180.0
CLOSED = math.pi / 2


@dataclass(frozen=True)
class Sensor:
    """One sensor, in SI units of its channel.

    ``measure(x) = clip(origin + resolution * round((x - origin + bias + noise) / resolution), lo, hi)``:
    quantised on a grid through ``origin`` and saturated at the ends of its range,
    so that a saturated sample equals ``lo`` or ``hi`` exactly.
    """

    channel: str
    sensor: str
    model: str
    lo: float
    hi: float
    noise_std: float
    resolution: float
    #: Standard deviation of a constant offset drawn once per trial.
    bias_std: float = 0.0
    origin: float = 0.0

    def measure(self, x, rng: np.random.Generator) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        bias = rng.normal(0.0, self.bias_std) if self.bias_std > 0 else 0.0
        noise = rng.normal(0.0, self.noise_std, x.shape) if self.noise_std > 0 else 0.0
        rel = x - self.origin + bias + noise
        if self.resolution > 0:
            rel = self.resolution * np.round(rel / self.resolution)
        return np.clip(self.origin + rel, self.lo, self.hi)

    def respond(self, x, dt: float) -> np.ndarray:
        """The sensing element's output for the physical signal ``x`` sampled every ``dt``.

        Ideal: the signal itself (:class:`FilteredSensor` has dynamics).
        """
        return x

    def info(self) -> dict:
        """Metadata stored with a trial (``Trial.sensors[channel]``), SI."""
        d = asdict(self)
        d["range"] = [d.pop("lo"), d.pop("hi")]
        return d


@dataclass(frozen=True)
class FilteredSensor(Sensor):
    """A sensor with dynamics: a causal low-pass before noise, quantisation and saturation.

    ``order`` 1: ``H(s) = w / (s + w)``; ``order`` 2: the Butterworth
    ``H(s) = w^2 / (s^2 + sqrt(2) w s + w^2)``; ``w = 2 pi bandwidth``, so that the gain is
    -3 dB at ``bandwidth`` (Hz) either way. ``bandwidth = 0`` is an ideal sensor.

    :meth:`respond` runs ``H`` on the sampled signal exactly for a signal linear between
    samples (first-order hold, as the rig's integrators take the force), from rest at the
    first sample's value: a sensor that has been reading it for a long time.
    """

    bandwidth: float = 0.0  # Hz, -3 dB; 0: no dynamics
    order: int = 2

    def __post_init__(self):
        if self.order not in (1, 2):
            raise UserError(f"{self.sensor}: low-pass order must be 1 or 2, got {self.order!r}")
        if not (math.isfinite(self.bandwidth) and self.bandwidth >= 0.0):
            raise UserError(
                f"{self.sensor}: bandwidth must be a finite number >= 0 Hz, got {self.bandwidth!r}"
            )

    def transfer(self) -> tuple[np.ndarray, np.ndarray]:
        """Numerator and denominator of ``H(s)`` (descending powers of s, s in rad/s)."""
        w = 2.0 * math.pi * self.bandwidth
        if self.order == 1:
            return np.array([w]), np.array([1.0, w])
        return np.array([w * w]), np.array([1.0, math.sqrt(2.0) * w, w * w])

    def respond(self, x, dt: float) -> np.ndarray:
        from scipy.signal import cont2discrete, lfilter, lfilter_zi

        x = np.asarray(x, dtype=np.float64)
        if self.bandwidth == 0.0 or x.size == 0:
            return x
        if not (math.isfinite(dt) and dt > 0.0):
            raise UserError(f"{self.sensor}: sample period must be positive, got {dt!r} s")
        b, a, _ = cont2discrete(self.transfer(), dt, method="foh")
        b = np.ravel(b)
        return lfilter(b, a, x, zi=lfilter_zi(b, a) * x[0])[0]


LOAD_CELL = Sensor(
    "force", "load cell", "FUTEK LTH300", -445.0, 445.0, noise_std=0.15, resolution=890.0 / 2**16
)
GYROSCOPE = Sensor(
    "dtheta",
    "gyroscope",
    "BAE Systems unipolar gyroscope",
    -100.0 * DEG,
    100.0 * DEG,
    noise_std=0.05 * DEG,
    resolution=200.0 * DEG / 2**16,
    bias_std=0.1 * DEG,
)
INCLINOMETER = Sensor(
    "theta",
    "inclinometer",
    "Columbia Research Laboratories SI-701B",
    CLOSED - 10.0 * DEG,
    CLOSED + 10.0 * DEG,
    noise_std=0.01 * DEG,
    resolution=20.0 * DEG / 2**16,
    origin=CLOSED,
)

#: The seed's sensor set, by channel.
SEED_SENSORS = {"force": LOAD_CELL, "theta": INCLINOMETER, "dtheta": GYROSCOPE}
