"""Reading results files: the views of ``evo-door show``, ``runs`` and ``compare``.

Everything a user sees about a run is derived here from its results file (layout in
``docs/experiments.md``, "Results files"), in one place per question:

- :func:`run_status`: complete, running (a process holds the file's lock) or
  interrupted (the file says ``running`` but nobody holds the lock: the run was
  stopped by Ctrl-C, SIGTERM, SIGKILL or a crash, and ``evo-door resume`` continues it);
- :func:`bound_hits`: which estimates sit on a bound of their search range;
- :class:`Results` (``show``), :func:`list_runs` (``runs``, cheap: no arrays read),
  :func:`compare` (``compare``), and the figures :func:`plot_fit` and
  :func:`plot_convergence`.
"""

from __future__ import annotations

import functools
import json
import math
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evo_door.channels import unit as channel_unit
from evo_door.errors import UserError
from evo_door.experiment import store
from evo_door.files import FileLock, open_h5, read_attrs, save_figure
from evo_door.optim.problem import Objective

A = store.ATTRS

#: an estimate this close to a bound (as a fraction of its search range) was decided
#: by the bound, not by the data
BOUND_TOLERANCE = 1e-3


# -- the questions every view asks ---------------------------------------------------
def bound_hits(names, x, lower, upper, tolerance: float = BOUND_TOLERANCE) -> dict[str, str]:
    """The estimates that sit on a bound of their search range: name -> ``"lower"|"upper"``.

    An estimate within ``tolerance`` (0.1 %) of the range ``hi - lo`` from a bound was
    stopped by the bound: the data would have taken it further, so the value says
    more about the range in ``free:`` than about the product.

    >>> bound_hits(["k", "c", "m"], [500.0, 2.0, 0.2004], [20, 0, 0.2], [500, 10, 8])
    {'k': 'upper', 'm': 'lower'}
    """
    out = {}
    for name, v, lo, hi in zip(names, x, lower, upper):
        v, lo, hi = float(v), float(lo), float(hi)
        if not math.isfinite(v):
            continue
        slack = tolerance * (hi - lo)
        if abs(v - lo) <= slack:
            out[name] = "lower"
        elif abs(hi - v) <= slack:
            out[name] = "upper"
    return out


@dataclass(frozen=True)
class Status:
    """Where a run stands, as :func:`run_status` reads it.

    Attributes
    ----------
    state : str
        ``complete``, ``running`` (a process holds the file) or ``interrupted``.
    text : str
        One line for a person: ``interrupted at generation 7/20``, ``running (process 812)``.
    hint : str
        What to do about it (``evo-door resume FILE`` for an interrupted run), or "".
    pid : int or None
        The process writing the file, while one does (and says which).
    """

    state: str
    text: str
    hint: str = ""
    pid: int | None = None


def run_status(path, attrs: dict, config: dict) -> Status:
    """The status of the run in ``path`` from its root ``attrs`` and resolved ``config``.

    The file says ``running`` from the first checkpoint until the last one, however the
    run ends; only the lock (:class:`~evo_door.files.FileLock`, held by ``run`` and
    ``resume`` while they write, dropped by the system when the process dies) tells a
    run at work from one that was stopped.
    """
    stored = attrs.get("status") or "unknown"
    if stored != "running":
        return Status(stored, stored)
    pid = FileLock.holder(path)
    if pid is not None:
        by = f"process {pid}" if pid > 0 else "another process"
        return Status("running", f"running ({by})", pid=pid if pid > 0 else None)
    return Status("interrupted", _where_stopped(attrs, config), f"evo-door resume {path}")


def _where_stopped(attrs: dict, config: dict) -> str:
    """``interrupted at generation 7/20`` and the like: the last work the file holds."""
    done = list(attrs.get("generations_done") or [])
    total = attrs.get("generations", 0)
    jobs_done, jobs = _jobs(attrs)
    if jobs_done >= jobs:
        return "interrupted after the last fit, before the results were written"
    if config["algorithm"]["kind"] != "ga":
        return f"interrupted after {jobs_done}/{jobs} fits done"
    # jobs run one after the other: the first one not done is the one stopped
    gen = done[jobs_done] if jobs_done < len(done) else -1
    at = "before the first generation" if gen < 0 else f"at generation {gen}/{total}"
    if jobs == 1:
        return f"interrupted {at}"
    return f"interrupted in fit {jobs_done + 1}/{jobs} ({jobs_done}/{jobs} fits done), {at}"


def _jobs(attrs: dict) -> tuple[int, int]:
    """``(fits done, fits in all)``, counted alike by ``show`` and ``runs``."""
    done = list(attrs.get("generations_done") or [])
    return int(attrs.get("jobs_done") or 0), int(attrs.get("jobs") or max(len(done), 1))


def _progress(attrs: dict, config: dict) -> str:
    done = attrs.get("generations_done") or []
    total = attrs.get("generations", 0)
    jobs_done, jobs = _jobs(attrs)
    if config["algorithm"]["kind"] != "ga":
        return f"{jobs_done}/{jobs} fits done"
    if jobs == 1 and len(done) <= 1:
        return f"{max(done[0], 0) if done else 0}/{total} gen"
    return f"{jobs_done}/{jobs} fits done x {total} gen"


