"""The supplier's process: how far each built specification strays from its drawing.

A specification stage hands a supplier a table of values; the supplier builds each
within a tolerance. :class:`Process` holds, for the table's rows, the tolerance of
each (a fraction of the nominal value, ``10 %``, or a half-width in the parameter's
unit), how it scatters (``normal`` with 3 sigma = the tolerance, or ``uniform`` on
[-t, +t]) and where the number comes from; :func:`process_for` builds it from an
experiment's ``process:`` table (the resolved configuration's ``process`` section) and
the defaults of each parameter's kind (:data:`DEFAULTS`, from
``evo_door/params/process_defaults.yaml``). The yield of a specification is estimated
with doors drawn by :meth:`Process.sample`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from evo_door.errors import UserError
from evo_door.params.declaration import suggest
from evo_door.params.process import DEFAULTS, DISTRIBUTIONS, KINDS, KindDefault, parse_tolerance

__all__ = [
    "DEFAULTS",
    "DISTRIBUTIONS",
    "KINDS",
    "NOT_BUILT",
    "Process",
    "default_entry",
    "format_tolerance",
    "process_entries",
    "process_for",
]

#: the source of a row that no supplier builds (tolerance 0)
NOT_BUILT = "not a built quantity"


def format_tolerance(tolerance, unit: str = "") -> str:
    """A tolerance for people: ``"+-10 %"``, ``"+-0.0002 rad"``.

    >>> format_tolerance("10 %"), format_tolerance(0.0002, "rad"), format_tolerance(0.1, "1")
    ('+-10 %', '+-0.0002 rad', '+-0.1')
    """
    relative, value = parse_tolerance(tolerance)
    if relative:
        return f"+-{100.0 * value:g} %"
    return f"+-{value:g}" + (f" {unit}" if unit and unit != "1" else "")


def default_entry(kind: KindDefault | str) -> dict:
    """The table entry of a kind's default: ``{"tolerance", "distribution", "source"}``."""
    if isinstance(kind, str):
        kind = DEFAULTS[kind]
    return {
        "tolerance": kind.tolerance,
        "distribution": kind.distribution,
        "source": f"default: {kind.meaning} ({kind.source})",
    }


def _params(model):
    """The declaration (:class:`~evo_door.params.ParamTable`) of a model or a table."""
    return getattr(model, "params", model)


def process_entries(model, given: Mapping | None = None) -> dict[str, dict]:
    """Every built parameter of ``model`` (declaration order) -> its table entry:
    ``given``'s where it has one, else its kind's default (:func:`default_entry`)."""
    given = given or {}
    return {
        p.name: dict(given[p.name]) if p.name in given else default_entry(p.process)
        for p in _params(model)
        if p.process
    }


