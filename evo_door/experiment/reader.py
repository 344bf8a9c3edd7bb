"""One results file, opened once, read into typed records.

Every command that looks at results (``show``, ``runs``, ``compare``, ``report``,
``export-spec``) reads its file here, in one open: :func:`read_results` gives a
:class:`RunRecord` for a run's file or a :class:`PipelineRecord` (its stages' runs) for a
pipeline's, :func:`read_run` one run or one stage. The records are plain data with
attributes (like scipy's ``OdeResult``); what a run *means* (its best values, errors,
status) is :class:`evo_door.experiment.results.Results`, built on a record.

``arrays=False`` reads what a folder listing needs (attributes, the configuration, the
halls of fame), never the populations, trials or responses: ``runs`` stays cheap on a
folder of large files. The layout read is :mod:`.store`'s.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evo_door.channels import RESPONSE_CHANNELS
from evo_door.errors import UserError
from evo_door.experiment import store
from evo_door.experiment.feel_check import FeelCheck, try_feel_check
from evo_door.experiment.integration_error import IntegrationError
from evo_door.experiment.stored import (
    PIPELINE_ATTRS,
    checked,
    config_of,
    feel_from_tree,
    job_keys,
    numbers_of,
    root_attrs,
    trial_from_tree,
)
from evo_door.files import ATTRS, MissingInFile, Node, fields, read_attrs, read_group
from evo_door.optim.smallest_change import SmallestChange
from evo_door.optim.tolerance import Specification


@dataclass(frozen=True)
class RunSettings:
    """``setup/``: how the run was set up (model, free parameters and their ranges)."""

    model: str
    free: list[str]
    param_names: list[str]
    objective: dict
    method: str
    substeps: int
    fit_ids: list[str]
    validation_ids: list[str]
    base: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    #: ``dopri5``'s tolerance; None in a file written before it was kept (the model's)
    tolerance: float | None = None

    @property
    def bounds(self) -> dict[str, tuple[float, float]]:
        """Free parameter name -> its search range (lower, upper)."""
        return {n: (float(lo), float(hi)) for n, lo, hi in zip(self.free, self.lower, self.upper)}


@dataclass(frozen=True)
class StoredGAState:
    """``jobs/<k>/ga``: where a job's genetic algorithm stands (logbook: full reads only)."""

    generation: int
    evaluations: int
    blowups: int
    best_fitness: float
    hof_x: np.ndarray
    hof_fitness: np.ndarray
    logbook: dict | None  # column -> array; None when read with arrays=False


@dataclass(frozen=True)
class StoredJob:
    """``jobs/<k>``: one fit of a run (a trial's, all trials', or the run's only one)."""

    name: str
    done: bool
    ga_stop: str
    ga: StoredGAState | None
    local_fitness: float | None  # after the SLSQP polish, where there was one
    #: NSGA-II's front and the smallest change chosen from it (full reads of done jobs)
    front: SmallestChange | None = None


@dataclass(frozen=True)
class Best:
    """``best/``: a complete run's answer, its errors, and the estimates on a bound."""

    fitness: float
    values: dict[str, float]
    fit_errors: dict[str, float]
    validation_errors: dict[str, float]
    meaning: str | None  # None: written before the attribute existed
    at_bound: dict[str, str] | None  # None: written before the attribute existed
    identifiability: dict | None  # the stored tree (optim.identifiability reads it)


@dataclass(frozen=True)
class PerTrialFits:
    """``summary/``: one fit per trial (``per_trial`` runs), as seed table 5.3."""

    trials: list[str]
    x: np.ndarray  # trial x free parameter
    min: np.ndarray
    max: np.ndarray
    mean: np.ndarray


@dataclass(frozen=True)
class StoredResponse:
    """``response/<k>``: the best parameters' response to one trial, with its target."""

    trial_id: str
    role: str  # fit or validate
    channel: str
    error: float
    t: np.ndarray
    force: np.ndarray
    target: np.ndarray
    model: np.ndarray


@dataclass(frozen=True)
class StoredTrial:
    """``trials/<role>_<k>``: a trial the run fitted or validated on."""

    key: str
    trial_id: str
    truth: dict
    node: dict  # the stored group, for :meth:`trial`

    @property
    def role(self) -> str:
        return self.key.rsplit("_", 1)[0]

    def trial(self):
        """The :class:`~evo_door.data.trial.Trial` itself (its arrays, its sensors)."""
        return trial_from_tree(self.node)


