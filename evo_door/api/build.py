"""Experiments and pipelines built in Python, checked by the YAML files' own checks.

The keyword arguments of :class:`Experiment` and :class:`Pipeline` are the keys of an
experiment or pipeline file (``docs/experiments.md``, ``docs/case-study.md``). They are
turned into the tree the YAML parser makes (:func:`to_tree`) and checked by the same
code (:func:`~evo_door.experiment.config.experiment_from_tree`,
:func:`~evo_door.experiment.pipeline.pipeline_from_tree`): one validation, one set of
messages. Where a file's message names ``FILE:LINE``, a Python one names the argument,
``Experiment(free=...): free.Mx: model 'door' has no parameter 'Mx' (did you mean 'M'?)``.
Relative file names are looked up in the folder current when the object is built.
"""

from __future__ import annotations

import json
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any

from evo_door.errors import UserError
from evo_door.experiment import config
from evo_door.experiment.pipeline import PipelineConfig as PipelineSpec
from evo_door.experiment.pipeline import PipelineRun as PipelineRunner
from evo_door.experiment.pipeline import pipeline_from_tree
from evo_door.experiment.runner import ExperimentRun
from evo_door.experiment.yamltree import LinedList, LinedMap

if TYPE_CHECKING:
    from evo_door.api.outcome import PipelineResult, Run

#: the source a Python-built experiment's results file names (``experiment/@source``)
PYTHON_SOURCE = "<python>"


@dataclass(frozen=True)
class TrialFile:
    """A target of measured trials: ``target: {data: FILE, ...}`` of an experiment file.

    Made by :func:`trial_file`; any field left None is left out (the file's default).
    """

    data: str
    trials: str | Sequence[str] | None = None
    kinds: Sequence[str] | None = None
    users: Sequence[str] | None = None
    validate: Sequence[str] | None = None
    preprocess: Mapping[str, Any] | None = None

    def as_mapping(self) -> dict[str, Any]:
        """The ``target`` mapping of an experiment file."""
        return {k: v for k, v in vars(self).items() if v is not None}


def trial_file(
    path: str | PurePath,
    *,
    trials: str | Sequence[str] | None = None,
    kinds: Sequence[str] | None = None,
    users: Sequence[str] | None = None,
    validate: Sequence[str] | None = None,
    preprocess: Mapping[str, Any] | None = None,
) -> TrialFile:
    """The trials of a file as an experiment's target (checked with the experiment).

    ``trials`` (``"all"`` or ids), ``kinds``, ``users``, ``validate`` (ids held out) and
    ``preprocess`` (``{"rate_bias": "start", ...}``) are the keys of ``target:``.
    """
    return TrialFile(
        str(path) if isinstance(path, PurePath) else path,
        trials,
        kinds,
        users,
        validate,
        preprocess,
    )


def to_tree(value: object, where: str) -> object:
    """``value`` as the YAML parser would give it, every location ``where``.

    Mappings become :class:`LinedMap`, lists and tuples :class:`LinedList`, paths text,
    numpy scalars and arrays Python numbers and lists; anything else is left as it is
    for the checks to name.
    """
    if isinstance(value, TrialFile):
        value = value.as_mapping()
    if isinstance(value, PurePath):
        return str(value)
    if value is None or isinstance(value, (bool, str)):
        return value
    if hasattr(value, "dtype") and hasattr(value, "tolist"):  # numpy, without importing it
        value = value.tolist()
        if not isinstance(value, (list, tuple)):
            return to_tree(value, where)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value)
    if isinstance(value, Mapping):
        out = LinedMap(loc=where)
        for key, item in value.items():
            if isinstance(key, PurePath):
                key = str(key)
            if key is None or not isinstance(key, (str, int, float, bool)):
                raise UserError(f"{where}: mapping keys must be plain names, got {key!r}")
            out[key] = to_tree(item, where)
            out.key_locs[key] = where
        return out
    if isinstance(value, (list, tuple)):
        return LinedList([to_tree(item, where) for item in value], loc=where)
    return value


def _arguments_tree(loc: str, key_loc: str, given: Mapping[str, Any]) -> LinedMap:
    """The tree of keyword arguments: itself located ``loc``, key ``k`` located
    ``key_loc`` with ``{key}`` replaced by k (``Experiment(k=...)``)."""
    tree = LinedMap(loc=loc)
    for key, value in given.items():
        where = key_loc.replace("{key}", str(key))
        tree[key] = to_tree(value, where)
        tree.key_locs[key] = where
    return tree


#: the command line's words in the messages of a new run's output, and Python's
_PYTHON_WORDS = (("give another --out", "give another out"), ("--force", "overwrite=True"))


def _output(call: str, out: object) -> Path | None:
    """A run's ``out``: a path (or None, the default file), else one line naming it."""
    if out is None or isinstance(out, (str, PurePath)):
        return None if out is None else Path(out)
    raise UserError(f"{call}(out=...): expected the results file's path (.h5), got {out!r}")