@dataclass
class Process:
    """The supplier's process of the rows of a specification table.

    Attributes
    ----------
    names : list of str
        The specifications, in the order given; every array is in this order.
    relative : numpy.ndarray of bool
        True where the tolerance is a fraction of the nominal value.
    tolerance : numpy.ndarray
        The fraction (0.1 = 10 %) or the absolute half-width (the parameter's unit).
    distribution : list of str
        ``normal`` (3 sigma = the half-width) or ``uniform`` (on [-t, +t]).
    source : list of str
        Where each comes from, for people.
    units : list of str
        Each parameter's unit (empty: not known).
    """

    names: list[str]
    relative: np.ndarray
    tolerance: np.ndarray
    distribution: list[str]
    source: list[str]
    units: list[str] = field(default_factory=list)

    def _nominal(self, nominal) -> np.ndarray:
        if isinstance(nominal, Mapping):
            nominal = [nominal[n] for n in self.names]
        nominal = np.asarray(nominal, dtype=np.float64)
        if nominal.shape != (len(self.names),):
            raise ValueError(f"expected {len(self.names)} nominal values, got {nominal.shape}")
        return nominal

    def half_widths(self, nominal) -> np.ndarray:
        """The absolute half-width ``t`` of each name at these nominal values (an array
        in :attr:`names` order, or a mapping name -> value), in the parameter's unit."""
        nominal = self._nominal(nominal)
        return np.where(self.relative, self.tolerance * np.abs(nominal), self.tolerance)

    def sample(self, nominal, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` x ``len(names)`` deviations from the nominal values (absolute, to add).

        Columns are drawn in :attr:`names` order, one call of ``rng`` each: a normal
        column as ``rng.standard_normal(n)`` times ``t / 3``, a uniform one as
        ``rng.uniform(-1.0, 1.0, n)`` times ``t``. Every column is drawn, a zero
        tolerance too, so a given generator state gives the same standard draws
        whatever the tolerances (common random numbers: two processes compared on
        one seed differ only by their tolerances).
        """
        t = self.half_widths(nominal)
        out = np.empty((int(n), len(self.names)))
        for j, kind in enumerate(self.distribution):
            if kind == "uniform":
                out[:, j] = rng.uniform(-1.0, 1.0, int(n)) * t[j]
            else:
                out[:, j] = rng.standard_normal(int(n)) * (t[j] / 3.0)
        return out

    def tolerance_text(self, j: int) -> str | float:
        """Row ``j``'s tolerance as written: ``"10 %"`` or the half-width."""
        if self.relative[j]:
            return f"{100.0 * float(self.tolerance[j]):g} %"
        return float(self.tolerance[j])

    def as_dict(self, nominal) -> dict[str, dict]:
        """name -> ``{"half_width", "tolerance", "distribution", "source"}`` (JSON-able);
        ``half_width`` in the parameter's unit at these nominal values."""
        t = self.half_widths(nominal)
        return {
            name: {
                "half_width": float(t[j]),
                "tolerance": self.tolerance_text(j),
                "distribution": self.distribution[j],
                "source": self.source[j],
            }
            for j, name in enumerate(self.names)
        }


def _entry(name: str, entry) -> tuple[bool, float, str, str]:
    """``(relative, value, distribution, source)`` of one table entry (a mapping with
    ``tolerance`` and optional ``distribution`` and ``source``, or a bare tolerance)."""
    if not isinstance(entry, Mapping):
        entry = {"tolerance": entry}
    try:
        relative, value = parse_tolerance(entry.get("tolerance"))
    except ValueError as exc:
        raise UserError(f"process: {name}: {exc}") from None
    distribution = entry.get("distribution", "normal")
    if distribution not in DISTRIBUTIONS:
        raise UserError(
            f"process: {name}: distribution {distribution!r} is not one of "
            f"{', '.join(DISTRIBUTIONS)}"
        )
    return relative, value, distribution, str(entry.get("source") or "given")


def process_for(model, names, table: Mapping | None = None) -> Process:
    """The process of every name in ``names`` (the specification table's rows).

    Parameters
    ----------
    model :
        A model (its ``params``) or its :class:`~evo_door.params.ParamTable`.
    names : iterable of str
        The rows, in order.
    table : mapping, optional
        The resolved configuration's ``process`` section (``{"entries": {name:
        entry}}``) or its entries alone; an entry is ``{"tolerance": "5 %" or a
        number, "distribution": ..., "source": ...}`` or a bare tolerance.

    A name the table has takes its entry; another takes its kind's default; one without
    a kind (not built: a sensation, a setting) gets tolerance 0 and the source
    :data:`NOT_BUILT`. A table entry for a name without a kind, or not declared, is a
    :class:`~evo_door.errors.UserError`.
    """
    params = _params(model)
    table = dict(table or {})
    entries = table.get("entries", table) if isinstance(table.get("entries"), Mapping) else table
    for name in entries:
        if name not in params:
            raise UserError(
                f"process: model {params.model!r} has no parameter {name!r}"
                + suggest(str(name), params.names)
            )
        if not params[name].process:
            raise UserError(f"process: {name}: {NOT_BUILT}; it has no tolerance")
    names = list(names)
    rel, tol, dist, src, units = [], [], [], [], []
    for name in names:
        p = params[name]
        if name in entries:
            r, v, d, s = _entry(name, entries[name])
        elif p.process:
            kind = DEFAULTS[p.process]
            r, v, d, s = kind.relative, kind.value, kind.distribution, default_entry(kind)["source"]
        else:
            r, v, d, s = False, 0.0, "normal", NOT_BUILT
        rel.append(r)
        tol.append(v)
        dist.append(d)
        src.append(s)
        units.append(p.unit)
    return Process(
        names, np.array(rel, dtype=bool), np.array(tol, dtype=np.float64), dist, src, units
    )
