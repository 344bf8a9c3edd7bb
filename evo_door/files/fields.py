"""What a file holds, read with where it came from, and checked for what a reader expects.

A file's checksums (:mod:`~evo_door.files.integrity`) say it is as its sender wrote it,
not that its sender was evo-door: a file made with h5py and sealed again can hold a
text where a number belongs, a 2-D array where a 1-D one does, a group too few. Readers
take what they need through the functions here, which give the value in the type asked
for or raise one line (:class:`DamagedFile`) naming the file, the object and what was
expected (part of issue 37, "files are data")::

    run.h5: /best, attribute 'fitness': expected a number, got 'x'
    run.h5: /setup/base: expected a 1-D array of numbers, got shape (2, 45)
    run.h5: /jobs/0/ga: missing

A group read by :func:`~evo_door.files.h5tree.read_group` is a :class:`Node`: a dict
that knows its place, so that a member or an attribute it lacks is that one line too
(a :class:`MissingInFile`, also a ``KeyError`` for the readers that look before they
leap). :func:`stored` builds a dataclass from a group, each field checked against its
annotation, the arrays against the shapes given.
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from collections.abc import Mapping

from evo_door.errors import plain_text
from evo_door.files.integrity import DamagedFile

#: a getter's ``default`` when the value is required
REQUIRED = object()


class MissingInFile(DamagedFile, KeyError):
    """A member or attribute a reader needs that the file does not have (a KeyError
    too, so that readers that catch one for a file's optional parts still do)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class Node(dict):
    """A group's members or an object's attributes as read from a file, with their place
    (``FILE: /group``) and how a key is named there (``style``): a ``member``
    (``run.h5: /best/x``), an ``attribute`` (``run.h5: /best, attribute 'fitness'``) or
    a ``key`` of a JSON mapping (``run.h5: /experiment/resolved: algorithm.population``;
    a place ending in ``:`` names its keys after a space)."""

    def __init__(self, *args, place: str = "", style: str = "member", **kwargs):
        super().__init__(*args, **kwargs)
        self.place = place
        self.style = style

    def name(self, key) -> str:
        """Where ``key`` is (see the class docstring)."""
        if self.style == "attribute":
            return f"{self.place}, attribute {key!r}"
        if self.style == "key":
            return f"{self.place} {key}" if self.place.endswith(":") else f"{self.place}.{key}"
        return f"{self.place.rstrip('/')}/{key}"

    def __missing__(self, key):
        raise MissingInFile(f"{self.name(key)}: missing")

    def __reduce__(self):
        return (_node, (dict(self), self.place, self.style))


def _node(items: dict, place: str, style: str) -> Node:
    return Node(items, place=place, style=style)


def place_of(node, key) -> str:
    """Where ``key`` of ``node`` is, for a message: a :class:`Node` (or any mapping with
    a ``place`` and a ``name(key)``) says; of a plain dict, the key alone."""
    name = getattr(node, "name", None)
    if callable(name) and getattr(node, "place", None):
        return name(key)
    return f"stored value {key!r}"


def node_place(node) -> str:
    """Where ``node`` itself is (``FILE: /group``), or "stored data"."""
    return getattr(node, "place", None) or "stored data"


def show(value) -> str:
    """A short text of a value found where another was expected."""
    import numpy as np

    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape} ({value.dtype})"
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _fail(where: str, expected: str, value) -> DamagedFile:
    return DamagedFile(f"{where}: expected {expected}, got {show(value)}")


# -- one value ---------------------------------------------------------------------------
def as_number(value, where: str, *, finite: bool = False, lo=None, hi=None) -> float:
    """``value`` as a float: a number (not a bool, not a text)."""
    import numpy as np

    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if isinstance(value, (bool, np.bool_)) or not isinstance(
        value, (int, float, np.integer, np.floating)
    ):
        raise _fail(where, "a number", value)
    try:
        x = float(value)
    except OverflowError:  # a whole number of hundreds of digits
        raise _fail(where, "a number within a float's range", value) from None
    if finite and not math.isfinite(x):
        raise _fail(where, "a finite number", value)
    low, high = -math.inf if lo is None else lo, math.inf if hi is None else hi
    if not low <= x <= high and not (math.isnan(x) and lo is None and hi is None):
        raise _fail(where, f"a number in [{low:g}, {high:g}]", value)
    return x


