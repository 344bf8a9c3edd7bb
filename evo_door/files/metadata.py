"""How metadata is stored in HDF5: attributes as they are, or as JSON text.

Attributes hold str, int, float and bool as they are; anything else (dict, list, None)
is stored as JSON text behind the prefix ``json:`` (:func:`encode_attr`), and so is a
str that itself starts with ``json:``, so that reading is never ambiguous
(:func:`decode_attr`). Files written by evo-door 0.1 with the older encoding (a
``NAME.__json__`` flag beside the attribute) still read.
"""

from __future__ import annotations

import json

ATTRS = "@attrs"
#: the attribute holding a group's checksum (:mod:`evo_door.files.integrity`), not metadata
DIGEST = "_digest"
JSON_PREFIX = "json:"
#: flag attribute of the encoding used before this module (trial files, format 1)
_LEGACY_JSON_FLAG = ".__json__"


def jsonable(value):
    """``value`` with numpy scalars and arrays (and tuples, bytes) as plain Python.

    >>> import numpy as np
    >>> jsonable({"x": np.arange(2), "k": np.int64(3), "pair": (1.5, b"a")})
    {'x': [0, 1], 'k': 3, 'pair': [1.5, 'a']}
    """
    import numpy as np  # here, not at the top: commands that write no file start quicker

    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bytes):
        return value.decode()
    return value


def to_json(value, indent=None) -> str:
    """JSON text of ``value`` (numpy included; NaN and inf as JavaScript writes them)."""
    separators = None if indent is not None else (",", ":")
    return json.dumps(jsonable(value), separators=separators, indent=indent, allow_nan=True)


def encode_attr(value):
    """An HDF5 attribute value for ``value`` (see the module docstring).

    >>> encode_attr({"range": [-1, 1]}), encode_attr(None), encode_attr(2.5)
    ('json:{"range":[-1,1]}', 'json:null', 2.5)
    >>> decode_attr(encode_attr("json: is text here"))
    'json: is text here'
    """
    if value is None or isinstance(value, (dict, list, tuple)):
        return JSON_PREFIX + to_json(value)
    if isinstance(value, str) and value.startswith(JSON_PREFIX):
        return JSON_PREFIX + to_json(value)
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    return value


def decode_attr(value):
    """The Python value of an HDF5 attribute written by :func:`encode_attr`."""
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, str) and value.startswith(JSON_PREFIX):
        return json.loads(value[len(JSON_PREFIX) :])
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def write_attrs(obj, attrs: dict) -> None:
    """Set the attributes of an HDF5 group or dataset from ``attrs``."""
    for name, value in attrs.items():
        obj.attrs[str(name)] = encode_attr(value)


def read_attrs(obj) -> dict:
    """The attributes of an HDF5 group or dataset, decoded (both encodings), as a
    :class:`~evo_door.files.fields.Node` that names the file and the object: JSON that
    does not parse, or a text no file can hold, is one line naming the attribute."""
    from evo_door.files.fields import Node

    raw = obj.attrs
    out = Node(place=f"{obj.file.filename}: {obj.name}", style="attribute")
    for name, value in raw.items():
        if name.endswith(_LEGACY_JSON_FLAG) or name == DIGEST:
            continue
        out[name] = _decoded(obj, name, value, name + _LEGACY_JSON_FLAG in raw, out.name(name))
    return out


def _decoded(obj, name: str, value, legacy: bool, where: str):
    """One attribute's value, decoded and checked (see :func:`read_attrs`)."""
    from evo_door.files.integrity import DamagedFile

    try:
        value = decode_attr(value)
        if legacy:
            value = json.loads(value)
        _check_values(value, where)
    except UnicodeDecodeError:
        raise DamagedFile(f"{where}: not UTF-8 text") from None
    except RecursionError:
        raise DamagedFile(f"{where}: JSON nested too deeply") from None
    except (ValueError, TypeError) as exc:
        if isinstance(exc, DamagedFile):
            raise
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DamagedFile(f"{where}: not valid JSON ({first[:80]})") from None
    return value


def _check_values(value, where: str) -> None:
    """Every value in ``value`` (a decoded attribute, at any depth) one a file can hold
    again: a text a file and a terminal can hold (:func:`~evo_door.errors.plain_text`),
    a whole number of 64 bits (JSON has no limit, HDF5 has)."""
    from evo_door.errors import plain_text
    from evo_door.files.integrity import DamagedFile

    if isinstance(value, str):
        plain_text(value, where, DamagedFile)
    elif isinstance(value, int) and not -(2**63) <= value < 2**63:
        raise DamagedFile(f"{where}: a whole number beyond 64 bits")
    elif isinstance(value, dict):
        for k, v in value.items():
            _check_values(k, where)
            _check_values(v, where)
    elif isinstance(value, list):
        for v in value:
            _check_values(v, where)


def attrs_tree(data: dict) -> dict:
    """A nested dict as a tree of groups holding attributes (``truth/params/...``).

    >>> attrs_tree({"model": "door", "params": {"mass": 1.2}})
    {'@attrs': {'model': 'door'}, 'params': {'@attrs': {'mass': 1.2}}}
    """
    out = {ATTRS: {}}
    for key, value in data.items():
        if isinstance(value, dict):
            out[str(key)] = attrs_tree(value)
        else:
            out[ATTRS][str(key)] = value
    return out


def tree_attrs(tree: dict) -> dict:
    """The inverse of :func:`attrs_tree` (datasets, if any, are left out)."""
    out = dict(tree.get(ATTRS, {}))
    for key, value in tree.items():
        if key != ATTRS and isinstance(value, dict):
            out[key] = tree_attrs(value)
    return out
