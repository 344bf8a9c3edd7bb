"""From a checked :class:`~evo_door.experiment.config.ExperimentConfig` to a :class:`Problem`.

Resolution reads what the experiment names (the base parameter set, the trial file,
the target model and its inputs) once; everything the run needs afterwards (the full
base vector, the fitted and validation trials with their targets) is kept in a
:class:`Setup` and stored in the results file, so a run can be resumed or inspected
without the original files.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from evo_door.data.trial import Trial
from evo_door.errors import MissingChannelError, UserError
from evo_door.optim.problem import Objective, Problem
from evo_door.params.declaration import suggest
from evo_door.sim_settings import refined, tolerance_of


@dataclass
class Setup:
    """What a run optimises, fully resolved (see the module docstring)."""

    model_name: str
    base: np.ndarray  # full parameter vector, declaration order
    free: list  # free parameter names
    lower: np.ndarray
    upper: np.ndarray
    fit: list  # fitted Trials
    validation: list  # validation Trials
    objective: Objective
    method: str
    substeps: int
    start: dict = field(default_factory=dict)
    #: ``dopri5``'s tolerance per step; None: the model's (a run written before it was kept)
    tolerance: float | None = None
    #: s per candidate's evaluation of a model that runs native code (an FMU); None: default
    time_limit: float | None = None
    #: the chosen feel of the perceptual objective (:class:`~evo_door.perception.FeelTarget`)
    feel: object = None

    @property
    def model(self):
        from evo_door.models import get_model

        return get_model(self.model_name)

    def problem(self, trial_indices=None) -> Problem:
        trials = self.fit if trial_indices is None else [self.fit[i] for i in trial_indices]
        return Problem(
            self.model,
            self.free,
            self.lower,
            self.upper,
            self.base,
            trials,
            self.objective,
            self.validation,
            self.method,
            self.substeps,
            self.model_name,  # a pickled problem finds its model by it (executors)
            self.tolerance,
            self.feel,
            self.time_limit,
        )

    def refined(self) -> Setup:
        """The same setup at the settings of the a-posteriori error check
        (:func:`evo_door.sim.simulate.refined`: twice the sub-steps, tolerance / 32)."""
        method, substeps, tolerance = refined(
            self.method, self.substeps, tolerance_of(self.model, self.tolerance)
        )
        return replace(self, method=method, substeps=substeps, tolerance=tolerance)

    def start_vector(self) -> np.ndarray:
        """Start point of a local method: ``algorithm.start``, else the base values (clipped)."""
        model = self.model
        x = np.array([self.start.get(n, self.base[model.params.index(n)]) for n in self.free])
        return np.clip(x, self.lower, self.upper)


def users_trials(exp, trials=None) -> list:
    """The target's trials of the users ``target.users`` names (data targets)."""
    spec = exp.target
    where = spec.locs.get("users", spec.locs.get("trials", exp.source))
    if trials is None:
        if spec.kind != "data":
            raise UserError(f"{where}: target.users: selects among a data file's trials")
        from evo_door.data.io import read_trials

        try:
            trials = read_trials(spec.data)
        except UserError as exc:
            raise UserError(f"{spec.locs['data']}: target.data: {exc}") from None
    present = sorted({str(tr.user_id) for tr in trials if tr.user_id})
    for user in spec.users:
        if user not in present:
            raise UserError(
                f"{where}: target.users: no trial of user {user!r}; users: "
                + (", ".join(present) or "none (the trials carry no user id)")
            )
    return [tr for tr in trials if str(tr.user_id) in spec.users]


