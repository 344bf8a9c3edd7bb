"""What a run found, read from its results file: the view every command shares.

:class:`Results` is one run (a run's file or one stage of a pipeline's) built on a
:class:`~evo_door.experiment.reader.RunRecord`: its answer (:meth:`Results.best`, every
value, the truth where the trials carry it, the estimates on a bound), its errors in the
channel's unit, and its status. :func:`run_status` says complete, running (a process
holds the file's lock) or interrupted (the file says ``running`` but nobody holds the
lock: the run was stopped by Ctrl-C, SIGTERM, SIGKILL or a crash, and ``evo-door resume``
continues it).

The views built on it live in :mod:`evo_door.reporting`, one question per module:
``format_json`` (the documents of ``show --json``'s neighbours ``runs`` and
``compare``), ``format_text`` and ``format_tables`` (what a person reads) and
``figures`` (the fit and convergence figures).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evo_door.channels import unit as channel_unit
from evo_door.errors import UserError
from evo_door.experiment.config_algorithm import POPULATION_KINDS
from evo_door.experiment.feel_check import jnds_used, run_jnd_sources
from evo_door.experiment.reader import RunRecord, StoredResponse, read_run
from evo_door.experiment.stored import identifiability_from_tree, job_keys
from evo_door.files import FileLock
from evo_door.optim.bounds import bound_hits
from evo_door.optim.problem import Objective


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
    if config["algorithm"]["kind"] not in POPULATION_KINDS:
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


def progress_text(attrs: dict, config: dict) -> str:
    done = attrs.get("generations_done") or []
    total = attrs.get("generations", 0)
    jobs_done, jobs = _jobs(attrs)
    if config["algorithm"]["kind"] not in POPULATION_KINDS:
        return f"{jobs_done}/{jobs} fits done"
    if jobs == 1 and len(done) <= 1:
        return f"{max(done[0], 0) if done else 0}/{total} gen"
    return f"{jobs_done}/{jobs} fits done x {total} gen"


# -- a run's model: units and names ------------------------------------------------
@functools.lru_cache(maxsize=64)
def model_of(model_name: str):
    """A run's model, or None where it cannot be loaded (a user model file moved away).

    Cached, for the few models of many files: ``runs`` lists a folder, and a model that
    cannot be loaded is tried once, not once a file. Bounded (64 names): a long-lived
    process that reads many runs keeps only the models it reads now.
    """
    from evo_door.models import get_model

    try:
        return get_model(model_name)
    except UserError:
        return None


@functools.lru_cache(maxsize=64)
def declaration_of(model_name: str):
    """A run's model's declaration (names, units, bounds), or None where the model
    cannot be loaded: for a bundled model read without its kernels (no numba:
    :func:`~evo_door.models.get_declaration`), so that ``show``, ``runs`` and
    ``export-spec`` start at once; else the model itself. Cached as :func:`model_of`."""
    from evo_door.models import get_declaration

    try:
        return get_declaration(model_name)
    except UserError:
        return None


def declared_params(model_name: str) -> dict:
    """Parameter name -> declaration of a run's model ({}: values without units)."""
    model = declaration_of(model_name)
    return {} if model is None else {p.name: p for p in model.params}


def units_of(model_name: str) -> dict[str, str]:
    return {n: p.unit for n, p in declared_params(model_name).items()}


def theta_unit_of(model_name: str) -> str:
    """The unit of a run's model coordinate (``rad`` when the model cannot be loaded)."""
    model = declaration_of(model_name)
    return "rad" if model is None else model.theta_unit


def objective_unit(obj: dict, model_name: str = "") -> str:
    objective = Objective(obj["kind"], obj["derivative"], obj["combine"])
    return objective.unit_for(theta_unit_of(model_name)) if model_name else objective.unit


def trial_error_unit(obj: dict, model_name: str = "") -> str:
    """The unit of a run's errors per trial (ISE's beside a perceptual fitness)."""
    objective = Objective(obj["kind"], obj["derivative"], obj["combine"]).trial_objective
    return objective.unit_for(theta_unit_of(model_name)) if model_name else objective.unit


def objective_text(obj: dict) -> str:
    """``ise on dtheta`` (the compared channel says the derivative in the user's terms)."""
    return f"{obj['kind']} on {Objective(obj['kind'], obj['derivative']).channel}"


def finite(v):
    v = float(v)
    return v if math.isfinite(v) else None


def fmt_number(v) -> str:
    return "blew up" if v is None else f"{v:.4g}"


