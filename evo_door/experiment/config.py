"""Experiment files: parse once into checked objects, reject anything unknown.

An experiment is YAML (reference: ``docs/experiments.md``)::

    name: haptic-from-measurements
    model: haptic
    target: {data: data/default.h5, trials: all, validate: [u3-t10]}
    fixed: {radius: 0.3}
    free: {inertia: [0.5, 3.0], friction_closing: [0.0, 10.0]}
    objective: {kind: max_square, derivative: 1, combine: sum}
    algorithm: {kind: ga, population: 100, generations: 20, reproduction_ratio: 0.6,
                mutation_probability: 0.1, mutation_amplitude: 0.8, seed: 1, polish: none}
    per_trial: false

:func:`load_experiment` checks everything that can be checked without reading data
(keys, types, ranges, parameter names against the model's declaration, bounds,
files exist) and raises :class:`~evo_door.errors.UserError` with one line
``FILE:LINE: key.path: what is wrong (did you mean ...?)``. Checks that need the data
(trial ids, channels) happen in :mod:`evo_door.experiment.setup` and name the key's
line too.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from evo_door.errors import UserError
from evo_door.experiment.yamltree import LinedList, LinedMap, apply_override, parse
from evo_door.files import read_text
from evo_door.optim.ga import GASettings
from evo_door.optim.kernels import KINDS
from evo_door.optim.local import LocalSettings
from evo_door.optim.problem import COMBINE, Objective
from evo_door.params.declaration import suggest
from evo_door.sim.integrators import METHODS

TOP_KEYS = (
    "name",
    "description",
    "model",
    "params",
    "target",
    "fixed",
    "free",
    "objective",
    "algorithm",
    "per_trial",
    "pooled",
    "simulation",
    "output",
    "executor",
)
DATA_TARGET_KEYS = ("data", "trials", "kinds", "users", "validate", "preprocess")
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
PREPROCESS_KEYS = ("rate_bias", "lowpass", "trim")
RATE_BIAS = ("none", "start", "all")
OBJECTIVE_KEYS = ("kind", "derivative", "combine")
GA_KEYS = tuple(f.name for f in fields(GASettings))
#: the SLSQP settings an experiment may set (the finite-difference step stays internal)
LOCAL_KEYS = ("max_iterations", "ftol")
ALGORITHM_KEYS = ("kind", *GA_KEYS, "polish", *LOCAL_KEYS, "start")
SIMULATION_KEYS = ("method", "substeps")
ALGORITHM_KINDS = ("ga", "nlpql")
POLISH = ("none", "slsqp")


@dataclass
class PreprocessSpec:
    """What is done to every target trial before fitting (:mod:`evo_door.data.preprocess`).

    Applied in this order: ``rate_bias`` (remove the gyroscope's bias, measured at rest:
    ``start`` before the first motion, ``all`` on every rest run, ``none``), ``lowpass``
    (zero-phase Butterworth at this many Hz on every channel, or None), ``trim`` (cut to
    the motion).
    """

    rate_bias: str = "none"
    lowpass: float | None = None
    trim: bool = False

    @property
    def active(self) -> bool:
        return self.rate_bias != "none" or self.lowpass is not None or self.trim


@dataclass
class TargetSpec:
    """What the model is fitted to: trials from a file, or another model's response."""

    kind: str  # "data" or "model"
    trials: object = "all"  # "all" or list of trial ids
    kinds: list = field(default_factory=list)  # with trials: all, only these trial kinds
    users: list = field(default_factory=list)  # only these users' trials (kind "data")
    validate: list = field(default_factory=list)
    data: str | None = None  # resolved path (kind "data")
    model: str | None = None  # target model (kind "model")
    params: object = None  # preset name, resolved file path or {name: value}
    set: dict = field(default_factory=dict)
    inputs: object = None  # resolved file path, or a rig specification (mapping)
    theta0: float | None = None
    dtheta0: float | None = None
    preprocess: PreprocessSpec = field(default_factory=lambda: PreprocessSpec())
    #: location (file:line) of each key, for messages about the data
    locs: dict = field(default_factory=dict)


