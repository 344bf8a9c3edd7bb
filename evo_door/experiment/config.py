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

The sections have modules of their own: reading a key and locating its errors
(:mod:`~evo_door.experiment.config_reader`), the target
(:mod:`~evo_door.experiment.config_target`), the objective and the algorithm
(:mod:`~evo_door.experiment.config_algorithm`). This module holds the experiment
itself, its parameters (free, fixed, start) and the loading.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

from evo_door.errors import UserError
from evo_door.experiment.config_algorithm import AlgorithmSpec, _algorithm, _objective
from evo_door.experiment.config_reader import (
    KeyReader,
    _param_spec,
    _resolve_path,
    _show,
    executor_setting,
)
from evo_door.experiment.config_target import TargetSpec, _target
from evo_door.experiment.yamltree import LinedMap, apply_override, parse
from evo_door.files import read_text
from evo_door.optim.problem import Objective
from evo_door.params.declaration import suggest
from evo_door.sim_settings import METHODS, tolerance_of

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
    "perception",
    "channels",
    "process",
)
SIMULATION_KEYS = ("method", "substeps", "tolerance", "time_limit")


@dataclass
class ExperimentConfig:
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
    #: ``dopri5``'s tolerance per step (``tol (1 + |x|)``, rad and rad/s)
    tolerance: float | None = None
    #: s: the longest one candidate's evaluation may take, for a model that runs native
    #: code of its own (an FMU; :mod:`evo_door.optim.sandbox`); None: the default
    time_limit: float | None = None
    output: str = "results"
    #: the just-noticeable differences a feel is judged with (:class:`~evo_door.perception.JND`
    #: settings by name; the defaults where left out)
    perception: dict = field(default_factory=dict)
    #: where each setting of ``perception`` comes from (the file and line, a table's
    #: source, a JND file's session), by name; the others are the literature's defaults
    perception_sources: dict = field(default_factory=dict)
    #: the supplier's process of a fit to a chosen feel: every built parameter of the
    #: model -> ``{"tolerance": "10 %" or a half-width, "distribution", "source"}``
    #: (:mod:`evo_door.optim.process`; the kinds' defaults where ``process:`` is silent);
    #: {} for another fit
    process: dict = field(default_factory=dict)
    #: the entries ``process:`` itself sets (a pipeline's table gives the rest)
    process_given: dict = field(default_factory=dict)
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

    def jnd(self):
        """The :class:`~evo_door.perception.JND` this experiment judges a feel with."""
        from evo_door.perception import JND

        return JND.from_mapping(self.perception)

    def jnd_sources(self) -> dict[str, str]:
        """Where each JND setting comes from, by name (:meth:`jnd`'s settings)."""
        from evo_door.experiment.feel_check import default_source
        from evo_door.perception import JND

        return {k: self.perception_sources.get(k) or default_source(k) for k in JND().as_dict()}

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
            "simulation": {
                "method": self.method,
                "substeps": self.substeps,
                "tolerance": self.tolerance,
            },
            "output": self.output,
            "perception": self.jnd().as_dict(),
            # provenance of the settings above (a resumed run compares the values only)
            "perception_sources": self.jnd_sources(),
        }
        if self.objective.perceptual:
            # the supplier's tolerances the yield of the answer is estimated with
            out["process"] = {"entries": self.process}
        return json.loads(json.dumps(out))


def _with_channels(r: KeyReader, tree: LinedMap) -> str:
    """``model:`` with the FMU channel mapping of ``channels:`` added to its name
    (``x.fmu?force=F&theta=angle``): the name a results file and a worker find it by."""
    from evo_door.models.fmu import is_fmu_spec, join_spec, split_spec

    name = r.string("model", required=True)
    channels = r.get("channels")
    if channels is None:
        return name
    if not is_fmu_spec(name):
        raise UserError(
            f"{tree.where('channels')}: channels: maps an FMU's variables to the trial's "
            f"channels; model {name!r} is not an FMU"
        )
    if not isinstance(channels, LinedMap) or not all(isinstance(v, str) for v in channels.values()):
        raise r.fail("channels", "expected a mapping channel: VARIABLE (force: F_hand, ...)")
    path, interface, mapping = split_spec(name)
    mapping.update({str(k): v for k, v in channels.items()})
    return join_spec(path, interface, mapping)