# -- one run ---------------------------------------------------------------------------
class Results:
    """One run of a results file (see ``docs/experiments.md`` for the layout).

    ``Results(path, stage)`` reads the run (one open of the file); :meth:`of` wraps a
    record already read (:func:`~evo_door.experiment.reader.read_results`), so that a
    command reading a pipeline's stages opens its file once.
    """

    def __init__(self, path, stage: str | None = None, record: RunRecord | None = None):
        #: the run as read: typed fields (settings, jobs, best, responses...)
        self.record = record if record is not None else read_run(path, stage)
        self.path = Path(path)
        #: the stage of a pipeline's file this is (None: a run's own file)
        self.stage = stage
        self.attrs = self.record.attrs
        self.config = self.record.config

    @classmethod
    def of(cls, record: RunRecord) -> Results:
        return cls(record.path, record.stage, record)

    @property
    def tree(self) -> dict:
        """The raw layout (:mod:`.store`), for code that rebuilds the run's setup from it."""
        return self.record.tree

    @property
    def model(self):
        """The run's model, or None where it cannot be loaded (a user file moved away)."""
        return model_of(self.attrs["model"])

    @property
    def declaration(self):
        """The run's model's names, units and bounds (a bundled model's without its
        kernels: :func:`declaration_of`), or None where the model cannot be loaded."""
        return declaration_of(self.attrs["model"])

    @property
    def complete(self) -> bool:
        return self.record.complete

    def status(self) -> Status:
        """Complete, running or interrupted (:func:`run_status`; asks the lock each time)."""
        return run_status(self.path, self.attrs, self.config)

    @property
    def free(self) -> list[str]:
        return list(self.record.settings.free)

    @property
    def bounds(self) -> dict[str, tuple[float, float]]:
        """Free parameter name -> its search range (lower, upper)."""
        return self.record.settings.bounds

    def units(self) -> dict[str, str]:
        """Parameter name -> unit, from the model's declaration ({} if it cannot load)."""
        return units_of(self.attrs["model"])

    @property
    def fitness_unit(self) -> str:
        return objective_unit(self.config["objective"], self.attrs["model"])

    @property
    def trial_error_unit(self) -> str:
        return trial_error_unit(self.config["objective"], self.attrs["model"])

    def jobs(self) -> list[dict]:
        """Each job's stored group whole (populations included), in job order."""
        keys = job_keys(self.tree["jobs"])
        return [self.tree["jobs"][k] for k in keys]

    def best(self) -> dict[str, float]:
        """Free parameter name -> value: the run's answer, or the GA's best so far."""
        if self.record.best is not None:
            return dict(self.record.best.values)
        return best_so_far(self.record)[0]

    def at_bound(self) -> dict[str, str]:
        """Free parameters whose estimate (:meth:`best`) is on a bound: name -> side.

        Stored with the run's answer (``best`` attribute ``at_bound``); computed for a
        run without one yet, or written before the attribute existed.
        """
        return at_bound(self.record, self.best())

    def values(self) -> dict[str, float]:
        """Every parameter of the model -> the value the run ends with (or would now).

        The free ones are :meth:`best`; the others come from the run's base vector
        (``fixed:``, ``params:`` or the declared defaults).
        """
        s = self.record.settings
        out = dict(zip(s.param_names, map(float, s.base)))
        out.update(self.best())
        return out

    def truth(self) -> dict[str, float]:
        """True values of the free parameters, when the fitted trials carry them.

        Trials made by the virtual rig (or any model) store the parameters that made
        them; when every fitted trial has them, for this run's model, and they agree,
        they score the fit. Otherwise (measured data) an empty dict.
        """
        found = None
        model = self.declaration
        names = {self.attrs.get("model"), model.name if model is not None else None}
        for stored in self.record.trials:
            if stored.role != "fit":
                continue
            truth = stored.truth
            if truth.get("model") not in names or "params" not in truth:
                return {}
            values = {n: float(truth["params"][n]) for n in self.free if n in truth["params"]}
            if len(values) != len(self.free) or (found is not None and values != found):
                return {}
            found = values
        return found or {}

    def fitness(self) -> float:
        if self.record.best is not None:
            return self.record.best.fitness
        fits = [j.ga.best_fitness for j in self.record.jobs if j.ga is not None]
        return min(fits) if fits else math.nan

    def progress(self) -> str:
        return progress_text(self.attrs, self.config)

    def sources(self) -> dict[str, str]:
        """A pipeline stage's ``{from: STAGE}``: ``params`` / ``target.params`` -> the
        earlier stage it took them from ({} for a run's own file, or a stage of its own)."""
        return dict(self.record.sources)

    def summary(self) -> dict:
        """Everything ``show --json`` prints (JSON-able)."""
        out = self._head()
        if self.record.best is not None:
            out.update(self._answer())
        if self.record.per_trial is not None:
            out.update(self._per_trial())
        front = self.smallest_change()
        if front is not None:
            out.update(self._smallest_change(front))
        spec = self.record.tolerance
        if spec is not None and self.record.best is not None:
            # reachable: the feel by the mechanism (nsga2's front) and the yield's target
            out["reachable"] = bool(out.get("reachable", True)) and spec.reachable
        return out

    def smallest_change(self):
        """NSGA-II's front and the smallest change chosen from it (a
        :class:`~evo_door.optim.smallest_change.SmallestChange`), None for another run
        or one not finished."""
        fronts = [j.front for j in self.record.jobs if j.front is not None]
        return fronts[-1] if fronts else None

    def _smallest_change(self, front) -> dict:
        """``show --json``'s keys of an ``nsga2`` run: ``reachable``, ``kept`` and the
        ``smallest_change`` (the front, the chosen point, the check, a miss)."""
        free = self.free
        closest = dict(zip(free, map(float, front.front_x[front.closest])))
        return {
            "reachable": front.reachable,
            "kept": list(front.kept),
            "smallest_change": {
                "feel_reachable": front.reachable,
                "measure": front.measure,
                "change_unit": "1",
                "error_unit": "JND^2",
                "asis": dict(zip(free, map(float, front.asis))),
                "answer": dict(zip(free, map(float, front.x))),
                "error": front.error,
                "change": front.change,
                "chosen": front.chosen,
                "closest": front.closest,
                "closest_door": dict(zip(free, map(float, front.x)))
                if not front.reachable
                else None,
                "closest_on_front": closest,
                "polished": front.polished,
                "check": front.check,
                "miss": front.miss(),
                "steps": list(front.steps),
                "front": [
                    {
                        "values": dict(zip(free, map(float, x))),
                        "error": float(f[0]),
                        "change": float(f[1]),
                    }
                    for x, f in zip(front.front_x, front.front_f)
                ],
            },
        }

    def _head(self) -> dict:
        """What every run has, finished or not: status, settings, best so far, cost."""
        cfg = self.config
        t = self.record.timings
        status = self.status()
        return {
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
            "fitness": finite(self.fitness()),
            "fitness_unit": self.fitness_unit,
            "trial_error_unit": self.trial_error_unit,
            "fixed": cfg.get("fixed", {}),
            "free": cfg.get("free", {}),
            "objective": cfg["objective"],
            "algorithm": cfg["algorithm"],
            "simulation": self.simulation(),
            "per_trial": cfg["per_trial"],
            "target": cfg["target"],
            "progress": self.progress(),
            "evaluations": t.get("evaluations", 0),
            "blowups": sum(j.ga.blowups for j in self.record.jobs if j.ga is not None),
            "seconds": t.get("total_s"),
            "evaluations_per_s": t.get("evaluations_per_s"),
            "versions": self.record.provenance.versions,
        }

    def _answer(self) -> dict:
        """A complete run's errors and identifiability."""
        b = self.record.best
        out = {
            "fit_errors": {k: finite(v) for k, v in b.fit_errors.items()},
            "validation_errors": {k: finite(v) for k, v in b.validation_errors.items()},
            "best_meaning": b.meaning if b.meaning is not None else "",
            "channel_errors": self.channel_errors(),
            # None: not recorded (a file written before the estimate existed)
            "integration_error": (
                None
                if self.record.integration_error is None
                else self.record.integration_error.as_dict()
            ),
        }
        check = self.record.perceptual_check
        if check is not None:  # a run fitted to a chosen feel
            out["perceptual_check"] = check.judged()
        ident = self.identifiability()
        if ident is not None:
            out["identifiability"] = ident.as_dict()
            out["identifiability_text"] = ident.format()
        spec = self.record.tolerance
        if spec is not None:  # what a supplier builds: show, show --json and the table
            d = spec.as_dict()
            out["tolerance"] = d
            out["process"] = d["process"]
            out["distribution"] = d["distribution"]
            out["yield"] = d["yield"]
            out["allocation"] = d["allocation"]
            out["tolerance_text"] = "\n".join(spec.summary_lines())
        if check is not None:  # the position JND at the handle, in m, beside the settings
            out["jnds"] = {
                **jnds_used(check.jnd, run_jnd_sources(self.config)),
                "position_m": check.jnd.position,
            }
        return out

    def _per_trial(self) -> dict:
        """A per_trial run's fits, those a bound decided, and seed table 5.3's ranges."""
        s = self.record.per_trial
        bounds = self.bounds
        lower = [bounds[n][0] for n in self.free]
        upper = [bounds[n][1] for n in self.free]
        return {
            "per_trial_fits": {
                trial: dict(zip(self.free, map(float, row))) for trial, row in zip(s.trials, s.x)
            },
            "per_trial_at_bound": {
                trial: hits
                for trial, row in zip(s.trials, s.x)
                if (hits := bound_hits(self.free, row, lower, upper))
            },
            "table": {
                n: {"min": float(s.min[i]), "max": float(s.max[i]), "mean": float(s.mean[i])}
                for i, n in enumerate(self.free)
            },
        }

    def simulation(self) -> dict:
        """How the run integrated: ``method``, ``substeps`` per sample and ``dopri5``'s
        ``tolerance`` (None in a file written before it was kept: the model's)."""
        s = self.record.settings
        return {"method": s.method, "substeps": s.substeps, "tolerance": s.tolerance}

    def identifiability(self):
        """The identifiability of the run's answer (an
        :class:`~evo_door.optim.identifiability.Identifiability`), None where the file has
        none (a run not finished, or written before the check existed)."""
        best = self.record.best
        if best is None or best.identifiability is None:
            return None
        return identifiability_from_tree(best.identifiability)

    def channel_errors(self) -> dict[str, dict]:
        """Each trial's fit error as a person reads it: the RMS and the largest absolute
        difference of the compared channel, model minus target, in its unit (and in
        degrees for an angle, a speed or an acceleration), over the samples the objective
        counts (a saturated sensor's are left out). Trial id -> {role, channel, unit,
        rms, max, at (time of the max, s), rms_deg, max_deg}; {} before the run is done.
        """
        out = {}
        theta_unit = theta_unit_of(self.attrs["model"])
        trials = {stored.trial_id: stored for stored in self.record.trials}
        for r in self.responses():
            row = _channel_error(r, trials.get(r.trial_id), theta_unit)
            if row is not None:
                out[r.trial_id] = row
        return out

    def responses(self) -> list[StoredResponse]:
        """The best parameters' response to each trial, with its target (complete runs)."""
        return list(self.record.responses)


