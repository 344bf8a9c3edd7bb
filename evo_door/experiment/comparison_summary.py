"""What each objective achieved: the runs of a comparison read back into one row each.

:func:`run_record` reads one run's results file (estimates, their error against the true
values, fitness, validation error, the common yardstick
(:func:`evo_door.experiment.objectives.yardstick`), evaluations and time);
:func:`summarise` makes one row per (kind, derivative) of a comparison
(:mod:`.comparison`), the spread over its GA seeds; :func:`best_rows` says which did
best by each measure.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from evo_door.errors import UserError
from evo_door.experiment import store
from evo_door.experiment.comparison import Comparison, Variant
from evo_door.experiment.objectives import yardstick
from evo_door.experiment.results import Results
from evo_door.optim.problem import Objective


def run_record(path, variant: Variant | None = None) -> dict:
    """One run's numbers for the tables, read from its results file."""
    res = Results(path)
    if not res.complete:
        raise UserError(f"{path}: the run is not complete (evo-door resume {path})")
    obj = res.config["objective"]
    if variant is None:
        variant = Variant(obj["kind"], int(obj["derivative"]), int(res.attrs.get("seed", 0)))
    values, truth = res.best(), res.truth()
    errors = {
        n: (100.0 * (v - truth[n]) / truth[n] if truth.get(n) not in (None, 0.0) else None)
        for n, v in values.items()
    }
    summary = res.summary()
    validation = [
        math.inf if e is None else e for e in summary.get("validation_errors", {}).values()
    ]
    objective = Objective(obj["kind"], int(obj["derivative"]), obj["combine"])
    combined = None
    if validation:
        errs = np.array([validation])
        combined = float(objective.combine_errors(errs, np.isfinite(errs))[0])
    timings = res.tree["timings"][store.ATTRS]
    model = res.model
    return {
        "file": Path(path).name,
        "path": str(path),
        "kind": variant.kind,
        "derivative": variant.derivative,
        "channel": variant.channel,
        "seed": variant.seed,
        "free": list(res.free),
        "units": {n: res.units().get(n, "") for n in res.free},
        "values": values,
        "truth": truth,
        "errors": errors,
        "at_bound": res.at_bound(),
        "fitness": res.fitness(),
        "fitness_unit": res.fitness_unit,
        "validation_error": combined,
        "yardstick": yardstick(res),
        "theta_unit": "rad" if model is None else model.theta_unit,
        "evaluations": int(timings.get("evaluations", 0)),
        "seconds": float(timings.get("total_s") or 0.0),
    }


def run_records(comp: Comparison) -> list[dict]:
    """:func:`run_record` of every run of the plan, in its order."""
    return [run_record(comp.path(v), v) for v in comp.variants]


def _spread(values) -> dict:
    """Mean, min, max, sample std and count of one number over the seeds.

    A missing value (None) makes every statistic NaN; a blown-up one (inf) makes the
    mean and max inf and the std NaN.
    """
    v = np.array([np.nan if x is None else x for x in values], dtype=float)
    if not v.size or np.isnan(v).any():
        return {"mean": math.nan, "min": math.nan, "max": math.nan, "std": math.nan, "n": v.size}
    finite = bool(np.isfinite(v).all())
    return {
        "mean": float(v.mean()),
        "min": float(v.min()),
        "max": float(v.max()),
        "std": float(v.std(ddof=1)) if finite and v.size > 1 else math.nan,
        "n": int(v.size),
    }


def summarise(records: list[dict]) -> list[dict]:
    """One row per (kind, derivative): the seeds' estimates, errors and costs.

    Each row has ``kind``, ``derivative``, ``channel``, ``seeds``, ``params`` (name ->
    ``value`` and ``error`` spreads (:func:`_spread`: mean, min, max, std, n), ``true``,
    ``abs_error`` mean, ``unit``), ``fitness``, ``validation_error`` (the objective's
    own units, ``fitness_unit``), ``rms_fit``, ``rms_validation``, ``max_fit`` and
    ``max_validation`` (the yardstick, :func:`yardstick`, in ``rms_unit`` of
    ``rms_channel``), ``evaluations``, ``seconds`` (spreads),
    ``seconds_total`` and ``at_bound`` (``"seed 2: F_load upper"`` notes).
    """
    rows = []
    for key in dict.fromkeys((r["kind"], r["derivative"]) for r in records):
        group = [r for r in records if (r["kind"], r["derivative"]) == key]
        rows.append(_row(key, group))
    return rows


def _row(key: tuple, group: list[dict]) -> dict:
    """The row of one (kind, derivative) from its seeds' records (see :func:`summarise`)."""
    first = group[0]
    ys = first["yardstick"]

    def spread(field: str, present: bool = True):
        """The seeds' spread of ``field`` (None where the run has none)."""
        return _spread([r[field] for r in group]) if present else None

    def yardstick(field: str, present: bool = True):
        return _spread([r["yardstick"][field] for r in group]) if present else None

    validated = ys["validation"] is not None
    return {
        "kind": key[0],
        "derivative": key[1],
        "channel": first["channel"],
        "seeds": [r["seed"] for r in group],
        "params": {n: _param_row(n, group) for n in first["free"]},
        "fitness": spread("fitness"),
        "fitness_unit": first["fitness_unit"],
        "validation_error": spread("validation_error", first["validation_error"] is not None),
        "rms_channel": ys["channel"],
        "rms_unit": ys["unit"],
        "rms_fit": yardstick("fit"),
        "rms_validation": yardstick("validation", validated),
        "max_fit": yardstick("fit_max"),
        "max_validation": yardstick("validation_max", validated),
        "theta_unit": first["theta_unit"],
        "evaluations": spread("evaluations"),
        "seconds": spread("seconds"),
        "seconds_total": float(sum(r["seconds"] for r in group)),
        "at_bound": [
            f"seed {r['seed']}: {n} {side}" for r in group for n, side in r["at_bound"].items()
        ],
    }


def _param_row(name: str, group: list[dict]) -> dict:
    """One free parameter over the seeds: unit, value spread, truth, error spread and
    mean absolute error (None without a truth)."""
    first = group[0]
    errors = [r["errors"][name] for r in group]
    known = all(e is not None for e in errors)
    return {
        "unit": first["units"].get(name, ""),
        "value": _spread([r["values"][name] for r in group]),
        "true": first["truth"].get(name),
        "error": _spread(errors) if known else None,
        "abs_error": float(np.mean([abs(e) for e in errors])) if known else None,
    }


def best_rows(rows: list[dict]) -> dict:
    """Which (kind, derivative) did best, by each measure.

    ``truth``: the smallest mean |error| against the true values (over the free
    parameters and seeds); ``rms`` and ``max``: the smallest yardstick on the validation
    trials (on the fitted ones without validation trials). Each is ``(row, value)`` or
    None; ``role`` says which trials the yardstick is on.
    """
    role = "validation" if all(r["rms_validation"] is not None for r in rows) else "fit"
    out = {"truth": None, "rms": None, "max": None, "role": role}
    scored = []
    for r in rows:
        errs = [p["abs_error"] for p in r["params"].values()]
        if errs and all(e is not None for e in errs):
            scored.append((float(np.mean(errs)), r))
    for measure in ("rms", "max"):
        ranked = [(r[f"{measure}_{role}"]["mean"], r) for r in rows]
        ranked = [(v, r) for v, r in ranked if math.isfinite(v)]
        if ranked:
            value, row = min(ranked, key=lambda s: s[0])
            out[measure] = (row, value)
    if scored:
        value, row = min(scored, key=lambda s: s[0])
        out["truth"] = (row, value)
    return out
