"""An FMU as a workbench model: :class:`FmuModel` and :func:`load_fmu`.

An :class:`FmuModel` is a :class:`~evo_door.models.Model` whose response is not given
by a compiled ``accel`` but by the FMU itself: it carries a ``runner``
(:class:`FmuRunner`) that :func:`evo_door.sim.simulate` and the objective kernels
(:func:`evo_door.optim.kernels.population_errors`) hand the run to. What needs the
acceleration at any state as a compiled function (the perceptual objective, the felt
inertia) refuses an FMU in one line; the force-angle curve asks the runner for the
force that holds the door (:meth:`FmuRunner.hold_force`), which a model-exchange FMU
whose states are the angle and the speed gives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit

from evo_door.errors import UserError
from evo_door.models.base import Model
from evo_door.models.fmu import kernels
from evo_door.models.fmu.description import (
    FmuInfo,
    is_fmu_spec,
    read_info,
    split_spec,
    start_value,
    state_layout,
)
from evo_door.models.fmu.instance import instance
from evo_door.models.fmu.plant import FmuPlant
from evo_door.sim.plant import Plant

#: objective kinds, as :mod:`evo_door.optim.kernels` codes them
MAX_SQUARE, ISE = 0, 1
#: what the run statuses of :mod:`~evo_door.models.fmu.kernels` mean, for messages
STATUS_TEXT = {
    kernels.FMU_ERROR: "the FMU returned an error",
    kernels.NOT_FINITE: "the response is not finite",
    kernels.TERMINATED: "the FMU asked to terminate",
}


@njit(cache=True)
def no_accel(theta, dtheta, force, p):
    """An FMU's stand-in ``accel``: never called (the runner simulates); NaN if it were."""
    return math.nan


@dataclass(frozen=True)
class FmuModel(Model):
    """A model read from an FMU (see the module docstring)."""

    info: FmuInfo | None = None

    @property
    def runner(self) -> FmuRunner:
        assert self.info is not None, "an FmuModel is made by load_fmu"
        return FmuRunner(self.info)

    @cached_property
    def plant(self) -> Plant:
        """The FMU as a :class:`~evo_door.sim.plant.Plant`: it runs itself, contained."""
        return FmuPlant(self)


class FmuRunner:
    """Runs an FMU for the simulator and the objective (this process's instance)."""

    def __init__(self, info: FmuInfo):
        self.info = info

    def prepare(self) -> None:
        """Load the FMU in this process and the compiled kernels, running no trial: an
        empty run at the declared defaults (what a sandbox's child does before it says
        it is ready, so that its time limit counts candidates, not compilation)."""
        inst = instance(self.info)
        inst.run(self.info.declaration.defaults, np.zeros(0), 1.0, 0.0, 0.0)

    def simulate(self, p, force, dt, theta0=None, dtheta0=None, t0=0.0, substeps=4):
        """``(theta, dtheta, ddtheta, ok)``, each (n,) in SI: one run of the FMU.

        ``theta0`` / ``dtheta0`` None (not given) leave the state at the FMU's own start
        values, after the parameters are set and the FMU initialised."""
        self.check_start(theta0, dtheta0)
        inst = instance(self.info)
        out, status = inst.run(p, force, dt, theta0, dtheta0, t0, substeps)
        theta, dtheta, ddtheta = channels_of(out, inst.outputs, dt)
        return theta, dtheta, ddtheta, status == kernels.OK

    def check_hold(self, what: str = "the force that holds the door") -> None:
        """Refuse, in one line, ``what`` (which sets the state to any angle and speed)
        for an FMU that cannot be put there: co-simulation, or states other than the
        angle and the speed (:func:`~evo_door.models.fmu.description.state_layout`)."""
        state_layout(self.info, what)

    def hold_force(self, p, theta, dtheta) -> np.ndarray:
        """The force (N, + toward closing) that holds ``ddtheta = 0`` at each angle
        ``theta`` (rad) and speed ``dtheta`` (rad/s, one value or one per angle): the
        model-exchange FMU's derivatives at the forces 0 and 1, with its states set to
        (theta, dtheta) after it is initialised at ``p`` (its discrete states, a latch's
        say, stay as the initialisation left them). Refused in one line where that
        cannot be done (:meth:`check_hold`)."""
        layout = state_layout(self.info, "the force-angle curve")
        theta = np.atleast_1d(np.asarray(theta, dtype=np.float64))
        dtheta = np.broadcast_to(np.asarray(dtheta, dtype=np.float64), theta.shape)
        return instance(self.info).hold_forces(
            np.asarray(p, dtype=np.float64), theta, dtheta, layout
        )

    def check_start(
        self, theta0: float | None, dtheta0: float | None, where: str = "", p=None
    ) -> None:
        """Refuse an initial state the FMU cannot be given: no variable takes it (the
        ``theta0`` / ``dtheta0`` channels) and the FMU starts elsewhere by itself (at
        the parameters ``p``, default the declared ones). None is the FMU's own start."""
        ch = self.info.channels
        self.info.check_channels()
        free_theta = theta0 is None or "theta0" in ch or "theta" not in ch
        if free_theta and (dtheta0 is None or "dtheta0" in ch or "dtheta" not in ch):
            return
        p = self.info.declaration.defaults if p is None else p
        inst = instance(self.info)
        out, status = inst.run(p, np.zeros(1), 1e-3, theta0, dtheta0)
        for j, key in enumerate(inst.outputs):
            value = theta0 if key == "theta" else dtheta0 if key == "dtheta" else None
            if value is None or f"{key}0" in ch or status != kernels.OK:
                continue
            own = float(out[0, j])
            if abs(own - value) > 1e-9 * max(1.0, abs(value)):
                raise UserError(
                    f"{where + ': ' if where else ''}the run starts at {key} = {value:.6g} "
                    f"(SI), but FMU {self.info.path.name} starts at {own:.6g} by itself and "
                    f"{ch[key].name!r} cannot be set before initialisation; map the "
                    f"variable that sets it: channels: {{{key}0: VARIABLE}}"
                )

    def population_errors(
        self, P, force, target, mask, offsets, dt, theta0, dtheta0, substeps, derivative,
        kind, err_out, ok_out,
    ):  # fmt: skip
        """As :func:`evo_door.optim.kernels.population_errors`, one run per candidate
        and trial on this process's instance (an FMU instance is not shared between
        threads)."""
        inst = instance(self.info)
        for i in range(P.shape[0]):
            for j in range(offsets.size - 1):
                a, b = offsets[j], offsets[j + 1]
                out, status = inst.run(
                    P[i], force[a:b], dt[j], theta0[j], dtheta0[j], 0.0, substeps
                )
                y = channels_of(out, inst.outputs, dt[j])[derivative]
                if status != kernels.OK:
                    err_out[i, j], ok_out[i, j] = math.inf, False
                    continue
                e = error_of(y, target[a:b], mask[a:b], dt[j], kind)
                err_out[i, j], ok_out[i, j] = e, math.isfinite(e)
                if not ok_out[i, j]:
                    err_out[i, j] = math.inf


