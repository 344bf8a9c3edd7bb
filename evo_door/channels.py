"""The signals of a trial and of a simulation: names, SI units, what they measure.

The one table of channel units: trial files, simulation outputs, objectives, plots and
reports all take a channel's unit from here.

>>> unit("dtheta"), RESPONSE_CHANNELS[2], label("theta")
('rad/s', 'ddtheta', 'angle theta [rad]')
"""

from __future__ import annotations

#: channel -> (SI unit, physical dimension), in the order of a simulation's output.
CHANNELS = {
    "t": ("s", "time"),
    "force": ("N", "force"),
    "theta": ("rad", "angle"),
    "dtheta": ("rad/s", "angular speed"),
    "ddtheta": ("rad/s^2", "angular acceleration"),
}

#: Response channels, in derivative order (0 angle, 1 speed, 2 acceleration).
RESPONSE_CHANNELS = ("theta", "dtheta", "ddtheta")

#: channel -> SI unit.
UNITS = {name: unit for name, (unit, _) in CHANNELS.items()}


def unit(channel: str, theta_unit: str = "rad") -> str:
    """The SI unit of ``channel``; the response channels of a model whose coordinate is
    not an angle (a drawer's stroke, ``theta_unit="m"``) take that unit.

    >>> unit("ddtheta"), unit("dtheta", theta_unit="m"), unit("force", theta_unit="m")
    ('rad/s^2', 'm/s', 'N')
    """
    if channel in RESPONSE_CHANNELS and theta_unit != "rad":
        return theta_unit + ("", "/s", "/s^2")[RESPONSE_CHANNELS.index(channel)]
    return CHANNELS[channel][0]


def title(channel: str) -> str:
    """What the channel measures, and its name: ``angular speed dtheta``."""
    return f"{CHANNELS[channel][1]} {channel}"


def label(channel: str) -> str:
    """An axis label: what the channel measures, its name and unit."""
    return f"{title(channel)} [{unit(channel)}]"