@dataclass(frozen=True)
class Provenance:
    """What made the run: the experiment as given and the package versions."""

    source: str
    overrides: list[str]
    text: str
    versions: dict


@dataclass
class RunRecord:
    """One run (a run's file, or one stage of a pipeline's file) as read.

    ``attrs`` are the root attributes as stored (status, jobs done, generations...),
    ``config`` the resolved experiment; ``sources`` says which earlier stage a pipeline
    stage's ``{from: STAGE}`` took (``params``, ``target.params``).
    ``integration_error`` is the answer's integration error (``integration_error/``), None
    where it is not recorded (a run not finished, or written before it was estimated).
    ``perceptual_check`` is the answer's perceptual check against the chosen feel
    (``perceptual_check/``; for a file written before the group existed, computed on a
    full read), None for a run not fitted to a chosen feel or not finished. ``tree`` is the raw
    layout, kept for code that rebuilds a run's setup from it
    (:func:`.stored.setup_from_tree`); None when read with ``arrays=False``.
    """

    path: Path
    stage: str | None
    attrs: dict
    config: dict
    settings: RunSettings
    jobs: list[StoredJob]
    best: Best | None
    per_trial: PerTrialFits | None
    timings: dict
    provenance: Provenance
    sources: dict[str, str] = field(default_factory=dict)
    responses: list[StoredResponse] = field(default_factory=list)
    trials: list[StoredTrial] = field(default_factory=list)
    tree: dict | None = None
    integration_error: IntegrationError | None = None
    perceptual_check: FeelCheck | None = None
    #: the specifications' tolerances against a chosen feel (``tolerance/``), None where
    #: not recorded (no chosen feel, not finished, or read with ``arrays=False``)
    tolerance: Specification | None = None

    @property
    def complete(self) -> bool:
        return self.attrs.get("status") == "complete"


@dataclass
class PipelineRecord:
    """A pipeline's file: its root attributes, each declared stage, the started stages' runs.

    ``stages`` lists every declared stage in order; ``runs`` holds the started ones, in
    that order (``started``: as the file lists them, which its messages name);
    ``sources`` maps a stage to its ``{from: STAGE}`` sources, ``report`` the pipeline
    file's settings of ``evo-door report``.
    """

    path: str | Path  # as given: the pipeline's status and resume line name it so
    attrs: dict
    stages: list[str]
    started: list[str]
    runs: dict[str, RunRecord]
    sources: dict[str, dict[str, str]]
    report: dict


def read_results(path, *, arrays: bool = True) -> RunRecord | PipelineRecord:
    """The results file ``path``, in one open: a run's record, or a pipeline's with every
    started stage. ``arrays=False`` leaves out populations, trials and responses."""
    with store._open(path) as f:  # the one open of the file
        try:
            if read_attrs(f).get("format") != store.PIPELINE_FORMAT:
                return _run(f, Path(path), None, {}, arrays)
            return _pipeline(f, path, arrays)
        except (OSError, KeyError) as exc:  # a damaged file, read as peek says it
            detail = str(exc).removeprefix(f"{path}: ") if isinstance(exc, MissingInFile) else exc
            raise UserError(f"{path}: not a readable results file ({detail})") from None


def read_run(path, stage: str | None = None, arrays: bool = True) -> RunRecord:
    """One run, whole: a run's file, or the stage ``stage`` of a pipeline's (one open;
    a missing or unknown stage is a one-line error naming the stages there are).
    ``arrays`` False reads its attributes and small arrays only: its settings and best
    values, without its trials, responses and histories (a pipeline's next stage
    needs no more of a finished one)."""
    path = Path(path)
    with store._open(path) as f:  # the one open of the file
        group = store._run_group(f, path, stage)
        sources = _sources(f).get(stage, {}) if stage is not None else {}
        return _run(group, path, stage, sources, arrays)


def pick(record: RunRecord | PipelineRecord, stage: str | None) -> RunRecord:
    """The run ``stage`` names in a record read by :func:`read_results`, with the errors
    :func:`read_run` gives (no stage of a run's file; a pipeline needs one)."""
    if isinstance(record, RunRecord):
        store.check_stage(record.path, stage)
        return record
    store.check_stage(Path(record.path), stage, record.stages, record.started)
    return record.runs[stage]


