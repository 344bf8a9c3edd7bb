"""Python entry points around the compiled integrators.

``simulate`` runs one model on one sampled force; ``simulate_batch`` runs a whole
population of parameter vectors in one compiled, multi-threaded call;
``quasi_static_curve`` gives the force-angle characteristic (the force a user must
apply to move the door very slowly), which engineers compare with a measured force
trace.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evo_door.channels import CHANNELS
from evo_door.errors import UserError
from evo_door.params.sets import param_vector
from evo_door.sim.integrators import METHODS, integrate, integrate_batch


@dataclass
class Response:
    """A simulated trial: all arrays share the time axis ``t`` (s)."""

    t: np.ndarray  # s
    force: np.ndarray  # N, user force at the handle, + toward closing
    theta: np.ndarray  # rad, 0 open, pi/2 closed
    dtheta: np.ndarray  # rad/s
    ddtheta: np.ndarray  # rad/s^2
    ok: bool = True  # False when the simulation blew up (NaN tail)

    COLUMNS = tuple(CHANNELS)

    def table(self) -> np.ndarray:
        return np.column_stack([getattr(self, c) for c in self.COLUMNS])

    def to_csv(self, path) -> None:
        """Write ``t, force, theta, dtheta, ddtheta`` (SI) with a header line."""
        from evo_door.files import atomic_write

        with atomic_write(path) as tmp:
            np.savetxt(
                tmp,
                self.table(),
                delimiter=",",
                header=",".join(self.COLUMNS),
                comments="",
                fmt="%.10g",
            )


def _method_code(method: str) -> int:
    try:
        return METHODS[method]
    except KeyError:
        raise UserError(
            f"unknown integration method {method!r}; choose from {', '.join(METHODS)}"
        ) from None


def check_force(force, dt) -> np.ndarray:
    force = np.ascontiguousarray(force, dtype=np.float64)
    if force.ndim != 1 or force.size < 2:
        raise UserError("the input force needs at least two samples")
    if not np.all(np.isfinite(force)):
        raise UserError(
            f"the input force has a non-finite sample at index "
            f"{int(np.flatnonzero(~np.isfinite(force))[0])}"
        )
    if not (np.isfinite(dt) and dt > 0):
        raise UserError(f"sample period must be positive, got {dt!r} s")
    return force


def simulate(
    model, params, force, dt, theta0=None, dtheta0=0.0, t0=0.0, method=None, substeps=None
) -> Response:
    """Simulate ``model`` with a :class:`~evo_door.params.ParamSet` (or vector).

    Parameters
    ----------
    model : Model
    params : ParamSet or array_like
        Values in declaration order.
    force : array_like
        User force (N) sampled every ``dt`` seconds.
    theta0, dtheta0 : float
        Initial angle (rad; default the model's) and angular speed (rad/s).
    method, substeps :
        Override the model's integration defaults.

    Examples
    --------
    The physical door, fully open, given a 20 N push toward closing for 0.1 s, then let
    go: it swings up and the pad friction brakes it to a near stop at about 62 deg.

    >>> from evo_door.models import get_model
    >>> door = get_model("door")
    >>> dt = 1 / 1024                                   # s, the rig's sampling
    >>> force = np.where(np.arange(2048) * dt < 0.1, 20.0, 0.0)   # N, + toward closing
    >>> r = simulate(door, door.load_params("default"), force, dt, theta0=0.0)
    >>> r.ok, f"{np.degrees(r.theta[-1]):.0f} deg", f"{r.dtheta[-1]:.3f} rad/s"
    (True, '62 deg', '0.009 rad/s')
    """
    force = check_force(force, dt)
    p = param_vector(params, model.params)
    theta0 = model.theta0 if theta0 is None else float(theta0)
    n = force.size
    out = np.empty((3, n))
    ok = integrate(
        model.accel,
        p,
        force,
        float(dt),
        int(substeps or model.substeps),
        theta0,
        float(dtheta0),
        _method_code(method or model.method),
        out[0],
        out[1],
        out[2],
    )
    t = t0 + dt * np.arange(n)
    return Response(t, force, out[0], out[1], out[2], bool(ok))


def simulate_batch(model, P, force, dt, theta0=None, dtheta0=0.0, method=None, substeps=None):
    """Simulate one input for every row of ``P`` in one compiled parallel call.

    Returns ``(theta, dtheta, ddtheta, ok)``: three ``(len(P), len(force))`` arrays
    and a boolean array that is False where a simulation blew up.
    """
    force = check_force(force, dt)
    P = np.ascontiguousarray(P, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != len(model.params):
        raise UserError(f"model {model.name!r}: parameter matrix must be (n, {len(model.params)})")
    theta0 = model.theta0 if theta0 is None else float(theta0)
    n_ind, n = P.shape[0], force.size
    theta, dtheta, ddtheta = (np.empty((n_ind, n)) for _ in range(3))
    ok = np.zeros(n_ind, dtype=np.bool_)
    integrate_batch(
        model.accel,
        P,
        force,
        float(dt),
        int(substeps or model.substeps),
        theta0,
        float(dtheta0),
        _method_code(method or model.method),
        theta,
        dtheta,
        ddtheta,
        ok,
    )
    return theta, dtheta, ddtheta, ok


def quasi_static_force(model, params, theta, dtheta) -> np.ndarray:
    """User force (N, + toward closing) that holds ``ddtheta = 0`` at each (theta, dtheta).

    Uses that ``accel`` is affine in the force: F = -a(F=0) / (a(F=1) - a(F=0)).
    """
    p = param_vector(params, model.params)
    theta = np.atleast_1d(np.asarray(theta, dtype=np.float64))
    dtheta = np.broadcast_to(np.asarray(dtheta, dtype=np.float64), theta.shape)
    out = np.empty(theta.shape)
    for i, (th, w) in enumerate(zip(theta, dtheta)):
        a0 = model.accel(th, w, 0.0, p)
        a1 = model.accel(th, w, 1.0, p)
        out[i] = -a0 / (a1 - a0)
    return out


def quasi_static_curve(model, params, n=721, speed=0.02, lo=0.0, hi=np.pi / 2):
    """Force-angle characteristic for slow opening and closing.

    Returns a dict with ``theta`` (rad, the grid) and ``opening`` / ``closing``: the
    user force (N, + toward closing) needed to move at constant ``speed`` (rad/s)
    toward open (dtheta = -speed) and toward closed (dtheta = +speed).
    """
    theta = np.linspace(lo, hi, n)
    return {
        "theta": theta,
        "opening": quasi_static_force(model, params, theta, -abs(speed)),
        "closing": quasi_static_force(model, params, theta, +abs(speed)),
    }