def _require_declared(where: str, name, model) -> None:
    if name not in model.params:
        why = model.plant.not_a_parameter(str(name))
        if why:  # a variable of the model that is no real, settable parameter (an FMU's)
            raise UserError(f"{where}: {why}")
        raise UserError(
            f"{where}: model {model.name!r} has no parameter {name!r}"
            + suggest(str(name), model.params.names)
        )


def perception_setting(r: KeyReader, base_dir: Path) -> tuple[dict, dict]:
    """The ``perception`` section: JND settings by name, checked (:class:`JND`), and
    the source of each one it sets.

    A setting is a number (its source: this file and line), a table entry
    ``{weber: W, source: TEXT}`` of a Weber fraction, or measured by one of the JND
    files of ``files:`` (paths next to the YAML file; several on one setting give the
    geometric mean, :func:`~evo_door.perception.jnd_file.measured_jnd`). One setting is
    given one way; a conflict or a file that cannot set a JND is one line naming the
    file and line.
    """
    from evo_door.perception import JND

    node = r.get("perception")
    if node is None:
        return {}, {}
    if not isinstance(node, dict):
        raise r.fail("perception", "expected a mapping of JND settings (e.g. force: 0.1)")
    p = KeyReader(node, "perception", r.node.where("perception"))
    names = list(JND().as_dict())
    p.check_keys((*names, "files"))
    values, sources, table = {}, {}, {}
    for k in node:  # each setting checked alone, so that its error names its own line
        if k == "files":
            continue
        if isinstance(node[k], dict):
            table[k] = _weber_entry(p, k)
            continue
        values[k] = p.number(k, None, lo=0.0, open_lo=True)
        try:
            JND.from_mapping({k: values[k]})
        except UserError as exc:
            raise p.fail(k, f"{str(exc).split(': ', 1)[-1]}, got {values[k]:g}") from None
        sources[k] = f"set in {p.node.where(k)}"
    files = _jnd_files(p, base_dir, set(values) | set(table))
    if files or table:
        measured, measured_sources = _measured(files, table)
        for k in (*table, *(s for _, s in files)):
            values[k] = getattr(measured, k)
            sources[k] = measured_sources[k]
    return values, sources


def _weber_entry(p: KeyReader, key: str) -> dict:
    """A table entry ``{weber: W, source: TEXT}`` of the Weber setting ``key``, checked;
    its source says where it was given."""
    from evo_door.perception.jnd_file import WEBER_SETTINGS

    if key not in WEBER_SETTINGS:
        raise p.fail(
            key,
            "{weber: W, source: TEXT} sets a Weber fraction "
            f"({', '.join(WEBER_SETTINGS)}); {key} is a number",
        )
    entry = p.get(key)
    where = entry.where if isinstance(entry, LinedMap) else (lambda _k: p.node.where(key))
    if set(entry) - {"weber", "source"} or "weber" not in entry:
        raise p.fail(key, f"expected {{weber: W, source: TEXT}}, got keys {', '.join(entry)}")
    w = entry["weber"]
    if isinstance(w, bool) or not isinstance(w, (int, float)) or not 0.0 < w < 1.0:
        raise UserError(
            f"{where('weber')}: perception.{key}.weber: {_show(w)}: a Weber fraction "
            "between 0 and 1 (0.3 is 30 %)"
        )
    source = entry.get("source")
    if source is not None and (not isinstance(source, str) or not source.strip()):
        raise UserError(
            f"{where('source')}: perception.{key}.source: expected a text (who "
            f"measured it, how), got {_show(source)}"
        )
    return {
        "weber": float(w),
        "source": f"{source or 'no source given'} (table at {p.node.where(key)})",
    }