@functools.cache
def _model(model_name: str):
    """A run's model, or None where it cannot be loaded (a user model file moved away).

    Cached: ``runs`` lists many files of few models, and a model is loaded once.
    """
    from evo_door.models import get_model

    try:
        return get_model(model_name)
    except UserError:
        return None


def _declared(model_name: str) -> dict:
    """Parameter name -> declaration of a run's model ({}: values without units)."""
    model = _model(model_name)
    return {} if model is None else {p.name: p for p in model.params}


def _units(model_name: str) -> dict[str, str]:
    return {n: p.unit for n, p in _declared(model_name).items()}


def _theta_unit(model_name: str) -> str:
    """The unit of a run's model coordinate (``rad`` when the model cannot be loaded)."""
    model = _model(model_name)
    return "rad" if model is None else model.theta_unit


def _objective_unit(obj: dict, model_name: str = "") -> str:
    objective = Objective(obj["kind"], obj["derivative"], obj["combine"])
    return objective.unit_for(_theta_unit(model_name)) if model_name else objective.unit


def _objective_text(obj: dict) -> str:
    """``ise on dtheta`` (the compared channel says the derivative in the user's terms)."""
    return f"{obj['kind']} on {Objective(obj['kind'], obj['derivative']).channel}"


def _num(v):
    v = float(v)
    return v if math.isfinite(v) else None


def _fmt(v) -> str:
    return "blew up" if v is None else f"{v:.4g}"