def as_integer(value, where: str, *, lo=None, hi=None) -> int:
    """``value`` as an int: a whole number (an integral float too), within bounds."""
    import numpy as np

    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if isinstance(value, (float, np.floating)) and math.isfinite(value) and value == int(value):
        value = int(value)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise _fail(where, "a whole number", value)
    n = int(value)
    lo = -(2**63) if lo is None else lo  # what a file stores: 64 bits
    hi = 2**63 - 1 if hi is None else hi
    if n < lo or n > hi:
        span = f"{lo}..{hi}"
        raise _fail(where, f"a whole number in {span}", value)
    return n


def as_flag(value, where: str) -> bool:
    """``value`` as a bool: true or false (or 0 and 1)."""
    import numpy as np

    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)) and value in (0, 1):
        return bool(value)
    raise _fail(where, "true or false", value)


def as_text(value, where: str, *, choices=None) -> str:
    """``value`` as a str: a text (bytes as UTF-8) a file and a terminal can hold."""
    import numpy as np

    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if isinstance(value, bytes):
        try:
            value = value.decode("utf-8")
        except UnicodeDecodeError:
            raise _fail(where, "UTF-8 text", value) from None
    if not isinstance(value, str):
        raise _fail(where, "a text", value)
    plain_text(value, where, DamagedFile)
    if choices is not None and value not in choices:
        raise _fail(where, "one of " + ", ".join(map(str, choices)), value)
    return str(value)


def as_texts(value, where: str) -> list[str]:
    """``value`` as a list of str."""
    import numpy as np

    if isinstance(value, np.ndarray) and value.ndim == 1:
        value = value.tolist()
    if not isinstance(value, (list, tuple)):
        raise _fail(where, "a list of texts", value)
    return [as_text(v, f"{where}[{i}]") for i, v in enumerate(value)]


def as_numbers(value, where: str) -> list[float]:
    """``value`` as a list of float."""
    import numpy as np

    if isinstance(value, np.ndarray) and value.ndim == 1:
        value = value.tolist()
    if not isinstance(value, (list, tuple)):
        raise _fail(where, "a list of numbers", value)
    return [as_number(v, f"{where}[{i}]") for i, v in enumerate(value)]


def as_mapping(value, where: str, values=None) -> dict:
    """``value`` as a dict with text keys; ``values`` converts each value (``as_number``,
    ``as_text``...), or leaves them as they are."""
    if not isinstance(value, Mapping):
        raise _fail(where, "a mapping", value)
    out = {}
    for k, v in value.items():
        key = as_text(k, f"{where}, key")
        out[key] = values(v, f"{where}[{key!r}]") if values is not None else v
    return out


#: what ``as_array``'s ``kind`` accepts: numbers, or true and false
_KINDS = {
    "f": ("biuf", "float64", "an array of numbers"),
    "n": ("biuf", None, "an array of numbers"),  # kept in its own type (a logbook's counts)
    "i": ("iu", "int64", "an array of whole numbers"),
    "b": ("biu", "bool", "an array of flags"),
}


def as_array(value, where: str, shape=None, kind: str = "f"):
    """``value`` as a float64 array (``kind="i"``: int64, ``"b"``: bool, ``"n"``: numbers
    in their own type), of ``shape`` where given: a tuple of sizes, ``None`` for any
    (``(None,)``: 1-D of any length)."""
    import numpy as np

    accepted, dtype, what = _KINDS[kind]
    if shape is not None:
        what = f"a {len(shape)}-D {what.removeprefix('an ')}"
    if isinstance(value, (list, tuple)):
        try:
            value = np.asarray(value)
        except ValueError:
            raise _fail(where, what, value) from None
    elif isinstance(value, (int, float, np.number)) and not isinstance(value, bool):
        value = np.asarray(value)
    if not isinstance(value, np.ndarray) or value.dtype.kind not in accepted:
        raise _fail(where, what, value)
    if shape is not None:
        if value.ndim != len(shape):
            raise DamagedFile(f"{where}: expected {what}, got shape {value.shape}")
        for want, got in zip(shape, value.shape):
            if want is not None and want != got:
                raise DamagedFile(
                    f"{where}: expected shape {_shape_text(shape)}, got {value.shape}"
                )
    return value if dtype is None else value.astype(dtype)


