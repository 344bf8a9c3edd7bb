"""Python entry points around the compiled integrators.

``simulate`` runs one model on one sampled force; ``simulate_batch`` runs a whole
population of parameter vectors in one compiled, multi-threaded call;
``force_angle_curve`` gives the force-angle characteristic a specification reader
expects (the force a user must apply to move the door very slowly, dry friction at its
full Coulomb level, latch peaks resolved), which engineers compare with a measured
force trace; ``quasi_static_curve`` is the plain uniform-grid curve at a finite speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import ArrayLike

from evo_door.channels import CHANNELS
from evo_door.errors import UserError
from evo_door.params import ParamTable
from evo_door.params.sets import ParamSet, param_vector
from evo_door.sim.located import no_switches
from evo_door.sim_settings import METHODS

if TYPE_CHECKING:
    from evo_door.sim.plant import Plant


class Modelled(Protocol):
    """What the entry points below take as a model: anything with a
    :class:`~evo_door.sim.plant.Plant` (every :class:`~evo_door.models.Model`)."""

    @property
    def plant(self) -> Plant: ...

    @property
    def params(self) -> ParamTable: ...

    @property
    def name(self) -> str: ...

    @property
    def theta_range(self) -> tuple[float, float]: ...

    @property
    def theta_unit(self) -> str: ...


@dataclass
class Response:
    """A simulated trial: all arrays share the time axis ``t`` (s)."""

    t: np.ndarray  # s
    force: np.ndarray  # N, user force at the handle, + toward closing
    theta: np.ndarray  # rad, 0 open, pi/2 closed
    dtheta: np.ndarray  # rad/s
    ddtheta: np.ndarray  # rad/s^2
    ok: bool = True  # False when the simulation blew up (NaN tail)
    #: the model's other states by name (a model on a state vector), each like ``theta``
    states: dict[str, np.ndarray] = field(default_factory=dict)
    #: the whole state at the last sample (the plant's order): where a next call, given
    #: it as ``state``, goes on from
    final: np.ndarray | None = None

    COLUMNS = tuple(CHANNELS)

    def table(self) -> np.ndarray:
        """The columns ``COLUMNS`` then the other states', one row per sample."""
        cols = [getattr(self, c) for c in self.COLUMNS] + list(self.states.values())
        return np.column_stack(cols)

    def to_csv(self, path) -> None:
        """Write ``t, force, theta, dtheta, ddtheta`` (SI), then the other states of a
        model on a state vector, with a header line."""
        from evo_door.files import atomic_write

        with atomic_write(path) as tmp:
            np.savetxt(
                tmp,
                self.table(),
                delimiter=",",
                header=",".join((*self.COLUMNS, *self.states)),
                comments="",
                fmt="%.10g",
            )


def method_code(method: str) -> int:
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


def check_state(state, n_states: int, name: str) -> np.ndarray:
    """The whole initial state ``state`` as a float vector of ``n_states``, or one line."""
    x = np.array(state, dtype=np.float64).reshape(-1)
    if x.size != n_states or not np.all(np.isfinite(x)):
        raise UserError(
            f"model {name!r}: an initial state is {n_states} finite numbers, got {state!r}"
        )
    return x


def events_of(model, form=None) -> tuple:
    """``(switches, n_switches, stick_slip)`` of a model, as the kernels take them; with
    ``form`` (the :class:`~evo_door.sim.integrators.Prepared` form of the vectors the
    kernels are handed), that form's switching functions where it has its own."""
    switches = getattr(model, "switches", None)
    if switches is None:
        return no_switches, 0, bool(getattr(model, "stick_slip", False))
    if form is not None:
        switches = form.switches_or(switches)
    return switches, int(model.n_switches), bool(model.stick_slip)