def channels_of(out, outputs, dt) -> tuple:
    """``(theta, dtheta, ddtheta)`` from the FMU's output columns; a derivative the FMU
    does not give is the central difference of the one below it."""
    got = {k: out[:, j] for j, k in enumerate(outputs)}
    theta = got["theta"]
    dtheta = got.get("dtheta")
    if dtheta is None:
        dtheta = np.gradient(theta, dt) if theta.size > 1 else np.zeros_like(theta)
    ddtheta = got.get("ddtheta")
    if ddtheta is None:
        ddtheta = np.gradient(dtheta, dt) if dtheta.size > 1 else np.zeros_like(dtheta)
    return theta, dtheta, ddtheta


def error_of(y, target, mask, dt, kind) -> float:
    """The objective of one trial (max square or trapezoid ISE over unmasked samples,
    the trial's ends weighted 1/2), as :func:`evo_door.optim.kernels.trial_error`."""
    e2 = (y - target) ** 2
    if kind == MAX_SQUARE:
        return float(e2[mask].max()) if mask.any() else 0.0
    w = np.full(y.size, dt)
    w[0] = w[-1] = 0.5 * dt
    return float(np.sum(w[mask] * e2[mask]))


def load_fmu(spec: str, mapping=None) -> FmuModel:
    """The model of the FMU ``spec`` names (``path.fmu``, ``path.fmu:me|cs``, with a
    channel mapping: :func:`~evo_door.models.fmu.description.split_spec`); ``mapping``
    adds to the one the name gives."""
    path, interface, named = split_spec(spec)
    named.update(mapping or {})
    info = read_info(path.resolve() if path.exists() else path, interface, named)
    kinds = "model exchange" if info.interface == "me" else "co-simulation"
    md = info.description
    ch = info.channels
    if ch:
        mapped = ", ".join(
            f"{k} <- {c.name}" + (f" [{c.unit}]" if c.unit else "") for k, c in ch.items()
        )
        channels = f"channels: {mapped}"
    else:
        channels = f"channels not matched: {info.channel_problem}"
    # the FMU's own start angle (what a run that gives none starts at), for display
    start = None
    for key in ("theta0", "theta"):
        if start is None and key in ch:
            start = start_value(md, ch[key])
    notes = (
        f"FMU {info.path.name}: FMI {md.fmiVersion}, {kinds}, generated by "
        f"{md.generationTool or 'an unnamed tool'}.\n{channels}\nLoading an FMU runs "
        "its code: load only FMUs you trust."
    )
    return FmuModel(
        name=info.name,
        title=" ".join((md.description or md.modelName or info.path.stem).split()),
        params=info.declaration,
        accel=no_accel,
        method="rk4",
        substeps=4,
        notes=notes,
        theta_unit="rad",
        theta0=0.0 if start is None or not math.isfinite(start) else start,
        info=info,
    )


__all__ = ["FmuModel", "FmuRunner", "is_fmu_spec", "load_fmu"]