# -- reading the groups ----------------------------------------------------------------
def check_file_models(path) -> None:
    """Every model a results file names (a run's, each started stage's) is installed or
    named by the user; else one line, before anything from the file is built or run
    (``resume`` calls it first: it builds its run from the file)."""
    with store._open(path) as f:
        if read_attrs(f).get("format") != store.PIPELINE_FORMAT:
            _check_models(f, Path(path), None)
            return
        for name in store.started_stages(f, path):
            _check_models(f["stages"][name], Path(path), name)


def _check_models(g, path: Path, stage) -> None:
    """Every model the run's group names (its own, its target's, its inputs') is
    installed or named by the user (:func:`~evo_door.models.base.check_named_in_file`):
    a results file is data, and reading it never runs code it names."""
    from evo_door.models.base import check_named_in_file

    where = f"{path}" + (f", stage {stage}," if stage else "")
    names = [read_attrs(g).get("model")]
    try:
        config = json.loads(_text(g["experiment"]["resolved"][()]))
        target = config.get("target") or {}
        names += [target.get("model"), (target.get("inputs") or {}).get("model")]
    except (KeyError, ValueError, TypeError, AttributeError, RecursionError):
        pass  # (a damaged configuration: its reader says so in its own line)
    for name in names:
        if isinstance(name, str) and name:
            check_named_in_file(name, where)


def _sources(f) -> dict[str, dict[str, str]]:
    """Stage -> its ``{from: STAGE}`` sources, from ``pipeline/resolved`` ({} if none)."""
    return store.sources_of(_pipeline_resolved(f))


def _pipeline_resolved(f) -> dict:
    """``pipeline/resolved``: the pipeline's configuration ({} where the file has none)."""
    if "pipeline/resolved" not in f:
        return {}
    return store.pipeline_resolved(f["pipeline/resolved"][()], f"{f.filename}: /pipeline/resolved")


def _pipeline(f, path, arrays: bool) -> PipelineRecord:
    attrs = checked(read_attrs(f), PIPELINE_ATTRS)
    started = store.started_stages(f, path)
    resolved = _pipeline_resolved(f)
    sources = _sources(f)
    declared = fields.texts(attrs, "stages", [])
    # the stages in the pipeline's order (a file may list a later stage's group first)
    order = [name for name in declared if name in started]
    order += [name for name in started if name not in order]
    runs = {}
    for name in order:
        group = f["stages"][name]
        if not hasattr(group, "keys"):
            raise UserError(f"{path}: /stages/{name}: expected a group, got a dataset")
        runs[name] = _run(group, Path(path), name, sources.get(name, {}), arrays)
    return PipelineRecord(
        path=path,
        attrs=attrs,
        stages=declared,
        started=started,
        runs=runs,
        sources=sources,
        report=fields.mapping(
            Node(resolved, place=f"{path}: /pipeline/resolved:", style="key"), "report", {}
        ),
    )


def _run(g, path: Path, stage, sources: dict, arrays: bool) -> RunRecord:
    """A run's group: everything with ``arrays``, else attributes and small arrays only."""
    _check_models(g, path, stage)  # before anything is built from the file
    tree = read_group(g) if arrays else None
    node = tree if arrays else _Light(g)
    experiment = fields.group(node, "experiment")
    settings = _settings(fields.group(node, "setup"))
    jobs_node = fields.group(node, "jobs")
    record = RunRecord(
        path=path,
        stage=stage,
        attrs=root_attrs(node[ATTRS]),
        config=config_of(experiment["resolved"], fields.place_of(experiment, "resolved")),
        settings=settings,
        jobs=[_job(fields.group(jobs_node, k), arrays, settings) for k in job_keys(jobs_node)],
        best=_best(fields.group(node, "best"), arrays, settings) if "best" in node else None,
        per_trial=_per_trial(fields.group(node, "summary"), settings)
        if arrays and "summary" in node
        else None,
        timings=numbers_of(fields.group(node, "timings")[ATTRS]),
        provenance=Provenance(
            source=fields.text(experiment[ATTRS], "source", ""),
            overrides=fields.texts(experiment[ATTRS], "overrides", []),
            text=fields.text(experiment, "text") if arrays else "",
            versions=fields.group(node, "versions")[ATTRS],
        ),
        sources=sources,
        responses=_responses(tree) if arrays else [],
        trials=_trials(tree) if arrays else [],
        tree=tree,
        integration_error=_integration_error(node),
        tolerance=_tolerance(tree),
    )
    record.perceptual_check = _perceptual_check(node, record)
    return record