def _shape_text(shape) -> str:
    inner = ", ".join("any" if s is None else str(s) for s in shape)
    return f"({inner},)" if len(shape) == 1 else f"({inner})"


# -- a value of a node -------------------------------------------------------------------
def _get(node, key, default):
    value = node.get(key) if isinstance(node, Mapping) else None
    if value is None:
        if default is REQUIRED:
            if isinstance(node, Mapping) and key in node:
                raise DamagedFile(f"{place_of(node, key)}: expected a value, got None")
            raise MissingInFile(f"{place_of(node, key)}: missing")
        return True, default
    return False, value


def number(node, key, default=REQUIRED, **bounds) -> float:
    """``node[key]`` as a number (:func:`as_number`); ``default`` where missing or None."""
    missing, value = _get(node, key, default)
    return value if missing else as_number(value, place_of(node, key), **bounds)


def integer(node, key, default=REQUIRED, **bounds) -> int:
    """``node[key]`` as a whole number (:func:`as_integer`)."""
    missing, value = _get(node, key, default)
    return value if missing else as_integer(value, place_of(node, key), **bounds)


def flag(node, key, default=REQUIRED) -> bool:
    """``node[key]`` as true or false."""
    missing, value = _get(node, key, default)
    return value if missing else as_flag(value, place_of(node, key))


def text(node, key, default=REQUIRED, choices=None) -> str:
    """``node[key]`` as a text (:func:`as_text`)."""
    missing, value = _get(node, key, default)
    return value if missing else as_text(value, place_of(node, key), choices=choices)


def json_value(node, key, default=REQUIRED):
    """``node[key]``, a text holding JSON, decoded; ``default`` (a value, not JSON text)
    where missing. Text that is not JSON, or nests too deeply, is one line naming it."""
    missing, value = _get(node, key, default)
    return value if missing else as_json(value, place_of(node, key))


def as_json(value, where: str):
    """``value``, a text holding JSON, decoded; text that is not JSON, or nests too
    deeply, is one line naming ``where``."""
    try:
        return json.loads(as_text(value, where))
    except RecursionError:
        raise DamagedFile(f"{where}: JSON nested too deeply") from None
    except ValueError as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DamagedFile(f"{where}: not valid JSON ({first[:80]})") from None


def texts(node, key, default=REQUIRED) -> list[str]:
    """``node[key]`` as a list of texts."""
    missing, value = _get(node, key, default)
    return value if missing else as_texts(value, place_of(node, key))


def numbers(node, key, default=REQUIRED) -> list[float]:
    """``node[key]`` as a list of numbers."""
    missing, value = _get(node, key, default)
    return value if missing else as_numbers(value, place_of(node, key))


def mapping(node, key, default=REQUIRED, values=None) -> dict:
    """``node[key]`` as a mapping (:func:`as_mapping`)."""
    missing, value = _get(node, key, default)
    return value if missing else as_mapping(value, place_of(node, key), values)


def array(node, key, default=REQUIRED, shape=None, kind: str = "f"):
    """``node[key]`` as an array (:func:`as_array`)."""
    missing, value = _get(node, key, default)
    return value if missing else as_array(value, place_of(node, key), shape, kind)


def group(node, key, default=REQUIRED):
    """``node[key]``, a group (a mapping), or one line saying what it is instead."""
    missing, value = _get(node, key, default)
    if missing or isinstance(value, Mapping):
        return value
    raise DamagedFile(f"{place_of(node, key)}: expected a group, got {show(value)}")