def simulate(
    model: Modelled,
    params: ParamSet | ArrayLike,
    force: ArrayLike,
    dt: float,
    theta0: float | None = None,
    dtheta0: float | None = None,
    t0: float = 0.0,
    method: str | None = None,
    substeps: int | None = None,
    tolerance: float | None = None,
    state: ArrayLike | None = None,
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
        Initial angle (rad) and angular speed (rad/s); None (not given): the plant's
        own (the model's ``theta0`` at rest; an FMU's start values).
    state : array_like, optional
        The whole initial state instead (a previous response's ``final``), for a model
        on a state vector the states of its own too.
    method, substeps, tolerance :
        Override the model's integration defaults (``tolerance``: ``dopri5`` only).

    A model with a fast form (:func:`~evo_door.sim.integrators.register_prepared`, the
    door's pose table) runs it: the parameter set is prepared once, then integrated.

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
    return model.plant.simulate(
        params, force, dt, theta0, dtheta0, t0, method=method, substeps=substeps,
        tolerance=tolerance, state=state,
    )  # fmt: skip


def simulate_batch(
    model: Modelled,
    P: ArrayLike,
    force: ArrayLike,
    dt: float,
    theta0: float | None = None,
    dtheta0: float | None = None,
    method: str | None = None,
    substeps: int | None = None,
    tolerance: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Simulate one input for every row of ``P`` in one compiled parallel call.

    Returns ``(theta, dtheta, ddtheta, ok)``: three ``(len(P), len(force))`` arrays
    and a boolean array that is False where a simulation blew up. A model with a fast
    form (see :func:`simulate`) is prepared row by row inside the compiled loop.
    """
    return model.plant.simulate_batch(
        P, force, dt, theta0, dtheta0, method=method, substeps=substeps, tolerance=tolerance
    )


def quasi_static_force(
    model: Modelled, params: ParamSet | ArrayLike, theta: ArrayLike, dtheta: ArrayLike
) -> np.ndarray:
    """User force (N, + toward closing) that holds ``ddtheta = 0`` at each (theta, dtheta).

    The plant's static equilibrium at the handle (:meth:`~evo_door.sim.plant.Plant.hold_forces`).
    """
    p = param_vector(params, model.params)
    theta = np.atleast_1d(np.asarray(theta, dtype=np.float64))
    dtheta = np.broadcast_to(np.asarray(dtheta, dtype=np.float64), theta.shape)
    out = np.empty(theta.shape)
    for w in np.unique(dtheta):
        at = dtheta == w
        out[at] = hold_forces(model, p, theta[at], float(w))
    return out


def quasi_static_curve(model, params, n=721, speed=0.02, lo=0.0, hi=np.pi / 2):
    """Force-angle characteristic at a finite speed, on a plain uniform grid.

    Returns a dict with ``theta`` (rad, the grid) and ``opening`` / ``closing``: the
    user force (N, + toward closing) needed to move at constant ``speed`` (rad/s)
    toward open (dtheta = -speed) and toward closed (dtheta = +speed).

    The grid may step over a latch band narrower than its spacing, and at a finite
    speed the tanh friction laws give less than their Coulomb level: for the curve a
    specification reader expects use :func:`force_angle_curve`.
    """
    theta = np.linspace(lo, hi, n)
    return {
        "theta": theta,
        "opening": quasi_static_force(model, params, theta, -abs(speed)),
        "closing": quasi_static_force(model, params, theta, +abs(speed)),
    }


# -- the force-angle curve a specification reader expects ----------------------------
#: Speed (theta unit / s) of the Coulomb curve's evaluation: a term affine in the
#: speed (viscous, latch damping up to 1e5 N s/rad) adds at most 1e-10 N there.
#: the least per-step tolerance dopri5 is asked for: a few hundred times the double
#: precision's epsilon (2.2e-16) on values of order one; below it no step meets it and
#: the step size shrinks without end
TOLERANCE_FLOOR = 1e-13
COULOMB_SPEED = 1e-15
#: Value every speed sensitivity takes for the Coulomb curve: sensitivity x speed
#: = 1e12, so a tanh law or speed gate is exactly +-1 (or 0 / 1) in double precision
#: wherever its slip speed per unit of theta speed exceeds 2e-11 (m/rad, or 1).
COULOMB_SENSITIVITY = 1e12 / COULOMB_SPEED
#: Units of a speed sensitivity (a tanh slope or a speed gate), besides s/<theta unit>.
SENSITIVITY_UNITS = ("s/m", "s/rad")
#: Points of the dense scan that finds where the curve changes fast.
SCAN_POINTS = 2**18
#: Tolerance of the written curve, as a fraction of the force range.
CURVE_RTOL = 1e-3


def inertia_rows(model: Modelled, P: ArrayLike, theta: ArrayLike, dtheta: float) -> np.ndarray:
    """The inertia felt at the handle (force per angular acceleration, N / (rad/s^2),
    kg m for a door) of every row of the kernel matrix ``P`` at each ``theta`` and the
    speed ``dtheta``: an array (rows, angles), from the model's plant."""
    return model.plant.inertia_rows(P, theta, dtheta)


def speed_sensitivities(model) -> list[str]:
    """Names of ``model``'s speed sensitivities: parameters in s/m, s/rad or s/<theta unit>.

    A parameter with the unit of an inverse speed multiplies a speed inside a smooth
    switch: the slope ``a`` of a tanh friction law ``F tanh(a v)`` (eq. 3.1 of the
    seed) or of a speed gate. :func:`coulomb_vector` sends them to infinity. A model
    that writes such a slope as a constant in its kernel instead of declaring it keeps
    its tanh at the Coulomb curve's vanishing speed, where it gives no friction.
    """
    units = {*SENSITIVITY_UNITS, f"s/{model.theta_unit}"}
    return [p.name for p in model.params if p.unit.replace(" ", "") in units]


def coulomb_vector(model, params) -> np.ndarray:
    """The kernel vector with every non-zero speed sensitivity at :data:`COULOMB_SENSITIVITY`.

    Evaluated at :data:`COULOMB_SPEED`, the model's tanh laws are then their sign
    (dry friction at its full level, a speed gate shut or open) wherever the slip speed
    is not zero. A zero sensitivity stays zero (a law switched off stays off).
    """
    p = param_vector(params, model.params).copy()
    for name in speed_sensitivities(model):
        i = model.params.index(name)
        if p[i] != 0.0:
            p[i] = COULOMB_SENSITIVITY
    return p


def hold_forces(model: Modelled, p: ArrayLike, theta: ArrayLike, dtheta: float) -> np.ndarray:
    """Force (N, + toward closing) holding ``ddtheta = 0`` at every ``theta``, compiled.

    ``p`` is a kernel vector, ``dtheta`` one speed: the plant's static equilibrium at the
    handle (:meth:`~evo_door.sim.plant.Plant.hold_forces`; one compiled, multi-threaded
    call for a model given by ``accel``).
    """
    return model.plant.hold_forces(p, theta, dtheta)


def hold_forces_rows(model: Modelled, P: ArrayLike, theta: ArrayLike, dtheta: float) -> np.ndarray:
    """:func:`hold_forces` of every row of the kernel matrix ``P`` (one door a row):
    an array (rows, angles)."""
    return model.plant.hold_forces_rows(P, theta, dtheta)


def force_angle_curve(
    model: Modelled,
    params: ParamSet | ArrayLike,
    speed: float | None = None,
    n: int = 721,
    lo: float | None = None,
    hi: float | None = None,
    rtol: float = CURVE_RTOL,
    scan: int = SCAN_POINTS,
) -> dict:
    """The force-angle curve a specification reader expects: Coulomb level, latch peaks.

    The user force (N, + toward closing) that moves the door at a constant, slow speed
    toward open (``opening``, dtheta < 0) and toward closed (``closing``, dtheta > 0),
    against ``theta`` from ``lo`` to ``hi`` (default the model's ``theta_range``).

    ``speed`` None (the default) gives the **Coulomb curve**, the limit of slow motion
    with dry friction at its full level: every speed sensitivity (tanh slope, speed
    gate; :func:`speed_sensitivities`) is sent to infinity, so that tanh becomes sign,
    and the force is taken at a vanishing speed, so that viscous and latch damping
    vanish (:func:`coulomb_vector`, :data:`COULOMB_SPEED`). The levels are then the
    specification's: a friction of 3 N reads 3 N, a latch declared at 13 N peaks at
    13 N. A number gives the curve felt at that constant speed (theta unit / s), with
    the model's own tanh laws (at 0.02 rad/s the door presets' dry frictions give
    63-87 % of their Coulomb level over the stroke).

    The grid is the uniform grid of ``n`` points plus the points that the curve needs
    to be followed, by straight lines between points, within ``rtol`` of its force
    range: a dense scan of at least ``scan`` points finds where the curve changes fast
    (latch bands, friction reversals) and points are added there; every local extreme
    that stands out by more than that tolerance (a latch peak), or that the scan puts
    beyond the grid (the corner of a plateau), is then located to 1e-12 of the range
    between its neighbours of the scan, and added. Features narrower than the scan's spacing
    ((hi - lo) / scan, 6e-6 rad over a door's stroke) can be missed.

    Returns a dict: ``theta`` (rising), ``opening``, ``closing`` (N), ``added`` (True
    where a point was added to the uniform grid), ``speed`` (the speed used, 0.0 for
    the Coulomb curve) and ``coulomb`` (bool).

    Examples
    --------
    The haptic model with a 13 N lock: 721 uniform points alone would step over its
    0.0065 rad ramp; the curve peaks at the declared force.

    >>> from evo_door.models import get_model
    >>> haptic = get_model("haptic")
    >>> ps = haptic.load_params(None, {"open_force": 27.0, "close_force": 13.0,
    ...                                "friction_opening": 0.0, "friction_closing": 0.0})
    >>> c = force_angle_curve(haptic, ps)
    >>> f"{c['closing'].max():.2f} N", f"{-c['opening'].min():.2f} N", c["speed"]
    ('13.00 N', '27.00 N', 0.0)
    """
    # long: four steps of one grid, marked below (the checks, the dense scan,
    # the refinement, the extremes); they share the scan's arrays and tolerance
    lo = float(model.theta_range[0] if lo is None else lo)
    hi = float(model.theta_range[1] if hi is None else hi)
    n = int(n)
    if n < 2:
        raise UserError(f"a force-angle curve needs at least 2 points, got {n}")
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise UserError(f"force-angle curve: range [{lo:g}, {hi:g}] must rise from open to closed")
    coulomb = speed is None
    if speed is None:
        p, w = coulomb_vector(model, params), COULOMB_SPEED
    else:
        w = float(speed)
        if not (math.isfinite(w) and w > 0.0):
            raise UserError(f"force-angle curve: speed {speed!r} must be a number above 0")
        p = param_vector(params, model.params)

    # the dense scan; the uniform grid is every k-th of its points
    k = max(1, math.ceil((int(scan) - 1) / (n - 1)))
    x = np.linspace(lo, hi, (n - 1) * k + 1)
    signs = {"opening": -1.0, "closing": 1.0}
    dense = {d: hold_forces(model, p, x, s * w) for d, s in signs.items()}
    for d, f in dense.items():
        if not np.all(np.isfinite(f)):
            bad = x[np.flatnonzero(~np.isfinite(f))[0]]
            raise UserError(
                f"model {model.name!r}: the {d} force is not finite at theta = {bad:.6g} "
                f"{model.theta_unit}"
            )
    span = max(np.ptp(np.concatenate(list(dense.values()))), 1e-300)
    tol = rtol * span

    # add the dense point worst followed by straight lines, interval by interval
    idx = np.arange(0, x.size, k)
    for _ in range(200):
        err = np.zeros(x.size)
        for f in dense.values():
            np.maximum(err, np.abs(f - np.interp(x, x[idx], f[idx])), out=err)
        worst = np.maximum.reduceat(err, idx[:-1])
        bad = np.flatnonzero(worst > tol)
        if bad.size == 0:
            break
        new = [idx[j] + int(np.argmax(err[idx[j] : idx[j + 1]])) for j in bad]
        idx = np.union1d(idx, new)

    # locate every extreme: a sharp one (a latch peak) and one the dense scan puts
    # higher than the grid (the corner of a plateau), between its dense neighbours
    extra = []
    for d, s in signs.items():
        f = dense[d]
        g = f[idx]
        for i in range(1, idx.size - 1):
            left, right = g[i] - g[i - 1], g[i] - g[i + 1]
            if left * right <= 0.0:
                continue
            sign = 1.0 if left > 0.0 else -1.0  # maximum / minimum
            j0, j1 = idx[i - 1], idx[i + 1]
            j = j0 + int(np.argmax(sign * f[j0 : j1 + 1]))
            sharp = max(abs(left), abs(right)) > tol
            if sharp or sign * (f[j] - g[i]) > 1e-9 * span:
                extra.append(x[j])
                extra.append(_polish(model, p, x, f, j, s * w, sign))
    theta = np.union1d(x[idx], np.array(extra, dtype=np.float64))
    out: dict[str, Any] = {"theta": theta, "added": ~np.isin(theta, x[::k])}
    for d, s in signs.items():
        values = np.interp(theta, x[idx], dense[d][idx])
        exact = np.isin(theta, x[idx])
        if not exact.all():
            values[~exact] = hold_forces(model, p, theta[~exact], s * w)
        out[d] = values
    out["speed"] = 0.0 if coulomb else w
    out["coulomb"] = coulomb
    return out


def _polish(model, p, x, f, j, dtheta, sign) -> float:
    """The angle of the extreme of the dense point ``j``'s bracket (a maximum if ``sign`` > 0)."""
    from scipy.optimize import minimize_scalar

    a, b = x[max(j - 1, 0)], x[min(j + 1, x.size - 1)]

    def cost(u):
        return -sign * hold_forces(model, p, [a + u], dtheta)[0]

    # searched as the offset u from a: the method's tolerance grows with |u|, and an
    # angle near pi/2 would cost 1e-8 rad of it
    res = minimize_scalar(
        cost, bounds=(0.0, b - a), method="bounded", options={"xatol": 1e-12 * (x[-1] - x[0])}
    )
    return float(a + res.x) if -res.fun > sign * f[j] else float(x[j])  # -fun = sign F