def _tolerance(tree: dict | None) -> Specification | None:
    """``tolerance/``, None where the file has none or was read without arrays."""
    if tree is None or "tolerance" not in tree:
        return None
    return Specification.from_tree(fields.group(tree, "tolerance"))


def _integration_error(node) -> IntegrationError | None:
    """``integration_error/``, None where the file has none (written before it existed)."""
    if "integration_error" not in node:
        return None
    return IntegrationError.from_tree(fields.group(node, "integration_error"))


def _perceptual_check(node, record: RunRecord) -> FeelCheck | None:
    """``perceptual_check/``; where the file has none, computed for a complete run fitted
    to a chosen feel when the arrays are read (``arrays=False`` reads stay cheap)."""
    if "perceptual_check" in node:
        return FeelCheck.from_tree(fields.group(node, "perceptual_check"))
    if record.tree is None or not record.complete or "best" not in node:
        return None
    from evo_door.experiment.feel_check import fitted_to_feel
    from evo_door.models import get_model

    if not fitted_to_feel(record.config):
        return None
    try:
        model = get_model(record.attrs["model"])
    except UserError:  # a user model file moved away: nothing to compute with
        return None
    setup = node["setup"]
    feel = feel_from_tree(fields.group(setup, "feel")) if "feel" in setup else None
    return try_feel_check(model, node["best"]["full"], record.config, feel, recorded=False)


class _Light(Mapping):
    """An open group read on demand, as :func:`read_group` would give it: attributes of
    every group, datasets read only when asked for (``arrays=False`` reads)."""

    def __init__(self, group):
        self._g = group
        self.place = f"{group.file.filename}: {group.name}"

    def name(self, key) -> str:
        return f"{self.place.rstrip('/')}/{key}"

    def __contains__(self, key) -> bool:
        return key == ATTRS or key in self._g

    def __iter__(self):
        return iter(self._g)

    def __len__(self) -> int:
        return len(self._g)

    def __getitem__(self, key):
        if key == ATTRS:
            return read_attrs(self._g)
        if key not in self._g:
            raise MissingInFile(f"{self.name(key)}: missing")
        item = self._g[key]
        return item[()] if hasattr(item, "dtype") else _Light(item)


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _settings(s) -> RunSettings:
    a = s[ATTRS]
    free = fields.texts(a, "free")
    names = fields.texts(a, "param_names")
    n = len(free)
    settings = RunSettings(
        model=fields.text(a, "model"),
        free=free,
        param_names=names,
        objective=fields.mapping(a, "objective"),
        method=fields.text(a, "method", ""),
        substeps=fields.integer(a, "substeps", 1, lo=1),
        fit_ids=fields.texts(a, "fit_ids", []),
        validation_ids=fields.texts(a, "validation_ids", []),
        base=fields.array(s, "base", shape=(None,)),
        lower=fields.array(s, "lower", shape=(n,)),
        upper=fields.array(s, "upper", shape=(n,)),
        tolerance=fields.number(a, "tolerance", None),
    )
    if not set(free) <= set(names) and names:
        raise UserError(f"{fields.place_of(a, 'free')}: names a parameter not in param_names")
    return settings