def _claim(start: Callable[[], Any]) -> Any:
    """``start()`` (a run's creation, which claims its output), its refusals in Python's
    words (``overwrite=True`` for ``--force``)."""
    try:
        return start()
    except UserError as exc:
        text = str(exc)
        for cli, python in _PYTHON_WORDS:
            text = text.replace(cli, python)
        raise UserError(text) from None


def _overrides(overrides: object) -> list[str]:
    """``--set`` assignments: one text, or a list of them."""
    if overrides is None:
        return []
    if isinstance(overrides, str):
        return [overrides]
    if isinstance(overrides, (list, tuple)) and all(isinstance(o, str) for o in overrides):
        return list(overrides)
    raise UserError(
        f"from_yaml(overrides=...): expected KEY.PATH=VALUE texts (algorithm.seed=3), got "
        f"{overrides!r}"
    )


def _file_of(kind: str, path: object) -> Path:
    """The YAML file of ``from_yaml``: a path to an experiment (``kind``) or a pipeline."""
    from evo_door.experiment.pipeline import is_pipeline

    if not isinstance(path, (str, PurePath)):
        raise UserError(f"{kind}.from_yaml(path=...): expected a YAML file's path, got {path!r}")
    if (kind == "Experiment") == is_pipeline(path):
        other = "Pipeline" if kind == "Experiment" else "Experiment"
        what = "a pipeline (it has stages)" if kind == "Experiment" else "an experiment"
        raise UserError(f"{path}: {what}: evo_door.{other}.from_yaml reads it")
    return Path(path)


def _yaml_text(tree: LinedMap) -> str:
    """The YAML of a tree, as a results file keeps an experiment's text (made before the
    checks: a value no file could hold is written as its repr, and then refused)."""
    import yaml

    return yaml.safe_dump(json.loads(json.dumps(tree, default=repr)), sort_keys=False)


class Experiment:
    """An experiment, checked when it is made: the keys of an experiment file as keyword
    arguments (``docs/experiments.md``), or a file read by :meth:`from_yaml`.

    >>> Experiment(model="door", target={"data": "none.h5"}, free={"M": [0.3, 2.5]})
    Traceback (most recent call last):
    ...
    evo_door.errors.UserError: Experiment(target=...): target.data: file not found: none.h5 (...)

    Required: ``model``, ``target`` and ``free``. Unknown keywords are refused with the
    keys there are (and a did-you-mean), like unknown keys of a file.
    """

    def __init__(
        self,
        *,
        name: str | None = None,
        description: str | None = None,
        model: str | None = None,
        params: str | PurePath | Mapping[str, Any] | None = None,
        target: TrialFile | Mapping[str, Any] | None = None,
        fixed: Mapping[str, float] | None = None,
        free: Mapping[str, Sequence[float]] | None = None,
        objective: Mapping[str, Any] | None = None,
        algorithm: Mapping[str, Any] | None = None,
        per_trial: bool | None = None,
        pooled: bool | None = None,
        simulation: Mapping[str, Any] | None = None,
        output: str | None = None,
        executor: str | None = None,
        perception: Mapping[str, Any] | None = None,
        channels: Mapping[str, str] | None = None,
        process: str | PurePath | Mapping[str, Any] | None = None,
        **unknown: Any,
    ) -> None:
        known = {
            "name": name,
            "description": description,
            "model": model,
            "params": params,
            "target": target,
            "fixed": fixed,
            "free": free,
            "objective": objective,
            "algorithm": algorithm,
            "per_trial": per_trial,
            "pooled": pooled,
            "simulation": simulation,
            "output": output,
            "executor": executor,
            "perception": perception,
            "channels": channels,
            "process": process,
        }
        given = {k: v for k, v in {**known, **unknown}.items() if v is not None}
        tree = _arguments_tree("Experiment(...)", "Experiment({key}=...)", given)
        #: the arguments as the tree a file parses into (None: read from a file)
        self.tree: LinedMap | None = tree
        self.base_dir = Path.cwd()
        self.file: Path | None = None
        self.config: config.ExperimentConfig = config.experiment_from_tree(
            tree, _yaml_text(tree), PYTHON_SOURCE, self.base_dir
        )

    @classmethod
    def from_yaml(cls, path: str | PurePath, overrides: Sequence[str] | None = None) -> Experiment:
        """An experiment file, checked as ``evo-door run`` checks it (``overrides``:
        ``--set`` assignments, ``"algorithm.seed=3"``)."""
        path = _file_of("Experiment", path)
        exp = cls.__new__(cls)
        exp.config = config.load_experiment(path, _overrides(overrides))
        exp.tree = None
        exp.base_dir = Path(path).resolve().parent
        exp.file = Path(path).resolve()
        return exp

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def model(self) -> str:
        return self.config.model

    @property
    def free(self) -> dict[str, tuple[float, float]]:
        """Free parameter -> its search range (lower, upper), as checked."""
        return dict(self.config.free)

    @property
    def yaml(self) -> str:
        """The experiment as YAML: the file's own text, or the arguments written as one."""
        return self.config.text

    def __repr__(self) -> str:
        where = f" from {self.file}" if self.file is not None else ""
        return f"<Experiment {self.name!r}{where}: model {self.model}, free {', '.join(self.free)}>"

    def run(
        self, out: str | PurePath | None = None, *, overwrite: bool = False, progress: bool = False
    ) -> Run:
        """Run it to completion, writing the results file ``out`` (default: a new file in
        the experiment's ``output`` folder); the run as read back from that file.

        An existing results file is replaced only with ``overwrite``, any other file never.
        """
        from evo_door.api.outcome import load_run

        for where, stage in self.config.uses().items():
            raise UserError(
                f"{where}: {{from: {stage}}} takes an earlier stage's best parameters: run "
                "the experiment as a stage of a Pipeline"
            )
        path = _output("Experiment.run", out)
        run = _claim(lambda: ExperimentRun.create(self.config, path, overwrite=overwrite))
        run.run(progress=progress)
        return load_run(run.path)

    def _stage_value(self, name: str) -> object:
        """What a pipeline's ``stages.NAME`` holds for this experiment."""
        if self.tree is not None:
            return self.tree
        if self.config.overrides:
            raise UserError(
                f"Pipeline(stages=...): stages.{name}: an experiment file read with overrides "
                "cannot be a stage; give the file's path, or build the stage in Python"
            )
        return str(self.file)


