"""The ``target`` section of an experiment: what the model is fitted to.

Measured trials (``data: FILE``, chosen by id, kind and user, some kept for
validation, each preprocessed alike), another model's response (``model: NAME`` to
``inputs``: a trial or force file, or a rig specification; with the ``perceptual``
objective, its feel, and ``inputs`` may be left out) or a chosen feel given as a
force-angle curve (``curve: FILE.csv``, the columns ``evo-door curve`` writes). Read
and checked here without reading the data; :mod:`evo_door.experiment.setup` reads it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from evo_door.errors import UserError
from evo_door.experiment.config_reader import (
    KeyReader,
    _id_list,
    _param_spec,
    _resolve_path,
    _show,
)
from evo_door.experiment.yamltree import LinedMap

DATA_TARGET_KEYS = ("data", "trials", "kinds", "users", "validate", "preprocess")
CURVE_TARGET_KEYS = ("curve",)
MODEL_TARGET_KEYS = (
    "model",
    "params",
    "set",
    "inputs",
    "trials",
    "kinds",
    "validate",
    "theta0",
    "dtheta0",
    "preprocess",
)
PREPROCESS_KEYS = ("rate_bias", "lowpass", "trim", "windows")
RATE_BIAS = ("none", "start", "all")


@dataclass
class PreprocessSpec:
    """What is done to every target trial before fitting (:mod:`evo_door.data.preprocess`).

    Applied in this order: ``rate_bias`` (remove the gyroscope's bias, measured at rest:
    ``start`` before the first motion, ``all`` on every rest run, ``none``), ``lowpass``
    (zero-phase Butterworth at this many Hz on every channel, or None), ``trim`` (cut to
    the motion), ``windows`` (cut every trial into windows of this many seconds, each
    from its measured state: what a slow trial needs to be fitted, or None).
    """

    rate_bias: str = "none"
    lowpass: float | None = None
    trim: bool = False
    windows: float | None = None

    @property
    def active(self) -> bool:
        return (
            self.rate_bias != "none"
            or self.lowpass is not None
            or self.trim
            or self.windows is not None
        )


@dataclass
class TargetSpec:
    """What the model is fitted to: trials from a file, or another model's response."""

    kind: str  # "data", "model" or "curve"
    trials: object = "all"  # "all" or list of trial ids
    kinds: list = field(default_factory=list)  # with trials: all, only these trial kinds
    users: list = field(default_factory=list)  # only these users' trials (kind "data")
    validate: list = field(default_factory=list)
    data: str | None = None  # resolved path (kind "data")
    model: str | None = None  # target model (kind "model")
    params: object = None  # preset name, resolved file path or {name: value}
    set: dict = field(default_factory=dict)
    inputs: object = None  # resolved file path, or a rig specification (mapping)
    curve: str | None = None  # resolved path of a force-angle curve (kind "curve")
    theta0: float | None = None
    dtheta0: float | None = None
    preprocess: PreprocessSpec = field(default_factory=lambda: PreprocessSpec())
    #: location (file:line) of each key, for messages about the data
    locs: dict = field(default_factory=dict)


def _target(reader: KeyReader, base_dir: Path) -> TargetSpec:
    node = reader.get("target")
    if node is None:
        raise UserError(
            f"{reader.node.loc}: target: required key missing "
            "(e.g. target: {data: FILE, trials: all})"
        )
    t = KeyReader(node, "target", reader.node.where("target"))
    given = [k for k in ("data", "model", "curve") if k in t.node]
    if len(given) > 1:
        raise t.fail(
            given[1],
            "give one of data (measured trials), model (a target model) or curve (a "
            f"force-angle curve), not {' and '.join(given)}",
        )
    locs = _locations(t)
    if "curve" in t.node:
        t.check_keys(CURVE_TARGET_KEYS, required=("curve",))
        path = _resolve_path(
            t.string("curve", required=True), base_dir, t.node.where("curve"), "target.curve"
        )
        return TargetSpec("curve", trials=[], curve=path, locs=locs)
    if "data" in t.node:
        spec = _data_target(t, base_dir, locs)
    elif "model" in t.node:
        spec = _model_target(t, base_dir, locs)
    else:
        raise UserError(
            f"{t.node.loc}: target: give data: FILE (measured trials), "
            "model: NAME with inputs: FILE (another model's response) or curve: FILE.csv "
            "(a chosen feel)"
        )
    if isinstance(spec.trials, list):
        both = [x for x in spec.validate if x in spec.trials]
        if both:
            raise t.fail("validate", f"trial {both[0]!r} is both fitted and validated")
    return spec


def _locations(t: KeyReader) -> dict:
    """file:line of each key of the target, for messages about the data (the keys
    left out are located at the section)."""
    locs = {k: t.node.where(k) for k in t.node}
    for key in ("trials", "validate", "kinds", "users"):
        locs.setdefault(key, t.node.loc)
    return locs