def _job(j, arrays: bool, settings: RunSettings) -> StoredJob:
    a = j[ATTRS]
    ga = None
    n = len(settings.free)
    if "ga" in j:
        g = fields.group(j, "ga")
        ga_attrs = g[ATTRS]
        hof_f = np.zeros(0)
        if "hof_x" in g and "hof_fitness" in g:
            hof_f = _first_objective(fields.array(g, "hof_fitness"))
            if hof_f.ndim != 1:
                raise UserError(
                    f"{fields.place_of(g, 'hof_fitness')}: expected 1-D or 2-D numbers, "
                    f"got shape {hof_f.shape}"
                )
        ga = StoredGAState(
            generation=fields.integer(ga_attrs, "generation", lo=0),
            evaluations=fields.integer(ga_attrs, "evaluations", lo=0),
            blowups=fields.integer(ga_attrs, "blowups", lo=0),
            best_fitness=fields.number(ga_attrs, "best_fitness"),
            hof_x=fields.array(g, "hof_x", np.zeros((0, n)), shape=(hof_f.size, n)),
            hof_fitness=hof_f,
            logbook=_logbook(fields.group(g, "logbook")) if arrays else None,
        )
    local = None
    if "local" in j:
        local = fields.number(fields.group(j, "local")[ATTRS], "fitness")
    return StoredJob(
        name=fields.text(a, "name", ""),
        done=fields.flag(a, "done", False),
        ga_stop=fields.text(a, "ga_stop", ""),
        ga=ga,
        local_fitness=local,
        front=SmallestChange.from_tree(fields.group(j, "front"))
        if arrays and "front" in j
        else None,
    )


def _logbook(log) -> dict:
    """A GA's logbook: column -> 1-D array, every column as long."""
    out = {k: fields.array(log, k, shape=(None,), kind="n") for k in log if k != ATTRS}
    lengths = {len(v) for v in out.values()}
    if len(lengths) > 1:
        raise UserError(f"{fields.node_place(log)}: columns of different lengths")
    return out


def _first_objective(values) -> np.ndarray:
    """A hall of fame's fitness; NSGA-II's archive keeps two objectives a point: its
    first, the perceptual error, is the fitness a run is listed and compared by."""
    values = np.asarray(values)
    return values[:, 0] if values.ndim == 2 and values.shape[1] else values


def _best(b, arrays: bool, settings: RunSettings) -> Best:
    a = b[ATTRS]
    values = fields.mapping(a, "values", {}, fields.as_number)
    if not set(values) <= set(settings.free):
        raise UserError(f"{fields.place_of(a, 'values')}: names a parameter that is not free")
    return Best(
        fitness=fields.number(a, "fitness"),
        values=values,
        fit_errors=fields.mapping(a, "fit_errors", {}, fields.as_number),
        validation_errors=fields.mapping(a, "validation_errors", {}, fields.as_number),
        meaning=fields.text(a, "meaning", None),
        at_bound=fields.mapping(a, "at_bound", None, fields.as_text),
        identifiability=fields.group(b, "identifiability")
        if arrays and "identifiability" in b
        else None,
    )


def _per_trial(s: dict, settings: RunSettings) -> PerTrialFits:
    trials = fields.texts(s[ATTRS], "trials")
    n = len(settings.free)
    return PerTrialFits(
        trials=trials,
        x=fields.array(s, "x", shape=(len(trials), n)),
        min=fields.array(s, "min", shape=(n,)),
        max=fields.array(s, "max", shape=(n,)),
        mean=fields.array(s, "mean", shape=(n,)),
    )


def _responses(tree: dict) -> list[StoredResponse]:
    groups = fields.group(tree, "response", {})
    out = []
    for k in job_keys(groups):
        r = fields.group(groups, k)
        a = r[ATTRS]
        t = fields.array(r, "t", shape=(None,))
        shape = t.shape
        out.append(
            StoredResponse(
                trial_id=fields.text(a, "trial_id"),
                role=fields.text(a, "role"),
                channel=fields.text(a, "channel", choices=RESPONSE_CHANNELS),
                error=fields.number(a, "error"),
                t=t,
                force=fields.array(r, "force", shape=shape),
                target=fields.array(r, "target", shape=shape),
                model=fields.array(r, "model", shape=shape),
            )
        )
    return out


def _trials(tree: dict) -> list[StoredTrial]:
    """The stored trials in the file's order (fitted ones, then validation ones)."""
    out = []
    for key, node in fields.group(tree, "trials", {}).items():
        if key == ATTRS:
            continue
        node = fields.group(tree["trials"], key)
        a = node[ATTRS]
        truth = Node(fields.mapping(a, "truth", {}), place=fields.place_of(a, "truth"), style="key")
        fields.mapping(truth, "params", None, fields.as_number)
        fields.text(truth, "model", None)
        out.append(StoredTrial(key, fields.text(a, "trial_id"), truth, node))
    return out
