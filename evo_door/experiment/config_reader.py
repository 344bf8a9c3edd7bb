"""Reading one key of an experiment file: typed values, and errors that name its line.

:class:`KeyReader` wraps one mapping of the parsed YAML tree
(:mod:`evo_door.experiment.yamltree`) and reads its keys as whole numbers, numbers,
choices, booleans or text, each refused in one line ``FILE:LINE: key.path: what is
wrong``. The readers of values that several sections share (a file path next to the
experiment, a parameter set, a list of trial ids, the executor) are here too; the
sections themselves are in :mod:`~evo_door.experiment.config_target`,
:mod:`~evo_door.experiment.config_algorithm` and :mod:`~evo_door.experiment.config`.
"""

from __future__ import annotations

import math
from pathlib import Path

from evo_door.errors import UserError, plain_text
from evo_door.experiment.yamltree import LinedList, LinedMap
from evo_door.params.declaration import suggest


class KeyReader:
    """Typed access to one mapping of the tree, with located errors."""

    def __init__(self, node, path: str, where: str):
        self.path = path
        if node is None:
            node = LinedMap(loc=where)
        if not isinstance(node, LinedMap):
            raise UserError(f"{where}: {path}: expected a mapping of keys, got {_show(node)}")
        self.node = node

    def key_path(self, key) -> str:
        return f"{self.path}.{key}" if self.path else str(key)

    def fail(self, key, message) -> UserError:
        return UserError(f"{self.node.where(key)}: {self.key_path(key)}: {message}")

    def check_keys(self, allowed, required=()):
        for key in self.node:
            if key not in allowed:
                raise self.fail(
                    key,
                    "unknown key" + suggest(str(key), allowed) + f"; allowed: {', '.join(allowed)}",
                )
        for key in required:
            if key not in self.node:
                raise UserError(f"{self.node.loc}: {self.key_path(key)}: required key missing")

    def get(self, key, default=None):
        return self.node.get(key, default)

    def integer(self, key, default, lo=None, hi=None):
        v = self.node.get(key, default)
        if isinstance(v, float) and v.is_integer() and abs(v) < 2**53:
            v = int(v)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.fail(key, f"expected a whole number, got {_show(v)}")
        _range(self, key, v, lo, hi)
        return v

    def number(self, key, default, lo=None, hi=None, open_lo=False, allow_none=False):
        v = self.node.get(key, default)
        if v is None and allow_none:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.fail(key, f"expected a finite number, got {_show(v)}")
        v = float(v)
        if open_lo and lo is not None and not v > lo:
            raise self.fail(key, f"must be > {lo:g}, got {v:g}")
        _range(self, key, v, None if open_lo else lo, hi)
        return v

    def choice(self, key, default, choices):
        v = self.node.get(key, default)
        if v not in choices or isinstance(v, bool) != isinstance(choices[0], bool):
            text = repr(str(v)) if isinstance(v, str) else _show(v)
            raise self.fail(
                key,
                f"{text} is not one of {', '.join(map(str, choices))}"
                + (suggest(v, list(map(str, choices))) if isinstance(v, str) else ""),
            )
        return v

    def boolean(self, key, default):
        v = self.node.get(key, default)
        if not isinstance(v, bool):
            raise self.fail(key, f"expected true or false, got {_show(v)}")
        return v

    def string(self, key, default=None, required=False):
        v = self.node.get(key, default)
        if v is None and not required:
            return None
        if key not in self.node and v == default:
            return v
        if not isinstance(v, str) or not v.strip():
            raise self.fail(key, f"expected a text value, got {_show(v)}")
        return v


def _range(reader, key, v, lo, hi):
    if lo is not None and v < lo:
        raise reader.fail(key, f"must be >= {lo:g}, got {v:g}")
    if hi is not None and v > hi:
        raise reader.fail(key, f"must be <= {hi:g}, got {v:g}")


def _show(v) -> str:
    if isinstance(v, (LinedMap, dict)):
        return "a mapping"
    if isinstance(v, (LinedList, list)):
        return "a list"
    return repr(v)


def _resolve_path(text: str, base_dir: Path, where: str, key: str) -> str:
    """A relative path is looked up next to the experiment file, then in the current folder.

    ``where`` (file:line) and ``key`` (its dotted path) locate the entry in messages.
    """
    plain_text(text, f"{where}: {key}")  # no NUL, no lone surrogate: no path holds one
    p = Path(text).expanduser()
    candidates = [p] if p.is_absolute() else [base_dir / p, Path.cwd() / p]
    for c in candidates:
        if c.is_file():
            return str(c.resolve())
    tried = " or ".join(dict.fromkeys(str(c.resolve()) for c in candidates))
    raise UserError(f"{where}: {key}: file not found: {text} (looked for {tried})")


def _param_spec(reader: KeyReader, key, base_dir: Path):
    """A parameter set given as preset name, YAML file, render log (the session's chosen
    set) or inline mapping."""
    v = reader.get(key)
    if v is None:
        return None
    if isinstance(v, LinedMap) and "from" in v:
        # an earlier stage's best parameters: a pipeline fills them in (pipeline.py)
        if set(v) != {"from"} or not isinstance(v["from"], str) or not v["from"].strip():
            raise reader.fail(key, "expected {from: STAGE}, the name of an earlier stage")
        return {"from": v["from"].strip(), "where": v.where("from")}
    if isinstance(v, LinedMap):
        for name, value in v.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise UserError(
                    f"{v.where(name)}: {reader.key_path(key)}.{name}: expected a "
                    f"number, got {_show(value)}"
                )
        return {str(k): float(x) for k, x in v.items()}
    if not isinstance(v, str):
        raise reader.fail(
            key, f"expected a preset name, a parameter file or a mapping, got {_show(v)}"
        )
    if v.endswith((".yaml", ".yml", ".h5", ".hdf5")) or "/" in v:  # .h5: a render log
        return _resolve_path(v, base_dir, reader.node.where(key), reader.key_path(key))
    return v


def _id_list(reader: KeyReader, key, allow_all: bool):
    v = reader.get(key, "all" if allow_all else [])
    if allow_all and v == "all":
        return "all"
    if isinstance(v, (str, int)) and not isinstance(v, bool):
        v = [v]
    if not isinstance(v, list) or not all(
        isinstance(x, (str, int)) and not isinstance(x, bool) for x in v
    ):
        raise reader.fail(
            key,
            ("'all' or " if allow_all else "") + f"a list of trial ids expected, got {_show(v)}",
        )
    ids = [str(x) for x in v]
    dup = sorted({x for x in ids if ids.count(x) > 1})
    if dup:
        raise reader.fail(key, f"trial {dup[0]!r} listed twice")
    return ids


def executor_setting(reader: KeyReader) -> str:
    """The ``executor`` key of an experiment or a pipeline (default ``local``), checked."""
    from evo_door.optim.executors import DEFAULT, ExecutorNameError, check_executor

    value = reader.get("executor", DEFAULT)
    if not isinstance(value, str):
        raise reader.fail(
            "executor", f"expected a name (local, processes, dask), got {_show(value)}"
        )
    try:
        return check_executor(value)
    except ExecutorNameError as exc:
        raise reader.fail("executor", exc.reason) from None
