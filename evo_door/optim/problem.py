"""The estimation problem: model + target trials + free parameters + objective.

A :class:`Problem` knows nothing of genetic algorithms: it maps a matrix of candidate
vectors (one row per candidate, one column per *free* parameter, in the problem's
order) to objective values, in one compiled, parallel call per batch
(:func:`evo_door.optim.kernels.population_errors`). Any algorithm (the GA, SLSQP, a
grid) drives it through :meth:`Problem.evaluate`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from evo_door.channels import RESPONSE_CHANNELS, unit
from evo_door.data.trial import Trial
from evo_door.errors import UserError
from evo_door.sim_settings import KINDS, METHODS, tolerance_of

if TYPE_CHECKING:
    from evo_door.sim.simulate import Response

# The compiled kernels (:mod:`evo_door.optim.kernels`, :mod:`evo_door.sim.simulate`)
# are imported where a problem runs them: a command that only reads an objective from
# a results file (``show``) does not load numba and their machine code.

#: How the per-trial objectives of one candidate are combined into its fitness.
COMBINE = ("sum", "max", "mean")
#: The objective kind that scores a feel against a chosen one in JND units
#: (:mod:`evo_door.perception.target`), not a trial's response against its samples.
PERCEPTUAL = "perceptual"
#: Every objective kind: the trial kernels' and the perceptual one.
OBJECTIVE_KINDS = (*KINDS, PERCEPTUAL)


@dataclass(frozen=True)
class Objective:
    """Objective of eq. 5.3 (``max_square``) or 5.4 (``ise``) on derivative 0, 1 or 2,
    or the ``perceptual`` objective: the feel against a chosen one, in JND units.

    Parameters
    ----------
    kind : {"max_square", "ise", "perceptual"}
    derivative : {0, 1, 2}
        0 angle (rad), 1 angular speed (rad/s), 2 angular acceleration (rad/s^2): the
        channel of the trial objectives (with ``perceptual``, those the run reports on
        its trials beside the fitness, as ISE).
    combine : {"sum", "max", "mean"}
        How the objectives of several trials make one fitness.
    """

    kind: str = "max_square"
    derivative: int = 1
    combine: str = "sum"

    def __post_init__(self):
        if self.kind not in OBJECTIVE_KINDS:
            raise ValueError(f"objective kind {self.kind!r} not in {OBJECTIVE_KINDS}")
        if self.derivative not in (0, 1, 2):
            raise ValueError(f"objective derivative {self.derivative!r} not in (0, 1, 2)")
        if self.combine not in COMBINE:
            raise ValueError(f"objective combine {self.combine!r} not in {COMBINE}")

    @property
    def channel(self) -> str:
        """The trial channel compared: theta, dtheta or ddtheta."""
        return RESPONSE_CHANNELS[self.derivative]

    @property
    def unit(self) -> str:
        """The fitness unit for an angle coordinate: ``(rad/s)^2 s`` for ISE on speed."""
        return self.unit_for("rad")

    @property
    def perceptual(self) -> bool:
        return self.kind == PERCEPTUAL

    @property
    def trial_kind(self) -> str:
        """The trial kernel's kind: this one's, or ISE beside a perceptual fitness."""
        return "ise" if self.perceptual else self.kind

    @property
    def trial_objective(self) -> Objective:
        """The objective the trials are scored by (ISE beside a perceptual fitness)."""
        return Objective(self.trial_kind, self.derivative, self.combine)

    def unit_for(self, theta_unit: str) -> str:
        """The fitness unit for a model whose coordinate is in ``theta_unit``."""
        if self.perceptual:
            return "JND^2"
        return f"({unit(self.channel, theta_unit)})^2" + (" s" if self.kind == "ise" else "")

    def combine_errors(self, errors: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """Fitness per row of ``errors`` (n_candidates, n_trials); inf where any trial blew up."""
        errors = np.where(ok, errors, np.inf)
        if self.combine == "sum":
            out = errors.sum(axis=1)
        elif self.combine == "max":
            out = errors.max(axis=1)
        else:
            out = errors.mean(axis=1)
        return out


class TrialPack:
    """Trials concatenated for the kernel (see :mod:`evo_door.optim.kernels`)."""

    def __init__(self, trials: Sequence[Trial], derivative: int):
        self.trials = list(trials)
        channel = RESPONSE_CHANNELS[derivative]
        targets = [tr.require(derivative) for tr in self.trials]
        lengths = [tr.n for tr in self.trials]
        self.offsets = np.zeros(len(lengths) + 1, dtype=np.int64)
        self.offsets[1:] = np.cumsum(lengths)
        cat = lambda parts: np.ascontiguousarray(np.concatenate(parts)) if parts else np.zeros(0)
        self.force = cat([tr.force for tr in self.trials])
        self.target = cat(targets)
        # saturated sensor samples do not count
        masks = [tr.unsaturated(channel) for tr in self.trials]
        self.mask = (
            np.ascontiguousarray(np.concatenate(masks), dtype=np.bool_)
            if masks
            else np.zeros(0, dtype=np.bool_)
        )
        self.dt = np.array([tr.dt for tr in self.trials], dtype=np.float64)
        states = [tr.initial_state() for tr in self.trials]
        self.theta0 = np.array([s[0] for s in states], dtype=np.float64)
        self.dtheta0 = np.array([s[1] for s in states], dtype=np.float64)

    def __len__(self) -> int:
        return len(self.trials)

    @property
    def ids(self) -> list[str]:
        return [tr.trial_id for tr in self.trials]


class Problem:
    """Fit the free parameters of ``model`` to ``trials`` under ``objective``.

    Parameters
    ----------
    model : Model
    free : sequence of str
        Names of the free parameters: the columns of every candidate matrix.
    lower, upper : array_like
        Search bounds of the free parameters (inside their declared ranges).
    base : array_like
        Full parameter vector (declaration order) giving every non-free value.
    trials : sequence of Trial
        Fitted trials; their channel of the objective's derivative is the target.
    objective : Objective
    validation : sequence of Trial
        Trials not fitted; :meth:`validation_errors` reports the model's error on them.
    method, substeps, tolerance :
        Integration scheme, sub-steps per sample and ``dopri5``'s tolerance (default:
        the model's).
    feel : FeelTarget, optional
        The chosen feel (:class:`~evo_door.perception.FeelTarget`): required by the
        ``perceptual`` objective, which scores candidates against it alone; the
        trials may then be none.
    model_name : str, optional
        What :func:`~evo_door.models.get_model` finds ``model`` by (a name, an import
        path or a file path), default ``model.name``. A problem is pickled with the
        model by that name (a worker process loads the model's compiled code from
        numba's cache instead of compiling a pickled copy of it).

    A candidate's fitness depends on its genes only, never on the other candidates of
    the batch: executors (:mod:`evo_door.optim.executors`) may cut a batch in chunks.
    """

    def __init__(
        self,
        model,
        free: Sequence[str],
        lower,
        upper,
        base,
        trials,
        objective: Objective,
        validation: Sequence[Trial] = (),
        method: str | None = None,
        substeps: int | None = None,
        model_name: str | None = None,
        tolerance: float | None = None,
        feel=None,
        time_limit: float | None = None,
    ):
        self.model = model
        #: a model that runs native code of its own (an FMU) is evaluated in a sandbox
        #: process, each candidate within ``time_limit`` seconds (:mod:`.sandbox`)
        self.sandboxed = bool(model.plant.contained)
        self.time_limit = time_limit
        self.model_name = model_name
        self.free = tuple(free)
        self.index = np.array([model.params.index(n) for n in self.free], dtype=np.int64)
        self.lower = np.array(lower, dtype=np.float64).reshape(len(self.free))
        self.upper = np.array(upper, dtype=np.float64).reshape(len(self.free))
        if np.any(self.lower >= self.upper):
            raise UserError("every free parameter needs lower < upper")
        self.base = np.array(base, dtype=np.float64)
        if self.base.shape != (len(model.params),):
            raise ValueError(f"base vector must have {len(model.params)} values")
        self.objective = objective
        self.method = method or model.method
        self.method_code = METHODS[self.method]
        self.substeps = int(substeps or model.substeps)
        self.tolerance = tolerance_of(model, tolerance)
        self.feel = feel
        if objective.perceptual and feel is None:
            raise UserError(
                "objective perceptual: needs a chosen feel (target: curve: FILE, or model:)"
            )
        self.fit = TrialPack(trials, objective.derivative)
        if len(self.fit) == 0 and not objective.perceptual:
            raise UserError("no trial to fit")
        self.validation = TrialPack(validation, objective.derivative)

    # -- pickling (to worker processes) -------------------------------------------
    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["model"] = self.model_name or self.model.name
        return state

    def __setstate__(self, state: dict) -> None:
        from evo_door.models import get_model

        state = dict(state)
        state["model"] = get_model(state["model"])
        self.__dict__.update(state)

    # -- vectors --------------------------------------------------------------
    @property
    def n_var(self) -> int:
        return len(self.free)

    def full(self, X) -> np.ndarray:
        """Full parameter matrix (rows in declaration order) for candidates ``X``."""
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        P = np.repeat(self.base[None, :], X.shape[0], axis=0)
        P[:, self.index] = X
        return np.ascontiguousarray(P)

    def as_dict(self, x) -> dict[str, float]:
        """Free parameter name -> value for one candidate."""
        return {n: float(v) for n, v in zip(self.free, np.asarray(x, dtype=np.float64))}

    def check_bounds(self, X) -> None:
        X = np.atleast_2d(X)
        bad = ~((X >= self.lower) & (X <= self.upper))
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise ValueError(
                f"candidate {i}: {self.free[j]} = {X[i, j]!r} outside "
                f"[{self.lower[j]!r}, {self.upper[j]!r}]"
            )

    # -- evaluation -----------------------------------------------------------
    def trial_errors(self, X, pack: TrialPack | None = None):
        """``(errors, ok)``, both (n_candidates, n_trials), on the fit trials by default.

        Sandboxed (a model that runs native code), each candidate is run in the sandbox's
        child (:func:`~evo_door.optim.sandbox.contained`): one that crashes it or overruns
        the time limit is a blow-up (errors inf, ok False)."""
        pack = self.fit if pack is None else pack
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        self.check_bounds(X)
        if self.sandboxed:
            from evo_door.optim.sandbox import contained

            err = np.full((X.shape[0], len(pack)), np.inf)
            ok = np.zeros((X.shape[0], len(pack)), dtype=np.bool_)
            for i in range(X.shape[0]):
                done, got = contained(self, "trial_errors", X[i : i + 1], pack)
                if done:
                    err[i], ok[i] = got[0][0], got[1][0]
            return err, ok
        P = self.full(X)
        err = np.empty((P.shape[0], len(pack)))
        ok = np.zeros((P.shape[0], len(pack)), dtype=np.bool_)
        if len(pack) and P.shape[0]:
            from evo_door.optim.kernels import population_errors

            population_errors(
                self.model,
                P,
                pack.force,
                pack.target,
                pack.mask,
                pack.offsets,
                pack.dt,
                pack.theta0,
                pack.dtheta0,
                self.substeps,
                self.method_code,
                self.tolerance,
                self.objective.derivative,
                KINDS[self.objective.trial_kind],
                err,
                ok,
            )
        return err, ok

    def evaluate(self, X):
        """``(fitness, blown)`` per candidate; a blown-up candidate has fitness inf."""
        if self.sandboxed:
            from evo_door.optim.sandbox import sandbox_for

            X = np.atleast_2d(np.asarray(X, dtype=np.float64))
            self.check_bounds(X)
            return sandbox_for(self, self.time_limit).evaluate(X)
        if self.objective.perceptual:
            X = np.atleast_2d(np.asarray(X, dtype=np.float64))
            self.check_bounds(X)
            f = self.feel.evaluate(self.model, self.full(X))
            blown = ~np.isfinite(f) | (f >= 1e12)
            return np.where(blown, np.inf, f), blown
        err, ok = self.trial_errors(X)
        blown = ~ok.all(axis=1)
        return self.objective.combine_errors(err, ok), blown

    def validation_errors(self, x) -> np.ndarray:
        """Objective of one candidate on each validation trial (inf where it blew up)."""
        if not len(self.validation):
            return np.zeros(0)
        err, ok = self.trial_errors(x, self.validation)
        return np.where(ok, err, np.inf)[0]

    def responses(
        self, x, pack: TrialPack | None = None, indices: Sequence[int] | None = None
    ) -> list[Response]:
        """Full simulated responses of one candidate on the trials of ``pack``.

        ``pack`` is the fit trials by default (or ``self.validation``); ``indices``
        picks some of its trials. Sandboxed, each trial is run in the sandbox's child: one
        that crashes it or overruns the time limit is a response of NaN, not ok.
        """
        from evo_door.sim.simulate import Response, simulate

        pack = self.fit if pack is None else pack
        p = self.full(x)[0]
        out = []
        for i in range(len(pack)) if indices is None else indices:
            tr = pack.trials[i]
            if self.sandboxed:
                from evo_door.optim.sandbox import contained

                done, got = contained(self, "responses", x, pack, [i])
                if not done:
                    nan = np.full(tr.force.shape, np.nan)
                    got = [Response(tr.t, tr.force, nan, nan.copy(), nan.copy(), False)]
                out.append(got[0])
                continue
            out.append(
                simulate(
                    self.model,
                    p,
                    tr.force,
                    tr.dt,
                    theta0=pack.theta0[i],
                    dtheta0=pack.dtheta0[i],
                    t0=float(tr.t[0]),
                    method=self.method,
                    substeps=self.substeps,
                    tolerance=self.tolerance,
                )
            )
        return out

    def trial_runs(self, X, j: int):
        """``(theta, dtheta, ddtheta, ok)`` of every row of the candidates ``X`` on the
        fitted trial ``j``, as :func:`~evo_door.sim.simulate.simulate_batch` gives them
        (the sensitivities of :mod:`evo_door.optim.sensitivity`). Sandboxed, each row is
        run in the sandbox's child: one that crashes it or overruns the time limit is
        NaN, not ok."""
        pack = self.fit
        a, b = pack.offsets[j], pack.offsets[j + 1]
        P = self.full(X)
        if self.sandboxed:
            from evo_door.optim.sandbox import contained

            X = np.atleast_2d(np.asarray(X, dtype=np.float64))
            runs = [np.full((X.shape[0], b - a), np.nan) for _ in range(3)]
            ok = np.zeros(X.shape[0], dtype=np.bool_)
            for i in range(X.shape[0]):
                done, got = contained(self, "trial_runs", X[i : i + 1], j)
                if done:
                    for k in range(3):
                        runs[k][i] = got[k][0]
                    ok[i] = got[3][0]
            return runs[0], runs[1], runs[2], ok
        from evo_door.sim.simulate import simulate_batch

        return simulate_batch(
            self.model,
            P,
            pack.force[a:b],
            pack.dt[j],
            theta0=pack.theta0[j],
            dtheta0=pack.dtheta0[j],
            method=self.method,
            substeps=self.substeps,
        )

    def with_objective(self, objective: Objective) -> Problem:
        """The same problem under another objective (the max-square polish's ISE stage)."""
        return Problem(
            self.model,
            self.free,
            self.lower,
            self.upper,
            self.base,
            self.fit.trials,
            objective,
            self.validation.trials,
            self.method,
            self.substeps,
            self.model_name,
            self.tolerance,
            self.feel,
            self.time_limit,
        )
