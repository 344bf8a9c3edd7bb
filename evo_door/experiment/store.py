"""The results file of a run: its HDF5 layout, written and read back.

A run is checkpointed by writing the *whole* results file after every generation
(:func:`evo_door.files.write_h5`: temporary file, fsync, atomic rename), so a run
killed at any moment leaves the previous checkpoint or the new one. The layout
(``docs/experiments.md``, "Results files")::

    /            @attrs: format, format_version, name, model, status, created, updated,
                         seed, algorithm, polish, objective, per_trial, jobs, jobs_done,
                         generations, generations_done, evo_door_version
    experiment/  text (the YAML as given), resolved (JSON, every default filled in)
    versions/    @attrs: python, numpy, scipy, numba, deap, h5py, ...
    setup/       base, lower, upper; @attrs: model, free, method, substeps, tolerance, ...
    trials/      fit_<k>/, validate_<k>/: t, force, response channels; @attrs: trial fields
    jobs/<k>/    @attrs: name, trials, done, ...; ga/ (population history, fitness,
                 generator states, hall of fame, logbook; NSGA-II: both objectives, the
                 Pareto archive as the hall of fame, crowding), local/, best_x,
                 fit_errors, ...; front/ (NSGA-II: front_x, front_f, asis, x; @attrs:
                 chosen, closest, kept, reachable, check, ...)
    timings/     @attrs: total_s, jobs_s, evaluations, evaluations_per_s, ...
    best/        x, full; @attrs: fitness, values, fit_errors, validation_errors (complete)
    summary/     per-trial fits: x, min, max, mean, std (per_trial runs)
    response/<k> t, force, target, model, model_theta (complete runs)
    integration_error/  the answer's integration error, estimated a posteriori: per trial
                 theta_max, dtheta_max, channel_max, channel_rms, residual_rms, error,
                 error_refined, ok; @attrs: both settings, the overall values, units
                 (complete runs; :mod:`.integration_error`)
    perceptual_check/  a run fitted to a chosen feel: mechanism/ and chosen/ (theta rad,
                 opening, closing N: both force-angle curves); @attrs: jnd, dynamics,
                 passes, verdict (complete runs; :mod:`.feel_check`)
    tolerance/   against a chosen feel, what a supplier builds (format 2): nominal, asis,
                 half_width, sensitivity, loss, curves/ (the sampled doors' force band),
                 nearest_feel/, allocation_nominal; @attrs: names, units, distribution,
                 source, free, design, yield, target, worst, alternative, allocation, ...
                 (complete perceptual runs of a built mechanism; :mod:`evo_door.optim.tolerance`)

:func:`run_tree` builds the tree of a run; :func:`read_tree` / :func:`peek` read a
file; :mod:`.stored`'s ``*_from_tree`` functions rebuild what a resumed run needs, each
value checked.
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np

from evo_door.errors import NotResultsFileError, UserError
from evo_door.files import ATTRS, DamagedFile, Keep, Node, fields, open_h5, read_attrs, read_group
from evo_door.optim.bounds import bound_hits
from evo_door.optim.ga import LOG_FIELDS, GeneticAlgorithm
from evo_door.optim.nsga2 import NSGA2, FrontState
from evo_door.params.declaration import suggest
from evo_door.sim_settings import tolerance_of

FORMAT = "evo-door run"
FORMAT_VERSION = 1
#: gzip level of results files: fast, since the file is rewritten every generation
COMPRESSION = 1


# -- reading -----------------------------------------------------------------------
#: the root format of a pipeline's file: one run's tree per stage, in ``stages/<name>``
PIPELINE_FORMAT = "evo-door pipeline"


def _open(path):
    f = open_h5(path, "results file")
    try:
        found = read_attrs(f).get("format")
    except BaseException:
        f.close()
        raise
    if found not in (FORMAT, PIPELINE_FORMAT):
        f.close()
        raise NotResultsFileError(f"{path}: not an evo-door results file (format {found!r})")
    return f


def started_stages(f, path) -> list[str]:
    """The stages a pipeline's file holds runs of (``/stages``' groups), in its order."""
    if "stages" not in f:
        return []
    if not hasattr(f["stages"], "keys"):
        raise DamagedFile(f"{path}: /stages: expected a group, got a dataset")
    return list(f["stages"])


def _run_group(f, path, stage):
    """The group holding one run: the root of a run's file, a stage's group of a pipeline's."""
    attrs = read_attrs(f)
    if attrs.get("format") != PIPELINE_FORMAT:
        check_stage(path, stage)
        return f
    declared = fields.texts(attrs, "stages", [])
    started = started_stages(f, path)
    check_stage(path, stage, declared, started)
    group = f["stages"][stage]
    if not hasattr(group, "keys"):
        raise DamagedFile(f"{path}: /stages/{stage}: expected a group, got a dataset")
    return group


