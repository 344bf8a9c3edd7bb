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

The GA's evaluations run on the run's executor (``executor:``, ``--executor``;
:mod:`evo_door.optim.executors`), started once for the run (or handed over by a
pipeline) and closed after it; the executor changes where the numbers are computed,
never what they are, and is recorded as provenance (the root's ``executor``).

What is checked and claimed before a run starts (its results file, its memory) is in
:mod:`evo_door.experiment.run_preflight`.
"""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from evo_door.experiment import store
from evo_door.experiment.answer_checks import identifiability_of, integration_error_of
from evo_door.experiment.checkpoint import (
    CHECKPOINT_EVERY,
    TermAsInterrupt,
    finished,
    position,
    write_checkpoint,
)
from evo_door.experiment.config import AlgorithmSpec
from evo_door.experiment.feel_check import try_feel_check
from evo_door.experiment.run_preflight import (
    _LOCKED,
    check_memory,
    check_stored_memory,
    claim_output,
    default_output,
)
from evo_door.experiment.setup import Setup, users_trials
from evo_door.experiment.stored import config_of, restore_jobs, root_attrs, setup_from_tree
from evo_door.files import ATTRS, FileLock, fields, remove_stale_temporaries
from evo_door.optim.bounds import bound_hits
from evo_door.optim.executors import DEFAULT as DEFAULT_EXECUTOR
from evo_door.optim.executors import Executor, check_executor, open_executor
from evo_door.optim.hooks import Callback, EarlyStop, ProgressBar
from evo_door.optim.local import LocalResult, polish
from evo_door.optim.multistart import scan_and_polish
from evo_door.optim.smallest_change import ChangeObjectives, SmallestChange, smallest_change_of
from evo_door.optim.spread import trial_estimates, with_trial_spread

#: the name of the job fitting every trial at once in a ``per_trial`` run with ``pooled``
POOLED = "pooled"


class Interrupted(Exception):
    """Raised by a checkpoint hook to stop a run as a kill would (tests)."""


@dataclass
class Job:
    """One optimisation: all fitted trials, or one of them (``per_trial``)."""

    name: str
    trials: list  # indices into Setup.fit
    ga: object = None  # GAState
    ga_stop: str = ""
    local: LocalResult | None = None
    done: bool = False
    best_x: np.ndarray | None = None
    best_fitness: float = float("nan")
    fit_errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    validation_errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    seconds: float = 0.0
    identifiability: object = None  # Identifiability at best_x (optim.identifiability)
    #: ``nsga2``: the front and the smallest change chosen from it (optim.smallest_change)
    front: SmallestChange | None = None


class ExperimentRun:
    """A run of an experiment, backed by its results file.

    Build one with :meth:`create` (from a checked experiment) or :meth:`open` (from a
    results file, to resume), then call :meth:`run`. ``config`` is the resolved
    experiment as stored in the file; ``algorithm`` its typed ``algorithm`` section.
    """

    def __init__(
        self,
        config: dict,
        algorithm: AlgorithmSpec,
        setup: Setup,
        path,
        experiment: dict,
        versions: dict,
        created: str,
        jobs: list[Job] | None = None,
        elapsed: float = 0.0,
    ):
        self.config = config
        self.algorithm = algorithm
        self.setup = setup
        self.path = Path(path)
        self.experiment = experiment  # text, source, overrides
        self.versions = versions
        self.created = created
        self.elapsed_before = elapsed  # seconds spent by earlier sessions of this run
        self.per_trial = bool(config["per_trial"])
        # with per_trial, also one fit of every trial at once: the run's answer
        self.pooled = self.per_trial and bool(config.get("pooled", False))
        if jobs is None:
            everything = list(range(len(setup.fit)))
            if self.per_trial:
                jobs = [Job(tr.trial_id, [i]) for i, tr in enumerate(setup.fit)]
                if self.pooled:
                    jobs.append(Job(POOLED, everything))
            else:
                jobs = [Job("all", everything)]
        self.jobs = jobs
        #: writes the run's tree (:meth:`checkpoint`); a pipeline puts it in a stage's group
        self.writer = None
        #: shown before the run's name in the progress display (a pipeline's stage)
        self.label_prefix = ""
        self.status = "complete" if all(j.done for j in jobs) else "running"
        self._t0 = time.perf_counter()
        self.result: dict = {}
        # the trials never change: after the first write they are copied from the
        # previous checkpoint (a resumed run starts from a file that has them)
        self._trials_on_disk = False
        # a finished job never changes either: once written, it is copied as well (the
        # jobs finished when the file was last written from the run's current state)
        self._jobs_on_disk: frozenset[int] = frozenset()
        self._hook = None
        self._lock: FileLock | None = None
        self._term: TermAsInterrupt | None = None
        #: where the GA's evaluations run (an executor's name); provenance only
        self.executor = DEFAULT_EXECUTOR
        self._ex: Executor | None = None
        self.on_disk: str | None = None  # where the file's last checkpoint stands, if any
        #: seconds between a GA's checkpoints (:data:`CHECKPOINT_EVERY`; 0: every one)
        self.checkpoint_every = CHECKPOINT_EVERY
        self._written = time.monotonic()  # when the file was last written
        #: a finished generation not written yet: (tree, position), for Ctrl-C to write
        self._pending: tuple[dict, str] | None = None

    # -- construction ------------------------------------------------------------------
    @classmethod
    def create(cls, exp, out=None, trials=None, overwrite: bool = False) -> ExperimentRun:
        """A new run of the checked experiment ``exp`` writing to ``out``.

        The file is locked from here until :meth:`run` ends (:class:`FileLock`): no
        other process can write it meanwhile. An existing results file at ``out`` is
        replaced only with ``overwrite``; any other existing file never is.
        """

        def start(path: Path, lock: FileLock) -> ExperimentRun:
            run = cls.new(exp, path, trials)
            run._lock = lock
            run.checkpoint()
            return run

        return claim_output(Path(out) if out else default_output(exp), overwrite, start)

    @classmethod
    def new(cls, exp, path, trials=None, versions=None, created=None) -> ExperimentRun:
        """A new run of ``exp`` in memory: its data read and checked, nothing written,
        no lock taken (:meth:`create` does both; a pipeline owns its file's lock)."""
        from evo_door.experiment.setup import resolve

        if exp.target.users:
            trials = users_trials(exp, trials)
        setup = resolve(exp, trials)
        check_memory(exp.algorithm, len(setup.free))
        run = cls(
            exp.resolved(),
            exp.algorithm,
            setup,
            path,
            {"text": exp.text, "source": exp.source, "overrides": list(exp.overrides)},
            versions or store.versions(),
            created or cls.now(),
        )
        run.executor = exp.executor
        return run

    @classmethod
    def open(cls, path) -> ExperimentRun:
        """Rebuild a run from its results file (to resume it), locked like :meth:`create`."""
        lock = FileLock(path).acquire(_LOCKED)
        try:
            run = cls._from_file(path)
        except BaseException:
            lock.release()
            raise
        run._lock = lock
        if run.status == "complete":  # nothing will be written
            run.release()
        return run

    @classmethod
    def _from_file(cls, path) -> ExperimentRun:
        run = cls.from_tree(store.read_tree(path), path)
        remove_stale_temporaries(path)
        return run

    @classmethod
    def from_tree(cls, tree: dict, path) -> ExperimentRun:
        """Rebuild a run from its results tree (a file's root, or a pipeline stage's group);
        every value it takes is checked (:mod:`evo_door.files.fields`): a results file is
        data, and a resumed run never starts from a state that does not fit together."""
        experiment = fields.group(tree, "experiment")
        config = config_of(experiment["resolved"], fields.place_of(experiment, "resolved"))
        algorithm = AlgorithmSpec.from_resolved(config["algorithm"])
        setup = setup_from_tree(tree)
        check_stored_memory(algorithm, len(setup.free), path)
        root = root_attrs(tree[ATTRS])
        run = cls(
            config,
            algorithm,
            setup,
            path,
            {
                "text": fields.text(experiment, "text"),
                "source": fields.text(experiment[ATTRS], "source", ""),
                "overrides": fields.texts(experiment[ATTRS], "overrides", []),
            },
            dict(fields.group(tree, "versions")[ATTRS]),
            fields.text(root, "created"),
            elapsed=fields.number(fields.group(tree, "timings")[ATTRS], "total_s", 0.0),
        )
        restore_jobs(run.jobs, fields.group(tree, "jobs"), algorithm, setup, path)
        # every job done but the final write (best, responses) missing: still running
        run.status = (
            "complete"
            if (
                all(j.done for j in run.jobs)
                and root.get("status") == "complete"
                and "best" in tree
            )
            else "running"
        )
        run._trials_on_disk = True
        run._jobs_on_disk = finished(run.jobs)
        run.executor = fields.text(root, "executor", DEFAULT_EXECUTOR)
        run.on_disk = position(run.jobs)
        return run

    # -- running -----------------------------------------------------------------------
    def run(self, progress: bool = False, on_checkpoint=None, executor=None) -> ExperimentRun:
        """Run (or continue) every job; checkpoint after a generation when the last is
        :attr:`checkpoint_every` seconds old, after every job, and on Ctrl-C or SIGTERM.

        ``on_checkpoint(run, job)`` is called after each checkpoint is on disk, and with
        it every generation is written (raise :class:`Interrupted` there to simulate a
        kill). ``executor`` is where the GA's evaluations run: a name (it replaces
        :attr:`executor`) or an executor already started (a pipeline's, shared by its
        stages); by default :attr:`executor`, started here if a GA is left to run and
        closed at the end.
        """
        self._hook = on_checkpoint
        if isinstance(executor, str):
            self.executor = check_executor(executor)
        elif executor is not None:
            self.executor = executor.name
        self._written = time.monotonic()
        try:
            with TermAsInterrupt() as self._term, self._executor(executor, progress) as self._ex:
                try:
                    self._run_jobs(progress)
                except KeyboardInterrupt:
                    if self._pending is not None:  # Ctrl-C between checkpoints
                        self.checkpoint(*self._pending)
                    raise
        finally:
            self._ex = None
            self.release()
        return self

    def _executor(self, given, progress: bool):
        """The executor of :meth:`run`: ``given`` if started, else one for this run."""
        if isinstance(given, Executor):
            return contextlib.nullcontext(given)
        ga_left = self.algorithm.population_based and not all(j.done for j in self.jobs)
        ex = open_executor(self.executor if ga_left else DEFAULT_EXECUTOR)
        if progress and ex.name != DEFAULT_EXECUTOR:
            print(f"{self._label_root()}: starting executor {ex.name} ...", file=sys.stderr)
        return ex

    def _label_root(self) -> str:
        return self.label_prefix + self.config["name"]

    def release(self) -> None:
        """Let go of the results file's lock (done by :meth:`run` however it ends)."""
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def _run_jobs(self, progress: bool) -> None:
        for job in self.jobs:
            if job.done:
                continue
            t0 = time.perf_counter()
            problem = self.setup.problem(job.trials)
            if self.algorithm.population_based:
                self._run_ga(job, problem, progress)
            x = job.ga.best_x if job.ga is not None else self.setup.start_vector()
            if self.algorithm.kind == "nsga2":
                job.front = smallest_change_of(
                    problem,
                    job.ga,
                    self.algorithm.polish == "slsqp",
                    self.algorithm.local,
                    self.algorithm.margin,
                )
                x, job.best_fitness = job.front.x, job.front.error
            elif self.algorithm.kind == "nlpql" or self.algorithm.polish == "slsqp":
                if progress:
                    print(
                        f"{self._label(job)}: {'scan, ' * self.algorithm.scan.enabled}SLSQP from "
                        "fitness "
                        f"{problem.evaluate(x)[0][0]:.4g} ...",
                        end="",
                        file=sys.stderr,
                        flush=True,
                    )
                if self.algorithm.scan.enabled:
                    job.local = scan_and_polish(
                        problem, x, self.algorithm.scan, self.algorithm.local
                    )
                else:
                    job.local = polish(problem, x, self.algorithm.local)
                if progress:
                    print(
                        f" {job.local.fitness:.4g} ({job.local.evaluations} evaluations, "
                        f"{job.local.seconds:.1f} s)",
                        file=sys.stderr,
                        flush=True,
                    )
                x = job.local.x
                job.best_fitness = job.local.fitness
            else:
                job.best_fitness = job.ga.best_fitness
            job.best_x = np.array(x, dtype=np.float64)
            err, ok = problem.trial_errors(job.best_x)
            job.fit_errors = np.where(ok, err, np.inf)[0]
            job.validation_errors = problem.validation_errors(job.best_x)
            job.identifiability = identifiability_of(problem, job.best_x, self._measured)
            job.done = True
            job.seconds += time.perf_counter() - t0
            if progress:
                print(self._end_line(job), file=sys.stderr, flush=True)
            self._checkpoint_and_hook(job)
        self.status = "complete"
        self.result = self._results(progress)
        self.checkpoint()

    @property
    def _measured(self) -> bool:  # the target is data, not a model's noise-free response
        return self.config["target"].get("kind", "data") == "data"

    def _end_line(self, job: Job) -> str:
        """The progress display's last line for a job: its fitness, and any estimate
        that a search bound stopped (the bound, not the data, decided it)."""
        s = self.setup
        hits = bound_hits(s.free, job.best_x, s.lower, s.upper)
        funit = s.objective.unit_for(s.model.theta_unit)
        line = f"{self._label(job)}: best fitness {job.best_fitness:.4g} {funit}"
        for name, side in hits.items():
            i = s.free.index(name)
            bound = s.upper[i] if side == "upper" else s.lower[i]
            unit = s.model.params[name].unit
            line += f"; ! {name} on its {side} search bound ({bound:g} {unit}): widen free.{name}"
        return line

    def _label(self, job: Job) -> str:
        return (
            self.label_prefix + self.config["name"] + (f" [{job.name}]" if self.per_trial else "")
        )

    def _run_ga(self, job: Job, problem, progress: bool) -> None:
        """The GA's (or NSGA-II's) one loop, with this run's hooks: progress,
        checkpoint, early stop."""
        settings = self.algorithm.ga
        search = self.algorithm.search()

        def checkpoint(state):
            job.ga = state
            if self._checkpoint_due():
                self._checkpoint_and_hook(job)
            else:  # its tree now: the GA's next step changes ``state`` in place
                self._pending = (self._tree(), position(self.jobs))

        hooks = [Callback(checkpoint)]
        if settings.patience is not None:
            hooks.append(EarlyStop(settings.patience))
        if progress:
            hooks.insert(
                0,
                ProgressBar(
                    self._label(job),
                    settings.generations,
                    initial=0 if job.ga is None else job.ga.generation,
                ),
            )
        ex = self._ex
        if ex is None or ex.name == DEFAULT_EXECUTOR:
            state = search.run(self._searched(problem, problem), job.ga, hooks)
        else:
            with ex.bind(problem) as remote:
                state = search.run(self._searched(problem, remote), job.ga, hooks)
        job.ga_stop = state.stop_reason

    def _searched(self, problem, evaluator):
        """What the search evaluates: ``evaluator`` (the problem, or an executor's
        stand-in), with NSGA-II the change from the AS-IS door beside it."""
        if self.algorithm.kind == "nsga2":
            return ChangeObjectives.around(problem, evaluator)
        return evaluator

    def _checkpoint_due(self) -> bool:
        """Whether a finished generation is written: :attr:`checkpoint_every` seconds
        after the last write, or at once where a hook watches or SIGTERM came."""
        if self._hook is not None or (self._term is not None and self._term.requested):
            return True
        return time.monotonic() - self._written >= self.checkpoint_every

    def _checkpoint_and_hook(self, job: Job) -> None:
        self.checkpoint()
        if self._hook is not None:
            self._hook(self, job)
        if self._term is not None and self._term.requested:
            raise KeyboardInterrupt  # after a checkpoint: resume starts right here

    # -- results -----------------------------------------------------------------------
    @property
    def free(self) -> list[str]:
        return list(self.setup.free)

    @property
    def trial_jobs(self) -> list[Job]:
        """The per-trial fits of a ``per_trial`` run (every job but the pooled one)."""
        return [j for j in self.jobs if not (self.pooled and j.name == POOLED)]

    def _results(self, progress: bool = False) -> dict:
        """Best parameters, per-trial table, responses, and against a chosen feel the
        specification a supplier builds: filled when every job is done. Where that
        specification centres the nominal (a higher yield than the fit's door), the
        centred nominal is the run's answer; the fit's door stays its alternative."""
        from evo_door.experiment.run_specification import stage_specification
        from evo_door.optim.tolerance import full_nominal

        xs = np.array([j.best_x for j in self.trial_jobs])
        if self.pooled:
            best_x = self.jobs[-1].best_x
            best_fitness = self.jobs[-1].best_fitness
        elif self.per_trial:
            # each trial's own fit, combined as the objective combines trials
            best_x = xs.mean(axis=0)
            fits = np.array([[j.best_fitness for j in self.trial_jobs]])
            best_fitness = float(self.setup.objective.combine_errors(fits, np.isfinite(fits))[0])
        else:
            best_x = xs[0]
            best_fitness = self.jobs[0].best_fitness
        problem = self.setup.problem()
        full = problem.full(best_x)[0]
        spec = stage_specification(self.setup, self.config, full, progress)
        if spec is not None and spec.design == "centred":
            full = full_nominal(spec, self.setup.model, full)
            best_x = full[problem.index].copy()
            best_fitness = float(problem.evaluate(best_x[None, :])[0][0])
        if self.per_trial and not self.pooled:  # the mean of the fits, on every trial
            ident = identifiability_of(self.setup.problem(), best_x, self._measured)
        else:
            ident = self.jobs[-1].identifiability
        if self.per_trial and ident is not None:  # the trials' spread, a floor
            ident = with_trial_spread(
                ident, *trial_estimates([j.identifiability for j in self.trial_jobs])
            )
        t0 = time.perf_counter()
        integration = integration_error_of(self.setup, self._fit_vectors(), best_x)
        integration_s = time.perf_counter() - t0
        check = try_feel_check(self.setup.model, full, self.config, self.setup.feel)
        return {
            "best_x": best_x,
            "best_fitness": best_fitness,
            "full": full,
            "xs": xs,
            "identifiability": ident,
            "integration_error": integration,
            "integration_error_s": integration_s,
            "perceptual_check": check,
            "tolerance": spec,
        }

    def _fit_vectors(self) -> np.ndarray:
        """The free parameters each fitted trial's response is shown with, one row per
        trial: its own fit (``per_trial``), else the fit of every trial at once."""
        if self.per_trial and not self.pooled:
            return np.array([job.best_x for job in self.trial_jobs])
        best = np.asarray(self.jobs[-1].best_x, dtype=np.float64)
        return np.repeat(best[None, :], len(self.setup.fit), axis=0)

    def responses(self) -> list[dict]:
        """Best response next to the target for every fitted and validation trial.

        A fitted trial shows its own job's best (``per_trial``) or the run's best (the
        pooled fit of a ``per_trial`` run with ``pooled``); a validation trial shows the
        run's answer, ``result["best_x"]``.
        """
        problem = self.setup.problem()
        if self.per_trial and not self.pooled:
            jobs = self.trial_jobs
            fit = [problem.responses(job.best_x, indices=[i])[0] for i, job in enumerate(jobs)]
            fit_errors = [float(job.fit_errors[0]) for job in jobs]
        else:  # one fit of every trial: the run's, or the pooled one of a per_trial run
            fit = problem.responses(self.jobs[-1].best_x)
            fit_errors = list(map(float, self.jobs[-1].fit_errors))
        x = self.result["best_x"]
        validation = problem.responses(x, problem.validation)
        validation_errors = (
            problem.validation_errors(x)
            if self.per_trial and not self.pooled
            else self.jobs[-1].validation_errors
        )
        d = self.setup.objective.derivative
        out = []
        for role, pack, responses, errors in (
            ("fit", problem.fit, fit, fit_errors),
            ("validate", problem.validation, validation, validation_errors),
        ):
            for tr, r, error in zip(pack.trials, responses, errors):
                out.append(
                    {
                        "trial_id": tr.trial_id,
                        "role": role,
                        "error": float(error),
                        "t": tr.t,
                        "force": tr.force,
                        "target": tr.channel(d),
                        "model": (r.theta, r.dtheta, r.ddtheta)[d],
                        "model_theta": r.theta,
                        "ok": r.ok,
                    }
                )
        return out

    # -- the file ------------------------------------------------------------------------
    @staticmethod
    def now() -> str:
        """The time now, local, ISO 8601 to the second (for ``created`` / ``updated``)."""
        return datetime.now(UTC).astimezone().isoformat(timespec="seconds")

    def elapsed(self) -> float:
        """Seconds spent on this run by every session so far."""
        return self.elapsed_before + (time.perf_counter() - self._t0)

    def _tree(self) -> dict:
        """The whole run as the tree its results file holds (:func:`.store.run_tree`)."""
        tree = store.run_tree(self, self._trials_on_disk, self._jobs_on_disk)
        tree[ATTRS]["executor"] = self.executor
        return tree

    def checkpoint(self, tree: dict | None = None, where: str | None = None) -> None:
        """Write the whole run to its results file (atomically; refused: the last
        checkpoint is kept, :mod:`.checkpoint`), or hand it to :attr:`writer`.
        ``tree`` and ``where``: an earlier state of the run and its position."""
        done = self._jobs_on_disk  # an earlier state: no job finished since the last write
        if tree is None:
            tree, where = self._tree(), position(self.jobs)
            done = finished(self.jobs)
        if self.writer is not None:
            self.writer(tree)
        else:
            write_checkpoint(self.path, tree, self.on_disk)
        self._written = time.monotonic()
        self._pending = None
        self._trials_on_disk = True
        self._jobs_on_disk = done
        self.on_disk = where