@dataclass
class AlgorithmSpec:
    """The ``algorithm`` section: GA settings, local method, polish and start point."""

    kind: str = "ga"
    ga: GASettings = field(default_factory=GASettings)
    polish: str = "none"
    local: LocalSettings = field(default_factory=LocalSettings)
    start: dict = field(default_factory=dict)

    def resolved(self) -> dict:
        """The section as plain data, every default filled in (as results files store it)."""
        return {
            "kind": self.kind,
            **asdict(self.ga),
            "polish": self.polish,
            **asdict(self.local),
            "start": dict(self.start),
        }

    @classmethod
    def from_resolved(cls, data: dict) -> AlgorithmSpec:
        """The inverse of :meth:`resolved` (keys added since a file was written take
        their defaults)."""
        return cls(
            kind=data["kind"],
            ga=GASettings(**{k: data[k] for k in GA_KEYS if k in data}),
            polish=data["polish"],
            local=LocalSettings(
                **{f.name: data[f.name] for f in fields(LocalSettings) if f.name in data}
            ),
            start=dict(data.get("start") or {}),
        )


@dataclass
class Experiment:
    """A checked experiment (see the module docstring)."""

    name: str
    model: str
    target: TargetSpec
    free: dict  # name -> (lower, upper)
    fixed: dict = field(default_factory=dict)  # name -> value
    params: object = None  # base set: preset, file or mapping
    description: str = ""
    objective: Objective = field(default_factory=Objective)
    algorithm: AlgorithmSpec = field(default_factory=AlgorithmSpec)
    per_trial: bool = False
    pooled: bool = False
    method: str | None = None
    substeps: int | None = None
    output: str = "results"
    #: where the GA's evaluations run (:mod:`evo_door.optim.executors`); provenance,
    #: not part of the result, so not in :meth:`resolved`
    executor: str = "local"
    source: str = "<experiment>"
    text: str = ""
    overrides: list = field(default_factory=list)
    locs: dict = field(default_factory=dict)

    def uses(self) -> dict[str, str]:
        """The ``{from: STAGE}`` parameter sets still to fill in: location -> stage."""
        out = {}
        for spec in (self.params, self.target.params):
            if isinstance(spec, dict) and "from" in spec:
                out[spec["where"]] = spec["from"]
        return out

    def sources(self) -> dict[str, str]:
        """The ``{from: STAGE}`` parameter sets by key: ``params`` / ``target.params`` -> stage."""
        keys = (("params", self.params), ("target.params", self.target.params))
        return {
            key: spec["from"] for key, spec in keys if isinstance(spec, dict) and "from" in spec
        }

    def resolved(self) -> dict:
        """The configuration with every default filled in, as plain JSON-able data."""
        out = {
            "name": self.name,
            "description": self.description,
            "model": self.model,
            "params": self.params,
            "target": {k: v for k, v in asdict(self.target).items() if k != "locs"},
            "fixed": dict(self.fixed),
            "free": {k: list(v) for k, v in self.free.items()},
            "objective": asdict(self.objective),
            "algorithm": self.algorithm.resolved(),
            "per_trial": self.per_trial,
            "pooled": self.pooled,
            "simulation": {"method": self.method, "substeps": self.substeps},
            "output": self.output,
        }
        return json.loads(json.dumps(out))


# -- helpers ----------------------------------------------------------------------
class _Reader:
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
    p = Path(text).expanduser()
    candidates = [p] if p.is_absolute() else [base_dir / p, Path.cwd() / p]
    for c in candidates:
        if c.is_file():
            return str(c.resolve())
    tried = " or ".join(dict.fromkeys(str(c.resolve()) for c in candidates))
    raise UserError(f"{where}: {key}: file not found: {text} (looked for {tried})")


def _param_spec(reader: _Reader, key, base_dir: Path):
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


def _id_list(reader: _Reader, key, allow_all: bool):
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


def _kinds(t: _Reader) -> list:
    v = t.get("kinds", [])
    if isinstance(v, str):
        v = [v]
    if not isinstance(v, list) or not all(isinstance(k, str) for k in v):
        raise t.fail("kinds", f"expected a list of trial kinds (e.g. [impulse]), got {_show(v)}")
    if v and t.get("trials", "all") != "all":
        raise t.fail("kinds", "selects among trials: all; with a list of trial ids, leave it out")
    return list(v)


def _users(t: _Reader) -> list:
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


