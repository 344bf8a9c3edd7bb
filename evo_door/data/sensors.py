"""Sensor models of the virtual rig: range (saturation), noise, bias and quantisation.

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
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

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

    def info(self) -> dict:
        """Metadata stored with a trial (``Trial.sensors[channel]``), SI."""
        d = asdict(self)
        d["range"] = [d.pop("lo"), d.pop("hi")]
        return d


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
