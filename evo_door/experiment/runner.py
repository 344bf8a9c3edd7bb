"""Running an experiment: jobs, per-generation checkpoints, resume.

A run is one job (every fitted trial at once) or, with ``per_trial: true``, one job
per fitted trial, each a GA (then, with ``polish: slsqp``, an SLSQP refinement of its
best) or an SLSQP solve alone (``kind: nlpql``). After every generation the whole
state (populations, fitness, hall of fame, logbook, the generator's state, the jobs
done so far) is written to the results file atomically (:mod:`.store`);
:meth:`ExperimentRun.open` rebuilds the run from that file and :meth:`ExperimentRun.run`
continues it, ending with exactly the numbers of an uninterrupted run: every random
draw comes from the run's own :class:`random.Random`, whose state is in the file, and
every evaluation is a deterministic compiled function of the genes.

Job ``k`` of a run with seed ``s`` draws from ``random.Random(s)``: the per-trial fits
are independent runs with AMESim's "seed value", as if started one after the other.
"""

from __future__ import annotations

import dataclasses
import json
import random
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from evo_door.data.trial import RESPONSE_CHANNELS, Trial
from evo_door.errors import UserError
from evo_door.experiment import store
from evo_door.experiment.setup import Setup
from evo_door.optim.ga import LOG_FIELDS, GASettings, GeneticAlgorithm, Termination
from evo_door.optim.local import LocalResult, LocalSettings, polish
from evo_door.optim.problem import Objective

_GA_KEYS = [f.name for f in dataclasses.fields(GASettings)]
_LOCAL_KEYS = [f.name for f in dataclasses.fields(LocalSettings)]


class Interrupted(Exception):
    """Raised by a checkpoint hook to stop a run as a kill would (tests)."""


@dataclass
class Job:
    """One optimisation: all fitted trials, or one of them (``per_trial``)."""

    name: str
    trials: list                      # indices into Setup.fit
    ga: object = None                 # GAState
    ga_stop: str = ""
    local: LocalResult | None = None
    done: bool = False
    best_x: np.ndarray | None = None
    best_fitness: float = float("nan")
    fit_errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    validation_errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    seconds: float = 0.0


def _now() -> str:
    return datetime.now(timezone.utc).astimezone().isoformat(timespec="seconds")


def default_output(exp) -> Path:
    """``<output>/<name>-<YYYYmmdd-HHMMSS>.h5``, not overwriting anything."""
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    base = Path(exp.output) / f"{exp.name}-{stamp}"
    path, k = base.with_suffix(".h5"), 1
    while path.exists():
        k += 1
        path = Path(f"{base}-{k}.h5")
    return path


