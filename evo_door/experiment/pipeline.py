"""Pipelines: several experiments run as stages of one job, written to one results file.

The case study (``experiments/case_study.yaml``, ``docs/case-study.md``) is a chain of
estimations where each stage starts from what an earlier one found: the door's
specifications from the measurements, the haptic model from the door, the specification
from the chosen haptic behaviour. A pipeline file lists the stages, each an experiment
written inline or named by file::

    name: case-study
    stages:
      physical: experiments/default.yaml          # an experiment file
      haptic:                                     # or an experiment, inline
        model: haptic
        target: {model: door, params: {from: physical}, inputs: {...}}
        free: {inertia: [0.5, 3.0], ...}

``{from: STAGE}`` in ``params`` or ``target.params`` stands for the full parameter set
an earlier stage ended with (its free parameters' answer, everything else as it was in
that stage). Everything is checked before the first stage starts: every stage as an
experiment, every ``from`` naming an earlier stage of the same model.

The results file holds one group per stage, ``stages/<name>``, each laid out exactly as
a single run's file (:mod:`.store`), so everything that reads a run reads a stage
(``Results(path, stage=...)``); the root says which stages there are and how far the
pipeline got. Each stage checkpoints the whole file as a run does (a generation at most
every :data:`~evo_door.experiment.checkpoint.CHECKPOINT_EVERY` seconds, every job; the
finished stages are copied over unchanged), so a killed pipeline resumes at the stage
and generation of its last checkpoint and ends with the numbers of an
uninterrupted one.
"""

from __future__ import annotations

import contextlib
import json
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from evo_door.errors import UserError
from evo_door.experiment import store
from evo_door.experiment.checkpoint import CHECKPOINT_EVERY, stage_position, write_checkpoint
from evo_door.experiment.config import (
    ExperimentConfig,
    _safe_name,
    experiment_from_tree,
    perception_setting,
)
from evo_door.experiment.config_reader import KeyReader, _resolve_path, executor_setting
from evo_door.experiment.run_preflight import _LOCKED, claim_output, default_output
from evo_door.experiment.runner import ExperimentRun
from evo_door.experiment.yamltree import LinedMap, apply_override, parse
from evo_door.files import ATTRS, FileLock, Keep, fields, read_text, remove_stale_temporaries
from evo_door.params.declaration import suggest

PIPELINE_KEYS = (
    "name",
    "description",
    "stages",
    "output",
    "report",
    "executor",
    "perception",
    "process",
)
#: settings of ``evo-door report`` a pipeline file may give (the command line wins)
REPORT_KEYS = ("jnd", "force_floor")
FORMAT_VERSION = 1


@dataclass
class Stage:
    """One stage: its name and its checked experiment (``{from: ...}`` not filled in yet)."""

    name: str
    experiment: ExperimentConfig
    where: str  # file:line of the stage in the pipeline file

    def sources(self) -> dict[str, str]:
        """Which earlier stage each ``{from: STAGE}`` names: ``params`` (the values the
        stage starts from) and ``target.params`` (what it is fitted to) -> stage name.

        The provenance a results file records (:meth:`PipelineConfig.resolved`); the stage's
        experiment is never filled in place (:func:`fill` makes a copy), so this holds
        before, during and after a run.
        """
        return self.experiment.sources()

    def uses(self) -> list[str]:
        """The earlier stages this one takes parameters from."""
        return sorted(set(self.sources().values()))


@dataclass
class PipelineConfig:
    """A checked pipeline file (see the module docstring)."""

    name: str
    stages: list[Stage]
    description: str = ""
    output: str = "results"
    report: dict = field(default_factory=dict)
    source: str = "<pipeline>"
    text: str = ""
    overrides: list = field(default_factory=list)
    base_dir: str = "."
    #: where every stage's GA runs (None: each stage's own ``executor``, else local)
    executor: str | None = None

    def stage(self, name: str) -> Stage:
        return next(s for s in self.stages if s.name == name)

    def resolved(self) -> dict:
        return {
            "name": self.name,
            "description": self.description,
            "output": self.output,
            "report": self.report,
            "stages": {
                s.name: {"uses": s.uses(), "from": s.sources(), "where": s.where}
                for s in self.stages
            },
        }