def _data_target(t: KeyReader, base_dir: Path, locs: dict) -> TargetSpec:
    """``target: {data: FILE, ...}``: measured trials."""
    t.check_keys(DATA_TARGET_KEYS, required=("data",))
    path = _resolve_path(
        t.string("data", required=True), base_dir, t.node.where("data"), "target.data"
    )
    return TargetSpec(
        "data",
        trials=_id_list(t, "trials", True),
        kinds=_kinds(t),
        users=_users(t),
        validate=_id_list(t, "validate", False),
        data=path,
        preprocess=_preprocess(t),
        locs=locs,
    )


def _model_target(t: KeyReader, base_dir: Path, locs: dict) -> TargetSpec:
    """``target: {model: NAME, inputs: ...}``: another model's response to the inputs."""
    t.check_keys(MODEL_TARGET_KEYS, required=("model",))
    inputs = t.get("inputs")
    if inputs is None:
        pass  # only the perceptual objective needs no inputs: the experiment checks
    elif isinstance(inputs, str):
        inputs = _resolve_path(inputs, base_dir, t.node.where("inputs"), "target.inputs")
    elif isinstance(inputs, LinedMap):
        inputs = _rig_spec(t, inputs, base_dir)
    else:
        raise t.fail(
            "inputs",
            f"expected a trial / force file or a rig specification, got {_show(inputs)}",
        )
    overrides = t.get("set") or {}
    if not isinstance(overrides, dict):
        raise t.fail("set", "expected a mapping of parameter names to numbers")
    return TargetSpec(
        "model",
        trials=_id_list(t, "trials", True),
        kinds=_kinds(t),
        validate=_id_list(t, "validate", False),
        model=t.string("model", required=True),
        params=_param_spec(t, "params", base_dir),
        set={str(k): v for k, v in overrides.items()},
        inputs=inputs,
        theta0=t.number("theta0", None, allow_none=True),
        dtheta0=t.number("dtheta0", None, allow_none=True),
        preprocess=_preprocess(t),
        locs=locs,
    )


def _rig_spec(t: KeyReader, node: LinedMap, base_dir: Path) -> dict:
    """``target.inputs`` written as a rig specification, checked by the rig's own rules
    (:func:`evo_door.data.rig.check_spec`, those of ``rig generate``'s flags); a bad entry
    is refused with the file and line of its key. Returned as written (JSON), with a
    parameter file's path resolved next to the experiment."""
    from evo_door.data.rig import SpecError, check_spec

    spec = json.loads(json.dumps(node))
    params = spec.get("params")
    if isinstance(params, str) and (params.endswith((".yaml", ".yml")) or "/" in params):
        spec["params"] = _resolve_path(
            params, base_dir, node.where("params"), "target.inputs.params"
        )
    try:
        check_spec(spec)
    except SpecError as exc:
        key = (exc.key or "").split(".")[0]
        where = node.where(key) if key in node else t.node.where("inputs")
        name = "target.inputs" + (f".{exc.key}" if exc.key else "")
        raise UserError(f"{where}: {name}: {exc.reason}") from None
    return spec


def _preprocess(t: KeyReader) -> PreprocessSpec:
    if "preprocess" not in t.node:
        return PreprocessSpec()
    p = KeyReader(t.get("preprocess"), t.key_path("preprocess"), t.node.where("preprocess"))
    p.check_keys(PREPROCESS_KEYS)
    return PreprocessSpec(
        rate_bias=p.choice("rate_bias", "none", RATE_BIAS),
        lowpass=p.number("lowpass", None, lo=0.0, open_lo=True, allow_none=True),
        trim=p.boolean("trim", False),
        windows=p.number("windows", None, lo=0.0, open_lo=True, allow_none=True),
    )


def _kinds(t: KeyReader) -> list:
    v = t.get("kinds", [])
    if isinstance(v, str):
        v = [v]
    if not isinstance(v, list) or not all(isinstance(k, str) for k in v):
        raise t.fail("kinds", f"expected a list of trial kinds (e.g. [impulse]), got {_show(v)}")
    if v and t.get("trials", "all") != "all":
        raise t.fail("kinds", "selects among trials: all; with a list of trial ids, leave it out")
    return list(v)


def _users(t: KeyReader) -> list:
    v = t.get("users", [])
    if isinstance(v, (str, int)) and not isinstance(v, bool):
        v = [v]
    if not isinstance(v, list) or not all(
        isinstance(u, (str, int)) and not isinstance(u, bool) for u in v
    ):
        raise t.fail("users", f"expected a list of user ids (e.g. [U1]), got {_show(v)}")
    users = [str(u) for u in v]
    dup = sorted({u for u in users if users.count(u) > 1})
    if dup:
        raise t.fail("users", f"user {dup[0]!r} listed twice")
    return users
