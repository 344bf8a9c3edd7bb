"""The JSON-able documents of ``runs`` (a folder of runs, cheaply) and ``compare`` (runs
side by side); ``show --json`` is :meth:`Results.summary`. Every file is read once,
through :mod:`evo_door.experiment.reader`.
"""

from __future__ import annotations

import json
from pathlib import Path

from evo_door.errors import NotResultsFileError, UserError
from evo_door.experiment.reader import PipelineRecord, read_results
from evo_door.experiment.results import (
    Results,
    best_so_far,
    finite,
    objective_unit,
    progress_text,
    run_status,
    units_of,
)
from evo_door.experiment.yamltree import flatten
from evo_door.optim.bounds import bound_hits


# -- a folder of runs ----------------------------------------------------------------
def list_runs(folder) -> list[dict]:
    """One row per results file in ``folder`` (newest first); unreadable files are flagged.

    Cheap: each file is opened once and read without its arrays (root and ``best``
    attributes, the resolved configuration and, for a run without an answer yet, its
    halls of fame; never the populations or the trials). A pipeline's file gives one
    row per started stage; an HDF5 file of another kind (trials, a render log) none.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"{folder}: no such folder")
    rows = []
    for path in sorted(folder.glob("*.h5")):
        try:
            record = read_results(path, arrays=False)
        except NotResultsFileError:
            continue
        except UserError as exc:
            rows.append(_unreadable(path, exc))
            continue
        pipeline = isinstance(record, PipelineRecord)
        # a pipeline's stages as its file lists them (the sort below keeps ties so)
        runs = [record.runs[name] for name in record.started] if pipeline else [record]
        rows += [_run_row(run) for run in runs]
    rows.sort(key=lambda r: r["created"], reverse=True)
    return rows


def _unreadable(path: Path, exc: UserError) -> dict:
    """The row of a file that cannot be read: it says why, every other cell empty."""
    return {
        "file": path.name,
        "name": "?",
        "model": "?",
        "status": "unreadable",
        "status_text": str(exc),
        "resume": "",
        "progress": "",
        "objective": None,
        "fitness": None,
        "fitness_unit": "",
        "values": {},
        "units": {},
        "at_bound": {},
        "created": "",
        "seed": "",
    }


def _run_row(run) -> dict:
    """One run's (or stage's) row of :func:`list_runs`."""
    a = run.attrs
    cfg = run.config
    values, fitness = best_so_far(run)
    status = run_status(run.path, a, cfg)
    free = cfg.get("free", {})
    names = [n for n in free if n in values]
    if run.best is not None and run.best.at_bound is not None:
        at_bound = dict(run.best.at_bound)
    else:  # the configuration's ranges, as the run was asked for
        at_bound = bound_hits(
            names,
            [values[n] for n in names],
            [free[n][0] for n in names],
            [free[n][1] for n in names],
        )
    return {
        "file": run.path.name + (f" [{run.stage}]" if run.stage else ""),
        "name": a.get("name", ""),
        "model": a.get("model", ""),
        "status": status.state,
        "status_text": status.text,
        "resume": status.hint,
        "progress": progress_text(a, cfg),
        "objective": cfg["objective"],
        "fitness": finite(fitness),
        "fitness_unit": objective_unit(cfg["objective"], a.get("model", "")),
        "values": values,
        "units": units_of(a.get("model", "")),
        "at_bound": at_bound,
        "created": a.get("created", ""),
        "seed": a.get("seed", ""),
    }


# -- several runs side by side ---------------------------------------------------------
def _differences(dicts: list[dict]) -> dict[str, list]:
    """Dotted key -> the value in each dict, for the keys whose values differ.

    A key missing from one dict counts as ``None`` there.
    """
    flat = [flatten(d) for d in dicts]
    keys = []
    for f in flat:
        keys += [k for k in f if k not in keys]
    return {
        k: [f.get(k) for f in flat] for k in keys if len({json.dumps(f.get(k)) for f in flat}) > 1
    }


def _run_entry(res: Results, params: list[str]) -> dict:
    """One run's column of :func:`compare` (JSON-able)."""
    status = res.status()
    best, values, truth, at_bound = res.best(), res.values(), res.truth(), res.at_bound()
    units = res.units()
    bounds = res.bounds
    fixed = res.config.get("fixed", {})
    entry = {}
    for n in params:
        free = n in best
        v = values.get(n)
        true = truth.get(n)
        entry[n] = {
            "value": v,
            "unit": units.get(n, ""),
            "role": "free" if free else "fixed" if n in fixed else "base",
            "bounds": list(bounds[n]) if free else None,
            "at_bound": at_bound.get(n),
            "true": true,
            "error_percent": (
                100 * (v - true) / true
                if free and true not in (None, 0) and v is not None
                else None
            ),
        }
    b = res.record.best
    t = res.record.timings
    return {
        "file": str(res.path),
        "stage": res.stage,
        "name": res.attrs.get("name"),
        "model": res.attrs.get("model"),
        "status": status.state,
        "status_text": status.text,
        "resume": status.hint,
        "progress": res.progress(),
        "objective": res.config["objective"],
        "fitness": finite(res.fitness()),
        "fitness_unit": res.fitness_unit,
        "trial_error_unit": res.trial_error_unit,
        "best_meaning": b.meaning if b is not None and b.meaning is not None else "best so far",
        "params": entry,
        "fit_errors": {k: finite(v) for k, v in (b.fit_errors if b else {}).items()},
        "validation_errors": {k: finite(v) for k, v in (b.validation_errors if b else {}).items()},
        "timings": {
            "total_s": t.get("total_s"),
            "evaluations": t.get("evaluations", 0),
            "ga_evaluations": t.get("ga_evaluations", 0),
            "evaluations_per_s": t.get("evaluations_per_s"),
            "local_s": t.get("local_s"),
        },
    }


def compare(runs: list[Results]) -> dict:
    """Runs side by side (``evo-door compare``), as one JSON-able object.

    ``params`` are the free parameters of any run (their value in every run: free,
    fixed or the base value); for runs of different models only those every model
    declares, and ``models_differ`` says so. ``differences`` holds the settings of the
    resolved configurations (dotted keys) and the package versions that differ.
    ``stages`` gives the pipeline stage of each run (None: a run's own file).
    """
    if len(runs) < 2:
        given = f": only {runs[0].path}" if runs else ""
        raise UserError(f"compare needs two results files or more{given}")
    declared = [list(r.record.settings.param_names) for r in runs]
    models = [r.attrs.get("model") for r in runs]
    free = []
    for r in runs:
        free += [n for n in r.free if n not in free]
    shared = [n for n in free if all(n in d for d in declared)]
    doc = {
        "files": [str(r.path) for r in runs],
        "stages": [r.stage for r in runs],
        "models": models,
        "models_differ": len(set(models)) > 1,
        "params": shared,
        "not_shared": [n for n in free if n not in shared],
        "objectives_differ": len({json.dumps(r.config["objective"]) for r in runs}) > 1,
        "runs": [_run_entry(r, shared) for r in runs],
        "differences": _differences([r.config for r in runs]),
    }
    versions = _differences([r.record.provenance.versions for r in runs])
    doc["differences"].update({f"versions.{k}": v for k, v in versions.items()})
    return doc