def is_pipeline(path) -> bool:
    """Whether the YAML file ``path`` is a pipeline (it has ``stages``), not an experiment."""
    p = Path(path)
    if p.suffix.lower() not in (".yaml", ".yml") or not p.is_file():
        return False
    try:
        tree = parse(read_text(p, "experiment file"), str(path))
    except UserError:
        return False  # load_experiment says what is wrong with it
    return isinstance(tree, LinedMap) and "stages" in tree


def load_pipeline(path=None, overrides=(), text=None, source=None, base_dir=None) -> PipelineConfig:
    """Read and check a pipeline file; ``--set`` overrides take the stage's name first
    (``stages.physical.algorithm.seed=3``) or a top-level key."""
    if text is None:
        p = Path(path)
        text = read_text(p, "pipeline file")
        source = source or str(path)
        base_dir = p.resolve().parent if base_dir is None else Path(base_dir)
    source = source or "<pipeline>"
    base_dir = Path(base_dir) if base_dir is not None else Path.cwd()
    tree = parse(text, source)
    overrides = list(overrides)
    for item in overrides if isinstance(tree, LinedMap) else ():
        apply_override(tree, item)
    return pipeline_from_tree(tree, text, source, base_dir, overrides)


def pipeline_from_tree(
    tree, text: str, source: str, base_dir: Path, overrides=()
) -> PipelineConfig:
    """The checked pipeline of a parsed tree (a file's, or the Python API's arguments)."""
    if not isinstance(tree, LinedMap):
        raise UserError(f"{source}:1: a pipeline is a mapping of keys ({', '.join(PIPELINE_KEYS)})")
    overrides = list(overrides)
    r = KeyReader(tree, "", tree.loc)
    r.check_keys(PIPELINE_KEYS, required=("stages",))
    node = tree["stages"]
    if not isinstance(node, LinedMap) or not node:
        raise r.fail("stages", "expected a mapping of stage names to experiments (inline or files)")
    default_name = Path(source).stem if not source.startswith("<") else "pipeline"
    rep = KeyReader(r.get("report"), "report", tree.where("report"))
    rep.check_keys(REPORT_KEYS)
    report = {}
    if "jnd" in rep.node:
        report["jnd"] = rep.number("jnd", None, lo=0.0, hi=1.0, open_lo=True)
    if "force_floor" in rep.node:
        report["force_floor"] = rep.number("force_floor", None, lo=0.0, open_lo=True)
    pipe = PipelineConfig(
        name=_safe_name(r.string("name", default_name)),
        stages=[],
        description=r.string("description", "") or "",
        output=r.string("output", "results"),
        report=json.loads(json.dumps(report)),
        source=source,
        text=text,
        overrides=overrides,
        base_dir=str(base_dir),
        executor=executor_setting(r) if "executor" in tree else None,
    )
    # the JND settings of every stage, which a stage's own perception: overrides
    perception, perception_sources = perception_setting(r, base_dir)
    for name, value in node.items():
        where = node.where(name)
        if not isinstance(name, str) or _safe_name(name) != name:
            raise UserError(f"{where}: stages: {name!r}: name stages with letters, digits, - _ .")
        exp = _stage_experiment(name, value, where, base_dir)
        exp.perception = {**perception, **exp.perception}
        exp.perception_sources = {**perception_sources, **exp.perception_sources}
        pipe.stages.append(Stage(name, exp, where))
    _process(pipe, r, base_dir)
    _check_uses(pipe)
    return pipe


def _process(pipe: PipelineConfig, r: KeyReader, base_dir: Path) -> None:
    """The pipeline's ``process``: the supplier's tolerances of every stage fitted to a
    chosen feel whose model has built parameters (a haptic model's are sensations); a
    stage's own entries win, name by name."""
    from evo_door.experiment.config_process import has_built, process_given, process_table
    from evo_door.models import get_model

    if "process" not in r.node:
        return
    taken = False
    for stage in pipe.stages:
        exp = stage.experiment
        if not exp.objective.perceptual:
            continue
        model = get_model(exp.model)
        if not has_built(model):
            continue
        try:
            given = process_given(r, base_dir, model)
        except UserError as exc:
            raise UserError(f"{exc} (in stage {stage.name})") from None
        exp.process_given = {**given, **exp.process_given}
        exp.process = process_table(model, exp.process_given)
        taken = True
    if not taken:
        raise r.fail(
            "process",
            "the supplier's tolerances serve the stages fitted to a chosen feel "
            "(objective.kind perceptual) of a model with built parameters; no stage is one",
        )