# -- one run ---------------------------------------------------------------------------
class Results:
    """A results file, read once (see ``docs/experiments.md`` for the layout)."""

    def __init__(self, path, stage: str | None = None):
        self.path = Path(path)
        #: the stage of a pipeline's file this is (None: a run's own file)
        self.stage = stage
        self.tree = store.read_tree(self.path, stage)
        self.attrs = self.tree[A]
        self.config = json.loads(self.tree["experiment"]["resolved"])

    @property
    def model(self):
        """The run's model, or None where it cannot be loaded (a user file moved away)."""
        return _model(self.attrs["model"])

    @property
    def complete(self) -> bool:
        return self.attrs.get("status") == "complete"

    def status(self) -> Status:
        """Complete, running or interrupted (:func:`run_status`; asks the lock each time)."""
        return run_status(self.path, self.attrs, self.config)

    @property
    def free(self) -> list[str]:
        return list(self.tree["setup"][A]["free"])

    @property
    def bounds(self) -> dict[str, tuple[float, float]]:
        """Free parameter name -> its search range (lower, upper)."""
        s = self.tree["setup"]
        return {n: (float(lo), float(hi)) for n, lo, hi in zip(self.free, s["lower"], s["upper"])}

    def units(self) -> dict[str, str]:
        """Parameter name -> unit, from the model's declaration ({} if it cannot load)."""
        return _units(self.attrs["model"])

    @property
    def fitness_unit(self) -> str:
        return _objective_unit(self.config["objective"], self.attrs["model"])

    def jobs(self) -> list[dict]:
        keys = sorted((k for k in self.tree["jobs"] if k != A), key=int)
        return [self.tree["jobs"][k] for k in keys]

    def best(self) -> dict[str, float]:
        """Free parameter name -> value: the run's answer, or the GA's best so far."""
        if "best" in self.tree:
            return dict(self.tree["best"][A]["values"])
        best, fit = None, math.inf
        for job in self.jobs():
            if "ga" in job and job["ga"]["hof_fitness"].size and job["ga"]["hof_fitness"][0] <= fit:
                fit = float(job["ga"]["hof_fitness"][0])
                best = job["ga"]["hof_x"][0]
        return {} if best is None else dict(zip(self.free, map(float, best)))

    def at_bound(self) -> dict[str, str]:
        """Free parameters whose estimate (:meth:`best`) is on a bound: name -> side.

        Stored with the run's answer (``best`` attribute ``at_bound``); computed for a
        run without one yet, or written before the attribute existed.
        """
        if "best" in self.tree and "at_bound" in self.tree["best"][A]:
            return dict(self.tree["best"][A]["at_bound"])
        best, bounds = self.best(), self.bounds
        names = [n for n in self.free if n in best]
        return bound_hits(
            names,
            [best[n] for n in names],
            [bounds[n][0] for n in names],
            [bounds[n][1] for n in names],
        )

    def values(self) -> dict[str, float]:
        """Every parameter of the model -> the value the run ends with (or would now).

        The free ones are :meth:`best`; the others come from the run's base vector
        (``fixed:``, ``params:`` or the declared defaults).
        """
        names = self.tree["setup"][A]["param_names"]
        out = dict(zip(names, map(float, self.tree["setup"]["base"])))
        out.update(self.best())
        return out

    def truth(self) -> dict[str, float]:
        """True values of the free parameters, when the fitted trials carry them.

        Trials made by the virtual rig (or any model) store the parameters that made
        them; when every fitted trial has them, for this run's model, and they agree,
        they score the fit. Otherwise (measured data) an empty dict.
        """
        trials = self.tree.get("trials", {})
        found = None
        for key, group in trials.items():
            if key == A or not key.startswith("fit_"):
                continue
            truth = group[A].get("truth") or {}
            model = self.model
            names = {self.attrs.get("model"), model.name if model is not None else None}
            if truth.get("model") not in names or "params" not in truth:
                return {}
            values = {n: float(truth["params"][n]) for n in self.free if n in truth["params"]}
            if len(values) != len(self.free) or (found is not None and values != found):
                return {}
            found = values
        return found or {}

    def fitness(self) -> float:
        if "best" in self.tree:
            return float(self.tree["best"][A]["fitness"])
        fits = [float(j["ga"][A]["best_fitness"]) for j in self.jobs() if "ga" in j]
        return min(fits) if fits else math.nan

    def progress(self) -> str:
        return _progress(self.attrs, self.config)

    def sources(self) -> dict[str, str]:
        """A pipeline stage's ``{from: STAGE}``: ``params`` / ``target.params`` -> the
        earlier stage it took them from ({} for a run's own file, or a stage of its own)."""
        if self.stage is None:
            return {}
        return store.stage_sources(self.path).get(self.stage, {})

    def summary(self) -> dict:
        """Everything ``show --json`` prints (JSON-able)."""
        cfg = self.config
        t = self.tree["timings"][A]
        status = self.status()
        out = {
            "file": str(self.path),
            "stage": self.stage,
            "from": self.sources(),
            "name": self.attrs.get("name"),
            "model": self.attrs.get("model"),
            "status": status.state,
            "status_text": status.text,
            "resume": status.hint,
            "pid": status.pid,
            "created": self.attrs.get("created"),
            "updated": self.attrs.get("updated"),
            "seed": self.attrs.get("seed"),
            "best": self.best(),
            "units": {
                n: u for n, u in self.units().items() if n in self.free or n in cfg.get("fixed", {})
            },
            "at_bound": self.at_bound(),
            "truth": self.truth(),
            "fitness": _num(self.fitness()),
            "fitness_unit": self.fitness_unit,
            "fixed": cfg.get("fixed", {}),
            "free": cfg.get("free", {}),
            "objective": cfg["objective"],
            "algorithm": cfg["algorithm"],
            "per_trial": cfg["per_trial"],
            "target": cfg["target"],
            "progress": self.progress(),
            "evaluations": t.get("evaluations", 0),
            "blowups": sum(int(j["ga"][A]["blowups"]) for j in self.jobs() if "ga" in j),
            "seconds": t.get("total_s"),
            "evaluations_per_s": t.get("evaluations_per_s"),
            "versions": self.tree["versions"][A],
        }
        if "best" in self.tree:
            b = self.tree["best"][A]
            out["fit_errors"] = {k: _num(v) for k, v in b["fit_errors"].items()}
            out["validation_errors"] = {k: _num(v) for k, v in b["validation_errors"].items()}
            out["best_meaning"] = b.get("meaning", "")
            out["channel_errors"] = self.channel_errors()
            ident = self.identifiability()
            if ident is not None:
                out["identifiability"] = ident.as_dict()
                out["identifiability_text"] = ident.format()
        if "summary" in self.tree:
            s = self.tree["summary"]
            out["per_trial_fits"] = {
                trial: dict(zip(self.free, map(float, row)))
                for trial, row in zip(s[A]["trials"], s["x"])
            }
            bounds = self.bounds
            lower = [bounds[n][0] for n in self.free]
            upper = [bounds[n][1] for n in self.free]
            out["per_trial_at_bound"] = {
                trial: hits
                for trial, row in zip(s[A]["trials"], s["x"])
                if (hits := bound_hits(self.free, row, lower, upper))
            }
            out["table"] = {
                n: {
                    "min": float(s["min"][i]),
                    "max": float(s["max"][i]),
                    "mean": float(s["mean"][i]),
                }
                for i, n in enumerate(self.free)
            }
        return out

    def identifiability(self):
        """The identifiability of the run's answer (an
        :class:`~evo_door.optim.identifiability.Identifiability`), None where the file has
        none (a run not finished, or written before the check existed)."""
        node = self.tree.get("best", {}).get("identifiability")
        if node is None:
            return None
        return store.identifiability_from_tree(node)

    def channel_errors(self) -> dict[str, dict]:
        """Each trial's fit error as a person reads it: the RMS and the largest absolute
        difference of the compared channel, model minus target, in its unit (and in
        degrees for an angle, a speed or an acceleration), over the samples the objective
        counts (a saturated sensor's are left out). Trial id -> {role, channel, unit,
        rms, max, at (time of the max, s), rms_deg, max_deg}; {} before the run is done.
        """
        out = {}
        theta_unit = _theta_unit(self.attrs["model"])
        trials = {
            g[A]["trial_id"]: g
            for k, g in self.tree.get("trials", {}).items()
            if k != A and isinstance(g, dict)
        }
        for r in self.responses():
            channel = r["channel"]
            diff = np.asarray(r["model"], dtype=float) - np.asarray(r["target"], dtype=float)
            mask = np.isfinite(diff)
            node = trials.get(r["trial_id"])
            if node is not None and channel in node:
                mask &= store.trial_from_tree(node).unsaturated(channel)
            if not mask.any():
                continue
            d = np.where(mask, diff, 0.0)
            k = int(np.argmax(np.abs(d)))
            rms = float(np.sqrt(np.mean(diff[mask] ** 2)))
            row = {
                "role": r["role"],
                "channel": channel,
                "unit": channel_unit(channel, theta_unit),
                "rms": rms,
                "max": float(abs(d[k])),
                "at": float(np.asarray(r["t"])[k]),
            }
            if theta_unit == "rad":
                row["rms_deg"] = math.degrees(row["rms"])
                row["max_deg"] = math.degrees(row["max"])
            out[r["trial_id"]] = row
        return out

    def responses(self) -> list[dict]:
        if "response" not in self.tree:
            return []
        keys = sorted((k for k in self.tree["response"] if k != A), key=int)
        return [
            {
                **self.tree["response"][k][A],
                **{n: v for n, v in self.tree["response"][k].items() if n != A},
            }
            for k in keys
        ]