def _select(trials: list[Trial], spec, where_trials: str, where_validate: str, source: str):
    ids = [tr.trial_id for tr in trials]
    for key, wanted, where in (
        ("validate", spec.validate, where_validate),
        ("trials", spec.trials if spec.trials != "all" else [], where_trials),
    ):
        for w in wanted:
            if w not in ids:
                raise UserError(
                    f"{where}: target.{key}: {source} has no trial {w!r}"
                    + suggest(w, ids)
                    + f"; trials: {', '.join(ids)}"
                )
    validation = [tr for tr in trials if tr.trial_id in spec.validate]
    if spec.trials == "all":
        fit = [tr for tr in trials if tr.trial_id not in spec.validate]
        if spec.kinds:
            kinds = sorted({tr.kind for tr in trials})
            for k in spec.kinds:
                if k not in kinds:
                    raise UserError(
                        f"{spec.locs['kinds']}: target.kinds: {source} has no trial "
                        f"of kind {k!r}"
                        + suggest(k, kinds)
                        + f"; kinds: {', '.join(kinds) or 'none'}"
                    )
            fit = [tr for tr in fit if tr.kind in spec.kinds]
    else:
        by_id = {tr.trial_id: tr for tr in trials}
        fit = [by_id[w] for w in spec.trials]
    if not fit:
        raise UserError(f"{where_trials}: target.trials: no trial left to fit")
    return fit, validation


def _unique_ids(trials: list[Trial], source: str) -> list[Trial]:
    seen = set()
    out = []
    for k, tr in enumerate(trials):
        tid = tr.trial_id or f"trial{k}"
        if tid in seen:
            raise UserError(f"{source}: trial id {tid!r} appears twice")
        seen.add(tid)
        out.append(tr if tr.trial_id == tid else tr.replace(trial_id=tid))
    return out


def _input_trials(spec) -> list[Trial]:
    """The input forces of a model target: a trial / force file or a rig specification."""
    if isinstance(spec.inputs, dict):
        from evo_door.data.rig import trials_from_spec

        try:
            return list(trials_from_spec(spec.inputs))
        except UserError as exc:
            raise UserError(f"{spec.locs['inputs']}: target.inputs: {exc}") from None
    from evo_door.data.io import read_trials

    try:
        return read_trials(spec.inputs)
    except UserError as exc:
        # a bare force record (t, force) is enough to drive the target model
        if str(spec.inputs).lower().endswith(".csv"):
            from evo_door.data.forcecsv import read_force_csv

            try:
                t, force = read_force_csv(spec.inputs)
            except UserError:
                raise exc from None
            # no angle: the trial starts where the target model rests (initial_state)
            return [Trial(t, force, trial_id=Path(spec.inputs).stem, source=str(spec.inputs))]
        raise


def _target_params(spec):
    """``(model, ParamSet)`` of a model target, a bad parameter set refused at its line."""
    from evo_door.models import get_model

    target_model = get_model(spec.model)
    try:
        return target_model, target_model.load_params(spec.params, spec.set)
    except UserError as exc:
        raise UserError(
            f"{spec.locs.get('params', spec.locs.get('model'))}: target.params: {exc}"
        ) from None


def _model_target_trials(spec) -> list[Trial]:
    """Trials whose response is the target model's response to the inputs' forces."""
    from evo_door.sim import simulate

    target_model, params = _target_params(spec)
    out = []
    for tr in _input_trials(spec):
        theta0, dtheta0 = tr.initial_state(default_theta0=target_model.theta0)
        theta0 = spec.theta0 if spec.theta0 is not None else theta0
        dtheta0 = spec.dtheta0 if spec.dtheta0 is not None else dtheta0
        r = simulate(
            target_model, params, tr.force, tr.dt, theta0=theta0, dtheta0=dtheta0, t0=float(tr.t[0])
        )
        if not r.ok:
            raise UserError(
                f"{spec.locs['model']}: target.model: {spec.model} blew up on "
                f"input {tr.trial_id!r}; check target.params"
            )
        out.append(
            Trial(
                tr.t,
                tr.force,
                r.theta,
                r.dtheta,
                r.ddtheta,
                trial_id=tr.trial_id,
                user_id=tr.user_id,
                kind=tr.kind,
                theta0=theta0,
                dtheta0=dtheta0,
                truth={"model": spec.model, "params": params.as_dict()},
                source=f"{spec.model} response to {tr.label}",
            )
        )
    return out