class ExperimentRun:
    """A run of an experiment, backed by its results file.

    Build one with :meth:`create` (from a checked experiment) or :meth:`open` (from a
    results file, to resume), then call :meth:`run`.
    """

    def __init__(self, config: dict, setup: Setup, path, experiment: dict, versions: dict,
                 created: str, jobs: list[Job] | None = None, elapsed: float = 0.0):
        self.config = config
        self.setup = setup
        self.path = Path(path)
        self.experiment = experiment          # text, source, overrides
        self.versions = versions
        self.created = created
        self.elapsed_before = elapsed         # seconds spent by earlier sessions of this run
        alg = config["algorithm"]
        self.kind = alg["kind"]
        self.polish = alg["polish"]
        self.ga_settings = GASettings(**{k: alg[k] for k in _GA_KEYS})
        self.local_settings = LocalSettings(**{k: alg[k] for k in _LOCAL_KEYS})
        self.per_trial = bool(config["per_trial"])
        if jobs is None:
            if self.per_trial:
                jobs = [Job(tr.trial_id, [i]) for i, tr in enumerate(setup.fit)]
            else:
                jobs = [Job("all", list(range(len(setup.fit))))]
        self.jobs = jobs
        self.status = "complete" if all(j.done for j in jobs) else "running"
        self._t0 = time.perf_counter()
        self.result: dict = {}
        # the trials never change: after the first write they are copied from the
        # previous checkpoint (a resumed run starts from a file that has them)
        self._trials_on_disk = False

    # -- construction ------------------------------------------------------------------
    @classmethod
    def create(cls, exp, out=None, trials=None) -> "ExperimentRun":
        """A new run of the checked experiment ``exp`` writing to ``out``."""
        from evo_door.experiment.setup import resolve

        setup = resolve(exp, trials)
        path = Path(out) if out else default_output(exp)
        if path.suffix.lower() not in (".h5", ".hdf5"):
            raise UserError(f"{path}: results files are HDF5, name them .h5")
        run = cls(exp.resolved(), setup, path,
                  {"text": exp.text, "source": exp.source, "overrides": list(exp.overrides)},
                  store.versions(), _now())
        run.checkpoint()
        return run

    @classmethod
    def open(cls, path) -> "ExperimentRun":
        """Rebuild a run from its results file (to resume it)."""
        tree = store.read_tree(path)
        config = json.loads(tree["experiment"]["resolved"])
        setup = _setup_from_tree(tree)
        run = cls(config, setup, path,
                  {"text": tree["experiment"]["text"],
                   "source": tree["experiment"][store.ATTRS]["source"],
                   "overrides": tree["experiment"][store.ATTRS]["overrides"]},
                  tree["versions"][store.ATTRS], tree[store.ATTRS]["created"],
                  elapsed=float(tree["timings"][store.ATTRS].get("total_s", 0.0)))
        ga = GeneticAlgorithm(run.ga_settings)
        for job, (key, node) in zip(run.jobs, sorted(
                ((k, v) for k, v in tree["jobs"].items() if k != store.ATTRS),
                key=lambda kv: int(kv[0]))):
            a = node[store.ATTRS]
            if a["name"] != job.name:
                raise UserError(f"{path}: job {key} is {a['name']!r}, expected {job.name!r}")
            job.seconds = float(a.get("seconds", 0.0))
            if "ga" in node:
                job.ga = ga.restore(_snapshot_from_tree(node["ga"]))
                job.ga_stop = a.get("ga_stop", "")
            if a.get("done"):
                job.done = True
                job.best_x = np.array(node["best_x"])
                job.best_fitness = float(a["best_fitness"])
                job.fit_errors = np.array(node["fit_errors"])
                job.validation_errors = np.array(node["validation_errors"])
                if "local" in node:
                    job.local = _local_from_tree(node["local"])
        # every job done but the final write (best, responses) missing: still running
        run.status = "complete" if (all(j.done for j in run.jobs)
                                    and tree[store.ATTRS].get("status") == "complete"
                                    and "best" in tree) else "running"
        run._trials_on_disk = True
        store.remove_stale_temporaries(path)
        return run

    # -- running -----------------------------------------------------------------------
    def run(self, progress: bool = False, on_checkpoint=None) -> "ExperimentRun":
        """Run (or continue) every job; checkpoint after every generation.

        ``on_checkpoint(run, job)`` is called after each checkpoint is on disk
        (raise :class:`Interrupted` there to simulate a kill).
        """
        self._hook = on_checkpoint
        for job in self.jobs:
            if job.done:
                continue
            t0 = time.perf_counter()
            problem = self.setup.problem(job.trials)
            if self.kind == "ga":
                self._run_ga(job, problem, progress, t0)
            x = job.ga.best_x if job.ga is not None else self.setup.start_vector()
            if self.kind == "nlpql" or self.polish == "slsqp":
                if progress:
                    label = self.config["name"] + (f" [{job.name}]" if self.per_trial else "")
                    print(f"{label}: SLSQP from fitness {problem.evaluate(x)[0][0]:.4g} ...",
                          end="", file=sys.stderr, flush=True)
                job.local = polish(problem, x, self.local_settings)
                if progress:
                    print(f" {job.local.fitness:.4g} ({job.local.evaluations} evaluations, "
                          f"{job.local.seconds:.1f} s)", file=sys.stderr, flush=True)
                x = job.local.x
                job.best_fitness = job.local.fitness
            else:
                job.best_fitness = job.ga.best_fitness
            job.best_x = np.array(x, dtype=np.float64)
            err, ok = problem.trial_errors(job.best_x)
            job.fit_errors = np.where(ok, err, np.inf)[0]
            job.validation_errors = problem.validation_errors(job.best_x)
            job.done = True
            job.seconds += time.perf_counter() - t0
            self._checkpoint_and_hook(job)
        self.status = "complete"
        self.result = self._results()
        self.checkpoint()
        return self

    def _run_ga(self, job: Job, problem, progress: bool, t0: float) -> None:
        ga = GeneticAlgorithm(self.ga_settings)
        termination = Termination(self.ga_settings.generations, self.ga_settings.target_fitness)
        bar = None
        if progress:
            from tqdm import tqdm

            label = self.config["name"] + (f" [{job.name}]" if self.per_trial else "")
            bar = tqdm(total=self.ga_settings.generations, unit="gen", desc=label,
                       file=sys.stderr, dynamic_ncols=True,
                       initial=0 if job.ga is None else job.ga.generation)

        def after_generation(state):
            job.ga = state
            if bar is not None:
                log = state.logbook[-1]
                # throughput of this session's GA so far (breeding + evaluation, not I/O)
                rate = state.evaluations / max(float(np.sum(state.times)), 1e-9)
                bar.set_postfix_str(f"best {state.best_fitness:.4g}  mean {log['mean']:.4g}  "
                                    f"{rate:,.0f} evals/s"
                                    + (f"  blow-ups {state.blowups}" if state.blowups else ""),
                                    refresh=False)
                bar.update(1 if state.generation > 0 else 0)
            self._checkpoint_and_hook(job)

        try:
            if job.ga is None:
                state = ga.initialize(problem, random.Random(self.ga_settings.seed))
                after_generation(state)
            state = job.ga
            while termination.reason(state) is None:
                ga.step(problem, state)
                after_generation(state)
            job.ga_stop = termination.reason(state)
        finally:
            if bar is not None:
                bar.close()

    def _checkpoint_and_hook(self, job: Job) -> None:
        self.checkpoint()
        if self._hook is not None:
            self._hook(self, job)

    # -- results -----------------------------------------------------------------------
    @property
    def free(self) -> list[str]:
        return list(self.setup.free)

    def _results(self) -> dict:
        """Best parameters, per-trial table, responses: filled when every job is done."""
        xs = np.array([j.best_x for j in self.jobs])
        if self.per_trial:
            # each trial's own fit, combined as the objective combines trials
            best_x = xs.mean(axis=0)
            fits = np.array([[j.best_fitness for j in self.jobs]])
            best_fitness = float(self.setup.objective.combine_errors(fits, np.isfinite(fits))[0])
        else:
            best_x = xs[0]
            best_fitness = self.jobs[0].best_fitness
        full = self.setup.problem().full(best_x)[0]
        return {"best_x": best_x, "best_fitness": best_fitness, "full": full, "xs": xs}

    def responses(self) -> list[dict]:
        """Best response next to the target for every fitted and validation trial."""
        setup = self.setup
        out = []
        d = setup.objective.derivative
        for role, trials in (("fit", setup.fit), ("validate", setup.validation)):
            for i, tr in enumerate(trials):
                if self.per_trial and role == "fit":
                    job = self.jobs[i]
                    x, error = job.best_x, float(job.fit_errors[0])
                elif self.per_trial:
                    x = self.result["best_x"]
                    error = float(setup.problem().validation_errors(x)[i])
                else:
                    job = self.jobs[0]
                    x = job.best_x
                    error = float(job.fit_errors[i] if role == "fit" else job.validation_errors[i])
                problem = setup.problem()
                theta0, dtheta0 = tr.initial_state()
                from evo_door.sim import simulate

                r = simulate(problem.model, problem.full(x)[0], tr.force, tr.dt, theta0=theta0,
                             dtheta0=dtheta0, t0=float(tr.t[0]), method=setup.method,
                             substeps=setup.substeps)
                out.append({"trial_id": tr.trial_id, "role": role, "error": error,
                            "t": tr.t, "force": tr.force, "target": tr.channel(d),
                            "model": (r.theta, r.dtheta, r.ddtheta)[d],
                            "model_theta": r.theta, "ok": r.ok})
        return out

    # -- the file ------------------------------------------------------------------------
    def checkpoint(self) -> None:
        """Write the whole run to its results file (atomically)."""
        store.write_atomic(self.path, self.tree())
        self._trials_on_disk = True

    def tree(self) -> dict:
        setup = self.setup
        cfg = self.config
        A = store.ATTRS
        jobs_done = sum(j.done for j in self.jobs)
        generations_done = [(-1 if j.ga is None else j.ga.generation) for j in self.jobs]
        elapsed = self.elapsed_before + (time.perf_counter() - self._t0)
        tree = {
            A: {"format": store.FORMAT, "format_version": store.FORMAT_VERSION,
                "name": cfg["name"], "model": setup.model_name, "status": self.status,
                "created": self.created, "updated": _now(), "seed": self.ga_settings.seed,
                "algorithm": self.kind, "polish": self.polish,
                "objective": cfg["objective"], "per_trial": self.per_trial,
                "jobs": len(self.jobs), "jobs_done": jobs_done,
                "generations": self.ga_settings.generations,
                "generations_done": generations_done,
                "evo_door_version": self.versions.get("evo_door", "")},
            "experiment": {A: {"source": self.experiment["source"],
                               "overrides": list(self.experiment["overrides"])},
                           "text": self.experiment["text"],
                           "resolved": json.dumps(cfg, indent=1)},
            "versions": {A: dict(self.versions)},
            "setup": _setup_tree(setup),
            "trials": store.Keep(lambda: _trials_tree(setup)) if self._trials_on_disk
            else _trials_tree(setup),
            "jobs": {str(k): _job_tree(job, self.kind) for k, job in enumerate(self.jobs)},
            "timings": {A: {"total_s": elapsed,
                            "jobs_s": [float(j.seconds) for j in self.jobs]}},
        }
        ga_evals = sum(j.ga.evaluations for j in self.jobs if j.ga is not None)
        local_evals = sum(j.local.evaluations for j in self.jobs if j.local is not None)
        eval_time = sum(float(np.sum(j.ga.eval_times)) for j in self.jobs if j.ga is not None)
        tree["timings"][A].update({
            "evaluations": ga_evals + local_evals, "ga_evaluations": ga_evals,
            "ga_evaluation_s": eval_time,
            # the compiled kernel's throughput during the GA's batched calls
            "evaluations_per_s": ga_evals / eval_time if eval_time else 0.0,
            "local_evaluations": local_evals,
            "local_s": sum(float(j.local.seconds) for j in self.jobs if j.local is not None)})
        if self.status == "complete" and self.result:
            tree["best"] = _best_tree(self)
            if self.per_trial:
                tree["summary"] = _summary_tree(self)
            tree["response"] = {}
            for k, r in enumerate(self.responses()):
                tree["response"][str(k)] = {
                    A: {"trial_id": r["trial_id"], "role": r["role"], "error": r["error"],
                        "channel": RESPONSE_CHANNELS[setup.objective.derivative], "ok": r["ok"]},
                    "t": r["t"], "force": r["force"], "target": r["target"], "model": r["model"],
                    "model_theta": r["model_theta"]}
        return tree