def _preprocess_text(pre: dict) -> str:
    """What was done to the target trials, as a tail for the objective line (or "")."""
    steps = []
    if pre.get("rate_bias", "none") != "none":
        steps.append(f"gyroscope bias removed ({pre['rate_bias']})")
    if pre.get("lowpass") is not None:
        steps.append(f"low-pass {pre['lowpass']:g} Hz")
    if pre.get("trim"):
        steps.append("trimmed to the motion")
    return f"; target preprocessed: {', '.join(steps)}" if steps else ""


def bound_advice(name: str, side: str, lo: float, hi: float, declared=None) -> str:
    """One line on an estimate stopped by a bound: which bound, and what to do.

    ``declared`` is the parameter's declaration (:class:`~evo_door.params.Param`), which
    says how far the range may be widened; None when the model cannot be loaded.

    >>> for part in bound_advice("k", "upper", 20.0, 90.0).split("; "):
    ...     print(part)
    k is on the upper bound of its search range, 90: the bound, not the data, decided it
    widen the range in free: (e.g. k: [20, 160])
    """
    bound = hi if side == "upper" else lo
    unit = f" {declared.unit}" if declared is not None and declared.unit != "1" else ""
    head = f"{name} is on the {side} bound of its search range, {bound:g}{unit}"
    limit = None if declared is None else (declared.upper if side == "upper" else declared.lower)
    if limit is not None and bound == limit:
        # nowhere to widen to: the model's own limit (a friction of 0, say) is the answer
        return (
            f"{head}, the model's declared limit: the data push {name} beyond what the "
            "model allows (a term the model lacks, or one the trials cannot see)"
        )
    # one more range's width on that side, inside what the model declares
    width = hi - lo
    new_lo, new_hi = (lo, hi + width) if side == "upper" else (lo - width, hi)
    if declared is not None:
        new_lo, new_hi = max(new_lo, declared.lower), min(new_hi, declared.upper)
    return (
        f"{head}: the bound, not the data, decided it; widen the range in free: "
        f"(e.g. {name}: [{new_lo:g}, {new_hi:g}])"
    )


#: the marker after an estimate on a bound
_MARK = {"lower": "<- lower bound", "upper": "<- upper bound"}