def _stage_experiment(name: str, value, where: str, base_dir: Path) -> ExperimentConfig:
    if isinstance(value, str):
        file = Path(_resolve_path(value, base_dir, where, f"stages.{name}"))
        text = read_text(file, "experiment file")
        exp = experiment_from_tree(parse(text, str(file)), text, str(file), file.parent)
    elif isinstance(value, LinedMap):
        import yaml

        text = yaml.safe_dump(json.loads(json.dumps(value, default=repr)), sort_keys=False)
        exp = experiment_from_tree(value, text, where, base_dir)
        if "name" not in value:
            exp.name = name
    else:
        raise UserError(f"{where}: stages.{name}: expected an experiment (a mapping) or its file")
    return exp


def _model_name(name: str) -> str:
    from evo_door.models import get_model

    return get_model(name).name


def _check_uses(pipe: PipelineConfig) -> None:
    """Every ``{from: S}`` names an earlier stage whose model is the one it feeds."""
    seen: dict[str, Stage] = {}
    for stage in pipe.stages:
        exp = stage.experiment
        for spec, model in ((exp.params, exp.model), (exp.target.params, exp.target.model)):
            if not (isinstance(spec, dict) and "from" in spec):
                continue
            source = spec["from"]
            if source not in seen:
                later = any(s.name == source for s in pipe.stages)
                raise UserError(
                    f"{spec['where']}: from: {source!r} is "
                    + (
                        "a later stage: a stage takes parameters from earlier ones"
                        if later
                        else "not a stage of this pipeline; stages: "
                        + ", ".join(s.name for s in pipe.stages)
                    )
                )
            given = seen[source].experiment.model
            if _model_name(given) != _model_name(model):
                raise UserError(
                    f"{spec['where']}: from: {source!r} is a fit of model {given!r}, "
                    f"but these parameters are for model {model!r}"
                )
        seen[stage.name] = stage


def fill(exp: ExperimentConfig, values: dict[str, dict]) -> ExperimentConfig:
    """A copy of ``exp`` with each ``{from: S}`` replaced by ``values[S]`` (name -> value).

    ``exp`` itself keeps its ``{from: S}``: the pipeline records from it which stages
    each stage started from (a stage filled in place would forget it).
    """
    params, target = exp.params, exp.target
    if isinstance(params, dict) and "from" in params:
        params = dict(values[params["from"]])
    if isinstance(target.params, dict) and "from" in target.params:
        target = replace(target, params=dict(values[target.params["from"]]))
    return replace(exp, params=params, target=target)


def stage_loader(path, stage: str, results=None):
    """``loader(overrides) -> ExperimentConfig``: one stage of the pipeline file ``path`` as an
    experiment of its own (``--set`` assignments apply to the stage), its ``{from: S}``
    filled in from the stages of the results file ``results``."""
    from evo_door.experiment.results import Results

    def load(overrides=()):
        pipe = load_pipeline(path, [f"stages.{stage}.{o}" for o in overrides])
        names = [s.name for s in pipe.stages]
        if stage not in names:
            raise UserError(
                f"{path}: no stage {stage!r}; stages: {', '.join(names)}" + suggest(stage, names)
            )
        exp = pipe.stage(stage).experiment
        uses = pipe.stage(stage).uses()
        if uses and results is None:
            raise UserError(
                f"{path}: stage {stage!r} starts from stage(s) {', '.join(uses)}: give the "
                "results file of a run of the pipeline (--from RUN.h5)"
            )
        return fill(exp, {name: Results(results, name).values() for name in uses})

    return load