def check_stage(path, stage, declared=None, started=None) -> None:
    """Refuse ``stage`` where it names no run: any stage of a run's file (``declared``
    None), none or one not started of a pipeline's (its ``declared`` and ``started``
    stages)."""
    if declared is None:
        if stage is not None:
            raise UserError(f"{path}: holds one run, not a pipeline: there is no stage {stage!r}")
        return
    if stage is None:
        raise UserError(
            f"{path}: a pipeline of stages {', '.join(declared)}: name one with --stage"
        )
    if stage not in started:
        why = "has not started yet" if stage in declared else "is not a stage of it"
        raise UserError(
            f"{path}: stage {stage!r} {why}; stages with results: {', '.join(started) or 'none'}"
            + (suggest(stage, declared) if stage not in declared else "")
        )


def read_tree(path, stage: str | None = None) -> dict:
    """The run in a results file as a tree (see :mod:`evo_door.files`); ``stage`` picks
    one stage of a pipeline's file."""
    with _open(path) as f:
        return read_group(_run_group(f, path, stage))


def pipeline_attrs(path) -> dict | None:
    """The root attributes of a pipeline's file (``stages``, ``status``...), None for a run's."""
    with _open(path) as f:
        from evo_door.experiment.stored import PIPELINE_ATTRS, checked

        attrs = read_attrs(f)
        if attrs.get("format") != PIPELINE_FORMAT:
            return None
        checked(attrs, PIPELINE_ATTRS)
        attrs["started"] = started_stages(f, path)
        return attrs


def pipeline_resolved(value, where: str) -> dict:
    """``pipeline/resolved``: a pipeline's configuration (JSON text), its ``stages``
    (name -> ``uses``, ``from``, ``where``) and ``report`` checked for their types."""
    resolved = fields.as_json(value, where)
    node = Node(fields.as_mapping(resolved, where), place=f"{where}:", style="key")
    stages = fields.mapping(node, "stages", {})
    for name, entry in stages.items():
        entry = Node(
            fields.as_mapping(entry, f"{where}: stages.{name}"),
            place=f"{where}: stages.{name}",
            style="key",
        )
        fields.mapping(entry, "from", {}, fields.as_text)
        fields.texts(entry, "uses", [])
    fields.mapping(node, "report", {})
    return dict(node)


def sources_of(resolved: dict) -> dict[str, dict[str, str]]:
    """Stage -> its ``{from: STAGE}`` sources, of a checked :func:`pipeline_resolved`."""
    stages = resolved.get("stages") or {}
    return {name: dict(entry.get("from") or {}) for name, entry in stages.items()}


def peek(path, stage: str | None = None) -> dict:
    """Root attributes, the resolved configuration and each job's GA attributes, cheaply."""
    from evo_door.experiment.stored import config_of, root_attrs

    try:
        with _open(path) as f:
            g = _run_group(f, path, stage)
            jobs = g["jobs"]
            if not hasattr(jobs, "keys") or not hasattr(g["experiment"], "keys"):
                raise DamagedFile(f"{path}: {g.name}: jobs and experiment must be groups")
            return {
                ATTRS: root_attrs(read_attrs(g)),
                "resolved": config_of(
                    g["experiment/resolved"][()], f"{path}: {g['experiment'].name}/resolved"
                ),
                "jobs": {
                    k: read_attrs(jobs[k]["ga"])
                    if hasattr(jobs[k], "keys") and "ga" in jobs[k]
                    else {}
                    for k in jobs
                },
                "best": read_attrs(g["best"]) if "best" in g else None,
            }
    except DamagedFile:
        raise
    except (OSError, KeyError) as exc:
        raise UserError(f"{path}: not a readable results file ({exc})") from None


