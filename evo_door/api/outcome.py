"""What a run found, as typed objects: read from its results file.

:func:`load` reads a results file (a run's, or a pipeline's with a :class:`Run` per
stage); :meth:`Experiment.run <evo_door.api.build.Experiment.run>` returns the same
objects, read back from the file it wrote. The numbers are those ``evo-door show``
prints (:class:`~evo_door.experiment.results.Results`, which :meth:`Run.results` gives
for everything else); nothing is computed anew.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Any

from evo_door.errors import UserError
from evo_door.experiment.pipeline_status import pipeline_summary
from evo_door.experiment.reader import PipelineRecord, RunRecord, read_results
from evo_door.experiment.results import Results
from evo_door.experiment.spec import SpecTable, spec_table


@dataclass(frozen=True)
class Estimate:
    """One free parameter's answer: its value in its unit, the search range it was
    looked for in, the bound that decided it (if one did) and the truth (trials made by
    a model carry it)."""

    name: str
    value: float
    unit: str
    lower: float
    upper: float
    at_bound: str | None = None  # "lower" or "upper": the bound, not the data, decided it
    truth: float | None = None

    def __str__(self) -> str:
        unit = f" {self.unit}" if self.unit and self.unit != "1" else ""
        bound = f" (on the {self.at_bound} bound)" if self.at_bound else ""
        return f"{self.name} = {self.value:.4g}{unit}{bound}"


@dataclass(frozen=True)
class Identifiable:
    """Whether the data pin one estimate down (``docs/experiments.md``, "Identifiability
    and honest intervals"): the verdict, the standard error and the 95 % interval."""

    name: str
    verdict: str  # "identifiable", "correlated" or "not identifiable"
    se: float  # standard error, in the parameter's unit (inf: not determined)
    interval: tuple[float, float]  # 95 %, in the parameter's unit
    unit: str
    reason: str = ""  # why it is not identifiable (or with what it is correlated)
    partner: str = ""  # the most correlated other parameter

    @property
    def ok(self) -> bool:
        return self.verdict == "identifiable"


@dataclass(frozen=True)
class Checks:
    """The checks of a run's answer, each of which may fail without losing it.

    ``at_bound``: estimates a bound decided (name -> ``lower`` / ``upper``);
    ``not_identifiable``: estimates the identifiability check could not pin down;
    ``mismatch``: the residual's RMS over its noise level (None: not checked);
    ``integration_warning``: the integration error's warning (None: small, or not
    recorded: ``integration_recorded`` says which); ``feel_passes``: the perceptual
    check of a fit to a chosen feel (None for a fit to trials).
    """

    at_bound: dict[str, str] = field(default_factory=dict)
    not_identifiable: tuple[str, ...] = ()
    mismatch: float | None = None
    integration_warning: str | None = None
    integration_recorded: bool = False
    feel_passes: bool | None = None

    @property
    def ok(self) -> bool:
        """Nothing to look into: no estimate on a bound or undetermined, the integration
        error small, the chosen feel (if any) reached."""
        return (
            not self.at_bound
            and not self.not_identifiable
            and self.integration_warning is None
            and self.feel_passes is not False
        )


@dataclass(frozen=True)
class Run:
    """One run (a run's results file, or one stage of a pipeline's), as read."""

    path: Path
    stage: str | None
    name: str
    model: str
    status: str  # "complete", "running" or "interrupted"
    seed: int | None
    fitness: float | None
    fitness_unit: str
    estimates: dict[str, Estimate]
    identifiability: dict[str, Identifiable]
    checks: Checks
    fit_errors: dict[str, float | None]
    validation_errors: dict[str, float | None]
    #: the specification table (``evo-door export-spec``) of a complete run, None before
    spec: SpecTable | None
    #: the experiment with every default filled in, as the file keeps it
    config: dict[str, Any]

    def results(self) -> Results:
        """The full view of the run that every command reads (responses, trials, ...)."""
        return Results(self.path, self.stage)

    def values(self) -> dict[str, float]:
        """Free parameter -> its estimate (the run's answer)."""
        return {n: e.value for n, e in self.estimates.items()}

    def __str__(self) -> str:
        where = f"{self.path}" + (f" [{self.stage}]" if self.stage else "")
        fitness = "none" if self.fitness is None else f"{self.fitness:.4g} {self.fitness_unit}"
        lines = [f"{self.name} ({self.model} model), {self.status}, fitness {fitness}: {where}"]
        lines += [f"  {e}" for e in self.estimates.values()]
        return "\n".join(lines)


@dataclass(frozen=True)
class PipelineResult:
    """A pipeline's results file: its status and a :class:`Run` per started stage."""

    path: Path
    name: str
    status: str
    stages: dict[str, Run]

    def __getitem__(self, stage: str) -> Run:
        try:
            return self.stages[stage]
        except KeyError:
            raise UserError(
                f"{self.path}: no stage {stage!r} run; stages: {', '.join(self.stages)}"
            ) from None


def load(path: str | PurePath, stage: str | None = None) -> Run | PipelineResult:
    """A results file: a :class:`Run`, or a pipeline's :class:`PipelineResult` (one of
    its stages as a :class:`Run` with ``stage``)."""
    if not isinstance(path, (str, PurePath)):
        raise UserError(f"load(path=...): expected a results file's path (.h5), got {path!r}")
    if stage is not None:
        return load_run(path, stage)
    record = read_results(path)
    if isinstance(record, PipelineRecord):
        return _pipeline_result(record)
    return _run(Results.of(record))


def load_run(path: str | PurePath, stage: str | None = None) -> Run:
    """One run of a results file (``stage``: of a pipeline's)."""
    return _run(Results(path, stage))


def load_pipeline_result(path: str | PurePath) -> PipelineResult:
    """A pipeline's results file (a run's own file is refused in one line)."""
    record = read_results(path)
    if not isinstance(record, PipelineRecord):
        raise UserError(f"{path}: holds one run, not a pipeline (evo_door.load reads it)")
    return _pipeline_result(record)


def _pipeline_result(record: PipelineRecord) -> PipelineResult:
    summary = pipeline_summary(record) or {}
    runs: dict[str, RunRecord] = record.runs
    return PipelineResult(
        path=Path(record.path),
        name=str(summary.get("name", "")),
        status=str(summary.get("status", "")),
        stages={name: _run(Results.of(r)) for name, r in runs.items()},
    )


def _finite(value: Any) -> float | None:
    if value is None:
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def _run(res: Results) -> Run:
    units = res.units()
    truth = res.truth()
    hits = res.at_bound()
    best = res.best()
    estimates = {
        n: Estimate(
            n,
            float(best[n]),
            units.get(n, ""),
            float(res.bounds[n][0]),
            float(res.bounds[n][1]),
            hits.get(n),
            truth.get(n),
        )
        for n in res.free
        if n in best
    }
    ident = res.identifiability()
    table: dict[str, Identifiable] = {}
    if ident is not None:
        for n, row in ident.as_dict().items():
            half = float(row["ci_half"])
            table[n] = Identifiable(
                n,
                row["verdict"],
                float(row["se"]),
                (row["value"] - half, row["value"] + half),
                row["unit"],
                row["reason"],
                row["partner"],
            )
    record = res.record
    b = record.best
    return Run(
        path=res.path,
        stage=res.stage,
        name=str(res.attrs.get("name", "")),
        model=str(res.attrs.get("model", "")),
        status=res.status().state,
        seed=res.attrs.get("seed"),
        fitness=_finite(res.fitness()),
        fitness_unit=res.fitness_unit,
        estimates=estimates,
        identifiability=table,
        checks=_checks(res, hits, table, ident),
        fit_errors={} if b is None else {k: _finite(v) for k, v in b.fit_errors.items()},
        validation_errors=(
            {} if b is None else {k: _finite(v) for k, v in b.validation_errors.items()}
        ),
        spec=_spec(res),
        config=res.config,
    )


def _checks(res: Results, hits: dict, table: dict[str, Identifiable], ident) -> Checks:
    record = res.record
    error = record.integration_error
    feel = record.perceptual_check
    mismatch = None if ident is None else _finite(getattr(ident, "mismatch", None))
    return Checks(
        at_bound=dict(hits),
        not_identifiable=tuple(n for n, v in table.items() if v.verdict == "not identifiable"),
        mismatch=mismatch,
        integration_warning=None if error is None else error.warning(),
        integration_recorded=error is not None,
        feel_passes=None if feel is None else bool(feel.judged()["passes"]),
    )


def _spec(res: Results) -> SpecTable | None:
    """The specification table of a complete run whose model loads (None otherwise);
    tolerances only as the file keeps them (never computed here)."""
    if not res.complete or res.model is None:
        return None
    try:
        return spec_table(res, tolerance=False)
    except UserError:
        return None