def _jnd_files(p: KeyReader, base_dir: Path, given: set) -> list[tuple[str, str]]:
    """``perception.files``: each JND file found next to the YAML file and checked
    (complete, a unit with a JND setting, a bounded estimate below 1): (path, setting).
    A setting the section also gives as a number or a table entry is refused."""
    from evo_door.perception.jnd_file import read_jnd_file, usable_weber

    node = p.get("files")
    if node is None:
        return []
    items = [node] if isinstance(node, str) else node
    if not isinstance(items, list) or not items or not all(isinstance(x, str) for x in items):
        raise p.fail("files", f"expected a list of JND files (jnd/p01-force.h5), got {_show(node)}")
    where = p.node.where("files")
    out = []
    for i, text in enumerate(items):
        key = f"perception.files[{i}]"
        path = _resolve_path(text, base_dir, where, key)
        try:
            record = read_jnd_file(path)
            usable_weber(record)
        except UserError as exc:
            raise UserError(f"{where}: {key}: {exc}") from None
        setting = str(record.setting)
        if setting in given:
            raise UserError(
                f"{where}: {key}: {Path(text).name} measures the {setting} JND, which "
                f"perception.{setting} sets too (at {p.node.where(setting)}); give it once"
            )
        out.append((path, setting))
    return out


def _measured(files: list[tuple[str, str]], table: dict):
    """The JND settings measured by ``files`` and given by ``table``, with their sources."""
    from evo_door.perception import JND
    from evo_door.perception.jnd_file import measured_jnd

    return measured_jnd(JND(), [f for f, _ in files], table)


def _check_perceptual(exp: ExperimentConfig) -> None:
    """The perceptual objective needs a chosen feel; a model target without one needs inputs."""
    t = exp.target
    if exp.objective.perceptual and t.kind == "data":
        raise UserError(
            f"{exp.locs['objective']}: objective.kind perceptual: scores a feel against a "
            "chosen one; measured trials are not one (target: curve: FILE.csv, or model:)"
        )
    if exp.algorithm.kind == "nsga2":
        where = exp.locs["algorithm"]
        if not exp.objective.perceptual:
            raise UserError(
                f"{where}: algorithm.kind nsga2: trades the perceptual error against the "
                "change from the AS-IS door; it needs a chosen feel (target: curve: FILE.csv, "
                "or model: without inputs; objective.kind perceptual)"
            )
        if exp.per_trial:
            raise UserError(
                f"{exp.locs['per_trial']}: per_trial: a chosen feel is one target; "
                "algorithm.kind nsga2 makes one front of it (leave per_trial out)"
            )
    if t.kind == "model" and t.inputs is None and not exp.objective.perceptual:
        raise UserError(
            f"{t.locs['model']}: target.inputs: required key missing (the input forces the "
            "target model is driven by; only the perceptual objective needs none)"
        )


def _process(exp: ExperimentConfig, r: KeyReader, base_dir: Path, model) -> None:
    """``process``: the supplier's tolerances, for a fit to a chosen feel only."""
    from evo_door.experiment.config_process import process_given, process_table

    if "process" in r.node and not exp.objective.perceptual:
        raise r.fail(
            "process",
            "the supplier's tolerances serve a fit to a chosen feel (objective.kind "
            f"perceptual), whose yield they estimate; objective.kind {exp.objective.kind} "
            "would ignore them",
        )
    if exp.objective.perceptual:
        exp.process_given = process_given(r, base_dir, model)
        exp.process = process_table(model, exp.process_given)


def _check_parameters(exp: ExperimentConfig, reader: KeyReader, model) -> None:
    """free / fixed / start against the model's declaration."""
    fixed = _check_fixed(exp, reader, model)
    _check_free(exp, reader, model, fixed)
    _check_start(exp, reader)


def _check_fixed(exp: ExperimentConfig, reader: KeyReader, model) -> LinedMap:
    """``fixed``: each value checked by its declaration into ``exp.fixed``; the section
    returned (the free parameters' check names the line of a parameter also fixed)."""
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
    return fixed


def _check_free(exp: ExperimentConfig, reader: KeyReader, model, fixed: LinedMap) -> None:
    """``free``: at least one, each declared, not fixed too, its bounds into ``exp.free``."""
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
        exp.free[name] = _free_bounds(where, bounds, model.params[name])


def _free_bounds(where: str, bounds, p) -> tuple[float, float]:
    """``[lower, upper]`` of one free parameter: two finite numbers, in order, apart,
    within the declared range of ``p``."""
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
    return lo, hi


