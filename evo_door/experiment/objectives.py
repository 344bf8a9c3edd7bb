"""The same estimation under each objective: max-square or ISE, on derivative 0, 1 or 2.

The seed (section 5.1) says of eq. 5.3 (max-square) and eq. 5.4 (ISE) only that
"sometimes one works better than the other". :func:`plan_comparison` turns one
experiment into a grid of runs, one per objective kind x derivative x GA seed, all
else (model, free parameters and bounds, target, preprocessing, algorithm) as the file
says; :func:`run_comparison` runs them, each into a normal results file of one folder
(so ``evo-door show``, ``runs`` and ``compare`` work on each); :func:`run_records` and
:func:`summarise` read the files back into one row per (kind, derivative): the
estimates over the seeds (mean, min..max, std), their error against the true values
where the trials carry them, fit and validation error, evaluations and run time; and
:func:`write_outputs` writes ``compare.csv``, ``compare.md``, ``compare.png`` and
``runs.csv`` (one row per run).

Fitnesses of different objectives are not on one scale (``(rad/s)^2`` against
``(rad/s)^2 s``, speed against angle), so every run is also scored on one yardstick:
the RMS and the largest absolute error of the angular speed (``dtheta``; of the channel
the trials carry when they have no speed) of the run's answer, simulated on the fitted
and on the validation trials, over the samples the sensor did not saturate
(:func:`yardstick`).

The library call behind ``evo-door compare-objectives``::

    comp = plan_comparison("experiments/default.yaml", seeds=3)
    run_comparison(comp, progress=True)
    records = run_records(comp)
    rows = summarise(records)
    write_outputs(comp, records, rows)
"""

from __future__ import annotations

import json
import math
import os
import sys
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np

from evo_door.channels import RESPONSE_CHANNELS, unit
from evo_door.errors import UserError
from evo_door.experiment import store
from evo_door.experiment.config import Experiment, load_experiment
from evo_door.experiment.format_json import flatten
from evo_door.experiment.results import Results
from evo_door.experiment.runner import ExperimentRun
from evo_door.files import check_image_path, save_figure, write_text
from evo_door.optim.kernels import KINDS as _KINDS
from evo_door.optim.problem import Objective
from evo_door.params.declaration import suggest

#: objective kinds, in the order the seed writes them (eq. 5.3, eq. 5.4)
KINDS = tuple(_KINDS)
DERIVATIVES = (0, 1, 2)
#: the files a comparison writes next to its runs
OUTPUTS = ("compare.csv", "compare.md", "compare.png", "runs.csv")
#: the channel of the common yardstick, in order of preference (speed first: the seed's
#: measured channel and the one people feel)
YARDSTICK_CHANNELS = ("dtheta", "theta", "ddtheta")


# -- options ---------------------------------------------------------------------------
def _items(text: str, option: str, example: str) -> list[str]:
    items = [s.strip() for s in str(text).split(",")]
    if not all(items):
        raise UserError(
            f"{option} {text!r}: expected a comma-separated list, e.g. {option} {example}"
        )
    return items


def parse_kinds(text: str) -> list[str]:
    """``--kinds max_square,ise`` -> ``["max_square", "ise"]`` (``max-square`` accepted).

    >>> parse_kinds("ise, max-square")
    ['ise', 'max_square']
    """
    out = []
    for item in _items(text, "--kinds", "max_square,ise"):
        kind = item.lower().replace("-", "_")
        if kind not in KINDS:
            raise UserError(
                f"--kinds {text}: {item!r} is not an objective kind"
                + suggest(kind, KINDS)
                + f"; kinds: {', '.join(KINDS)}"
            )
        if kind not in out:
            out.append(kind)
    return out


def parse_derivatives(text: str) -> list[int]:
    """``--derivatives 0,1,2`` -> ``[0, 1, 2]``; anything but 0, 1, 2 is refused.

    >>> parse_derivatives("1,0")
    [1, 0]
    """
    out = []
    for item in _items(text, "--derivatives", "0,1,2"):
        if item not in ("0", "1", "2"):
            raise UserError(
                f"--derivatives {text}: {item!r} is not a derivative: 0 (angle theta), "
                "1 (angular speed dtheta) or 2 (angular acceleration ddtheta)"
            )
        if int(item) not in out:
            out.append(int(item))
    return out