def _channel_error(r: StoredResponse, stored, theta_unit: str) -> dict | None:
    """One trial's row of :meth:`Results.channel_errors` (None: no sample counts)."""
    channel = r.channel
    diff = np.asarray(r.model, dtype=float) - np.asarray(r.target, dtype=float)
    mask = np.isfinite(diff)
    if stored is not None and channel in stored.node:
        mask &= stored.trial().unsaturated(channel)
    if not mask.any():
        return None
    d = np.where(mask, diff, 0.0)
    k = int(np.argmax(np.abs(d)))
    row = {
        "role": r.role,
        "channel": channel,
        "unit": channel_unit(channel, theta_unit),
        "rms": float(np.sqrt(np.mean(diff[mask] ** 2))),
        "max": float(abs(d[k])),
        "at": float(np.asarray(r.t)[k]),
    }
    if theta_unit == "rad":
        row["rms_deg"] = math.degrees(row["rms"])
        row["max_deg"] = math.degrees(row["max"])
    return row


def best_so_far(record: RunRecord) -> tuple[dict[str, float], float]:
    """The answer and its fitness: ``best`` of a complete run, else the best of its jobs'
    halls of fame (a few numbers each: a record read without arrays has them)."""
    if record.best is not None:
        return dict(record.best.values), record.best.fitness
    best, fit = None, math.inf
    for job in record.jobs:
        hof = job.ga.hof_fitness if job.ga is not None else ()
        if len(hof) and hof[0] <= fit:
            fit = float(hof[0])
            best = job.ga.hof_x[0]
    free = record.settings.free
    return ({} if best is None else dict(zip(free, map(float, best)))), fit


def at_bound(record: RunRecord, best: dict[str, float]) -> dict[str, str]:
    """The estimates of ``best`` on a bound: as stored with the answer, else computed."""
    if record.best is not None and record.best.at_bound is not None:
        return dict(record.best.at_bound)
    bounds = record.settings.bounds
    names = [n for n in record.settings.free if n in best]
    return bound_hits(
        names,
        [best[n] for n in names],
        [bounds[n][0] for n in names],
        [bounds[n][1] for n in names],
    )