# -- tree builders ----------------------------------------------------------------------
def _setup_tree(setup: Setup) -> dict:
    model = setup.model
    return {store.ATTRS: {"model": setup.model_name, "free": list(setup.free),
                          "method": setup.method, "substeps": int(setup.substeps),
                          "objective": dataclasses.asdict(setup.objective),
                          "start": dict(setup.start),
                          "param_names": list(model.params.names),
                          "fit_ids": [t.trial_id for t in setup.fit],
                          "validation_ids": [t.trial_id for t in setup.validation]},
            "base": np.asarray(setup.base, dtype=np.float64),
            "lower": np.asarray(setup.lower, dtype=np.float64),
            "upper": np.asarray(setup.upper, dtype=np.float64)}


_TRIAL_SCALARS = ("trial_id", "user_id", "kind", "theta0", "dtheta0", "source")
_TRIAL_DICTS = ("sensors", "truth", "meta")


def _trials_tree(setup: Setup) -> dict:
    out = {}
    for role, trials in (("fit", setup.fit), ("validate", setup.validation)):
        for k, tr in enumerate(trials):
            attrs = {"role": role}
            for name in _TRIAL_SCALARS + _TRIAL_DICTS:
                if hasattr(tr, name):
                    attrs[name] = getattr(tr, name)
            node = {store.ATTRS: attrs, "t": tr.t, "force": tr.force}
            for ch in tr.channels:
                node[ch] = getattr(tr, ch)
            out[f"{role}_{k}"] = node
    return out