def parse_seeds(text) -> int:
    """``--seeds N``: a whole number of GA seeds, at least 1.

    >>> parse_seeds("3")
    3
    """
    try:
        n = int(str(text).strip())
    except ValueError:
        raise UserError(f"--seeds {text}: expected a whole number of GA seeds, e.g. 3") from None
    if n < 1:
        raise UserError(
            f"--seeds {n}: at least 1 (the GA seeds are the experiment's algorithm.seed + 0 .. N-1)"
        )
    return n


# -- the plan --------------------------------------------------------------------------
@dataclass(frozen=True)
class Variant:
    """One run of a comparison: objective kind, derivative, GA seed."""

    kind: str
    derivative: int
    seed: int

    @property
    def channel(self) -> str:
        return RESPONSE_CHANNELS[self.derivative]

    @property
    def overrides(self) -> list[str]:
        """The ``--set`` assignments that make the experiment this variant."""
        return [
            f"objective.kind={self.kind}",
            f"objective.derivative={self.derivative}",
            f"algorithm.seed={self.seed}",
        ]

    def file_name(self, name: str) -> str:
        return f"{name}-{self.kind}-d{self.derivative}-s{self.seed}.h5"


@dataclass
class Comparison:
    """A checked plan: the runs to make and where (see :func:`plan_comparison`)."""

    source: str
    overrides: list
    name: str
    folder: Path
    kinds: list
    derivatives: list
    seeds: list
    #: derivatives left out because the trials lack their channel: derivative -> why
    skipped: dict = field(default_factory=dict)
    experiments: dict = field(default_factory=dict)  # Variant -> Experiment
    #: with ``resume``: complete runs already in the folder, kept as they are
    kept: set = field(default_factory=set)
    force: bool = False
    resume: bool = False

    @property
    def variants(self) -> list[Variant]:
        return [Variant(k, d, s) for k in self.kinds for d in self.derivatives for s in self.seeds]

    def path(self, variant: Variant) -> Path:
        return self.folder / variant.file_name(self.name)

    def notes(self) -> list[str]:
        return [
            f"derivative {d} ({RESPONSE_CHANNELS[d]}) left out: {why}"
            for d, why in self.skipped.items()
        ]


def default_folder(exp: Experiment) -> Path:
    """``<output>/<name>-objectives-<YYYYmmdd-HHMMSS>/``, not an existing one."""
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    base = Path(exp.output) / f"{exp.name}-objectives-{stamp}"
    folder, k = base, 1
    while folder.exists():
        k += 1
        folder = Path(f"{base}-{k}")
    return folder


