"""YAML that remembers where each key came from, for one-line error messages.

``parse(text, source)`` returns plain dicts / lists / scalars, except that every
mapping is a :class:`LinedMap` that knows the location (``file:line``) of itself and
of each of its keys, and every list a :class:`LinedList` with its own location.
Duplicate keys are an error (PyYAML silently keeps the last one).

``apply_override(tree, "algorithm.seed=3")`` sets a value from the command line;
the value is parsed as YAML (``3`` an int, ``[0.5, 2]`` a list, ``none`` a string)
and its location becomes ``--set algorithm.seed=3``.
"""

from __future__ import annotations

import yaml
from yaml.constructor import SafeConstructor

from evo_door.errors import UserError
from evo_door.yaml_numbers import Loader, load


class LinedMap(dict):
    """A dict with ``loc`` (its own location) and ``key_locs`` (location of each key)."""

    loc: str = ""

    def __init__(self, *args, loc: str = "", **kwargs):
        super().__init__(*args, **kwargs)
        self.loc = loc
        self.key_locs: dict = {}

    def where(self, key) -> str:
        return self.key_locs.get(key, self.loc)


class LinedList(list):
    loc: str = ""

    def __init__(self, *args, loc: str = ""):
        super().__init__(*args)
        self.loc = loc


def _loc(source: str, node) -> str:
    return f"{source}:{node.start_mark.line + 1}"


#: the most values a document may expand to, aliases followed (each use of an alias
#: is converted again: aliases inside aliases multiply)
MAX_EXPANDED = 200_000


def _convert(node, source: str, constructor: SafeConstructor, budget=None):
    budget = budget if budget is not None else [MAX_EXPANDED]
    budget[0] -= 1
    if budget[0] < 0:
        raise UserError(
            f"{source}: expands to more than {MAX_EXPANDED} values (aliases used inside "
            "aliases); write the values out"
        )
    if isinstance(node, yaml.MappingNode):
        out = LinedMap(loc=_loc(source, node))
        constructor.flatten_mapping(node)
        for key_node, value_node in node.value:
            key = constructor.construct_object(key_node, deep=True)
            if not isinstance(key, (str, int, float, bool)) or key is None:
                raise UserError(f"{_loc(source, key_node)}: mapping keys must be plain names")
            if key in out:
                raise UserError(
                    f"{_loc(source, key_node)}: duplicate key {key!r} "
                    f"(first at {out.key_locs[key]})"
                )
            out[key] = _convert(value_node, source, constructor, budget)
            out.key_locs[key] = _loc(source, key_node)
        return out
    if isinstance(node, yaml.SequenceNode):
        return LinedList(
            [_convert(n, source, constructor, budget) for n in node.value],
            loc=_loc(source, node),
        )
    return constructor.construct_object(node, deep=True)


def parse(text: str, source: str):
    """Parse YAML ``text`` (from ``source``, for messages) into a located tree."""
    try:
        node = yaml.compose(text, Loader=Loader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise UserError(f"{source}{line}: not valid YAML ({problem})") from None
    if node is None:
        return LinedMap(loc=f"{source}:1")
    return _convert(node, source, SafeConstructor())


def override_keys(path: str, where: str) -> list[str]:
    """The keys of an override's path ``a.b.c``; a key in double quotes may hold dots
    (``free."box.mass"``: a mechanism's parameter names do).

    >>> override_keys('free."box.mass"', "--set")
    ['free', 'box.mass']
    """
    keys, key, quoted = [], "", False
    for ch in path:
        if ch == '"':
            quoted = not quoted
        elif ch == "." and not quoted:
            keys.append(key.strip())
            key = ""
        else:
            key += ch
    keys.append(key.strip())
    if quoted or not all(keys):
        raise UserError(f"{where}: expected KEY.PATH=VALUE, e.g. algorithm.seed=3")
    return keys


def apply_override(tree: LinedMap, assignment: str) -> None:
    """Set ``a.b.c=value`` in ``tree`` (creating intermediate mappings).

    Where the rest of the path is itself a key of the mapping reached (``box.mass`` in
    ``free``), that key is set: ``free.box.mass=[2, 8]`` sets a mechanism's parameter
    the file names; ``free."box.mass"=[2, 8]`` names it whether the file does or not.
    """
    where = f"--set {assignment}"
    path, sep, text = assignment.partition("=")
    if not sep:
        raise UserError(f"{where}: expected KEY.PATH=VALUE, e.g. algorithm.seed=3")
    keys = override_keys(path, where)
    try:
        value = load(text) if text.strip() else None
    except yaml.YAMLError:
        raise UserError(f"{where}: {text!r} is not a YAML value") from None
    if isinstance(value, dict):
        m = LinedMap(value, loc=where)
        m.key_locs = {k: where for k in value}
        value = m
    elif isinstance(value, list):
        value = LinedList(value, loc=where)
    node = tree
    for i, key in enumerate(keys[:-1]):
        rest = ".".join(keys[i:])
        if rest in node:  # a dotted key the mapping holds (a mechanism's parameter)
            keys = [rest]
            break
        child = node.get(key)
        if not isinstance(child, LinedMap):
            child = LinedMap(loc=where)
            node[key] = child
            node.key_locs[key] = where
        node = child
    node[keys[-1]] = value
    node.key_locs[keys[-1]] = where


def flatten(config, prefix: str = "") -> dict:
    """A nested mapping as dotted keys; lists and other values are leaves.

    >>> flatten({"objective": {"kind": "ise", "derivative": 1}, "free": {"k": [20, 500]}})
    {'objective.kind': 'ise', 'objective.derivative': 1, 'free.k': [20, 500]}
    """
    out = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out