def format_show(res: Results) -> str:
    """The human-readable ``evo-door show``."""
    s = res.summary()
    cfg = res.config
    alg = cfg["algorithm"]
    obj = cfg["objective"]
    status = f"{s['status']} ({s['progress']})"
    if s["status"] == "running" and s["pid"]:
        status = f"running ({s['progress']}, process {s['pid']})"
    lines = [
        f"{s['name']}  ({res.path})",
        f"  model {s['model']}, status {status}, seed {s['seed']}, created {s['created']}",
    ]
    if s["status"] == "interrupted":
        lines.append(f"  {s['status_text']}; {s['resume']} continues it")
    if s["from"]:  # a pipeline's stage that started from earlier ones
        lines.append(f"  stage {s['stage']}: {format_sources(s['from'])}")
    lines += [
        f"  objective {obj['kind']} on derivative {obj['derivative']}, {obj['combine']} "
        f"over trials" + _preprocess_text(cfg["target"].get("preprocess") or {}),
        (
            "  algorithm "
            + (
                f"GA population {alg['population']} x {alg['generations']} "
                f"generations, reproduction {alg['reproduction_ratio']:g}, "
                f"mutation p {alg['mutation_probability']:g} amplitude "
                f"{alg['mutation_amplitude']:g}, polish {alg['polish']}"
                if alg["kind"] == "ga"
                else f"nlpql (SLSQP), max {alg['max_iterations']} iterations"
            )
        ),
        f"  {s['evaluations']} evaluations, {s['blowups']} blow-ups, {(s['seconds'] or 0):.1f} s",
    ]
    units = s["units"]
    if "table" in s:
        lines.append(f"\nper-trial fits ({len(s['per_trial_fits'])} trials), as seed table 5.3:")
        w = max(len(n) for n in res.free)
        lines.append(f"  {'parameter':<{w}}  {'min':>12}  {'max':>12}  {'mean':>12}  unit")
        for n, row in s["table"].items():
            # which per-trial fits the bounds decided
            on = [f"{t} {hits[n]}" for t, hits in s["per_trial_at_bound"].items() if n in hits]
            note = f"  on a bound: {', '.join(on)}" if on else ""
            lines.append(
                f"  {n:<{w}}  {row['min']:>12.6g}  {row['max']:>12.6g}  "
                f"{row['mean']:>12.6g}  {units.get(n, '')}{note}".rstrip()
            )
    funit = s["fitness_unit"]
    lines.append(
        f"\nbest ({s.get('best_meaning') or 'best so far'}): fitness {_fmt(s['fitness'])} {funit}"
    )
    at_bound = s["at_bound"]
    if s["best"]:
        w = max(len(n) for n in s["best"])
        truth = s["truth"]
        for n, v in s["best"].items():
            lo, hi = cfg["free"][n]
            line = f"  {n:<{w}}  {v:>14.8g} {units.get(n, ''):<8} in [{lo:g}, {hi:g}]"
            if n in truth:
                true = truth[n]
                rel = f" ({100 * (v - true) / true:+.2f} %)" if true != 0 else ""
                line = f"{line:<{w + 48}} true {true:.8g}{rel}"
            if n in at_bound:
                line = f"{line:<{w + 48}} {_MARK[at_bound[n]]}"
            lines.append(line.rstrip())
        declared = _declared(s["model"])
        for n, side in at_bound.items():
            lo, hi = cfg["free"][n]
            lines.append("! " + bound_advice(n, side, lo, hi, declared.get(n)))
    if s["fixed"]:
        lines.append(
            "fixed: "
            + ", ".join(f"{k} = {v:g} {units.get(k, '')}".rstrip() for k, v in s["fixed"].items())
        )
    if s.get("fit_errors"):
        lines.append(
            f"fit error per trial in {funit}: "
            + ", ".join(f"{k} {_fmt(v)}" for k, v in s["fit_errors"].items())
        )
    if s.get("validation_errors"):
        lines.append(
            f"validation error in {funit}:    "
            + ", ".join(f"{k} {_fmt(v)}" for k, v in s["validation_errors"].items())
        )
    lines += format_channel_errors(s.get("channel_errors") or {})
    if s.get("identifiability_text"):
        lines += ["", s["identifiability_text"]]
    return "\n".join(lines)


def format_sources(sources: dict[str, str]) -> str:
    """Where a pipeline stage's ``{from: STAGE}`` came from, for a person.

    >>> format_sources({"params": "physical", "target.params": "latch"})
    'params from stage physical, target.params from stage latch'
    """
    return ", ".join(f"{key} from stage {stage}" for key, stage in sources.items())


def format_channel_errors(errors: dict) -> list[str]:
    """``show``'s lines of each trial's RMS and largest error in the channel's unit."""
    if not errors:
        return []
    first = next(iter(errors.values()))
    deg = "rms_deg" in first
    dunit = first["unit"].replace("rad", "deg")
    lines = [f"error of {first['channel']} per trial, model - target (RMS / largest, at t):"]
    for trial, e in errors.items():
        text = f"{e['rms']:.3g} / {e['max']:.3g} {e['unit']}"
        if deg:
            text += f" ({e['rms_deg']:.3g} / {e['max_deg']:.3g} {dunit})"
        role = "" if e["role"] == "fit" else "  (validation)"
        lines.append(f"  {trial:<8} {text}, largest at {e['at']:.3f} s{role}")
    return lines


# -- a folder of runs ----------------------------------------------------------------
def _peek_best(path, p: dict, stage=None) -> tuple[dict[str, float], float]:
    """The answer (or best so far) and its fitness, without reading the big arrays.

    A run with ``best`` has them in its attributes (:func:`store.peek`); one without
    takes the best of its jobs' halls of fame: a few numbers each.
    """
    if p["best"] is not None:
        return dict(p["best"].get("values") or {}), p["best"]["fitness"]
    best, fit = {}, math.inf
    try:
        with open_h5(path, "results file") as f:
            if stage is not None:
                f = f["stages"][stage]
            free = read_attrs(f["setup"])["free"]
            for key in f["jobs"]:
                ga = f["jobs"][key].get("ga")
                if ga is None or "hof_fitness" not in ga or ga["hof_fitness"].shape[0] == 0:
                    continue
                if float(ga["hof_fitness"][0]) <= fit:
                    fit = float(ga["hof_fitness"][0])
                    best = dict(zip(free, map(float, ga["hof_x"][0])))
    except (OSError, KeyError) as exc:  # a damaged file: a row that says so, as peek does
        raise UserError(f"{path}: not a readable results file ({exc})") from None
    return best, fit