def executor_setting(reader: _Reader) -> str:
    """The ``executor`` key of an experiment or a pipeline (default ``local``), checked."""
    from evo_door.optim.executors import DEFAULT, check_executor

    value = reader.get("executor", DEFAULT)
    if not isinstance(value, str):
        raise reader.fail(
            "executor", f"expected a name (local, processes, dask), got {_show(value)}"
        )
    try:
        return check_executor(value)
    except UserError as exc:
        raise reader.fail("executor", str(exc).removeprefix("executor ")) from None


# -- the sections -----------------------------------------------------------------
def _preprocess(t: _Reader) -> PreprocessSpec:
    if "preprocess" not in t.node:
        return PreprocessSpec()
    p = _Reader(t.get("preprocess"), t.key_path("preprocess"), t.node.where("preprocess"))
    p.check_keys(PREPROCESS_KEYS)
    return PreprocessSpec(
        rate_bias=p.choice("rate_bias", "none", RATE_BIAS),
        lowpass=p.number("lowpass", None, lo=0.0, open_lo=True, allow_none=True),
        trim=p.boolean("trim", False),
    )


def _target(reader: _Reader, base_dir: Path) -> TargetSpec:
    node = reader.get("target")
    if node is None:
        raise UserError(
            f"{reader.node.loc}: target: required key missing "
            "(e.g. target: {data: FILE, trials: all})"
        )
    t = _Reader(node, "target", reader.node.where("target"))
    if "data" in t.node and "model" in t.node:
        raise t.fail(
            "model", "give either data (measured trials) or model (a target model), not both"
        )
    locs = {k: t.node.where(k) for k in t.node}
    locs.setdefault("trials", t.node.loc)
    locs.setdefault("validate", t.node.loc)
    locs.setdefault("kinds", t.node.loc)
    locs.setdefault("users", t.node.loc)
    if "data" in t.node:
        t.check_keys(DATA_TARGET_KEYS, required=("data",))
        path = _resolve_path(
            t.string("data", required=True), base_dir, t.node.where("data"), "target.data"
        )
        spec = TargetSpec(
            "data",
            trials=_id_list(t, "trials", True),
            kinds=_kinds(t),
            users=_users(t),
            validate=_id_list(t, "validate", False),
            data=path,
            preprocess=_preprocess(t),
            locs=locs,
        )
    elif "model" in t.node:
        t.check_keys(MODEL_TARGET_KEYS, required=("model", "inputs"))
        inputs = t.get("inputs")
        if isinstance(inputs, str):
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
        spec = TargetSpec(
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
    else:
        raise UserError(
            f"{t.node.loc}: target: give data: FILE (measured trials) or "
            "model: NAME with inputs: FILE (another model's response)"
        )
    if isinstance(spec.trials, list):
        both = [x for x in spec.validate if x in spec.trials]
        if both:
            raise t.fail("validate", f"trial {both[0]!r} is both fitted and validated")
    return spec


def _rig_spec(t: _Reader, node: LinedMap, base_dir: Path) -> dict:
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


def _objective(reader: _Reader) -> Objective:
    o = _Reader(reader.get("objective"), "objective", reader.node.where("objective"))
    o.check_keys(OBJECTIVE_KEYS)
    return Objective(
        kind=o.choice("kind", "max_square", tuple(KINDS)),
        derivative=o.choice("derivative", 1, (0, 1, 2)),
        combine=o.choice("combine", "sum", COMBINE),
    )


def _algorithm(reader: _Reader) -> AlgorithmSpec:
    a = _Reader(reader.get("algorithm"), "algorithm", reader.node.where("algorithm"))
    a.check_keys(ALGORITHM_KEYS)
    d = GASettings()
    for key in ("reproduction_ratio", "mutation_probability"):
        v = a.get(key)
        if isinstance(v, (int, float)) and not isinstance(v, bool) and 1 < v <= 100:
            raise a.fail(key, f"is a fraction in [0, 1]: AMESim's {v:g} % is {v / 100:g}")
    population = a.integer("population", d.population, lo=2)
    ga = GASettings(
        population=population,
        generations=a.integer("generations", d.generations, lo=0),
        reproduction_ratio=a.number("reproduction_ratio", d.reproduction_ratio, 0.0, 1.0),
        mutation_probability=a.number("mutation_probability", d.mutation_probability, 0.0, 1.0),
        mutation_amplitude=a.number("mutation_amplitude", d.mutation_amplitude, 0.0, open_lo=True),
        seed=a.integer("seed", d.seed, lo=0),
        elite=a.integer("elite", d.elite, lo=0, hi=population - 1),
        # the default tournament (3) shrinks to a smaller population; a given one must fit
        tournament=a.integer("tournament", min(d.tournament, population), lo=1, hi=population),
        crossover_eta=a.number("crossover_eta", d.crossover_eta, 0.0, open_lo=True),
        hall_of_fame=a.integer("hall_of_fame", d.hall_of_fame, lo=1),
        target_fitness=a.number("target_fitness", None, lo=0.0, allow_none=True),
        patience=(None if a.get("patience") is None else a.integer("patience", None, lo=1)),
    )
    ld = LocalSettings()
    local = LocalSettings(
        max_iterations=a.integer("max_iterations", ld.max_iterations, lo=1),
        ftol=a.number("ftol", ld.ftol, 0.0, open_lo=True),
    )
    kind = a.choice("kind", "ga", ALGORITHM_KINDS)
    polish = a.get("polish", "none")
    if polish is None or polish is False:
        polish = "none"
    if polish not in POLISH:
        raise a.fail(
            "polish",
            f"{polish!r} is not one of {', '.join(POLISH)}"
            + (suggest(polish, POLISH) if isinstance(polish, str) else ""),
        )
    if kind == "nlpql" and polish != "none":
        raise a.fail("polish", "kind nlpql is already the local method; leave polish out")
    start = a.get("start") or {}
    if not isinstance(start, dict):
        raise a.fail("start", "expected a mapping of free parameter names to start values")
    return AlgorithmSpec(
        kind=kind, ga=ga, polish=polish, local=local, start={str(k): v for k, v in start.items()}
    )


def _require_declared(where: str, name, model) -> None:
    if name not in model.params:
        raise UserError(
            f"{where}: model {model.name!r} has no parameter {name!r}"
            + suggest(str(name), model.params.names)
        )


def _check_parameters(exp: Experiment, reader: _Reader, model) -> None:
    """free / fixed / start against the model's declaration."""
    table = model.params
    fixed = reader.get("fixed") or LinedMap(loc=reader.node.loc)
    if not isinstance(fixed, LinedMap):
        raise reader.fail("fixed", "expected a mapping of parameter names to values")
    for name, value in fixed.items():
        where = f"{fixed.where(name)}: fixed.{name}"
        _require_declared(where, name, model)
        try:
            exp.fixed[name] = table[name].check(value)
        except UserError as exc:
            raise UserError(f"{where}: {exc}") from None
    free = reader.get("free")
    if not free:
        raise UserError(
            f"{reader.node.where('free')}: free: at least one free parameter "
            "is needed, as name: [lower, upper]"
        )
    if not isinstance(free, LinedMap):
        raise reader.fail("free", "expected a mapping name: [lower, upper]")
    for name, bounds in free.items():
        where = f"{free.where(name)}: free.{name}"
        _require_declared(where, name, model)
        if name in exp.fixed:
            raise UserError(
                f"{where}: {name!r} is also fixed (at {fixed.where(name)}); "
                "a parameter is either fixed or free"
            )
        if (
            not isinstance(bounds, list)
            or len(bounds) != 2
            or not all(
                isinstance(b, (int, float)) and not isinstance(b, bool) and math.isfinite(b)
                for b in bounds
            )
        ):
            raise UserError(
                f"{where}: expected [lower, upper], two finite numbers, got "
                f"{_show(bounds) if not isinstance(bounds, list) else bounds}"
            )
        lo, hi = map(float, bounds)
        p = table[name]
        if lo > hi:
            raise UserError(
                f"{where}: inverted bounds [{lo:g}, {hi:g}]: lower > upper (did you swap them?)"
            )
        if lo == hi:
            raise UserError(f"{where}: lower == upper == {lo:g}; write it under fixed instead")
        if lo < p.lower or hi > p.upper:
            raise UserError(
                f"{where}: [{lo:g}, {hi:g}] {p.unit} leaves the declared range "
                f"[{p.lower:g}, {p.upper:g}] {p.unit}"
            )
        exp.free[name] = (lo, hi)
    a = _Reader(reader.get("algorithm"), "algorithm", reader.node.where("algorithm"))
    start = a.get("start") or LinedMap()
    for name, value in exp.algorithm.start.items():
        where = f"{start.where(name) if isinstance(start, LinedMap) else a.node.loc}: algorithm.start.{name}"
        if name not in exp.free:
            raise UserError(
                f"{where}: {name!r} is not a free parameter" + suggest(name, list(exp.free))
            )
        lo, hi = exp.free[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
            raise UserError(f"{where}: start value {value!r} must be a number in [{lo:g}, {hi:g}]")
        exp.algorithm.start[name] = float(value)


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-") or "experiment"


def load_experiment(
    path=None, overrides=None, text: str | None = None, source: str | None = None, base_dir=None
) -> Experiment:
    """Read and check an experiment file (or ``text``), applying ``--set`` overrides.

    Parameters
    ----------
    path : str or Path, optional
        The YAML file. Relative file names inside it are looked up next to it first,
        then in the current folder.
    overrides : list of str
        ``KEY.PATH=VALUE`` assignments (``algorithm.seed=3``).
    text, source, base_dir :
        Parse ``text`` instead of a file (``source`` names it in messages).
    """
    if text is None:
        if path is None:
            raise ValueError("give path or text")
        p = Path(path)
        text = read_text(p, "experiment file")
        source = source or str(path)
        base_dir = p.resolve().parent if base_dir is None else Path(base_dir)
    source = source or "<experiment>"
    base_dir = Path(base_dir) if base_dir is not None else Path.cwd()
    tree = parse(text, source)
    if not isinstance(tree, LinedMap):
        raise UserError(f"{source}:1: an experiment is a mapping of keys ({', '.join(TOP_KEYS)})")
    overrides = list(overrides or [])
    for item in overrides:
        apply_override(tree, item)
    exp = experiment_from_tree(tree, text, source, base_dir, overrides)
    for where, stage in exp.uses().items():
        raise UserError(
            f"{where}: {{from: {stage}}} takes an earlier stage's best parameters: it "
            "belongs in a pipeline's stages (docs/case-study.md), not in an experiment"
        )
    return exp


def experiment_from_tree(
    tree: LinedMap, text: str, source: str, base_dir: Path, overrides=()
) -> Experiment:
    """The checked experiment of a parsed tree (a file's, or one stage of a pipeline).

    ``{from: STAGE}`` parameter sets are left as ``{"from": STAGE, "where": LOC}``
    (:meth:`Experiment.uses`) for the pipeline to fill in.
    """
    from evo_door.models import get_model, resolve_model_name

    if not isinstance(tree, LinedMap):
        raise UserError(f"{source}:1: an experiment is a mapping of keys ({', '.join(TOP_KEYS)})")
    overrides = list(overrides)
    r = _Reader(tree, "", tree.loc)
    r.check_keys(TOP_KEYS, required=("model", "target", "free"))
    model_name = resolve_model_name(r.string("model", required=True), base_dir)
    try:
        model = get_model(model_name)
    except UserError as exc:
        raise UserError(f"{tree.where('model')}: model: {exc}") from None
    default_name = Path(source).stem if source and not source.startswith("<") else "experiment"
    name = r.string("name", default_name)
    sim = _Reader(r.get("simulation"), "simulation", tree.where("simulation"))
    sim.check_keys(SIMULATION_KEYS)
    method = sim.choice("method", model.method, tuple(METHODS))
    substeps = sim.integer("substeps", model.substeps, lo=1, hi=1000)
    exp = Experiment(
        name=_safe_name(name),
        model=model_name,
        target=_target(r, base_dir),
        free={},
        params=_param_spec(r, "params", base_dir),
        description=r.string("description", "") or "",
        objective=_objective(r),
        algorithm=_algorithm(r),
        per_trial=r.boolean("per_trial", False),
        pooled=r.boolean("pooled", False),
        method=method,
        substeps=substeps,
        output=r.string("output", "results"),
        executor=executor_setting(r),
        source=source,
        text=text,
        overrides=overrides,
        locs={k: tree.where(k) for k in TOP_KEYS},
    )
    _check_parameters(exp, r, model)
    if exp.target.kind == "model":
        try:
            get_model(exp.target.model)
        except UserError as exc:
            raise UserError(f"{exp.target.locs['model']}: target.model: {exc}") from None
    return exp