def _check_start(exp: ExperimentConfig, reader: KeyReader) -> None:
    """``algorithm.start``: each a free parameter, its value within the free bounds."""
    a = KeyReader(reader.get("algorithm"), "algorithm", reader.node.where("algorithm"))
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


def _tolerance(sim: KeyReader, model) -> float:
    """``simulation.tolerance``: ``dopri5``'s tolerance, a number in (0, 1) (default the
    model's)."""
    from evo_door.sim.simulate import TOLERANCE_FLOOR

    value = sim.number("tolerance", tolerance_of(model))
    if not TOLERANCE_FLOOR <= value < 1.0:
        raise sim.fail(
            "tolerance",
            f"must be a number in [{TOLERANCE_FLOOR:g}, 1) (dopri5's per step: below it, "
            f"double precision cannot meet it and the run would not end), got {value:g}",
        )
    return value


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-") or "experiment"


def load_experiment(
    path=None, overrides=None, text: str | None = None, source: str | None = None, base_dir=None
) -> ExperimentConfig:
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
) -> ExperimentConfig:
    """The checked experiment of a parsed tree (a file's, or one stage of a pipeline).

    ``{from: STAGE}`` parameter sets are left as ``{"from": STAGE, "where": LOC}``
    (:meth:`ExperimentConfig.uses`) for the pipeline to fill in.
    """
    from evo_door.models import get_model, resolve_model_name

    if not isinstance(tree, LinedMap):
        raise UserError(f"{source}:1: an experiment is a mapping of keys ({', '.join(TOP_KEYS)})")
    overrides = list(overrides)
    r = KeyReader(tree, "", tree.loc)
    r.check_keys(TOP_KEYS, required=("model", "target", "free"))
    model_name = resolve_model_name(_with_channels(r, tree), base_dir)
    try:
        model = get_model(model_name)
        model.plant.check_ready()  # an FMU: its channels must match before anything runs
    except UserError as exc:
        raise UserError(f"{tree.where('model')}: model: {exc}") from None
    default_name = Path(source).stem if source and not source.startswith("<") else "experiment"
    name = r.string("name", default_name)
    sim = KeyReader(r.get("simulation"), "simulation", tree.where("simulation"))
    sim.check_keys(SIMULATION_KEYS)
    method = sim.choice("method", model.method, tuple(METHODS))
    substeps = sim.integer("substeps", model.substeps, lo=1, hi=1000)
    tolerance = _tolerance(sim, model)
    time_limit = sim.number("time_limit", 0.0) or None
    if time_limit is not None and time_limit <= 0.0:
        raise sim.fail("time_limit", f"must be a time in s above 0, got {time_limit:g}")
    exp = ExperimentConfig(
        name=_safe_name(name),
        model=model_name,
        target=_target(r, base_dir),
        free={},
        params=_param_spec(r, "params", base_dir),
        description=r.string("description", "") or "",
        objective=_objective(
            r, curve_target=isinstance(r.get("target"), dict) and "curve" in r.get("target")
        ),
        algorithm=_algorithm(r),
        per_trial=r.boolean("per_trial", False),
        pooled=r.boolean("pooled", False),
        method=method,
        substeps=substeps,
        tolerance=tolerance,
        time_limit=time_limit,
        output=r.string("output", "results"),
        executor=executor_setting(r),
        source=source,
        text=text,
        overrides=overrides,
        locs={k: tree.where(k) for k in TOP_KEYS},
    )
    exp.perception, exp.perception_sources = perception_setting(r, base_dir)
    _check_parameters(exp, r, model)
    _check_perceptual(exp)
    _process(exp, r, base_dir, model)
    if exp.objective.perceptual:
        try:
            model.plant.check_curve("the perceptual objective")
        except UserError as exc:
            raise UserError(
                f"{tree.where('objective')}: objective perceptual: {exc}; fit it to trials "
                "(ise, max_square)"
            ) from None
    if exp.target.kind == "model":
        try:
            get_model(exp.target.model)
        except UserError as exc:
            raise UserError(f"{exp.target.locs['model']}: target.model: {exc}") from None
    return exp