def _check_folder(folder: Path) -> None:
    """The output folder can be made (or is there) and written in, else one line."""
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{folder}: is a file, not a folder; give --out a folder")
    existing = folder
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise UserError(f"{folder}: {existing} is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise UserError(f"{folder}: cannot write in {existing}")


def _same_settings(path: Path, exp: Experiment) -> None:
    """A run kept by ``resume`` must have been made from the very same settings."""
    res = Results(path)
    old, new = flatten(res.config), flatten(exp.resolved())
    differ = [
        k for k in dict.fromkeys([*old, *new]) if json.dumps(old.get(k)) != json.dumps(new.get(k))
    ]
    if differ:
        key = differ[0]
        raise UserError(
            f"{path}: made with other settings ({key}: {old.get(key)!r}, now {new.get(key)!r}); "
            "give --force to run it again, or another --out"
        )


def plan_comparison(
    experiment,
    overrides=(),
    kinds=KINDS,
    derivatives=None,
    seeds: int = 1,
    out=None,
    force: bool = False,
    resume: bool = False,
    loader=None,
) -> Comparison:
    """Check everything a comparison needs before anything runs or is written.

    Parameters
    ----------
    experiment : str or Path
        The experiment file; ``overrides`` are its ``--set`` assignments.
    kinds : list of str
        Objective kinds (``max_square``, ``ise``).
    derivatives : list of int or None
        Derivatives compared. None: every derivative whose channel every fitted and
        validation trial carries, the others left out with a note
        (:attr:`Comparison.skipped`); a derivative asked for by name that the trials
        cannot serve is an error.
    seeds : int
        Number of GA seeds: the experiment's ``algorithm.seed`` + 0 .. seeds - 1.
    out : folder
        Where the runs and tables go (default :func:`default_folder`).
    force, resume :
        What to do with runs already in ``out``: replace them, or keep the complete
        ones made from the same settings and continue an interrupted one. Without
        either, a folder that already holds a run of the plan is refused.
    loader : callable, optional
        ``loader(overrides) -> Experiment`` in place of reading ``experiment`` as an
        experiment file (a pipeline's stage: :func:`evo_door.experiment.pipeline.stage_loader`).
    """
    if loader is None:

        def loader(assignments):
            return load_experiment(experiment, assignments)

    overrides = list(overrides)
    kinds = list(kinds)
    for kind in kinds:
        if kind not in KINDS:
            raise UserError(
                f"objective kind {kind!r} is not one of {', '.join(KINDS)}" + suggest(kind, KINDS)
            )
    if derivatives is not None:
        derivatives = list(derivatives)
        if not derivatives or any(d not in DERIVATIVES for d in derivatives):
            raise UserError(f"derivatives {derivatives}: each is 0, 1 or 2")
    if not kinds:
        raise UserError("no objective kind to compare")
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise UserError(f"seeds {seeds!r}: at least 1")
    base = loader(overrides)
    seed0 = base.algorithm.ga.seed
    folder = Path(out) if out is not None else default_folder(base)
    _check_folder(folder)
    comp = Comparison(
        source=str(experiment),
        overrides=overrides,
        name=base.name,
        folder=folder,
        kinds=kinds,
        derivatives=[],
        seeds=[seed0 + k for k in range(seeds)],
        force=force,
        resume=resume,
    )

    def variant_experiment(v: Variant) -> Experiment:
        return loader(overrides + v.overrides)

    # which derivatives the trials serve: read and check the data once per derivative,
    # as a run would (nothing is written). Only the channel check depends on the
    # derivative, so one that fails while another passes lacks its channel.
    failed: dict[int, UserError] = {}
    why: dict[int, str] = {}
    for d in DERIVATIVES:
        exp = variant_experiment(Variant(kinds[0], d, seed0))
        try:
            ExperimentRun.new(exp, folder / "x.h5")
        except UserError as exc:
            failed[d] = exc
            # the channel is missing: said without the file's objective line, which
            # the comparison overrides
            why[d] = str(exc).removeprefix(f"{exp.locs['objective']}: objective.derivative: ")
    wanted = list(DERIVATIVES) if derivatives is None else derivatives
    available = [d for d in DERIVATIVES if d not in failed]
    if not available:  # not a matter of channels: the experiment cannot run at all
        raise failed[wanted[0]]
    why = {d: text for d, text in why.items() if d in wanted}
    if derivatives is not None and why:
        d = next(d for d in wanted if d in why)
        raise UserError(
            f"--derivatives {d}: {why[d]}; these trials allow --derivatives "
            + ",".join(map(str, available))
        )
    served = [d for d in wanted if d not in failed]
    comp.derivatives = served
    comp.skipped = why
    for v in comp.variants:
        comp.experiments[v] = variant_experiment(v)
    # runs already in the folder: replaced (force), kept or continued (resume), or refused
    there = [v for v in comp.variants if comp.path(v).exists()]
    if there and not (force or resume):
        first = comp.path(there[0])
        more = f" and {len(there) - 1} more run(s) of this comparison" if len(there) > 1 else ""
        raise UserError(
            f"{folder}: already holds {first.name}{more}; give another --out, --force to "
            "replace them, or --resume to keep the complete ones and run the rest"
        )
    if resume and not force:
        for v in there:
            _same_settings(comp.path(v), comp.experiments[v])
            if Results(comp.path(v)).complete:
                comp.kept.add(v)
    return comp


# -- running ---------------------------------------------------------------------------
def make_folder(comp: Comparison) -> None:
    """The comparison's folder, made if need be (one line if the system refuses)."""
    try:
        comp.folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{comp.folder}: cannot make the folder ({exc.strerror or exc})") from None


def run_comparison(comp: Comparison, progress: bool = False, on_run=None) -> list[Path]:
    """Make every run of ``comp`` (kept ones excepted); return the results files.

    ``progress`` shows a header line and the run's progress bar on stderr per run;
    ``on_run(variant, path)`` is called after each run is complete. Ctrl-C leaves the
    run at work resumable (``evo-door resume FILE``, or the comparison with ``resume``).
    """
    variants = comp.variants
    paths = []
    make_folder(comp)
    for i, v in enumerate(variants, 1):
        path = comp.path(v)
        head = f"[{i}/{len(variants)}] {v.kind} on {v.channel}, seed {v.seed}"
        if v in comp.kept:
            if progress:
                print(f"{head}: kept {path} (complete)", file=sys.stderr, flush=True)
        else:
            if comp.resume and not comp.force and path.exists():
                run = ExperimentRun.open(path)
                what = "continuing"
            else:
                run = ExperimentRun.create(comp.experiments[v], path, overwrite=comp.force)
                what = "writing"
            if progress:
                print(f"{head}: {what} {path}", file=sys.stderr, flush=True)
            run.label_prefix = f"[{i}/{len(variants)}] "
            run.run(progress=progress)
        paths.append(path)
        if on_run is not None:
            on_run(v, path)
    return paths


# -- reading the runs back -------------------------------------------------------------
def yardstick(res: Results) -> dict:
    """The run's answer scored on one channel whatever the objective: RMS and max error.

    The channel is the angular speed ``dtheta`` when every fitted and validation trial
    carries it, else ``theta``, else ``ddtheta``; the run's answer is simulated on each
    trial (as the run itself did) and compared sample by sample, saturated samples left
    out. Returns ``{"channel", "unit", "fit", "validation", "fit_max",
    "validation_max"}``: the RMS and the largest absolute error over the samples of the
    fitted and of the validation trials, in the channel's SI unit (None without
    validation trials, inf where a simulation blew up). The RMS is ISE's measure and the
    max max-square's: both are given so that neither objective is judged on its own.
    """
    setup = store.setup_from_tree(res.tree)
    trials = setup.fit + setup.validation
    channel = next(
        c for c in YARDSTICK_CHANNELS if all(getattr(tr, c) is not None for tr in trials)
    )
    problem = setup.problem()
    x = np.asarray(res.tree["best"]["x"], dtype=np.float64)
    out = {"channel": channel, "unit": unit(channel, setup.model.theta_unit)}
    for role, pack in (("fit", problem.fit), ("validation", problem.validation)):
        out[role] = out[f"{role}_max"] = None
        if not len(pack):
            continue
        squares, count, largest = 0.0, 0, 0.0
        for tr, r in zip(pack.trials, problem.responses(x, pack)):
            if not r.ok:
                squares = largest = math.inf
                break
            keep = tr.unsaturated(channel)
            e = getattr(r, channel)[keep] - getattr(tr, channel)[keep]
            squares += float(e @ e)
            count += int(keep.sum())
            largest = max(largest, float(np.max(np.abs(e), initial=0.0)))
        finite = count and math.isfinite(squares)
        out[role] = math.sqrt(squares / count) if finite else math.inf
        out[f"{role}_max"] = largest if finite else math.inf
    return out


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
        first = group[0]
        params = {}
        for n in first["free"]:
            errors = [r["errors"][n] for r in group]
            params[n] = {
                "unit": first["units"].get(n, ""),
                "value": _spread([r["values"][n] for r in group]),
                "true": first["truth"].get(n),
                "error": _spread(errors) if all(e is not None for e in errors) else None,
                "abs_error": (
                    float(np.mean([abs(e) for e in errors]))
                    if all(e is not None for e in errors)
                    else None
                ),
            }
        ys = first["yardstick"]
        rows.append(
            {
                "kind": key[0],
                "derivative": key[1],
                "channel": first["channel"],
                "seeds": [r["seed"] for r in group],
                "params": params,
                "fitness": _spread([r["fitness"] for r in group]),
                "fitness_unit": first["fitness_unit"],
                "validation_error": (
                    _spread([r["validation_error"] for r in group])
                    if first["validation_error"] is not None
                    else None
                ),
                "rms_channel": ys["channel"],
                "rms_unit": ys["unit"],
                "rms_fit": _spread([r["yardstick"]["fit"] for r in group]),
                "rms_validation": (
                    _spread([r["yardstick"]["validation"] for r in group])
                    if ys["validation"] is not None
                    else None
                ),
                "max_fit": _spread([r["yardstick"]["fit_max"] for r in group]),
                "max_validation": (
                    _spread([r["yardstick"]["validation_max"] for r in group])
                    if ys["validation"] is not None
                    else None
                ),
                "theta_unit": first["theta_unit"],
                "evaluations": _spread([r["evaluations"] for r in group]),
                "seconds": _spread([r["seconds"] for r in group]),
                "seconds_total": float(sum(r["seconds"] for r in group)),
                "at_bound": [
                    f"seed {r['seed']}: {n} {side}"
                    for r in group
                    for n, side in r["at_bound"].items()
                ],
            }
        )
    return rows


# -- text ------------------------------------------------------------------------------
def _g(v, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "blew up"
    if isinstance(v, float) and math.isnan(v):
        return "-"
    return f"{v:.{digits}g}"


def _pct(v) -> str:
    """A percentage: two decimals, or two digits of a tiny one (``-1.4e-04``)."""
    if v is None or not math.isfinite(v):
        return "-"
    return f"{v:+.2f}" if abs(v) >= 0.01 or v == 0 else f"{v:+.1e}"


def _with_range(s: dict, fmt, unit_text: str = "") -> str:
    """``mean (min .. max)`` (only the mean for one seed)."""
    text = fmt(s["mean"])
    if s["n"] > 1 and math.isfinite(s["min"]):
        text += f" ({fmt(s['min'])} .. {fmt(s['max'])})"
    return text + unit_text


def _objective_label(row: dict) -> str:
    return f"{row['kind']} on {row['channel']} (d{row['derivative']})"


def _human_rms(row: dict) -> tuple[float, str]:
    """Factor and unit of the yardstick shown to people: degrees for an angle model."""
    if row["theta_unit"] == "rad":
        return 180.0 / math.pi, row["rms_unit"].replace("rad", "deg")
    return 1.0, row["rms_unit"]


def _scaled(s: dict | None, factor: float) -> dict | None:
    if s is None:
        return None
    return {k: (v * factor if k != "n" else v) for k, v in s.items()}


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


def verdict(rows: list[dict]) -> list[str]:
    """One line per measure: the objective that did best by it."""
    best = best_rows(rows)
    lines = []
    if best["truth"] is not None:
        row, value = best["truth"]
        lines.append(
            f"closest to the true values: {_objective_label(row)}, mean |error| "
            f"{value:.3g} % over the free parameters and seeds"
        )
    for measure in ("rms", "max"):
        if best[measure] is None:
            continue
        row, value = best[measure]
        factor, human = _human_rms(row)
        si = f" ({value:.3g} {row['rms_unit']})" if factor != 1.0 else ""
        what = (
            f"RMS {row['rms_channel']} error"
            if measure == "rms"
            else f"max |{row['rms_channel']} error|"
        )
        lines.append(
            f"smallest {what} on the {best['role']} trials: "
            f"{_objective_label(row)}, {value * factor:.3g} {human}{si}"
        )
    return lines


def markdown(comp: Comparison | None, rows: list[dict]) -> str:
    """``compare.md``: the table, the verdict, notes, and the command that made it."""
    names = list(rows[0]["params"])
    truth = any(p["true"] is not None for r in rows for p in r["params"].values())
    factor, human = _human_rms(rows[0])
    rms_units = human + (f"; {rows[0]['rms_unit']} in compare.csv" if factor != 1.0 else "")
    head = ["objective", "seeds"]
    for n in names:
        u = rows[0]["params"][n]["unit"]
        head.append(f"{n}" + (f" [{u}]" if u and u != "1" else ""))
        if truth:
            head.append(f"{n} error [%]")
    head += [
        "fitness",
        "validation error",
        f"RMS {rows[0]['rms_channel']} error, fit [{human}]",
        f"RMS {rows[0]['rms_channel']} error, validation [{human}]",
        f"max abs {rows[0]['rms_channel']} error, validation [{human}]",
        "evaluations",
        "time per run [s]",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [_objective_label(r), str(len(r["seeds"]))]
        for n in names:
            p = r["params"][n]
            cells.append(_with_range(p["value"], lambda v: _g(v, 5)))
            if truth:
                cells.append("-" if p["error"] is None else _with_range(p["error"], _pct))
        cells.append(_with_range(r["fitness"], _g, f" {r['fitness_unit']}"))
        cells.append(
            "-"
            if r["validation_error"] is None
            else _with_range(r["validation_error"], _g, f" {r['fitness_unit']}")
        )
        cells.append(_with_range(_scaled(r["rms_fit"], factor), lambda v: _g(v, 3)))
        for key in ("rms_validation", "max_validation"):
            rv = _scaled(r[key], factor)
            cells.append("-" if rv is None else _with_range(rv, lambda v: _g(v, 3)))
        cells.append(_with_range(r["evaluations"], lambda v: f"{v:.0f}"))
        cells.append(_with_range(r["seconds"], lambda v: f"{v:.1f}"))
        lines.append("| " + " | ".join(cells) + " |")
    out = [
        f"# Objectives compared: {comp.name if comp else ''}".rstrip(),
        "",
        "Mean over the GA seeds, (min .. max) over them. Fitness and validation error are "
        "in each objective's own units and not comparable across rows; the RMS and the "
        f"largest absolute {rows[0]['rms_channel']} error of each run's answer, simulated "
        f"on the trials, are on one scale ({rms_units}).",
        "",
        *lines,
        "",
    ]
    if truth:
        out += [f"Error against the true values stored with the trials: {_truth_text(rows)}.", ""]
    out += [f"- {line}" for line in verdict(rows)]
    bound = [f"{_objective_label(r)} {note}" for r in rows for note in r["at_bound"]]
    if bound:
        out.append(
            "- on a bound of its search range (the bound, not the data, decided): "
            + "; ".join(bound)
        )
    if comp is not None:
        out += [f"- {note}" for note in comp.notes()]
        out += ["", "Made with:", "", "```", command_line(comp), "```"]
    return "\n".join(out) + "\n"


def _truth_text(rows: list[dict]) -> str:
    p = rows[0]["params"]
    return ", ".join(
        f"{n} = {v['true']:.6g}" + (f" {v['unit']}" if v["unit"] not in ("", "1") else "")
        for n, v in p.items()
        if v["true"] is not None
    )


def command_line(comp: Comparison) -> str:
    """The command that makes this comparison again (into a new folder)."""
    parts = ["evo-door compare-objectives", comp.source]
    parts.append("--kinds " + ",".join(comp.kinds))
    parts.append("--derivatives " + ",".join(map(str, comp.derivatives)))
    parts.append(f"--seeds {len(comp.seeds)}")
    parts += [f"--set {a}" for a in comp.overrides]
    return " ".join(parts)


def format_summary(comp: Comparison | None, rows: list[dict]) -> str:
    """The table printed at the end of ``evo-door compare-objectives``."""
    names = list(rows[0]["params"])
    truth = any(p["true"] is not None for r in rows for p in r["params"].values())
    factor, human = _human_rms(rows[0])
    header = ["objective"]
    for n in names:
        u = rows[0]["params"][n]["unit"]
        header.append(
            f"{n}" + (f" [{u}]" if u and u != "1" else "") + (" (error %)" if truth else "")
        )
    role = "validation" if rows[0]["rms_validation"] is not None else "fit"
    ch = rows[0]["rms_channel"]
    header += [f"{ch} err, {role}: RMS | max [{human}]", "evals", "s/run"]
    table = []
    for r in rows:
        cells = [_objective_label(r)]
        for n in names:
            p = r["params"][n]
            text = _g(p["value"]["mean"], 5)
            if p["error"] is not None:
                e = p["error"]
                text += f" ({_pct(e['mean'])}"
                if e["n"] > 1 and math.isfinite(e["min"]):
                    text += f", {_pct(e['min'])}..{_pct(e['max'])}"
                text += ")"
            cells.append(text)
        rms = _scaled(r[f"rms_{role}"], factor)["mean"]
        cells.append(f"{_g(rms, 3)} | {_g(_scaled(r[f'max_{role}'], factor)['mean'], 3)}")
        cells.append(f"{r['evaluations']['mean']:.0f}")
        cells.append(f"{r['seconds']['mean']:.1f}")
        table.append(cells)
    widths = [max(len(h), *(len(row[i]) for row in table)) for i, h in enumerate(header)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    out = [fmt.format(*header).rstrip(), fmt.format(*("-" * w for w in widths)).rstrip()]
    out += [fmt.format(*row).rstrip() for row in table]
    n_seeds = len(rows[0]["seeds"])
    out.append(
        f"mean over {n_seeds} GA seed(s)" + (", (min..max) over them" if n_seeds > 1 else "")
    )
    out += verdict(rows)
    out += [
        f"on a search bound: {_objective_label(r)} {note}" for r in rows for note in r["at_bound"]
    ]
    if comp is not None:
        out += comp.notes()
    return "\n".join(out)


# -- files -----------------------------------------------------------------------------
def _csv_number(v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return f"{v:.10g}"


def _csv(header: list[str], rows: list[list]) -> str:
    lines = [",".join(header)]
    lines += [",".join(c if isinstance(c, str) else _csv_number(c) for c in row) for row in rows]
    return "\n".join(lines) + "\n"


def summary_csv(rows: list[dict]) -> str:
    """``compare.csv``: one line per (kind, derivative), SI units in the column names."""
    names = list(rows[0]["params"])
    ch, su = rows[0]["rms_channel"], rows[0]["rms_unit"]
    factor, human = _human_rms(rows[0])
    header = ["kind", "derivative", "channel", "seeds"]
    for n in names:
        u = rows[0]["params"][n]["unit"]
        header += [f"{n} {s} [{u}]" for s in ("mean", "min", "max", "std", "true")]
        header += [f"{n} error {s} [%]" for s in ("mean", "min", "max")]
        header.append(f"{n} abs error mean [%]")
    header += ["fitness mean", "fitness min", "fitness max", "fitness unit"]
    header += ["validation error mean", "validation error min", "validation error max"]
    for what in ("rms", "max abs"):
        for role in ("fit", "validation"):
            header += [f"{what} {ch} error {role} {s} [{su}]" for s in ("mean", "min", "max")]
            if factor != 1.0:
                header.append(f"{what} {ch} error {role} mean [{human}]")
    header += ["evaluations mean", "seconds mean", "seconds total", "on a bound"]
    table = []
    for r in rows:
        line = [r["kind"], str(r["derivative"]), r["channel"], " ".join(map(str, r["seeds"]))]
        for n in names:
            p = r["params"][n]
            v, e = p["value"], p["error"] or {}
            line += [v["mean"], v["min"], v["max"], v["std"], p["true"]]
            line += [e.get("mean"), e.get("min"), e.get("max"), p["abs_error"]]
        f = r["fitness"]
        line += [f["mean"], f["min"], f["max"], r["fitness_unit"]]
        ve = r["validation_error"] or {}
        line += [ve.get("mean"), ve.get("min"), ve.get("max")]
        for measure in ("rms", "max"):
            for role in ("fit", "validation"):
                s = r[f"{measure}_{role}"] or {}
                line += [s.get("mean"), s.get("min"), s.get("max")]
                if factor != 1.0:
                    line.append(None if not s else s["mean"] * factor)
        line += [r["evaluations"]["mean"], r["seconds"]["mean"], r["seconds_total"]]
        line.append("; ".join(r["at_bound"]))
        table.append(line)
    return _csv(header, table)


def runs_csv(records: list[dict]) -> str:
    """``runs.csv``: one line per run (file, objective, seed, estimates, errors, costs)."""
    first = records[0]
    ch, su = first["yardstick"]["channel"], first["yardstick"]["unit"]
    header = ["file", "kind", "derivative", "channel", "seed"]
    for n in first["free"]:
        header += [f"{n} [{first['units'][n]}]", f"{n} error [%]"]
    header += ["fitness", "fitness unit", "validation error"]
    header += [f"rms {ch} error {role} [{su}]" for role in ("fit", "validation")]
    header += [f"max abs {ch} error {role} [{su}]" for role in ("fit", "validation")]
    header += ["evaluations", "seconds", "on a bound"]
    table = []
    for r in records:
        line = [r["file"], r["kind"], str(r["derivative"]), r["channel"], str(r["seed"])]
        for n in r["free"]:
            line += [r["values"][n], r["errors"][n]]
        line += [r["fitness"], r["fitness_unit"], r["validation_error"]]
        y = r["yardstick"]
        line += [y["fit"], y["validation"], y["fit_max"], y["validation_max"]]
        line += [float(r["evaluations"]), r["seconds"]]
        line.append(" ".join(f"{n}:{s}" for n, s in r["at_bound"].items()))
        table.append(line)
    return _csv(header, table)


def figure(rows: list[dict], records: list[dict], title: str = ""):
    """Error against the truth (or the estimate) per free parameter and objective, the
    seeds as dots, their mean with a min..max bar; two last panels for the yardstick
    (RMS and largest error, :func:`yardstick`)."""
    from matplotlib.figure import Figure

    names = list(rows[0]["params"])
    factor, human = _human_rms(rows[0])
    panels = len(names) + 2
    ncols = min(panels, 3) if panels <= 6 else 4
    nrows = math.ceil(panels / ncols)
    fig = Figure(
        figsize=(max(3.3, 0.6 * len(rows) + 0.9) * ncols, 3.6 * nrows + 0.9), layout="constrained"
    )
    axes = list(fig.subplots(nrows, ncols, squeeze=False).flat)
    short = {"max_square": "max-sq", "ise": "ISE"}
    labels = [f"{short.get(r['kind'], r['kind'])}\n{r['channel']}" for r in rows]
    colors = {k: f"C{i}" for i, k in enumerate(KINDS)}
    x = np.arange(len(rows))

    def draw(ax, per_row, spreads, ylabel, zero_line):
        for i, (r, values, s) in enumerate(zip(rows, per_row, spreads)):
            color = colors.get(r["kind"], "0.3")
            finite = [v for v in values if v is not None and math.isfinite(v)]
            ax.plot([i] * len(finite), finite, "o", color=color, ms=3.5, alpha=0.45)
            if s is not None and math.isfinite(s["mean"]):
                lo = s["mean"] - s["min"] if math.isfinite(s["min"]) else 0.0
                hi = s["max"] - s["mean"] if math.isfinite(s["max"]) else 0.0
                ax.errorbar(
                    [i],
                    [s["mean"]],
                    yerr=[[lo], [hi]],
                    fmt="_",
                    color=color,
                    ms=14,
                    mew=2,
                    capsize=4,
                    lw=1.2,
                )
        if zero_line:
            ax.axhline(0.0, color="0.4", lw=0.8)
        ax.set_xticks(x, labels, fontsize=7.5)
        ax.set_xlim(-0.6, len(rows) - 0.4)
        ax.set_ylabel(ylabel, fontsize=9)
        ax.grid(alpha=0.3, axis="y")

    for ax, n in zip(axes, names):
        p0 = rows[0]["params"][n]
        if p0["true"] is not None:
            per_row = [[rec["errors"][n] for rec in _group(records, r)] for r in rows]
            spreads = [r["params"][n]["error"] for r in rows]
            draw(ax, per_row, spreads, f"error of {n} against the truth [%]", True)
            ax.set_title(f"{n} (true {p0['true']:.5g} {p0['unit']})", fontsize=9)
        else:
            per_row = [[rec["values"][n] for rec in _group(records, r)] for r in rows]
            spreads = [r["params"][n]["value"] for r in rows]
            draw(ax, per_row, spreads, f"{n} [{p0['unit']}]", False)
            ax.set_title(f"{n} (no true value in the trials)", fontsize=9)
    role = "validation" if rows[0]["rms_validation"] is not None else "fit"
    for ax, (measure, what) in zip(axes[len(names) :], (("rms", "RMS"), ("max", "largest"))):
        key = f"{role}_max" if measure == "max" else role
        per_row = [[rec["yardstick"][key] * factor for rec in _group(records, r)] for r in rows]
        spreads = [_scaled(r[f"{measure}_{role}"], factor) for r in rows]
        draw(ax, per_row, spreads, f"{what} {rows[0]['rms_channel']} error [{human}]", False)
        ax.set_ylim(bottom=0)
        ax.set_title(f"common yardstick: {what}, {role} trials", fontsize=9)
    for ax in axes[panels:]:
        ax.axis("off")
    n_seeds = len(rows[0]["seeds"])
    fig.suptitle(
        f"{title}: max-square (eq. 5.3) and ISE (eq. 5.4) on each derivative; "
        f"{n_seeds} GA seed(s): dots, mean with min..max bar",
        fontsize=10,
    )
    return fig


def _group(records: list[dict], row: dict) -> list[dict]:
    return [r for r in records if (r["kind"], r["derivative"]) == (row["kind"], row["derivative"])]


def write_outputs(comp: Comparison, records: list[dict], rows: list[dict]) -> list[Path]:
    """``compare.csv``, ``compare.md``, ``compare.png`` and ``runs.csv`` in the folder."""
    folder = comp.folder
    check_image_path(folder / "compare.png")
    paths = [folder / name for name in OUTPUTS]
    write_text(paths[0], summary_csv(rows))
    write_text(paths[1], markdown(comp, rows))
    save_figure(figure(rows, records, comp.name), paths[2], dpi=110)
    write_text(paths[3], runs_csv(records))
    return paths


def compare_objectives(
    experiment,
    overrides=(),
    kinds=KINDS,
    derivatives=None,
    seeds: int = 1,
    out=None,
    progress: bool = False,
) -> tuple[Comparison, list[dict], list[dict]]:
    """Plan, run, read back and write a comparison in one call (library use)."""
    comp = plan_comparison(experiment, overrides, kinds, derivatives, seeds, out)
    run_comparison(comp, progress=progress)
    records = run_records(comp)
    rows = summarise(records)
    write_outputs(comp, records, rows)
    return comp, records, rows