def list_runs(folder) -> list[dict]:
    """One row per results file in ``folder`` (newest first); unreadable files are flagged.

    Cheap: root and ``best`` attributes, the resolved configuration and, for a run
    without an answer yet, its halls of fame; never the populations or the trials.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"{folder}: no such folder")
    rows = []
    entries = []
    for path in sorted(folder.glob("*.h5")):
        try:
            pipeline = store.pipeline_attrs(path)
        except UserError:
            pipeline = None
        stages = pipeline["started"] if pipeline else [None]
        entries += [(path, stage) for stage in stages]
    for path, stage in entries:
        try:
            p = store.peek(path, stage)
            values, fitness = _peek_best(path, p, stage)
        except UserError as exc:
            if "not an evo-door results file" in str(exc):
                continue
            rows.append(
                {
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
            )
            continue
        a = p[A]
        cfg = p["resolved"]
        status = run_status(path, a, cfg)
        free = cfg.get("free", {})
        names = [n for n in free if n in values]
        if p["best"] is not None and "at_bound" in p["best"]:
            at_bound = dict(p["best"]["at_bound"])
        else:
            at_bound = bound_hits(
                names,
                [values[n] for n in names],
                [free[n][0] for n in names],
                [free[n][1] for n in names],
            )
        rows.append(
            {
                "file": path.name + (f" [{stage}]" if stage else ""),
                "name": a.get("name", ""),
                "model": a.get("model", ""),
                "status": status.state,
                "status_text": status.text,
                "resume": status.hint,
                "progress": _progress(a, cfg),
                "objective": cfg["objective"],
                "fitness": _num(fitness),
                "fitness_unit": _objective_unit(cfg["objective"], a.get("model", "")),
                "values": values,
                "units": _units(a.get("model", "")),
                "at_bound": at_bound,
                "created": a.get("created", ""),
                "seed": a.get("seed", ""),
            }
        )
    rows.sort(key=lambda r: r["created"], reverse=True)
    return rows


def _compact_values(row: dict) -> str:
    """``k=100 N/rad, c=2 N s/rad``; an estimate on a bound says so."""
    parts = []
    for n, v in row["values"].items():
        unit = row["units"].get(n, "")
        text = f"{n}={v:.4g}" + (f" {unit}" if unit and unit != "1" else "")
        if n in row["at_bound"]:
            text += f" ({row['at_bound'][n]} bound)"
        parts.append(text)
    return ", ".join(parts)


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    widths = [
        max(len(h), *(len(row[i]) for row in rows)) if rows else len(h)
        for i, h in enumerate(header)
    ]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    out = [fmt.format(*header).rstrip(), fmt.format(*("-" * w for w in widths)).rstrip()]
    return out + [fmt.format(*row).rstrip() for row in rows]


def format_runs(rows: list[dict]) -> str:
    header = [
        "file",
        "name",
        "model",
        "status",
        "progress",
        "objective",
        "best fitness",
        "parameters",
        "seed",
        "created",
    ]
    table = [
        [
            r["file"],
            r["name"],
            r["model"],
            r["status"],
            r["progress"],
            "" if r["objective"] is None else _objective_text(r["objective"]),
            "" if r["fitness"] is None else f"{r['fitness']:.4g} {r['fitness_unit']}",
            _compact_values(r),
            str(r["seed"]),
            r["created"],
        ]
        for r in rows
    ]
    out = _table(header, table)
    stopped = [r["file"] for r in rows if r["status"] == "interrupted"]
    if stopped:
        out.append(
            f"\ninterrupted: {', '.join(stopped)}; `evo-door resume FILE` continues a run "
            "where it stopped"
        )
    if any(r["at_bound"] for r in rows):
        out.append("(lower / upper bound): an estimate on a bound of its search range; see show")
    return "\n".join(out)


# -- several runs side by side ---------------------------------------------------------
def flatten(config, prefix: str = "") -> dict:
    """A nested mapping as dotted keys; lists and other values are leaves.

    >>> flatten({"objective": {"kind": "ise", "derivative": 1}, "free": {"k": [20, 500]}})
    {'objective.kind': 'ise', 'objective.derivative': 1, 'free.k': [20, 500]}
    """
    out = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


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
    b = res.tree["best"][A] if "best" in res.tree else {}
    t = res.tree["timings"][A]
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
        "fitness": _num(res.fitness()),
        "fitness_unit": res.fitness_unit,
        "best_meaning": b.get("meaning", "best so far"),
        "params": entry,
        "fit_errors": {k: _num(v) for k, v in b.get("fit_errors", {}).items()},
        "validation_errors": {k: _num(v) for k, v in b.get("validation_errors", {}).items()},
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
    declared = [list(r.tree["setup"][A]["param_names"]) for r in runs]
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
    versions = _differences([r.tree["versions"][A] for r in runs])
    doc["differences"].update({f"versions.{k}": v for k, v in versions.items()})
    return doc


#: the widest cell of ``compare``'s table (a long description must not push the
#: other runs off the screen; --json has every value whole)
MAX_CELL = 40


def _cell(value, width: int = MAX_CELL) -> str:
    """A configuration value as text: ``ise``, ``0.6``, ``[20, 500]``, ``-`` for none."""
    text = _value_text(value)
    return text if len(text) <= width else text[: width - 3] + "..."


def _value_text(value) -> str:
    if value is None:
        return "-"
    if value == "":
        return '""'
    if isinstance(value, bool):
        return str(value).lower()  # as the experiment file writes it
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list):
        return "[" + ", ".join(_value_text(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_value_text(v)}" for k, v in value.items()) + "}"
    return str(value)


def format_compare(doc: dict) -> str:
    """The human-readable ``evo-door compare``: one column per run."""
    runs = doc["runs"]
    stages = doc.get("stages") or [None] * len(runs)
    names = [Path(f).name for f in doc["files"]]
    if len(set(zip(names, stages))) < len(names):  # one name in several folders: the paths
        names = list(doc["files"])
    # a pipeline's stage as runs lists it: FILE [stage]
    names = [name + (f" [{stage}]" if stage else "") for name, stage in zip(names, stages)]
    rows: list[list[str]] = []

    def row(label, cells):
        rows.append([label, *cells])

    def section(title):
        rows.append([title] + [""] * len(runs))

    row("name", [r["name"] or "" for r in runs])
    row("model", [r["model"] or "" for r in runs])
    row("status", [f"{r['status']} ({r['progress']})" for r in runs])
    row(
        "objective",
        [f"{_objective_text(r['objective'])}, {r['objective']['combine']}" for r in runs],
    )
    units = {r["fitness_unit"] for r in runs}
    if len(units) == 1:
        row(f"fitness [{next(iter(units))}]", [_fmt(r["fitness"]) for r in runs])
    else:
        row("fitness", [f"{_fmt(r['fitness'])} {r['fitness_unit']}" for r in runs])
    row("answer", [r["best_meaning"] for r in runs])
    if doc["params"]:
        section("parameters")
    truth = any(r["params"][n]["true"] is not None for r in runs for n in doc["params"])
    for n in doc["params"]:
        unit = next((r["params"][n]["unit"] for r in runs if r["params"][n]["unit"]), "")
        cells = []
        for r in runs:
            p = r["params"][n]
            text = "-" if p["value"] is None else f"{p['value']:.8g}"
            if p["role"] != "free":
                text = f"{p['role']} {text}"
            elif p["at_bound"]:
                text += f" ({p['at_bound']} bound)"
            cells.append(text)
        row(f"  {n}" + (f" [{unit}]" if unit and unit != "1" else ""), cells)
        if truth:
            row("    true", [_cell(r["params"][n]["true"]) for r in runs])
            row(
                "    error",
                [
                    "-"
                    if r["params"][n]["error_percent"] is None
                    else f"{r['params'][n]['error_percent']:+.3f} %"
                    for r in runs
                ],
            )
    for key, title in (("fit_errors", "fit error"), ("validation_errors", "validation error")):
        trials = []
        for r in runs:
            trials += [t for t in r[key] if t not in trials]
        if trials:
            section(title + (f" [{next(iter(units))}]" if len(units) == 1 else ""))
            if len(units) > 1:
                row("  unit", [r["fitness_unit"] for r in runs])
            for t in trials:
                row(f"  {t}", [_fmt(r[key][t]) if t in r[key] else "-" for r in runs])
    section("timings")
    row("  wall time [s]", [_cell(_round(r["timings"]["total_s"], 2)) for r in runs])
    row("  evaluations", [str(r["timings"]["evaluations"]) for r in runs])
    row("  GA evaluations/s", [f"{(r['timings']['evaluations_per_s'] or 0):,.0f}" for r in runs])
    row("  SLSQP [s]", [_cell(_round(r["timings"]["local_s"], 2)) for r in runs])
    if doc["differences"]:
        section("settings that differ")
        for key, values in doc["differences"].items():
            row(f"  {key}", [_cell(v) for v in values])
    else:
        section("settings: the same")
    out = _table(["", *names], rows)
    notes = []
    if doc["models_differ"]:
        shared = ", ".join(doc["params"]) or "none"
        notes.append(
            f"runs of different models ({', '.join(dict.fromkeys(doc['models']))}): compared on "
            f"what they share; parameters declared by every model: {shared}"
            + (f"; not shared: {', '.join(doc['not_shared'])}" if doc["not_shared"] else "")
        )
    if doc["objectives_differ"]:
        notes.append("the objectives differ: fitness and errors are not on one scale across runs")
    for name, r in zip(names, runs):
        if r["status"] == "interrupted":
            notes.append(f"{name}: {r['status_text']}; {r['resume']} continues it")
    return "\n".join(out + ([""] + notes if notes else []))


def _round(v, digits):
    return None if v is None else round(float(v), digits)


# -- figures ---------------------------------------------------------------------------
def plot_fit(res: Results, path, max_trials: int = 12) -> None:
    """Best response next to the target, one panel per trial (fitted, then validation).

    The target is drawn wide and light underneath, the model dashed on top, so that a
    perfect fit shows both; the applied force is a faint trace on its own axis.
    """
    from matplotlib.figure import Figure

    from evo_door.channels import title, unit

    rows = res.responses()
    if not rows:
        raise UserError(
            f"{res.path}: the run is not complete, there is no best response yet "
            "(evo-door resume it first)"
        )
    rows = rows[:max_trials]
    n = len(rows)
    ncols = 1 if n == 1 else 2
    nrows = math.ceil(n / ncols)
    fig = Figure(
        figsize=(6.2 * ncols + (2.0 if n == 1 else 0.0), 2.6 * nrows + 1.0), layout="constrained"
    )
    axes = fig.subplots(nrows, ncols, squeeze=False)
    channel = rows[0]["channel"]
    funit = res.fitness_unit
    handles = []
    for ax, r in zip(axes.flat, rows):
        t = np.asarray(r["t"])
        axf = ax.twinx()
        # a twin axis is drawn over its host: lift the host (and clear its background)
        # so the responses lie over the force trace, not under it
        ax.set_zorder(axf.get_zorder() + 1)
        ax.patch.set_visible(False)
        (force,) = axf.plot(t, r["force"], color="tab:blue", lw=0.6, alpha=0.35, label="force")
        axf.set_ylabel("force [N]", color="tab:blue", fontsize=8)
        axf.tick_params(axis="y", labelcolor="tab:blue", labelsize=7)
        (target,) = ax.plot(
            t, r["target"], color="0.55", lw=3.2, alpha=0.6, solid_capstyle="round", label="target"
        )
        (model,) = ax.plot(t, r["model"], color="tab:red", lw=1.1, ls="--", label="model (best)")
        handles = [target, model, force]
        ax.set_title(
            f"{r['trial_id']} ({'fitted' if r['role'] == 'fit' else 'validation'}), "
            f"error {_fmt(_num(r['error']))} {funit}",
            fontsize=9,
        )
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"{channel} [{unit(channel, _theta_unit(res.attrs['model']))}]")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    axes.flat[0].legend(handles=handles, loc="best", fontsize=8)
    obj = res.config["objective"]
    fig.suptitle(
        f"{res.attrs['name']}: {title(channel)}, best model vs target\n"
        f"model {res.attrs['model']}, objective {obj['kind']} (derivative "
        f"{obj['derivative']}, {obj['combine']}), fitness {_fmt(_num(res.fitness()))} {funit}",
        fontsize=10,
    )
    save_figure(fig, path, dpi=110)


def _stop_text(res: Results, jobs: list[dict]) -> str:
    """Why the GA stopped (each job's ``ga_stop``), or where an unfinished run stands."""
    status = res.status()
    if status.state != "complete":
        return status.text if status.state == "interrupted" else f"running ({res.progress()})"
    stops = [(j[A].get("name", ""), j[A].get("ga_stop") or "") for j in jobs]
    reasons = list(dict.fromkeys(reason for _, reason in stops if reason))
    if len(reasons) <= 1:
        return f"stopped: {reasons[0]}" if reasons else ""
    return "stopped: " + "; ".join(f"{name}: {reason}" for name, reason in stops if reason)


def plot_convergence(res: Results, path) -> None:
    """Best and mean fitness of the population per generation, from the GA's logbook.

    One pair of lines per job (``per_trial``: per fitted trial), log scale; the fitness
    after the SLSQP polish, where there was one, is a star after the last generation. An
    unfinished run shows the generations it has.
    """
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    jobs = [j for j in res.jobs() if "ga" in j and np.size(j["ga"]["logbook"]["gen"])]
    if not jobs:
        kind = res.config["algorithm"]["kind"]
        why = "it has no genetic algorithm" if kind != "ga" else "no generation is finished yet"
        raise UserError(f"{res.path}: no convergence to plot: {why} (algorithm {kind})")
    fig = Figure(figsize=(7.5, 4.8), layout="constrained")
    ax = fig.subplots()
    several = len(jobs) > 1
    polished = False
    for i, job in enumerate(jobs):
        log = job["ga"]["logbook"]
        gen = np.asarray(log["gen"], dtype=float)
        color = f"C{i % 10}"
        label = f"{job[A].get('name', i)}: " if several else ""
        # log scale: an exact fit (0) or a population that all blew up (inf) has no point
        best = _positive(log["min"])
        ax.plot(gen, best, color=color, lw=1.8, marker="o", ms=3, label=f"{label}best")
        ax.plot(gen, _positive(log["mean"]), color=color, lw=1.0, ls="--", label=f"{label}mean")
        if "local" in job and job[A].get("done"):
            f = _positive([job["local"][A]["fitness"]])[0]
            if math.isfinite(f):
                polished = True
                x_end = gen[-1] + 0.6
                ax.plot([gen[-1], x_end], [best[-1], f], color=color, lw=0.8, ls=":")
                ax.plot([x_end], [f], color=color, marker="*", ms=11, ls="none")
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("generation")
    ax.set_ylabel(f"fitness [{res.fitness_unit}]")
    ax.grid(alpha=0.3)
    ax.grid(alpha=0.1, which="minor", axis="y")
    handles, labels = ax.get_legend_handles_labels()
    if polished:
        handles.append(Line2D([], [], color="0.3", marker="*", ms=11, ls="none"))
        labels.append("after the SLSQP polish")
    ax.legend(handles, labels, fontsize=8, loc="best", ncols=2 if several else 1)
    obj = res.config["objective"]
    head = (
        f"{res.attrs.get('name', '')}: best and mean fitness of the population per "
        f"generation ({obj['kind']} on {Objective(obj['kind'], obj['derivative']).channel})"
    )
    stop = _stop_text(res, jobs)
    fig.suptitle(
        "\n".join(textwrap.wrap(head, 90) + textwrap.wrap(stop, 90)),
        fontsize=10,
    )
    save_figure(fig, path, dpi=110)


def _positive(values) -> np.ndarray:
    v = np.asarray(values, dtype=float)
    return np.where(np.isfinite(v) & (v > 0), v, np.nan)
