"""The ``process`` section of an experiment or a pipeline: what a supplier can build.

A specification stage (objective ``perceptual``) takes a table of the tolerances a
supplier builds to (:mod:`evo_door.optim.process`), inline or in a file next to the
experiment::

    process: {K: "5 %", F_load: 2.0, mu: {tolerance: "20 %", distribution: uniform},
              kinds: {friction_force: "20 %"}}
    process: tolerances.yaml          # the same mapping, optionally under `process:`

A percentage is a fraction of the nominal value, a number a half-width in the
parameter's declared unit; ``kinds`` sets every parameter of a kind at once (a name
given on its own wins). Every error is one line ``FILE:LINE: process.KEY: what``.
"""

from __future__ import annotations

from pathlib import Path

from evo_door.errors import UserError
from evo_door.experiment.config_reader import KeyReader, _resolve_path, _show
from evo_door.experiment.yamltree import LinedMap, parse
from evo_door.files import read_text
from evo_door.optim.process import DISTRIBUTIONS, KINDS, process_entries
from evo_door.params.declaration import suggest
from evo_door.params.process import parse_tolerance

#: the keys of one entry written as a mapping
ENTRY_KEYS = ("tolerance", "distribution", "source")


def has_built(model) -> bool:
    """Whether ``model`` declares any parameter a supplier builds (a process kind)."""
    return any(p.process for p in model.params)


def process_given(r: KeyReader, base_dir: Path, model) -> dict[str, dict]:
    """The entries ``process:`` of ``r``'s mapping sets, by parameter name (a kind's
    entry given to each parameter of the kind; a name given on its own wins), checked
    against ``model``'s declaration; {} without the key."""
    node = r.get("process")
    if node is None:
        return {}
    where = r.node.where("process")
    if isinstance(node, str):
        node = _read_file(node, base_dir, where)
    if not isinstance(node, LinedMap):
        raise r.fail(
            "process",
            "expected a mapping name: tolerance (K: '5 %', F_load: 2.0) or a file of one, "
            f"got {_show(node)}",
        )
    names = [p.name for p in model.params]
    given: dict[str, dict] = {}
    kinds = node.get("kinds")
    if kinds is not None:
        if not isinstance(kinds, LinedMap):
            raise UserError(
                f"{node.where('kinds')}: process.kinds: expected a mapping kind: tolerance "
                f"(spring_rate: '5 %'), got {_show(kinds)}"
            )
        for kind in kinds:
            key = f"process.kinds.{kind}"
            if kind not in KINDS:
                raise UserError(
                    f"{kinds.where(kind)}: {key}: unknown kind"
                    + suggest(str(kind), KINDS)
                    + f"; kinds: {', '.join(KINDS)}"
                )
            entry = _entry(kinds, kind, key)
            for p in model.params:
                if p.process == kind:
                    given[p.name] = dict(entry)
    for name in node:
        if name == "kinds":
            continue
        key = f"process.{name}"
        if name not in names:
            raise UserError(
                f"{node.where(name)}: {key}: model {model.name!r} has no parameter {name!r}"
                + suggest(str(name), [*names, "kinds"])
            )
        p = model.params[name]
        if not p.process:
            raise UserError(
                f"{node.where(name)}: {key}: {name!r} ({p.group}) is not built by a supplier: "
                "it has no tolerance; the built ones: "
                + ", ".join(q.name for q in model.params if q.process)
            )
        given[name] = _entry(node, name, key)
    return given


def _read_file(text: str, base_dir: Path, where: str) -> LinedMap:
    """A ``process:`` file next to the experiment: its mapping (under ``process:`` or
    not), with its own file and lines."""
    path = _resolve_path(text, base_dir, where, "process")
    tree = parse(read_text(Path(path), "process file"), path)
    if isinstance(tree, LinedMap) and set(tree) == {"process"}:
        tree = tree["process"]
    if not isinstance(tree, LinedMap):
        loc = getattr(tree, "loc", "") or f"{path}:1"
        raise UserError(
            f"{loc}: process: a process file is a mapping name: tolerance (K: '5 %'), got "
            f"{_show(tree)} (from {where})"
        )
    return tree


def _entry(node: LinedMap, name, key: str) -> dict:
    """One entry, checked: ``{"tolerance", "distribution", "source"}``; its source says
    where it was set."""
    value = node[name]
    set_in = f"set in {node.where(name)}"
    if isinstance(value, LinedMap):
        for k in value:
            if k not in ENTRY_KEYS:
                raise UserError(
                    f"{value.where(k)}: {key}.{k}: unknown key"
                    + suggest(str(k), ENTRY_KEYS)
                    + f"; allowed: {', '.join(ENTRY_KEYS)}"
                )
        if "tolerance" not in value:
            raise UserError(f"{node.where(name)}: {key}.tolerance: required key missing")
        tolerance = _tolerance(value["tolerance"], value.where("tolerance"), f"{key}.tolerance")
        distribution = value.get("distribution", "normal")
        if distribution not in DISTRIBUTIONS:
            text = repr(distribution) if isinstance(distribution, str) else _show(distribution)
            raise UserError(
                f"{value.where('distribution')}: {key}.distribution: {text} is not one of "
                f"{', '.join(DISTRIBUTIONS)}"
                + (suggest(distribution, DISTRIBUTIONS) if isinstance(distribution, str) else "")
            )
        source = value.get("source")
        if source is not None and (not isinstance(source, str) or not source.strip()):
            raise UserError(
                f"{value.where('source')}: {key}.source: expected a text (who says so), got "
                f"{_show(source)}"
            )
        if source:
            set_in = f"{' '.join(source.split())} ({set_in})"
        return {"tolerance": tolerance, "distribution": distribution, "source": set_in}
    tolerance = _tolerance(value, node.where(name), key)
    return {"tolerance": tolerance, "distribution": "normal", "source": set_in}


def _tolerance(value, where: str, key: str):
    """A tolerance as the resolved table keeps it: ``"5 %"`` or a float."""
    try:
        relative, number = parse_tolerance(value)
    except ValueError as exc:
        raise UserError(f"{where}: {key}: {exc}") from None
    return f"{100.0 * number:g} %" if relative else number


def process_table(model, given: dict) -> dict[str, dict]:
    """Every built parameter of ``model`` -> its entry: ``given``'s or its kind's default."""
    return process_entries(model, given)