class PipelineRun:
    """A run of a pipeline, backed by its results file (see the module docstring).

    Build one with :meth:`create` or :meth:`open` (to resume), then :meth:`run`.
    """

    def __init__(self, pipeline: PipelineConfig, path, created: str, versions: dict):
        self.pipeline = pipeline
        self.path = Path(path)
        self.created = created
        self.versions = versions
        self.done: list[str] = []  # stages complete in the file
        self.current: ExperimentRun | None = None  # a stage started and not finished
        self.status = "running"
        self.elapsed_before = 0.0
        self._t0 = time.perf_counter()
        self._lock: FileLock | None = None
        #: the executor of every stage (``--executor``, the file's ``executor``), or
        #: None: each stage's own
        self.executor: str | None = pipeline.executor
        self.on_disk: str | None = None  # where the file's last checkpoint stands, if any
        #: seconds between a GA's checkpoints in every stage (ExperimentRun's)
        self.checkpoint_every = CHECKPOINT_EVERY

    @property
    def stage_names(self) -> list[str]:
        return [s.name for s in self.pipeline.stages]

    # -- construction --------------------------------------------------------------------
    @classmethod
    def create(cls, pipeline: PipelineConfig, out=None, overwrite: bool = False) -> PipelineRun:
        """A new run of ``pipeline`` writing ``out`` (locked until :meth:`run` ends)."""

        def start(path: Path, lock: FileLock) -> PipelineRun:
            run = cls(pipeline, path, ExperimentRun.now(), store.versions())
            run._lock = lock
            run.write()
            return run

        return claim_output(Path(out) if out else default_output(pipeline), overwrite, start)

    @classmethod
    def open(cls, path) -> PipelineRun:
        """The pipeline in ``path``, to resume it (locked like :meth:`create`)."""
        path = Path(path)
        lock = FileLock(path).acquire(_LOCKED)
        try:
            attrs = store.pipeline_attrs(path)
            if attrs is None:
                raise UserError(f"{path}: holds one run, not a pipeline")
            tree = _read_head(path)
            head = tree["pipeline"][ATTRS]
            text = fields.text(tree["pipeline"], "text")
            source, base_dir = fields.text(head, "source"), fields.text(head, "base_dir")
            overrides = fields.texts(head, "overrides")
            try:
                pipeline = load_pipeline(
                    text=text, source=source, base_dir=base_dir, overrides=overrides
                )
            except UserError as exc:
                raise UserError(
                    f"{path}: cannot resume: the pipeline's stages no longer load ({exc})"
                ) from None
            run = cls(pipeline, path, fields.text(attrs, "created"), tree["versions"][ATTRS])
            run.elapsed_before = fields.number(attrs, "total_s", 0.0)
            run.executor = fields.text(attrs, "executor", "") or pipeline.executor
            for name in attrs["started"]:
                stage = store.peek(path, name)
                if stage[ATTRS].get("status") == "complete" and stage["best"] is not None:
                    run.done.append(name)
                else:
                    run.current = ExperimentRun.from_tree(store.read_tree(path, name), path)
            if len(run.done) == len(pipeline.stages) and attrs.get("status") == "complete":
                run.status = "complete"
            run._lock = lock
            run.on_disk = stage_position(run.stage_names, run.done, run.current)
            remove_stale_temporaries(path)
        except BaseException:
            lock.release()
            raise
        if run.status == "complete":
            run.release()
        return run

    # -- running -------------------------------------------------------------------------
    def run(self, progress: bool = False, on_checkpoint=None, executor=None) -> PipelineRun:
        """Run (or continue) every stage; ``on_checkpoint(run, job)`` as for a run.

        ``executor`` (a name, or an executor already started) replaces the pipeline's;
        one executor serves all the stages (one started here is closed at the end).
        """
        from evo_door.optim.executors import Executor, check_executor, open_executor

        if isinstance(executor, Executor):
            self.executor = executor.name
        elif executor is not None:
            self.executor = check_executor(executor)
        left = any(s.name not in self.done for s in self.pipeline.stages)
        if isinstance(executor, Executor):
            shared = contextlib.nullcontext(executor)
        elif self.executor is not None and left:
            shared = open_executor(self.executor)
        else:
            shared = contextlib.nullcontext(None)
        try:
            with shared as ex:
                self._run_stages(progress, on_checkpoint, ex)
        finally:
            self.release()
        return self

    def _run_stages(self, progress: bool, on_checkpoint, ex) -> None:
        n = len(self.pipeline.stages)
        for k, stage in enumerate(self.pipeline.stages, 1):
            if stage.name in self.done:
                continue
            run = self.current
            if run is None or run.config["name"] != stage.experiment.name:
                run = self._start(stage)
            self.current = run
            run.writer = self._writer(stage.name)
            run.checkpoint_every = self.checkpoint_every
            run.label_prefix = f"stage {k}/{n} " if n > 1 else ""
            if progress:
                print(self._stage_line(k, stage, run), file=sys.stderr, flush=True)
            run.run(progress=progress, on_checkpoint=on_checkpoint, executor=ex)
            self.done.append(stage.name)
            self.current = None
        self.status = "complete"
        self.write()

    def _start(self, stage: Stage) -> ExperimentRun:
        """A stage's run, its ``{from: ...}`` filled in from the finished stages (their
        values only, read without their arrays)."""
        from evo_door.experiment.reader import read_run
        from evo_door.experiment.results import Results

        values = {
            name: Results.of(read_run(self.path, name, arrays=False)).values()
            for name in stage.uses()
        }
        exp = fill(stage.experiment, values)
        try:
            return ExperimentRun.new(exp, self.path, versions=self.versions)
        except UserError as exc:
            raise UserError(f"stage {stage.name}: {exc}") from None

    def _stage_line(self, k: int, stage: Stage, run: ExperimentRun) -> str:
        s = run.setup
        uses = f", from {', '.join(stage.uses())}" if stage.uses() else ""
        return (
            f"stage {k}/{len(self.pipeline.stages)} {stage.name}: model {s.model_name}, "
            f"{len(s.fit)} fitted trial(s), free: {', '.join(s.free)}{uses}"
        )

    def release(self) -> None:
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    # -- the file ------------------------------------------------------------------------
    def elapsed(self) -> float:
        return self.elapsed_before + (time.perf_counter() - self._t0)

    def _writer(self, name: str):
        def write(tree: dict) -> None:
            self.write({name: tree})

        return write

    def write(self, trees: dict | None = None) -> None:
        """The whole file: the finished stages copied, ``trees`` (stage -> run tree) new."""
        trees = dict(trees or {})
        stages = {name: Keep(_must_exist) for name in self.done if name not in trees}
        stages.update(trees)
        current = next(iter(trees), None)
        write_checkpoint(
            self.path,
            {
                ATTRS: {
                    "format": store.PIPELINE_FORMAT,
                    "format_version": FORMAT_VERSION,
                    "name": self.pipeline.name,
                    "status": self.status,
                    "stages": self.stage_names,
                    "stages_done": len(self.done),
                    "current": current or "",
                    "created": self.created,
                    "updated": ExperimentRun.now(),
                    "total_s": self.elapsed(),
                    "evo_door_version": self.versions.get("evo_door", ""),
                    "executor": self.executor or "",
                },
                "pipeline": {
                    ATTRS: {
                        "source": self.pipeline.source,
                        "base_dir": self.pipeline.base_dir,
                        "overrides": list(self.pipeline.overrides),
                    },
                    "text": self.pipeline.text,
                    "resolved": json.dumps(self.pipeline.resolved(), indent=1),
                },
                "versions": {ATTRS: dict(self.versions)},
                "stages": stages,
            },
            self.on_disk,
        )
        self.on_disk = stage_position(self.stage_names, self.done, self.current)


def _must_exist():
    raise UserError("a finished stage is missing from the results file being rewritten")


def _read_head(path) -> dict:
    """The pipeline's own groups (text, versions), not the stages."""
    from evo_door.files import open_h5, read_group

    with open_h5(path, "results file") as f:
        for name in ("pipeline", "versions"):
            if name not in f or not hasattr(f[name], "keys"):
                raise UserError(f"{path}: /{name}: missing, or not a group")
        return {"pipeline": read_group(f["pipeline"]), "versions": read_group(f["versions"])}


def resume_pipeline(path, progress=False, on_checkpoint=None) -> PipelineRun:
    """Continue an interrupted pipeline (a complete one is left as is)."""
    run = PipelineRun.open(path)
    if run.status == "complete":
        return run
    return run.run(progress=progress, on_checkpoint=on_checkpoint)