# -- a dataclass -------------------------------------------------------------------------
def stored(cls, *nodes, shapes=None, sizes=None, **given):
    """``cls(**fields)`` for a dataclass read from a file: each field is taken from the
    first of ``nodes`` that holds it (``given`` values as they are), checked against
    its annotation (float, int, bool, str, list[str], list[float], dict, np.ndarray,
    ``X | None``); a required field missing is one line naming where it should be.

    ``shapes`` gives arrays (and lists) their shape, a size a number, None (any) or a
    name: ``sizes`` binds a name to the length of a list field (``{"p": "names"}``); a
    name not bound so takes the first size met.
    """
    hints = typing.get_type_hints(cls)
    shapes = shapes or {}
    bound: dict = {}
    values: dict = {}
    late = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        if f.name in given:
            values[f.name] = given[f.name]
            continue
        source = next((n for n in nodes if isinstance(n, Mapping) and f.name in n), None)
        if source is None:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                where = place_of(nodes[0], f.name) if nodes else f.name
                raise MissingInFile(f"{where}: missing")
            continue
        value, where = source[f.name], place_of(source, f.name)
        hint, optional = _unwrap(hints.get(f.name))
        if value is None and optional:
            values[f.name] = None
        elif hint is _ndarray():
            late.append((f.name, value, where))
        else:
            values[f.name] = _convert(hint, value, where)
    for symbol, field_name in (sizes or {}).items():
        if isinstance(values.get(field_name), list):
            bound[symbol] = len(values[field_name])
    for name, value, where in late:
        values[name] = as_array(value, where, _resolve(shapes.get(name), bound, value))
    for name, shape in shapes.items():  # lists of a declared length
        if isinstance(values.get(name), list):
            _check_length(values[name], shape, bound, _place_of_any(nodes, name))
    try:
        return cls(**values)
    except ValueError as exc:  # a value out of its range (the class's own checks)
        raise DamagedFile(f"{node_place(nodes[0]) if nodes else cls.__name__}: {exc}") from None


def _place_of_any(nodes, key) -> str:
    source = next((n for n in nodes if isinstance(n, Mapping) and key in n), None)
    return place_of(source if source is not None else (nodes[0] if nodes else {}), key)


def _check_length(value: list, shape, bound: dict, where: str) -> None:
    if not shape:
        return
    want = shape[0]
    if isinstance(want, str):
        want = bound.setdefault(want, len(value))
    if want is not None and len(value) != want:
        raise DamagedFile(f"{where}: expected {want} entries, got {len(value)}")


def _resolve(shape, bound: dict, value):
    """``shape`` with its names replaced by their sizes (a name met first binds)."""
    if shape is None:
        return None
    import numpy as np

    out = []
    got = value.shape if isinstance(value, np.ndarray) else None
    for i, s in enumerate(shape):
        if isinstance(s, str):
            if s not in bound and got is not None and len(got) == len(shape):
                bound[s] = got[i]
            s = bound.get(s)
        out.append(s)
    return tuple(out)


def _ndarray():
    import numpy as np

    return np.ndarray


def _unwrap(hint):
    """(the hint without ``None``, whether None is allowed)."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        return (args[0] if len(args) == 1 else typing.Any), len(args) < len(typing.get_args(hint))
    return hint, False


def _convert(hint, value, where: str):
    """``value`` as ``hint`` says (a type not listed here: as it is)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is float:
        return as_number(value, where)
    if hint is bool:
        return as_flag(value, where)
    if hint is int:
        return as_integer(value, where)
    if hint is str:
        return as_text(value, where)
    if hint is dict or origin is dict:
        readers: dict = {float: as_number, str: as_text, int: as_integer}
        return as_mapping(value, where, readers.get(args[1]) if len(args) == 2 else None)
    if hint is list or origin is list:
        if args and args[0] is str:
            return as_texts(value, where)
        if args and args[0] in (float, int):
            return as_numbers(value, where)
        if not isinstance(value, (list, tuple)):
            raise _fail(where, "a list", value)
        return list(value)
    return value
