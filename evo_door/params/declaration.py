"""Parameter declarations: every model parameter is declared once, as data.

A :class:`Param` carries the name, SI unit, default, bounds, group and a one-line
meaning. A :class:`ParamTable` is the ordered declaration of one model; the order is
the layout of the flat ``float64`` vector that the compiled kernels receive, so
kernels index parameters through the constants the table generates
(``table.index("inertia")``), never through literal positions written elsewhere.
"""

from __future__ import annotations

import difflib
import math
import numbers
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # numpy is imported where a vector is built, not on import
    import numpy as np

from evo_door.errors import ParameterError
from evo_door.params.process import DEFAULTS as PROCESS_DEFAULTS

#: The groups a parameter can belong to.
GROUPS = ("geometry", "specification", "sensation", "device", "numerics")


@dataclass(frozen=True)
class Param:
    """One declared parameter.

    Attributes
    ----------
    name : str
        Identifier used in YAML, on the command line and in results files.
    unit : str
        SI unit of the value (``"1"`` for dimensionless).
    default : float
        Value used when a parameter set does not give one.
    lower, upper : float
        Admissible range, inclusive; a GA search range must lie inside it.
    group : str
        One of :data:`GROUPS`.
    meaning : str
        One line, in the user's words.
    symbol : str
        The symbol the seed writes it with, where it differs from ``name``
        (``c_at+``, ``A_3``); specification tables show it.
    process : str
        For a quantity a supplier builds, its kind of process (``spring_rate``,
        ``mass``...: :data:`evo_door.params.process.KINDS`), which gives its default
        tolerance; "" for anything not built (geometry the fit does not change,
        sensations, settings).
    """

    name: str
    unit: str
    default: float
    lower: float
    upper: float
    group: str
    meaning: str
    symbol: str = ""
    process: str = ""

    def __post_init__(self):
        if self.group not in GROUPS:
            raise ValueError(f"parameter {self.name!r}: group {self.group!r} not in {GROUPS}")
        if self.process:
            kind = PROCESS_DEFAULTS.get(self.process)
            if kind is None:
                raise ValueError(
                    f"parameter {self.name!r}: process {self.process!r} not in "
                    f"{tuple(PROCESS_DEFAULTS)}" + suggest(self.process, PROCESS_DEFAULTS)
                )
            if kind.unit and kind.unit != self.unit:
                raise ValueError(
                    f"parameter {self.name!r} in {self.unit}: process {self.process!r} gives "
                    f"its default tolerance in {kind.unit}"
                )
        if not (self.lower <= self.default <= self.upper):
            raise ValueError(
                f"parameter {self.name!r}: default {self.default} outside "
                f"[{self.lower}, {self.upper}]"
            )

    def check(self, value, source: str = "") -> float:
        """Return ``value`` as a float or raise :class:`ParameterError` naming it."""
        where = f"{source}: " if source else ""
        if isinstance(value, bool) or not isinstance(value, numbers.Real):  # numpy's too
            raise ParameterError(
                f"{where}parameter {self.name!r} must be a number in {self.unit}, got {value!r}"
            )
        value = float(value)
        if not math.isfinite(value):
            raise ParameterError(f"{where}parameter {self.name!r} is {value}, must be finite")
        if not (self.lower <= value <= self.upper):
            raise ParameterError(
                f"{where}parameter {self.name!r} = {value:g} {self.unit} is outside its "
                f"declared range [{self.lower:g}, {self.upper:g}] {self.unit}"
            )
        return value


def suggest(name: str, candidates: Iterable[str]) -> str:
    """A ``" (did you mean 'x'?)"`` hint, or an empty string (``name`` as a file gave
    it: a number or a date is compared as its text)."""
    close = difflib.get_close_matches(str(name), [str(c) for c in candidates], n=3, cutoff=0.5)
    if not close:
        return ""
    return " (did you mean " + " or ".join(repr(c) for c in close) + "?)"