def _trial_from_tree(node: dict) -> Trial:
    a = node[store.ATTRS]
    names = {f.name for f in dataclasses.fields(Trial)}
    kwargs = {k: a[k] for k in _TRIAL_SCALARS + _TRIAL_DICTS if k in a and k in names}
    for ch in RESPONSE_CHANNELS:
        if ch in node:
            kwargs[ch] = np.array(node[ch])
    return Trial(np.array(node["t"]), np.array(node["force"]), **kwargs)


def _setup_from_tree(tree: dict) -> Setup:
    s = tree["setup"]
    a = s[store.ATTRS]
    trials = {"fit": [], "validate": []}
    for role in trials:
        keys = sorted((k for k in tree["trials"] if k.startswith(role + "_")),
                      key=lambda k: int(k.rsplit("_", 1)[1]))
        trials[role] = [_trial_from_tree(tree["trials"][k]) for k in keys]
    return Setup(model_name=a["model"], base=np.array(s["base"]), free=list(a["free"]),
                 lower=np.array(s["lower"]), upper=np.array(s["upper"]),
                 fit=trials["fit"], validation=trials["validate"],
                 objective=Objective(**a["objective"]), method=a["method"],
                 substeps=int(a["substeps"]), start=dict(a.get("start") or {}))


def _job_tree(job: Job, kind: str) -> dict:
    A = store.ATTRS
    node = {A: {"name": job.name, "trials": list(job.trials), "done": job.done,
                "ga_stop": job.ga_stop, "seconds": float(job.seconds)}}
    if job.ga is not None:
        snap = GeneticAlgorithm.snapshot(job.ga)
        node["ga"] = {A: {"generation": snap["generation"], "evaluations": snap["evaluations"],
                          "blowups": snap["blowups"], "best_fitness": job.ga.best_fitness},
                      "population": snap["population"], "fitness": snap["fitness"],
                      "rng_states": snap["rng_states"], "rng_state": snap["rng_state"],
                      "hof_x": snap["hof_x"], "hof_fitness": snap["hof_fitness"],
                      "logbook": {A: {"columns": list(LOG_FIELDS)}, **snap["logbook"]},
                      "times": snap["times"], "eval_times": snap["eval_times"]}
    if job.local is not None:
        d = job.local.as_dict()
        node["local"] = {A: {k: v for k, v in d.items() if not isinstance(v, list)},
                         "x0": np.asarray(job.local.x0), "x": np.asarray(job.local.x)}
    if job.done:
        node[A]["best_fitness"] = float(job.best_fitness)
        node["best_x"] = np.asarray(job.best_x, dtype=np.float64)
        node["fit_errors"] = np.asarray(job.fit_errors, dtype=np.float64)
        node["validation_errors"] = np.asarray(job.validation_errors, dtype=np.float64)
    return node


