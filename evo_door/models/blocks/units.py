"""Numbers with a unit in a mechanism file: ``k: "200 N/m"``, ``pitch: "30 deg"``.

A number may be written as text, the number then its unit. The unit is a product of
symbols, each with an optional integer power (``kg m^2``), and at most one ``/`` before
the symbols that divide (``N m s/rad``). It fits the parameter's declared unit when
both have the same powers of the same base symbols; its scale then converts the
number. The symbols: ``m``, ``cm``, ``mm`` (lengths); ``kg``, ``g``; ``s``, ``ms``;
``N``; ``rad``, ``deg``, ``turn`` (angles: an angle is a unit of its own, so
``N m`` does not fit ``N m/rad``). Anything else is one line naming the element and
both units.
"""

from __future__ import annotations

import math
import re

from evo_door.errors import UserError

#: symbol -> (base symbol, scale to the base)
SYMBOLS: dict[str, tuple[str, float]] = {
    "m": ("m", 1.0),
    "cm": ("m", 1e-2),
    "mm": ("m", 1e-3),
    "kg": ("kg", 1.0),
    "g": ("kg", 1e-3),
    "s": ("s", 1.0),
    "ms": ("s", 1e-3),
    "N": ("N", 1.0),
    "rad": ("rad", 1.0),
    "deg": ("rad", math.pi / 180.0),
    "turn": ("rad", 2.0 * math.pi),
}
_QUANTITY = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*")
_FACTOR = re.compile(r"([A-Za-z]+)(?:\^(-?\d))?")


def parse_unit(text: str) -> tuple[dict[str, int], float] | None:
    """``(powers of the base symbols, scale)`` of a unit, or None if it is not one."""
    if text.count("/") > 1:
        return None
    powers: dict[str, int] = {}
    scale = 1.0
    for sign, part in zip((1, -1), text.split("/"), strict=False):
        factors = part.split()
        if sign < 0 and not factors:
            return None
        for factor in factors:
            m = _FACTOR.fullmatch(factor)
            if m is None or m.group(1) not in SYMBOLS:
                return None
            base, k = SYMBOLS[m.group(1)]
            n = sign * int(m.group(2) or 1)
            powers[base] = powers.get(base, 0) + n
            scale *= k**n
    return {b: n for b, n in powers.items() if n}, scale


def quantity(value: str, declared: str, where: str) -> float:
    """The number of the text ``value`` (``"NUMBER UNIT"``) in the ``declared`` unit."""
    m = _QUANTITY.fullmatch(value)
    if m is None:
        raise UserError(f"{where} must be a number or 'NUMBER UNIT', got {value!r}"[:300])
    number, unit = float(m.group(1)), " ".join(m.group(2).split())
    given, want = parse_unit(unit), parse_unit(declared)
    if unit == declared:
        return number
    if given is None:
        raise UserError(f"{where}: unknown unit {unit!r}; units: {', '.join(SYMBOLS)}"[:300])
    if want is None or given[0] != want[0]:
        raise UserError(f"{where}: the unit {unit or '(none)'} does not fit {declared or '(none)'}")
    return number * given[1] / want[1]