def versions() -> dict:
    """Versions of the packages that decide a run's numbers."""
    import platform
    from importlib import metadata

    from evo_door import __version__

    out = {
        "python": platform.python_version(),
        "evo_door": __version__,
        "platform": platform.platform(),
        "cpus": os.cpu_count() or 0,
    }
    for dist in ("numpy", "scipy", "numba", "deap", "h5py", "pyyaml"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:  # pragma: no cover
            out[dist] = "not installed"
    try:
        import numba

        out["numba_threads"] = int(numba.get_num_threads())
    except Exception:  # pragma: no cover
        pass
    return out


# -- a run as a tree ---------------------------------------------------------------
def run_tree(run, trials_on_disk: bool, jobs_on_disk=frozenset()) -> dict:
    """The results file of ``run`` (an :class:`~evo_door.experiment.runner.ExperimentRun`).

    With ``trials_on_disk``, the trials are copied from the previous checkpoint, and so
    are the jobs of ``jobs_on_disk`` (indices of jobs the previous checkpoint holds
    finished: a finished job does not change).
    """
    setup = run.setup
    cfg = run.config
    ga_settings = run.algorithm.ga
    elapsed = run.elapsed()
    timing = timings(run.jobs, elapsed)
    tree = {
        ATTRS: {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "name": cfg["name"],
            "model": setup.model_name,
            "status": run.status,
            "created": run.created,
            "updated": run.now(),
            "seed": ga_settings.seed,
            "algorithm": run.algorithm.kind,
            "polish": run.algorithm.polish,
            "scan": run.algorithm.scan.points,
            "objective": cfg["objective"],
            "per_trial": run.per_trial,
            "jobs": len(run.jobs),
            "jobs_done": sum(j.done for j in run.jobs),
            "generations": ga_settings.generations,
            "generations_done": [(-1 if j.ga is None else j.ga.generation) for j in run.jobs],
            "evo_door_version": run.versions.get("evo_door", ""),
        },
        "experiment": {
            ATTRS: {
                "source": run.experiment["source"],
                "overrides": list(run.experiment["overrides"]),
            },
            "text": run.experiment["text"],
            "resolved": json.dumps(cfg, indent=1),
        },
        "versions": {ATTRS: dict(run.versions)},
        "setup": setup_tree(setup),
        "trials": Keep(lambda: trials_tree(setup)) if trials_on_disk else trials_tree(setup),
        "jobs": {
            str(k): (
                Keep(lambda job=job: job_tree(job, setup.free))
                if k in jobs_on_disk
                else job_tree(job, setup.free)
            )
            for k, job in enumerate(run.jobs)
        },
        "timings": {ATTRS: timing},
    }
    if run.status == "complete" and run.result:
        tree["best"] = best_tree(run)
        if run.per_trial:
            tree["summary"] = summary_tree(run)
        tree["response"] = {
            str(k): response_tree(r, setup.objective.channel) for k, r in enumerate(run.responses())
        }
        if run.result.get("integration_error") is not None:
            tree["integration_error"] = run.result["integration_error"].to_tree()
            timing["integration_error_s"] = run.result["integration_error_s"]
        if run.result.get("perceptual_check") is not None:
            tree["perceptual_check"] = run.result["perceptual_check"].to_tree()
        if run.result.get("tolerance") is not None:
            tree["tolerance"] = run.result["tolerance"].to_tree()
    return tree


def timings(jobs, elapsed: float) -> dict:
    ga_evals = sum(j.ga.evaluations for j in jobs if j.ga is not None)
    local_evals = sum(j.local.evaluations for j in jobs if j.local is not None)
    eval_time = sum(float(np.sum(j.ga.eval_times)) for j in jobs if j.ga is not None)
    return {
        "total_s": elapsed,
        "jobs_s": [float(j.seconds) for j in jobs],
        "evaluations": ga_evals + local_evals,
        "ga_evaluations": ga_evals,
        "ga_evaluation_s": eval_time,
        # the compiled kernel's throughput during the GA's batched calls
        "evaluations_per_s": ga_evals / eval_time if eval_time else 0.0,
        "local_evaluations": local_evals,
        "local_s": sum(float(j.local.seconds) for j in jobs if j.local is not None),
    }


def setup_tree(setup) -> dict:
    model = setup.model
    return {
        ATTRS: {
            "model": setup.model_name,
            "free": list(setup.free),
            "method": setup.method,
            "substeps": int(setup.substeps),
            "tolerance": tolerance_of(model, setup.tolerance),
            "objective": dataclasses.asdict(setup.objective),
            "start": dict(setup.start),
            "param_names": list(model.params.names),
            "fit_ids": [t.trial_id for t in setup.fit],
            "validation_ids": [t.trial_id for t in setup.validation],
        },
        "base": np.asarray(setup.base, dtype=np.float64),
        "lower": np.asarray(setup.lower, dtype=np.float64),
        "upper": np.asarray(setup.upper, dtype=np.float64),
        **({"feel": feel_tree(setup.feel)} if setup.feel is not None else {}),
    }


def feel_tree(feel) -> dict:
    """The chosen feel of a perceptual objective: its curve (rad, N) and its settings."""
    return {
        ATTRS: {
            "source": feel.curve.source,
            "origin": json.dumps(feel.curve.origin),
            "jnd": json.dumps(feel.jnd.as_dict()),
            "dynamics": json.dumps(feel.dynamics),
            "closed": feel.closed,
            "latch_zone": feel.latch_zone,
            "peak_weight": feel.peak_weight,
            "excess_weight": feel.excess_weight,
            "angle_weight": feel.angle_weight,
        },
        "theta": feel.curve.theta,
        "opening": feel.curve.opening,
        "closing": feel.curve.closing,
    }


_TRIAL_FIELDS = (
    "trial_id",
    "user_id",
    "kind",
    "theta0",
    "dtheta0",
    "source",
    "sensors",
    "truth",
    "meta",
)


def trials_tree(setup) -> dict:
    out = {}
    for role, trials in (("fit", setup.fit), ("validate", setup.validation)):
        for k, tr in enumerate(trials):
            fields = {name: getattr(tr, name) for name in _TRIAL_FIELDS}
            # the trial's checksum: its source file's own where the trial is as read there
            node = {
                ATTRS: {"role": role, **fields, "data_digest": tr.digest()},
                "t": tr.t,
                "force": tr.force,
            }
            for ch in tr.channels:
                node[ch] = getattr(tr, ch)
            out[f"{role}_{k}"] = node
    return out


def job_tree(job, free=()) -> dict:
    """``jobs/<k>``: a job's state (its GA's or NSGA-II's snapshot), and its answer once
    done (with NSGA-II: ``front/``, the front and the smallest change chosen from it;
    :meth:`~evo_door.optim.smallest_change.SmallestChange.to_tree`)."""
    node = {
        ATTRS: {
            "name": job.name,
            "trials": list(job.trials),
            "done": job.done,
            "ga_stop": job.ga_stop,
            "seconds": float(job.seconds),
        }
    }
    if job.ga is not None:
        snap = (NSGA2 if isinstance(job.ga, FrontState) else GeneticAlgorithm).snapshot(job.ga)
        log = snap.pop("logbook")
        node["ga"] = {
            ATTRS: {
                "generation": snap.pop("generation"),
                "evaluations": snap.pop("evaluations"),
                "blowups": snap.pop("blowups"),
                "best_fitness": job.ga.best_fitness,
            },
            "logbook": {ATTRS: {"columns": list(LOG_FIELDS)}, **log},
            **snap,
        }
    if job.local is not None:
        d = job.local.as_dict()
        node["local"] = {
            ATTRS: {k: v for k, v in d.items() if not isinstance(v, list)},
            "x0": np.asarray(job.local.x0),
            "x": np.asarray(job.local.x),
        }
    if job.done:
        node[ATTRS]["best_fitness"] = float(job.best_fitness)
        node["best_x"] = np.asarray(job.best_x, dtype=np.float64)
        node["fit_errors"] = np.asarray(job.fit_errors, dtype=np.float64)
        node["validation_errors"] = np.asarray(job.validation_errors, dtype=np.float64)
        if job.identifiability is not None:
            node["identifiability"] = job.identifiability.to_tree()
        if job.front is not None:
            node["front"] = job.front.to_tree(free)
    return node


def best_tree(run) -> dict:
    """``/best``: the run's answer, its errors, and the estimates a bound decided.

    ``at_bound`` maps each free parameter within 1 % of its search range from a bound
    to ``"lower"`` or ``"upper"`` (:func:`evo_door.optim.bounds.bound_hits`).
    """
    res = run.result
    fit_ids = [t.trial_id for t in run.setup.fit]
    val_ids = [t.trial_id for t in run.setup.validation]
    if run.pooled:
        job = run.jobs[-1]
        fit_errors = dict(zip(fit_ids, map(float, job.fit_errors)))
        validation = dict(zip(val_ids, map(float, job.validation_errors)))
    elif run.per_trial:
        jobs = run.trial_jobs
        fit_errors = {j.name: float(j.fit_errors[0]) for j in jobs}
        val = np.array([j.validation_errors for j in jobs]) if val_ids else np.zeros((0, 0))
        validation = {v: float(np.mean(val[:, i])) for i, v in enumerate(val_ids)}
    else:
        job = run.jobs[0]
        fit_errors = dict(zip(fit_ids, map(float, job.fit_errors)))
        validation = dict(zip(val_ids, map(float, job.validation_errors)))
    return {
        ATTRS: {
            "fitness": float(res["best_fitness"]),
            "values": {n: float(v) for n, v in zip(run.setup.free, res["best_x"])},
            "fit_errors": fit_errors,
            "validation_errors": validation,
            "param_names": list(run.setup.model.params.names),
            "meaning": (
                _front_meaning(run.jobs[-1].front)
                if run.jobs[-1].front is not None
                else "fit of every trial at once"
                if run.pooled
                else "mean of the per-trial fits"
                if run.per_trial
                else "best of the run"
            ),
            "at_bound": bound_hits(run.setup.free, res["best_x"], run.setup.lower, run.setup.upper),
        },
        "x": np.asarray(res["best_x"], dtype=np.float64),
        "full": np.asarray(res["full"], dtype=np.float64),
        **(
            {"identifiability": res["identifiability"].to_tree()}
            if res.get("identifiability") is not None
            else {}
        ),
    }


def _front_meaning(front) -> str:
    """What an NSGA-II run's answer is: the smallest change, or the closest door."""
    if front.reachable:
        return "smallest change within the JND"
    return "closest door: the chosen feel is unreachable (no door of the front passes the check)"


def summary_tree(run) -> dict:
    xs = run.result["xs"]
    return {
        ATTRS: {"names": list(run.setup.free), "trials": [j.name for j in run.trial_jobs]},
        "x": xs,
        "min": xs.min(axis=0),
        "max": xs.max(axis=0),
        "mean": xs.mean(axis=0),
        "std": xs.std(axis=0),
        "fitness": np.array([j.best_fitness for j in run.trial_jobs]),
    }


def response_tree(r: dict, channel: str) -> dict:
    return {
        ATTRS: {
            "trial_id": r["trial_id"],
            "role": r["role"],
            "error": r["error"],
            "channel": channel,
            "ok": r["ok"],
        },
        "t": r["t"],
        "force": r["force"],
        "target": r["target"],
        "model": r["model"],
        "model_theta": r["model_theta"],
    }