def _snapshot_from_tree(node: dict) -> dict:
    a = node[store.ATTRS]
    log = {k: np.array(node["logbook"][k]) for k in LOG_FIELDS}
    return {"generation": a["generation"], "evaluations": a["evaluations"],
            "blowups": a["blowups"], "population": node["population"],
            "fitness": node["fitness"], "rng_states": node["rng_states"],
            "rng_state": node["rng_state"], "hof_x": node["hof_x"],
            "hof_fitness": node["hof_fitness"], "logbook": log,
            "times": node["times"], "eval_times": node["eval_times"]}


def _local_from_tree(node: dict) -> LocalResult:
    a = dict(node[store.ATTRS])
    return LocalResult(x0=np.array(node["x0"]), x=np.array(node["x"]),
                       **{k: a[k] for k in ("fitness0", "fitness", "iterations", "evaluations",
                                            "blowups", "success", "message", "seconds")})


def _best_tree(run: ExperimentRun) -> dict:
    res = run.result
    A = store.ATTRS
    names = run.free
    model = run.setup.model
    fit_ids = [t.trial_id for t in run.setup.fit]
    val_ids = [t.trial_id for t in run.setup.validation]
    if run.per_trial:
        fit_errors = {j.name: float(j.fit_errors[0]) for j in run.jobs}
        val = np.array([j.validation_errors for j in run.jobs]) if val_ids else np.zeros((0, 0))
        validation = {v: float(np.mean(val[:, i])) for i, v in enumerate(val_ids)}
    else:
        job = run.jobs[0]
        fit_errors = dict(zip(fit_ids, map(float, job.fit_errors)))
        validation = dict(zip(val_ids, map(float, job.validation_errors)))
    return {A: {"fitness": float(res["best_fitness"]),
                "values": {n: float(v) for n, v in zip(names, res["best_x"])},
                "fit_errors": fit_errors, "validation_errors": validation,
                "param_names": list(model.params.names),
                "meaning": "mean of the per-trial fits" if run.per_trial else "best of the run"},
            "x": np.asarray(res["best_x"], dtype=np.float64),
            "full": np.asarray(res["full"], dtype=np.float64)}


def _summary_tree(run: ExperimentRun) -> dict:
    xs = run.result["xs"]
    A = store.ATTRS
    return {A: {"names": run.free, "trials": [j.name for j in run.jobs]},
            "x": xs, "min": xs.min(axis=0), "max": xs.max(axis=0), "mean": xs.mean(axis=0),
            "std": xs.std(axis=0),
            "fitness": np.array([j.best_fitness for j in run.jobs])}
