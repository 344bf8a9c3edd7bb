"""The integration error of a run's answer, estimated a posteriori.

A fit's error holds two things: what the model cannot reproduce, and what the
integrator gets wrong. Only the first says anything about the door, so every run
states the second beside it. Once the answer is known, every fitted and validation
trial is simulated with the parameters its response is shown with (a trial's own fit
in a ``per_trial`` run, else the run's answer), once at the run's settings and once at
:func:`evo_door.sim.simulate.refined`'s: the same method at half the step, and for
``dopri5`` a 32 times tighter tolerance. For a method of order q the refined answer's
error is about 2^-q of the run's, so the difference of the two is the run's own
integration error to within that share (rk4 on a smooth stretch: 1/16). Where a trial
crosses a kink or a jump of the model (a latch, a stick), the order drops and the
difference may be as little as half the error (order 1): an estimate, not a bound.

Recorded per trial (:class:`IntegrationError`, the results file's ``integration_error``
group): the largest difference of the angle (rad), of the speed (rad/s) and of the
channel the objective compares (its unit, and its RMS over the samples the objective
counts), the trial's objective at both settings, and the RMS fit residual of that
channel (model minus target, at the run's settings). Over all trials: the largest
differences, and the run's objective (the fitted trials' errors combined as the
fitness combines them) at both settings.

**When it is not small** (:meth:`IntegrationError.warning`): the integration error is
flagged when any of these holds:

- the objective changes by more than :data:`OBJECTIVE_CHANGE` (1 %) between the two
  settings: the fitness the GA ranked candidates by is partly the integrator's;
- on some trial the fitted channel moves by more than :data:`RESIDUAL_SHARE` (a tenth)
  of that trial's RMS fit residual, RMS against RMS over the same samples: the
  residual is partly the integrator's (the largest difference is recorded too, but a
  latch crossed a hair earlier makes a short spike that says little of the fit);
- a simulation did not finish (blew up) at either setting.

A fit to data the same integrator made (a noise-free virtual target, fitted exactly)
can have a residual below its own integration error; it is then flagged, and rightly:
its fit error says nothing beyond the integrator's accuracy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from evo_door.channels import RESPONSE_CHANNELS
from evo_door.channels import unit as channel_unit
from evo_door.files import ATTRS, Dataset
from evo_door.sim_settings import tolerance_of

#: Relative change of the objective between the run's and the refined settings above
#: which the integration error is not small against the fit error.
OBJECTIVE_CHANGE = 0.01
#: Share of a trial's RMS fit residual that the fitted channel may move by (RMS).
RESIDUAL_SHARE = 0.1

#: Per-trial arrays of the group, in the order they are written.
_PER_TRIAL = (
    "theta_max",
    "dtheta_max",
    "channel_max",
    "channel_rms",
    "residual_rms",
    "error",
    "error_refined",
)


@dataclass(frozen=True)
class IntegrationError:
    """The a-posteriori integration error of a run's answer (see the module docstring).

    Per trial (arrays in the order of ``trial_ids``): ``theta_max`` (largest
    |delta theta|, the model's coordinate unit), ``dtheta_max`` (its speed unit),
    ``channel_max`` and ``channel_rms`` (the largest and the RMS difference of the
    objective's ``channel``), ``residual_rms`` (RMS of model minus target on that
    channel at the run's settings), ``error`` and ``error_refined`` (the
    trial's objective, ``fitness_unit``), ``ok`` (both simulations finished).
    ``objective`` and ``objective_refined`` are the fitted trials' errors combined as
    the run's fitness combines them.
    """

    method: str
    substeps: int
    tolerance: float
    refined_method: str
    refined_substeps: int
    refined_tolerance: float
    channel: str
    theta_unit: str
    fitness_unit: str
    trial_ids: list[str]
    roles: list[str]
    theta_max: np.ndarray
    dtheta_max: np.ndarray
    channel_max: np.ndarray
    channel_rms: np.ndarray
    residual_rms: np.ndarray
    error: np.ndarray
    error_refined: np.ndarray
    ok: np.ndarray
    objective: float
    objective_refined: float

    # -- what it says ----------------------------------------------------------------
    @property
    def units(self) -> dict[str, str]:
        """Each recorded quantity's unit."""
        ch = channel_unit(self.channel, self.theta_unit)
        return {
            "theta_max": self.theta_unit,
            "dtheta_max": channel_unit("dtheta", self.theta_unit),
            "channel_max": ch,
            "channel_rms": ch,
            "residual_rms": ch,
            "error": self.fitness_unit,
            "error_refined": self.fitness_unit,
            "objective": self.fitness_unit,
            "objective_refined": self.fitness_unit,
            "objective_change": "1",
        }

    @property
    def objective_change(self) -> float:
        """``(refined - run) / run`` of the objective (NaN where either is not finite)."""
        return relative_change(self.objective, self.objective_refined)

    def largest(self, name: str) -> float:
        """The largest of the per-trial ``name`` (``theta_max``...), inf if any blew up."""
        values = np.asarray(getattr(self, name), dtype=float)
        if not values.size:
            return 0.0
        return math.inf if not np.all(np.isfinite(values)) else float(values.max())

    def warning(self) -> str | None:
        """Why the integration error is not small against the fit error, or None
        (the rule: the module docstring)."""
        reasons = []
        blown = [t for t, ok in zip(self.trial_ids, self.ok) if not ok]
        if blown:
            reasons.append(
                f"a simulation blew up on trial {', '.join(blown)} (at the run's settings "
                "or the refined ones)"
            )
        change = self.objective_change
        if not blown and (math.isinf(change) or abs(change) > OBJECTIVE_CHANGE):
            reasons.append(
                f"the objective changes by {100 * change:+.3g} % at the refined settings "
                f"(more than {100 * OBJECTIVE_CHANGE:g} %)"
            )
        ratio = [
            _share(d, r) if ok else 0.0
            for d, r, ok in zip(self.channel_rms, self.residual_rms, self.ok)
        ]
        over = [k for k, q in enumerate(ratio) if q > RESIDUAL_SHARE]
        if over:
            k = max(over, key=lambda i: ratio[i])
            u = self.units["channel_rms"]
            reasons.append(
                f"{self.channel} moves by {self.channel_rms[k]:.3g} {u} RMS on trial "
                f"{self.trial_ids[k]}, {100 * ratio[k]:.3g} % of its RMS fit error "
                f"{self.residual_rms[k]:.3g} {u} (more than {100 * RESIDUAL_SHARE:g} %)"
                + (f", and on {len(over) - 1} other trial(s)" if len(over) > 1 else "")
            )
        if not reasons:
            return None
        return (
            "the integration error is not small against the fit error: "
            + "; ".join(reasons)
            + f"; refine the simulation ({self.advice()}) and run again"
        )

    def advice(self) -> str:
        """The experiment keys of the refined settings, as a person types them."""
        text = f"simulation.substeps: {self.refined_substeps}"
        if self.method == "dopri5":
            text += f", simulation.tolerance: {self.refined_tolerance:.3g}"
        return text

    def as_dict(self) -> dict:
        """JSON-able (non-finite numbers as None), with the warning's text or None."""
        trials = {}
        for k, tid in enumerate(self.trial_ids):
            row = {"role": self.roles[k], "ok": bool(self.ok[k])}
            row.update({name: _finite(getattr(self, name)[k]) for name in _PER_TRIAL})
            row["error_change"] = _finite(relative_change(self.error[k], self.error_refined[k]))
            trials[tid] = row
        return {
            "method": self.method,
            "substeps": self.substeps,
            "tolerance": self.tolerance,
            "refined": {
                "method": self.refined_method,
                "substeps": self.refined_substeps,
                "tolerance": self.refined_tolerance,
            },
            "channel": self.channel,
            "units": self.units,
            "theta_max": _finite(self.largest("theta_max")),
            "dtheta_max": _finite(self.largest("dtheta_max")),
            "channel_max": _finite(self.largest("channel_max")),
            "objective": _finite(self.objective),
            "objective_refined": _finite(self.objective_refined),
            "objective_change": _finite(self.objective_change),
            "trials": trials,
            "warning": self.warning(),
        }

    # -- the results file ------------------------------------------------------------
    def to_tree(self) -> dict:
        """The ``integration_error`` group: the overall values and settings as
        attributes, one dataset per per-trial quantity (each with its ``unit``)."""
        units = self.units
        node: dict = {
            ATTRS: {
                "method": self.method,
                "substeps": int(self.substeps),
                "tolerance": float(self.tolerance),
                "refined_method": self.refined_method,
                "refined_substeps": int(self.refined_substeps),
                "refined_tolerance": float(self.refined_tolerance),
                "channel": self.channel,
                "trial_ids": list(self.trial_ids),
                "roles": list(self.roles),
                "theta_max": self.largest("theta_max"),
                "dtheta_max": self.largest("dtheta_max"),
                "channel_max": self.largest("channel_max"),
                "objective": float(self.objective),
                "objective_refined": float(self.objective_refined),
                "objective_change": float(self.objective_change),
                "units": units,
            }
        }
        for name in _PER_TRIAL:
            data = np.asarray(getattr(self, name), dtype=np.float64)
            node[name] = Dataset(data, {"unit": units[name]})
        node["ok"] = np.asarray(self.ok, dtype=np.bool_)
        return node

    @classmethod
    def from_tree(cls, node) -> IntegrationError:
        """Read the group back (a tree, or a group read on demand), each value checked
        (:mod:`evo_door.files.fields`: a results file is data)."""
        from evo_door.channels import RESPONSE_CHANNELS
        from evo_door.files import fields

        a = node[ATTRS]
        units = fields.mapping(a, "units", None, fields.as_text)
        fields.text(a, "channel", choices=RESPONSE_CHANNELS)
        per = {name: ("t",) for name in (*_PER_TRIAL, "trial_ids", "roles")}
        return fields.stored(
            cls,
            node,
            a,
            shapes=per,
            sizes={"t": "trial_ids"},
            theta_unit=fields.text(units, "theta_max"),
            fitness_unit=fields.text(units, "objective"),
            ok=fields.array(node, "ok", kind="b", shape=(len(fields.texts(a, "trial_ids")),)),
        )


def relative_change(before: float, after: float) -> float:
    """``(after - before) / before``: 0 when both are 0, inf from 0, NaN if not finite.

    >>> relative_change(2.0, 2.5), relative_change(0.0, 0.0), relative_change(0.0, 1e-9)
    (0.25, 0.0, inf)
    """
    before, after = float(before), float(after)
    if not (math.isfinite(before) and math.isfinite(after)):
        return math.nan
    if before == 0.0:
        return 0.0 if after == 0.0 else math.inf
    return (after - before) / abs(before)


def _share(change: float, residual: float) -> float:
    """``change / residual`` (inf for a residual of 0; 0 where no sample counted)."""
    if not math.isfinite(residual):
        return 0.0
    return change / residual if residual > 0 else (math.inf if change > 0 else 0.0)


def _finite(v):
    v = float(v)
    return v if math.isfinite(v) else None


# -- the estimate ----------------------------------------------------------------------
def estimate(setup, fit_x, validation_x) -> IntegrationError:
    """The integration error of a run's answer.

    ``setup`` is the run's :class:`~evo_door.experiment.setup.Setup`; ``fit_x`` holds
    the free parameters each fitted trial's response is shown with (one row per trial,
    in ``setup.fit``'s order: the same row on every trial for a run of one fit), and
    ``validation_x`` those of the validation trials (the run's answer).
    """
    fit_x = np.atleast_2d(np.asarray(fit_x, dtype=np.float64))
    refined = setup.refined()
    rows = []
    if all(np.array_equal(x, fit_x[0]) for x in fit_x):  # one fit of every trial
        rows += _rows(setup.problem(), refined.problem(), fit_x[0], "fit")
    else:  # each trial its own fit
        for i, x in enumerate(fit_x):
            rows += _rows(setup.problem([i]), refined.problem([i]), x, "fit")
    if setup.validation:
        rows += _rows(setup.problem(), refined.problem(), validation_x, "validate")
    fitted = [r for r in rows if r["role"] == "fit"]
    combine = setup.objective.combine_errors

    def objective(key: str) -> float:
        errors = np.array([[r[key] for r in fitted]])
        return float(combine(errors, np.isfinite(errors))[0])

    model = setup.model
    column = {name: np.array([r[name] for r in rows], dtype=float) for name in _PER_TRIAL}
    return IntegrationError(
        method=setup.method,
        substeps=int(setup.substeps),
        tolerance=tolerance_of(model, setup.tolerance),
        refined_method=refined.method,
        refined_substeps=int(refined.substeps),
        refined_tolerance=float(refined.tolerance),
        channel=setup.objective.channel,
        theta_unit=model.theta_unit,
        fitness_unit=setup.objective.trial_objective.unit_for(model.theta_unit),
        trial_ids=[r["trial_id"] for r in rows],
        roles=[r["role"] for r in rows],
        ok=np.array([r["ok"] for r in rows], dtype=bool),
        objective=objective("error"),
        objective_refined=objective("error_refined"),
        **column,
    )


def _rows(problem, refined, x, role: str) -> list[dict]:
    """One row per trial of ``problem``'s fitted (``role`` fit) or validation trials,
    simulated with the free parameters ``x`` at both settings."""
    pack = problem.fit if role == "fit" else problem.validation
    pack_refined = refined.fit if role == "fit" else refined.validation
    error, ok = problem.trial_errors(x, pack)
    error_refined, ok_refined = refined.trial_errors(x, pack_refined)
    runs = problem.responses(x, pack)
    refs = refined.responses(x, pack_refined)
    d = problem.objective.derivative
    channel = RESPONSE_CHANNELS[d]
    rows = []
    for k, tr in enumerate(pack.trials):
        run, ref = runs[k], refs[k]
        model_channel = (run.theta, run.dtheta, run.ddtheta)[d]
        residual = model_channel - tr.channel(d)
        change = model_channel - (ref.theta, ref.dtheta, ref.ddtheta)[d]
        mask = tr.unsaturated(channel) & np.isfinite(residual)
        rows.append(
            {
                "trial_id": tr.trial_id,
                "role": role,
                "theta_max": _largest(run.theta - ref.theta),
                "dtheta_max": _largest(run.dtheta - ref.dtheta),
                "channel_max": _largest(change),
                "channel_rms": _rms(change, mask),
                "residual_rms": _rms(residual, mask),
                "error": float(error[0, k]) if ok[0, k] else math.inf,
                "error_refined": float(error_refined[0, k]) if ok_refined[0, k] else math.inf,
                "ok": bool(run.ok and ref.ok and ok[0, k] and ok_refined[0, k]),
            }
        )
    return rows


#: Past this magnitude (or under its inverse) a value's square overflows (or vanishes):
#: the RMS is then taken of the values scaled by the largest.
SQUARE_SAFE = 1e150


def _rms(values: np.ndarray, mask: np.ndarray) -> float:
    """RMS of ``values`` over the samples the objective counts (``mask``): inf where a
    simulation did not finish, NaN where no sample counts. Values whose squares would
    overflow (a damaged file's numbers) are scaled first: a number, never a warning."""
    if not mask.any():
        return math.nan
    picked = values[mask]
    if not np.all(np.isfinite(picked)):
        return math.inf
    largest = float(np.max(np.abs(picked)))
    if largest == 0.0 or 1.0 / SQUARE_SAFE < largest < SQUARE_SAFE:
        return float(np.sqrt(np.mean(picked**2)))
    return largest * float(np.sqrt(np.mean((picked / largest) ** 2)))


def _largest(diff: np.ndarray) -> float:
    """The largest |difference| (inf where a simulation did not finish: NaN samples)."""
    diff = np.asarray(diff, dtype=float)
    if not diff.size:
        return 0.0
    if not np.all(np.isfinite(diff)):
        return math.inf
    return float(np.max(np.abs(diff)))