class Pipeline:
    """Several experiments run as the stages of one job, one results file
    (``docs/case-study.md``): the keys of a pipeline file as keyword arguments.

    ``stages`` maps each stage's name to an :class:`Experiment`, a mapping of an
    experiment's keys, or an experiment file's path; ``{"from": "STAGE"}`` in ``params``
    or a target's ``params`` stands for an earlier stage's answer.
    """

    def __init__(
        self,
        *,
        name: str | None = None,
        description: str | None = None,
        stages: Mapping[str, Experiment | Mapping[str, Any] | str | PurePath] | None = None,
        output: str | None = None,
        report: Mapping[str, float] | None = None,
        executor: str | None = None,
        perception: Mapping[str, Any] | None = None,
        process: str | PurePath | Mapping[str, Any] | None = None,
        **unknown: Any,
    ) -> None:
        known = {
            "name": name,
            "description": description,
            "stages": stages,
            "output": output,
            "report": report,
            "executor": executor,
            "perception": perception,
            "process": process,
        }
        given = {k: v for k, v in {**known, **unknown}.items() if v is not None}
        plain = {k: v for k, v in given.items() if k != "stages"}
        tree = _arguments_tree("Pipeline(...)", "Pipeline({key}=...)", plain)
        if stages is not None:
            tree["stages"] = _stages_tree(stages)
            tree.key_locs["stages"] = "Pipeline(stages=...)"
        #: the arguments as the tree a file parses into (None: read from a file)
        self.tree: LinedMap | None = tree
        self.base_dir = Path.cwd()
        self.config: PipelineSpec = pipeline_from_tree(
            tree, _yaml_text(tree), "<python pipeline>", self.base_dir
        )

    @classmethod
    def from_yaml(cls, path: str | PurePath, overrides: Sequence[str] | None = None) -> Pipeline:
        """A pipeline file, checked as ``evo-door run`` checks it."""
        from evo_door.experiment.pipeline import load_pipeline

        path = _file_of("Pipeline", path)
        pipe = cls.__new__(cls)
        pipe.config = load_pipeline(path, _overrides(overrides))
        pipe.tree = None
        pipe.base_dir = Path(path).resolve().parent
        return pipe

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def stages(self) -> list[str]:
        return [s.name for s in self.config.stages]

    @property
    def yaml(self) -> str:
        return self.config.text

    def __repr__(self) -> str:
        return f"<Pipeline {self.name!r}: stages {', '.join(self.stages)}>"

    def run(
        self, out: str | PurePath | None = None, *, overwrite: bool = False, progress: bool = False
    ) -> PipelineResult:
        """Run every stage, writing the results file ``out``; the stages as read back."""
        from evo_door.api.outcome import load_pipeline_result

        path = _output("Pipeline.run", out)
        run = _claim(lambda: PipelineRunner.create(self.config, path, overwrite=overwrite))
        run.run(progress=progress)
        return load_pipeline_result(run.path)


def _stages_tree(stages: object) -> object:
    """``stages`` of a pipeline: each Experiment as its arguments' tree (or its file)."""
    if not isinstance(stages, Mapping):
        return to_tree(stages, "Pipeline(stages=...)")
    out = LinedMap(loc="Pipeline(stages=...)")
    for name, stage in stages.items():
        where = f"Pipeline(stages[{name!r}]=...)"
        if isinstance(stage, Experiment):
            value = stage._stage_value(str(name))
        elif isinstance(stage, Mapping):
            value = _arguments_tree(where, f"Pipeline(stages[{name!r}].{{key}}=...)", stage)
        else:
            value = to_tree(stage, where)
        out[name] = value
        out.key_locs[name] = where
    return out
