"""Units of the trial channels and the ``CHANNEL=SOURCE[:UNIT]`` mapping syntax.

Files on disk may use any common unit; a :class:`Trial` always holds SI. A unit
expression is ``[FACTOR*]UNIT[+OFFSET]``, read as ``SI(FACTOR * raw + OFFSET)`` in
``UNIT``; so

- ``kN``: kilonewton to newton;
- ``-1*N``: a load cell mounted the other way round (+ must push toward closing);
- ``44.5*N``: a raw voltage with a sensitivity of 44.5 N/V;
- ``-1*deg+90``: an inclinometer reading degrees *from closed*, positive opening,
  into the door angle ``theta`` (0 open, 90 deg closed).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from evo_door.channels import CHANNELS
from evo_door.errors import UserError
from evo_door.params.declaration import suggest

#: unit -> (dimension, factor to SI).
UNITS: dict[str, tuple[str, float]] = {
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
    "us": ("time", 1e-6),
    "min": ("time", 60.0),
    "N": ("force", 1.0),
    "kN": ("force", 1e3),
    "mN": ("force", 1e-3),
    "lbf": ("force", 4.4482216152605),
    "kgf": ("force", 9.80665),
    "rad": ("angle", 1.0),
    "mrad": ("angle", 1e-3),
    "deg": ("angle", math.pi / 180.0),
    "rad/s": ("angular speed", 1.0),
    "deg/s": ("angular speed", math.pi / 180.0),
    "rpm": ("angular speed", 2.0 * math.pi / 60.0),
    "mrad/s": ("angular speed", 1e-3),
    "rad/s^2": ("angular acceleration", 1.0),
    "deg/s^2": ("angular acceleration", math.pi / 180.0),
}

#: Spellings met in headers and TDMS ``unit_string`` properties.
ALIASES = {
    "sec": "s",
    "second": "s",
    "seconds": "s",
    "msec": "ms",
    "µs": "us",
    "newton": "N",
    "newtons": "N",
    "n": "N",
    "kn": "kN",
    "degree": "deg",
    "degrees": "deg",
    "°": "deg",
    "radian": "rad",
    "radians": "rad",
    "°/s": "deg/s",
    "deg/sec": "deg/s",
    "dps": "deg/s",
    "rad/sec": "rad/s",
    "rad/s2": "rad/s^2",
    "rad/s²": "rad/s^2",
    "deg/s2": "deg/s^2",
    "deg/s²": "deg/s^2",
}

_EXPR = re.compile(
    r"^\s*(?:(?P<factor>[-+]?[0-9.]+(?:[eE][-+]?[0-9]+)?)\s*\*\s*)?"
    r"(?P<unit>[^\s+*]+?)\s*"
    r"(?:(?P<offset>[-+]\s*[0-9.]+(?:[eE][-+]?[0-9]+)?))?\s*$"
)


#: The most characters of a file's content (a header, a cell, a column name) an error
#: message quotes: a CSV whose first line is 3 kB of JSON must not flood the terminal.
QUOTE_WIDTH = 80


def quote(text, width: int = QUOTE_WIDTH) -> str:
    """``repr(text)`` cut to about ``width`` characters, for one-line messages.

    >>> quote("force [N]"), quote("x" * 200, 10)
    ("'force [N]'", "'xxxxxxx...' (200 characters)")
    """
    text = str(text)
    if len(text) <= width:
        return repr(text)
    return f"{text[: width - 3] + '...'!r} ({len(text)} characters)"


def quote_list(names, width: int = QUOTE_WIDTH) -> str:
    """``a, b, c`` cut to about ``width`` characters; ``none`` if empty.

    >>> quote_list(["t", "force"]), quote_list([f"c{i}" for i in range(100)], 40)
    ('t, force', 'c0, c1, c2, c3, c4, ... (100 in all)')
    """
    names = [str(n) for n in names]
    text = ", ".join(names) or "none"
    if len(text) <= width:
        return text
    more = f", ... ({len(names)} in all)"
    shown = text[: max(width - len(more), 10)]
    # cut at the last whole name that fits
    shown = shown[: shown.rfind(", ")] if ", " in shown else shown + "..."
    return shown + more


def canonical_unit(unit: str) -> str | None:
    """The table spelling of ``unit`` (None if unknown)."""
    unit = unit.strip()
    if unit in UNITS:
        return unit
    return ALIASES.get(unit, ALIASES.get(unit.lower()))


@dataclass(frozen=True)
class UnitExpr:
    """``SI = to_si * (factor * raw + offset)``."""

    unit: str
    factor: float = 1.0
    offset: float = 0.0

    @property
    def to_si(self) -> float:
        return UNITS[self.unit][1]

    def apply(self, raw):
        return self.to_si * (self.factor * raw + self.offset)

    def __str__(self) -> str:
        text = self.unit if self.factor == 1.0 else f"{self.factor:g}*{self.unit}"
        return text + (f"{self.offset:+g}" if self.offset else "")


def parse_unit(text: str, channel: str, where: str = "") -> UnitExpr:
    """Parse a unit expression for ``channel``; raise a one-line :class:`UserError`."""
    prefix = f"{where}: " if where else ""
    m = _EXPR.match(text or "")
    if not m:
        raise UserError(
            f"{prefix}cannot read unit {quote(text)} for channel {channel!r} "
            "(expected [FACTOR*]UNIT[+OFFSET], e.g. kN, -1*N, -1*deg+90)"
        )
    unit = canonical_unit(m["unit"])
    if unit is None:
        raise UserError(
            f"{prefix}unknown unit {quote(m['unit'], 40)} for channel {channel!r}"
            + suggest(m["unit"], UNITS)
            + f"; known: {', '.join(UNITS)}"
        )
    want = CHANNELS[channel][1]
    if UNITS[unit][0] != want:
        raise UserError(
            f"{prefix}unit {unit!r} measures {UNITS[unit][0]}, channel {channel!r} "
            f"needs {want} ({CHANNELS[channel][0]})"
        )
    factor = float(m["factor"]) if m["factor"] else 1.0
    offset = float(m["offset"].replace(" ", "")) if m["offset"] else 0.0
    return UnitExpr(unit, factor, offset)


@dataclass(frozen=True)
class ChannelMap:
    """Trial channel ``channel`` comes from file column / dataset ``source`` in ``unit``.

    ``unit`` None means: the unit the file declares for that column, else SI.
    """

    channel: str
    source: str
    unit: UnitExpr | None = None

    def __str__(self) -> str:
        return f"{self.channel}={self.source}" + (f":{self.unit}" if self.unit else "")


def parse_map(spec: str) -> ChannelMap:
    """``CHANNEL=SOURCE[:UNIT]``, e.g. ``force=Fz:kN`` or ``theta=Incl:-1*deg+90``."""
    channel, eq, rest = spec.partition("=")
    channel = channel.strip()
    if not eq or not rest.strip():
        raise UserError(f"--map {spec!r}: expected CHANNEL=SOURCE[:UNIT], e.g. force=Fz:kN")
    if channel not in CHANNELS:
        raise UserError(
            f"--map {spec!r}: unknown channel {channel!r}"
            + suggest(channel, CHANNELS)
            + f"; channels: {', '.join(CHANNELS)}"
        )
    # the unit follows the last colon (source names may contain colons, units never do)
    source, colon, unit = rest.rpartition(":")
    if not colon:
        source, unit = rest, ""
    source = source.strip()
    if not source:
        raise UserError(f"--map {spec!r}: empty source name")
    return ChannelMap(
        channel, source, parse_unit(unit, channel, f"--map {spec!r}") if unit.strip() else None
    )


def parse_maps(specs) -> dict[str, ChannelMap]:
    """A list of ``--map`` strings (or ChannelMaps) as ``{channel: ChannelMap}``."""
    out: dict[str, ChannelMap] = {}
    for spec in specs or ():
        cm = spec if isinstance(spec, ChannelMap) else parse_map(spec)
        if cm.channel in out:
            raise UserError(f"--map: channel {cm.channel!r} mapped twice")
        out[cm.channel] = cm
    return out


_HEADER_UNIT = re.compile(r"^\s*(?P<name>.*?)\s*(?:\[(?P<u1>[^\]]*)\]|\((?P<u2>[^)]*)\))\s*$")


def split_header(name: str) -> tuple[str, str | None]:
    """``"force [kN]"`` or ``"force (kN)"`` -> ``("force", "kN")``; else ``(name, None)``."""
    m = _HEADER_UNIT.match(name)
    if m and m["name"]:
        return m["name"], (m["u1"] if m["u1"] is not None else m["u2"]).strip()
    return name.strip(), None
