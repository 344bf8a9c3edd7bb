"""The supplier's process by default, per kind of built quantity: data, read once.

Every parameter a supplier builds (a spring's rate, a door's mass, a pad's friction...)
is declared with a *process kind* (:attr:`~evo_door.params.Param.process`); the kind's
default tolerance, distribution and source are in ``process_defaults.yaml`` next to
this module (shipped as package data), and :data:`DEFAULTS` holds them checked. A
tolerance is written ``"10 %"`` (a fraction of the nominal value) or as a number (a
half-width in the kind's ``unit``); :func:`parse_tolerance` reads both, for the file
here and for an experiment's ``process:`` alike.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from pathlib import Path

#: How a built value scatters about its nominal: ``normal`` with 3 sigma = the
#: tolerance, or ``uniform`` on [-tolerance, +tolerance].
DISTRIBUTIONS = ("normal", "uniform")

#: The data file of the defaults (package data).
DEFAULTS_FILE = Path(__file__).with_name("process_defaults.yaml")


@dataclass(frozen=True)
class KindDefault:
    """The default process of one kind of built quantity.

    Attributes
    ----------
    kind : str
        Its name (``spring_rate``).
    meaning : str
        What it is, in a few words (``spring rate``).
    tolerance : str or float
        As written: ``"10 %"`` or a half-width in ``unit``.
    relative : bool
        Whether ``value`` is a fraction of the nominal value.
    value : float
        The fraction (0.1 for 10 %) or the half-width.
    distribution : str
        One of :data:`DISTRIBUTIONS`.
    unit : str
        The unit of an absolute tolerance, which every parameter of the kind is declared
        in ("" for a relative one).
    source : str
        Where the number comes from, one line.
    """

    kind: str
    meaning: str
    tolerance: str | float
    relative: bool
    value: float
    distribution: str
    unit: str
    source: str


def parse_tolerance(value) -> tuple[bool, float]:
    """``(relative, value)`` of a tolerance as written; ValueError with the reason.

    >>> parse_tolerance("10 %")
    (True, 0.1)
    >>> parse_tolerance(0.002)
    (False, 0.002)
    >>> parse_tolerance("120 %")
    Traceback (most recent call last):
    ...
    ValueError: a relative tolerance must be below 100 % (the part would be built at 0 or below), got '120 %'
    """
    if isinstance(value, str):
        text = value.strip()
        for sign in ("+-", "±"):
            text = text.removeprefix(sign).strip()
        if not text.endswith("%"):
            raise ValueError(
                f"expected a percentage ('10 %') or a half-width as a number, got {value!r}"
            )
        try:
            percent = float(text[:-1])
        except ValueError:
            raise ValueError(f"expected a percentage such as '10 %', got {value!r}") from None
        if not math.isfinite(percent):
            raise ValueError(f"a tolerance must be a finite number, got {value!r}")
        if percent < 0.0:
            raise ValueError(f"a tolerance cannot be negative, got {value!r}")
        if percent >= 100.0:
            raise ValueError(
                "a relative tolerance must be below 100 % (the part would be built at 0 or "
                f"below), got {value!r}"
            )
        return True, percent / 100.0
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(
            f"expected a percentage ('10 %') or a half-width as a number, got {value!r}"
        )
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"a tolerance must be a finite number, got {value}")
    if value < 0.0:
        raise ValueError(f"a tolerance cannot be negative, got {value:g}")
    return False, value


def _load(path: Path = DEFAULTS_FILE) -> dict[str, KindDefault]:
    """The defaults of ``path``, checked (a broken file is a bug of the package)."""
    from evo_door.yaml_numbers import load

    doc = load(path.read_text(encoding="utf-8"))
    out = {}
    for kind, entry in doc["kinds"].items():
        keys = {"meaning", "tolerance", "distribution", "source", "unit"}
        if set(entry) - keys or not {"meaning", "tolerance", "source"} <= set(entry):
            raise ValueError(f"{path}: kind {kind!r}: keys {sorted(entry)}, expected {keys}")
        relative, value = parse_tolerance(entry["tolerance"])
        unit = str(entry.get("unit", ""))
        if relative == bool(unit):
            raise ValueError(
                f"{path}: kind {kind!r}: an absolute tolerance, and only one, has a unit"
            )
        distribution = entry.get("distribution", "normal")
        if distribution not in DISTRIBUTIONS:
            raise ValueError(f"{path}: kind {kind!r}: distribution {distribution!r}")
        out[kind] = KindDefault(
            kind,
            str(entry["meaning"]),
            entry["tolerance"],
            relative,
            value,
            distribution,
            unit,
            " ".join(str(entry["source"]).split()),
        )
    return out


#: kind -> its default process (:class:`KindDefault`), from :data:`DEFAULTS_FILE`
DEFAULTS: dict[str, KindDefault] = _load()

#: The kinds of built quantity, in the data file's order.
KINDS: tuple[str, ...] = tuple(DEFAULTS)