class ParamTable:
    """The ordered parameter declaration of one model.

    Parameters
    ----------
    model : str
        Model name, e.g. ``"haptic"``.
    params : iterable of Param
        Declarations, in kernel-vector order.
    reads : iterable of str
        Other models whose parameter files and presets this one reads as its own (a
        variant of a model with the same parameters: ``haptic_tanh`` reads
        ``haptic``'s).
    """

    def __init__(self, model: str, params: Iterable[Param], reads: Iterable[str] = ()):
        self.model = model
        #: the models whose parameter files this table reads, its own first
        self.reads: tuple[str, ...] = (model, *reads)
        self.params: tuple[Param, ...] = tuple(params)
        self._index = {p.name: i for i, p in enumerate(self.params)}
        if len(self._index) != len(self.params):
            raise ValueError(f"{model}: duplicate parameter names")

    # -- lookup -----------------------------------------------------------
    def __len__(self) -> int:
        return len(self.params)

    def __iter__(self):
        return iter(self.params)

    def __contains__(self, name: str) -> bool:
        return name in self._index

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    def index(self, name: str) -> int:
        """Position of ``name`` in the kernel vector."""
        try:
            return self._index[name]
        except KeyError:
            raise ParameterError(
                f"model {self.model!r} has no parameter {name!r}" + suggest(name, self._index)
            ) from None

    def __getitem__(self, name: str) -> Param:
        return self.params[self.index(name)]

    @property
    def defaults(self) -> np.ndarray:
        import numpy as np  # here: the declaration alone (evo-door params) needs no numpy

        return np.array([p.default for p in self.params], dtype=np.float64)

    @property
    def lower(self) -> np.ndarray:
        import numpy as np  # here: the declaration alone (evo-door params) needs no numpy

        return np.array([p.lower for p in self.params], dtype=np.float64)

    @property
    def upper(self) -> np.ndarray:
        import numpy as np  # here: the declaration alone (evo-door params) needs no numpy

        return np.array([p.upper for p in self.params], dtype=np.float64)

    # -- building vectors -------------------------------------------------
    def vector(self, values: Mapping[str, float] | None = None, source: str = "") -> np.ndarray:
        """Defaults overridden by ``values``, checked, as the kernel vector."""
        vec = self.defaults
        for name, value in (values or {}).items():
            i = self.index(name) if name in self._index else None
            if i is None:
                where = f"{source}: " if source else ""
                raise ParameterError(
                    f"{where}model {self.model!r} has no parameter {name!r}"
                    + suggest(name, self._index)
                )
            vec[i] = self.params[i].check(value, source)
        return vec

    def as_dict(self, vector: np.ndarray) -> dict[str, float]:
        """Name -> value for a kernel vector."""
        import numpy as np

        vector = np.asarray(vector, dtype=np.float64)
        if vector.shape != (len(self),):
            raise ValueError(f"{self.model}: expected {len(self)} values, got {vector.shape}")
        return {p.name: float(v) for p, v in zip(self.params, vector)}

    # -- presentation -----------------------------------------------------
    def rows(self) -> list[dict]:
        """The declaration as plain dicts (for JSON, HDF5 attributes and reports)."""
        return [
            dict(
                name=p.name,
                unit=p.unit,
                default=p.default,
                lower=p.lower,
                upper=p.upper,
                group=p.group,
                meaning=p.meaning,
            )
            for p in self.params
        ]

    def format_table(self, values: Mapping[str, float] | None = None) -> str:
        """A fixed-width text table; with ``values`` a *value* column is added."""
        header = ["name", "unit", "default", "lower", "upper", "group", "meaning"]
        if values is not None:
            header.insert(2, "value")
        lines = []
        for p in self.params:
            row = [
                p.name,
                p.unit,
                f"{p.default:.6g}",
                f"{p.lower:.6g}",
                f"{p.upper:.6g}",
                p.group,
                p.meaning,
            ]
            if values is not None:
                row.insert(2, f"{values[p.name]:.6g}")
            lines.append(row)
        widths = [max(len(h), *(len(r[i]) for r in lines)) for i, h in enumerate(header)]
        widths[-1] = 0  # meaning is last and left ragged
        fmt = "  ".join(f"{{:<{w}}}" for w in widths)
        out = [
            fmt.format(*header).rstrip(),
            fmt.format(*("-" * max(w, 7) for w in widths)).rstrip(),
        ]
        out += [fmt.format(*r).rstrip() for r in lines]
        return "\n".join(out)