def _preprocessed(tr: Trial, pre, where: str) -> list[Trial]:
    """``tr`` after the experiment's ``target.preprocess`` steps (see PreprocessSpec):
    one trial, or its windows (``windows``)."""
    from evo_door.data import preprocess

    try:
        if pre.rate_bias != "none" and tr.dtheta is not None:
            tr = preprocess.remove_rate_bias(tr, pre.rate_bias)
        if pre.lowpass is not None:
            tr = preprocess.lowpass_trial(tr, pre.lowpass)
        if pre.trim:
            tr = preprocess.trim_to_motion(tr)
        if pre.windows is not None:
            return preprocess.split_windows(tr, pre.windows)
    except UserError as exc:
        raise UserError(f"{where}: target.preprocess: trial {tr.trial_id!r}: {exc}") from None
    return [tr]


def resolve(exp, trials: list[Trial] | None = None) -> Setup:
    """Read what ``exp`` names and build its :class:`Setup`.

    ``trials`` replaces the target's trials (library use and tests): the target's
    ``trials`` / ``validate`` selections still apply.
    """
    from evo_door.models import get_model

    model = get_model(exp.model)
    spec = exp.target
    feel = _feel(exp, model)
    all_trials: list[Trial]
    if spec.kind == "curve":
        all_trials, source = [], spec.curve
    elif spec.kind == "model" and spec.inputs is None:
        all_trials, source = [], f"target.model {spec.model}"
    elif trials is not None:
        all_trials, source = list(trials), "the trials given"
    elif spec.kind == "data":
        from evo_door.data.io import read_trials

        try:
            all_trials = read_trials(spec.data)
        except UserError as exc:
            raise UserError(f"{spec.locs['data']}: target.data: {exc}") from None
        source = spec.data
    else:
        all_trials, source = _model_target_trials(spec), "the inputs of target.model"
    all_trials = _unique_ids(all_trials, source)
    if all_trials:
        fit, validation = _select(
            all_trials, spec, spec.locs["trials"], spec.locs["validate"], source
        )
    else:  # a chosen feel alone (the perceptual objective): nothing to select
        fit, validation = [], []
    if spec.preprocess.active:
        where = spec.locs.get("preprocess", spec.locs["trials"])
        fit = [w for tr in fit for w in _preprocessed(tr, spec.preprocess, where)]
        validation = [w for tr in validation for w in _preprocessed(tr, spec.preprocess, where)]
    for tr in fit + validation:
        try:
            tr.require(exp.objective.derivative)
        except UserError as exc:
            raise MissingChannelError(exp.locs["objective"], f"{exc} in {source}") from None
        try:
            theta0, dtheta0 = tr.initial_state()
            model.plant.check_start(theta0, dtheta0, f"trial {tr.trial_id}")
        except UserError as exc:
            raise UserError(f"{spec.locs['trials']}: target: {exc}") from None
    try:
        base = model.load_params(exp.params, exp.fixed)
    except UserError as exc:
        raise UserError(f"{exp.locs['params']}: params: {exc}") from None
    free = list(exp.free)
    return Setup(
        model_name=exp.model,
        base=np.array(base.vector),
        free=free,
        lower=np.array([exp.free[n][0] for n in free]),
        upper=np.array([exp.free[n][1] for n in free]),
        fit=fit,
        validation=validation,
        objective=exp.objective,
        method=exp.method,
        substeps=exp.substeps,
        start=dict(exp.algorithm.start),
        tolerance=exp.tolerance,
        time_limit=exp.time_limit,
        feel=feel,
    )


def _feel(exp, model):
    """The chosen feel of a perceptual objective: the curve file's, or the target
    model's (its Coulomb curve and its felt dynamics); None for another objective."""
    from evo_door.perception import FeelTarget, read_curve_csv

    if not exp.objective.perceptual:
        return None
    spec = exp.target
    jnd = exp.jnd()
    closed = float(model.theta_range[1])
    if spec.kind == "curve":
        try:
            curve = read_curve_csv(spec.curve)
            return FeelTarget(curve, jnd, closed=closed)
        except UserError as exc:
            raise UserError(f"{spec.locs['curve']}: target.curve: {exc}") from None
    target_model, params = _target_params(spec)
    return FeelTarget.from_model(
        target_model, params, jnd, source=f"{spec.model} model", closed=closed
    )
