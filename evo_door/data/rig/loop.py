"""How a rig trial is simulated with the user in the loop: chunk by chunk, and at rest."""

from __future__ import annotations

import numpy as np

from evo_door.data.rig.policies import Policy
from evo_door.errors import UserError
from evo_door.sim.simulate import simulate


def run_closed_loop(
    model,
    params,
    policy: Policy,
    dt: float,
    theta0: float,
    dtheta0: float,
    t_max: float,
    chunk: int = 4,
    method=None,
    substeps=None,
    truth=None,
    state0=None,
) -> dict:
    """Simulate ``model`` under a user ``policy`` deciding the force chunk by chunk.

    Each chunk of ``chunk`` samples is one :func:`~evo_door.sim.simulate` call starting
    from the previous chunk's end state with the force sample they share, which is
    exactly what one call over the whole force would compute (the integrators are
    one-step methods). Returns ``t, force, theta, dtheta, ddtheta`` (truth, no noise).

    With a ``truth`` (:class:`~evo_door.models.door.truth.DoorTruth`) that truth is
    simulated instead, from its ``state0`` (default: at rest with the door at
    ``theta0``); the hand then acts on the truth's handle.
    """
    if truth is not None:
        if state0 is None:
            state0 = truth.state(theta0, dtheta0)
        return _run_truth_loop(truth, policy, dt, state0, t_max, chunk)
    n_max = int(round(t_max / dt)) + 1
    t = dt * np.arange(n_max)
    force = np.zeros(n_max)
    theta = np.empty(n_max)
    dtheta = np.empty(n_max)
    ddtheta = np.empty(n_max)
    theta[0], dtheta[0] = theta0, dtheta0
    k = 0
    state = None  # the model's whole state (its own states too), carried chunk to chunk
    while k < n_max - 1 and not policy.finished:
        k1 = min(k + chunk, n_max - 1)
        force[k + 1 : k1 + 1] = policy.plan(t[k + 1 : k1 + 1], t[k], theta[k], dtheta[k])
        r = _simulate_chunk(
            model, params, force[k : k1 + 1], dt, t[k], theta[k], dtheta[k], method, substeps,
            state,
        )  # fmt: skip
        state = r.final
        theta[k : k1 + 1], dtheta[k : k1 + 1], ddtheta[k : k1 + 1] = r.theta, r.dtheta, r.ddtheta
        policy.observe(t[k : k1 + 1], r.theta, r.dtheta)
        k = k1
    n = k + 1
    return {
        "t": t[:n],
        "force": force[:n],
        "theta": theta[:n],
        "dtheta": dtheta[:n],
        "ddtheta": ddtheta[:n],
    }


def _simulate_chunk(model, params, force, dt, t0, theta0, dtheta0, method, substeps, state=None):
    """One chunk of the loop from its first sample's state (``state``: the whole state
    the last chunk ended in; a one-line error if the simulation blows up, naming the
    time ``t0`` it started at)."""
    r = simulate(
        model,
        params,
        force,
        dt,
        theta0=theta0,
        dtheta0=dtheta0,
        method=method,
        substeps=substeps,
        state=state,
    )
    if not r.ok:
        raise UserError(
            f"rig: the simulation of model {model.name!r} blew up at "
            f"t = {t0:.3f} s; check the parameters or the integration settings"
        )
    return r


def _run_truth_loop(truth, policy: Policy, dt, state0, t_max, chunk) -> dict:
    """:func:`run_closed_loop` on a truth with a handle state: the hand feels the handle,
    the policy watches the door (what the inclinometer and gyroscope see)."""
    n_max = int(round(t_max / dt)) + 1
    t = dt * np.arange(n_max)
    force = np.zeros(n_max)
    out = {name: np.empty(n_max) for name in ("theta", "dtheta", "ddtheta", "theta_h", "dtheta_h")}
    state = np.array(state0, dtype=np.float64)
    out["theta"][0], out["dtheta"][0] = state[0], state[1]
    out["theta_h"][0], out["dtheta_h"][0] = state[2], state[3]
    k = 0
    while k < n_max - 1 and not policy.finished:
        k1 = min(k + chunk, n_max - 1)
        force[k + 1 : k1 + 1] = policy.plan(
            t[k + 1 : k1 + 1], t[k], out["theta_h"][k], out["dtheta_h"][k]
        )
        r, state, ok = truth.simulate(force[k : k1 + 1], dt, state)
        if not ok:
            raise UserError(
                f"rig: the simulation of the {truth.name} truth blew up at t = {t[k]:.3f} s; "
                "check its parameters"
            )
        for name, values in r.items():
            out[name][k : k1 + 1] = values
        policy.observe(t[k : k1 + 1], r["theta"], r["dtheta"])
        k = k1
    n = k + 1
    return {"t": t[:n], "force": force[:n], **{name: v[:n] for name, v in out.items()}}


def settle_truth(truth, theta0, dt, duration=0.5) -> np.ndarray:
    """The truth's state after resting with no force for ``duration`` s from ``theta0``."""
    n = int(round(duration / dt)) + 1
    _, end, ok = truth.simulate(np.zeros(n), dt, truth.state(theta0, 0.0))
    if not ok:
        raise UserError(
            f"rig: the {truth.name} truth blew up while resting at theta = {theta0:.4f} rad"
        )
    return end


def settle_model(model, params, theta0, dt, duration=0.5, method=None, substeps=None):
    """State after resting with no force for ``duration`` s from ``theta0``."""
    n = int(round(duration / dt)) + 1
    r = simulate(
        model, params, np.zeros(n), dt, theta0=theta0, dtheta0=0.0, method=method, substeps=substeps
    )
    if not r.ok:
        raise UserError(
            f"rig: model {model.name!r} blew up while resting at theta = {theta0:.4f} rad"
        )
    return float(r.theta[-1]), float(r.dtheta[-1])
