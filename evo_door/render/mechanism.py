"""Rendering a mechanism: any model on a state vector whose handle is one coordinate.

A mechanism file (``docs/blocks.md``) or a hand-written ``Model(rhs=...)`` is rendered
by :class:`MechanismLoop`, the servo loop (:class:`~evo_door.render.loop.ServoLoop`:
its pacing, force limit, faults, log, watchdog, stall rule and supervisor) with a cycle
of its own (:func:`~evo_door.render.mechanism_kernels.mechanism_command`):

- **the map.** A rotary handle (``theta_unit`` rad) is the angle on the haptic model's
  circle: radius :data:`RADIUS` about the model frame's origin, the device held on the
  circle and in its plane by the haptic model's default constraint springs
  (:data:`K_ACROSS` ...). A linear handle (m) runs along the device's y axis, the
  middle of its ``theta_range`` at y = 0, held on the axis (x and z) by the same
  springs. The virtual hands of ``--user`` read their angles on the circle, or, on a
  linear handle, as the fraction of the stroke (0 deg: the range's open end, 90 deg:
  its closed end; :class:`Stroke`).
- **the force.** The mechanism's force on the hand, explicit (the state read this
  cycle): the handle's acceleration with no hand force over its acceleration per
  newton of the hand (the rhs is affine in the force). On a rotary handle that is the
  moment over ``hand_lever``, applied along the circle at :data:`RADIUS`. The handle's
  own mass is the device's: its moving mass is set to it (``1 / gain``, and
  ``1 / (gain R)`` on the circle).
- **the other states** (other bodies, a component's own state) are integrated over each
  cycle with the handle's position and speed imposed from the device: classic
  Runge-Kutta in `ceil(rho T)` steps (:func:`fastest_rate`: rho), at most :data:`MAX_SUBSTEPS`.

Before it runs (and for every change) :func:`check_mechanism` refuses, in one line, a
mechanism the loop cannot render passively at its rate (Colgate and Schenkel's
``b > K T / 2 + |B|``, the criterion of :mod:`evo_door.render.safety`, with the
handle's stiffness and damping scanned over its range, :func:`scan`), one with a
damping the explicit loop cannot take, one whose other states are too stiff for the
cycle, and :func:`check_hands_off` one that, released anywhere with no hand, moves
faster than the hands-off limit.
"""

from __future__ import annotations

import math

import numpy as np

from evo_door.errors import UserError
from evo_door.kernel_cache import TypedFunction
from evo_door.models.haptic import CLOSED, PARAMS
from evo_door.params import param_vector
from evo_door.render.loop import ServoLoop
from evo_door.render.mechanism_kernels import (
    G_C_ACROSS,
    G_C_PLANE,
    G_CENTRE,
    G_GAIN,
    G_K_ACROSS,
    G_K_PLANE,
    G_LINEAR,
    G_RADIUS,
    N_GEOMETRY,
    N_WORK,
    advance_others,
    hand_force,
    handle_of,
    mechanism_command,
)
from evo_door.sim.states import RHS_TYPE

#: the circle of a rotary handle (m): the haptic model's default radius
RADIUS = PARAMS["radius"].default
#: what holds the device on the handle's path: the haptic model's default constraint,
#: across the path (off the circle / along z: N/m, N s/m) and out of its plane (x)
K_ACROSS = PARAMS["k_radial"].default
C_ACROSS = PARAMS["c_radial"].default
K_PLANE = PARAMS["k_plane"].default
C_PLANE = PARAMS["c_plane"].default
#: a sampled damper C on the moving mass m may take at most C T / m of the speed a
#: cycle: above 1 the explicit update reverses the speed (above 2 it grows)
DAMPING_LIMIT = 1.0
#: the other states' Runge-Kutta step: |h lambda| at most this (stable and accurate:
#: RK4's real and imaginary stability bounds are 2.79 and 2.83)
RK4_REACH = 1.0
#: Runge-Kutta steps of the other states a cycle at most (a mechanism that needs more
#: is refused: its cycle would outgrow the period)
MAX_SUBSTEPS = 64
#: Newton steps of :meth:`RenderedModel.rest` at most
REST_NEWTON = 30
#: positions scanned for the handle's stiffness, over the range and 10 % beyond each end
N_SCAN = 241
#: a linear handle's hands-off limit is the door's (rad/s) times this (m): the speed of
#: a door's handle 0.6 m from its hinge (3 rad/s: 1.8 m/s)
HANDS_OFF_REACH = 0.6
#: starts of the released mechanism: the range in this many equal parts, ends included
#: (every 5 deg on a door's 90)
HANDS_OFF_PARTS = 18


class Stroke:
    """A linear handle's path on the device: its coordinate along the y axis, the
    middle of the range ``(lo, hi)`` at y = 0. A virtual hand's angle (rad) is the
    fraction of the stroke: 0 at ``lo`` (open), pi/2 at ``hi`` (closed)."""

    def __init__(self, lo: float, hi: float):
        self.lo, self.hi = float(lo), float(hi)
        self.centre = 0.5 * (self.lo + self.hi)

    def point(self, angle: float) -> tuple[float, float, float]:
        q = self.lo + (self.hi - self.lo) * angle / CLOSED
        return (0.0, q - self.centre, 0.0)

    def angle(self, pos) -> float:
        return CLOSED * (pos[1] + self.centre - self.lo) / (self.hi - self.lo)


class RenderedModel:
    """A state-vector model ready to render: its law, handle, geometry and checks."""

    def __init__(self, model):
        self.model = model
        plant = model.plant
        self.law = plant.state_law("the renderer")
        self.ih, self.iv = int(plant.position), int(plant.speed)
        self.n = int(plant.n_states)
        self.handle = plant.state_names[self.ih]
        self.unit = model.theta_unit
        self.linear = self.unit != "rad"
        lo, hi = (float(v) for v in model.theta_range)
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise UserError(f"model {model.name!r}: its theta_range {lo:g}..{hi:g} is no stroke")
        self.range = (lo, hi)
        others = [i for i in range(self.n) if i not in (self.ih, self.iv)]
        self.others = np.array(others, dtype=np.int64)
        self.contacts = [k for k in self.law.contacts if k not in (self.ih, self.iv)]
        #: the rhs as the cycle's kernels take it, its entry point looked up once
        self.cycle_rhs = TypedFunction(self.law.rhs, RHS_TYPE)

    @property
    def path(self):
        """The handle's path for a virtual hand (:class:`Stroke` or the haptic circle)."""
        if self.linear:
            return Stroke(*self.range)
        from evo_door.render.device import Circle

        return Circle(RADIUS)

    def state(self, p, q: float, dq: float) -> np.ndarray:
        """The whole state with the handle at ``q``, ``dq`` and the others at their start."""
        return np.ascontiguousarray(self.law.initial_state(p, q, dq), dtype=np.float64)

    def rest(self, p, q: float, dq: float = 0.0) -> np.ndarray:
        """The whole state with the handle held at ``q`` (moving at ``dq``) and the other
        states at rest there: ``dx = 0`` for each of them (a towed body where its spring
        is slack, a fluid's force settled), by Newton's method from their start, forward
        differences; their start where it does not converge in :data:`REST_NEWTON`
        steps."""
        p = np.ascontiguousarray(p, dtype=np.float64)
        x = self.state(p, q, dq)
        idx = self.others
        if idx.size == 0:
            return x
        rhs, f0, f1 = self.law.rhs, np.empty(self.n), np.empty(self.n)
        y = x.copy()
        for _ in range(REST_NEWTON):
            rhs(y, 0.0, p, f0)
            if np.max(np.abs(f0[idx])) == 0.0:
                return y  # at rest already (a slack tow: its Jacobian may be singular)
            jac = np.empty((idx.size, idx.size))
            for col, j in enumerate(idx):
                h = 1e-7 * (1.0 + abs(y[j]))
                yj = y.copy()
                yj[j] += h
                rhs(yj, 0.0, p, f1)
                jac[:, col] = (f1[idx] - f0[idx]) / h
            try:
                step = np.linalg.solve(jac, -f0[idx])
            except np.linalg.LinAlgError:
                return x
            if not np.all(np.isfinite(step)):
                return x
            y[idx] += step
            if np.max(np.abs(step) / (1.0 + np.abs(y[idx]))) < 1e-12:
                return y
        return x

    def gain(self, p) -> float:
        """The handle's acceleration per newton of the hand (the rhs is affine in the
        force): from the acceleration at 0 and 1 N, checked at the range's ends."""
        rhs, dx0, dx1 = self.law.rhs, np.empty(self.n), np.empty(self.n)
        gains = []
        for q in self.range:
            x = self.state(p, q, 0.0)
            rhs(x, 0.0, p, dx0)
            rhs(x, 1.0, p, dx1)
            gains.append(dx1[self.iv] - dx0[self.iv])
        g = gains[0]
        if not (math.isfinite(g) and g > 0.0) or abs(gains[1] - g) > 1e-6 * abs(g):
            raise UserError(
                f"model {self.model.name!r}: its handle's acceleration does not grow in "
                f"proportion to the hand's force (per newton {gains[0]:.4g}, "
                f"{gains[1]:.4g} at the range's ends): the renderer needs a handle with a "
                "mass of its own"
            )
        return float(g)

    def geometry(self, p) -> np.ndarray:
        """The kernel's geometry vector for the parameter vector ``p``."""
        geo = np.zeros(N_GEOMETRY)
        geo[G_LINEAR] = 1.0 if self.linear else 0.0
        geo[G_RADIUS] = RADIUS
        geo[G_CENTRE] = 0.5 * (self.range[0] + self.range[1])
        geo[G_K_ACROSS], geo[G_C_ACROSS] = K_ACROSS, C_ACROSS
        geo[G_K_PLANE], geo[G_C_PLANE] = K_PLANE, C_PLANE
        geo[G_GAIN] = self.gain(p)
        return geo

    def device_mass(self, gain: float) -> float:
        """The moving mass (kg) the device renders: the handle's, at the device."""
        return 1.0 / gain if self.linear else 1.0 / (gain * RADIUS)

    def per_metre(self) -> float:
        """Metres of the device per unit of the handle's coordinate."""
        return 1.0 if self.linear else RADIUS

    def coordinate(self, q: float) -> str:
        return f"{self.handle} = {q:.5g} {self.unit}"


def scan(mech: RenderedModel, p) -> dict:
    """The handle's stiffness and damping over its range, in device units.

    At :data:`N_SCAN` positions over the range and 10 % beyond each end (where end stops
    push), moving at +-1 % and +-100 % of the range per second, the other states at
    rest there (:meth:`RenderedModel.rest`): ``K = -dF/dq``, ``C = -dF/dv`` of the
    force on the hand (:func:`~evo_door.render.mechanism_kernels.hand_force`) by
    one-sided differences, the smaller of the two (:func:`_one_sided`: a jump or a kink
    of the law, a stop's edge with its damper switching on, is no stiffness), divided by
    the device's metres per unit (the circle's radius on a rotary handle). Returns
    ``K`` (N/m, the largest), ``K_at`` (the coordinate where it begins), ``K_param``
    (the parameter it is proportional to: halving it halves K there, "" if none),
    ``C`` (N s/m, the largest), ``C_at``, ``B`` (N s/m, the size of the most negative
    damping, 0 if none), ``B_at``.
    """
    p = np.ascontiguousarray(p, dtype=np.float64)
    lo, hi = mech.range
    span = hi - lo
    gain = mech.gain(p)
    rhs, dx = mech.cycle_rhs, np.empty(mech.n)  # its entry point looked up once
    metres = mech.per_metre()
    hq, best = 1e-7 * span, dict(K=0.0, K_at=lo, C=0.0, C_at=lo, B=0.0, B_at=lo)

    def force(x, q, v, pv):
        x[mech.ih], x[mech.iv] = q, v
        return hand_force(rhs, x, pv, mech.iv, gain, dx)

    def stiffness(x, q, v, pv):
        f0 = force(x, q, v, pv)
        up = -(force(x, q + hq, v, pv) - f0) / hq
        down = -(f0 - force(x, q - hq, v, pv)) / hq
        return max(_one_sided(up, down), 0.0) / metres

    stiffest = None
    for q in np.linspace(lo - 0.1 * span, hi + 0.1 * span, N_SCAN):
        for v in (-span, -0.01 * span, 0.01 * span, span):
            x = mech.rest(p, q, v)
            hv = 1e-6 * abs(v)
            k = stiffness(x, q, v, p)
            f0 = force(x, q, v, p)
            up = -(force(x, q, v + hv, p) - f0) / hv
            down = -(f0 - force(x, q, v - hv, p)) / hv
            c = _one_sided(up, down) / metres
            if k > best["K"] * (1.0 + 1e-6):  # the first of equals: where it begins
                best.update(K=k, K_at=q)
                stiffest = (x.copy(), q, v)
            if c > best["C"]:
                best.update(C=c, C_at=q)
            if -c > best["B"]:
                best.update(B=-c, B_at=q)
    best["K_param"] = ""
    if stiffest is not None:  # which parameter makes it: halving it halves K (within 10 %)
        x, q, v = stiffest
        off = 0.1
        for j, name in enumerate(mech.model.params.names):
            if p[j] == 0.0:
                continue
            ph = p.copy()
            ph[j] *= 0.5
            ratio = stiffness(x, q, v, ph) / best["K"]
            if abs(ratio - 0.5) < off:
                off, best["K_param"] = abs(ratio - 0.5), name
    return best


def _one_sided(up: float, down: float) -> float:
    """Of a forward and a backward difference, the smaller if both have one sign, else 0:
    a law that jumps or kinks here has no slope to sample."""
    if up > 0.0 and down > 0.0:
        return min(up, down)
    if up < 0.0 and down < 0.0:
        return max(up, down)
    return 0.0


def fastest_rate(mech: RenderedModel, p) -> float:
    """The fastest rate (1/s) of the states besides the handle: the largest eigenvalue
    magnitude of their Jacobian (forward differences, the handle held) at 25 positions
    over the range, the handle still and moving at half the range a second, the other
    states at rest there, a contact's speed off zero (its sign law is a jump there);
    inf where it is not finite, 0 for a mechanism with no other states."""
    if mech.others.size == 0:
        return 0.0
    p = np.ascontiguousarray(p, dtype=np.float64)
    lo, hi = mech.range
    rhs, f0, f1 = mech.law.rhs, np.empty(mech.n), np.empty(mech.n)
    others = mech.others
    fastest = 0.0
    for q in np.linspace(lo, hi, 25):
        for v in (0.0, 0.5 * (hi - lo)):
            x = mech.rest(p, q, v)
            for k in mech.contacts:
                x[k] = 1e-3 * (hi - lo) if x[k] == 0.0 else x[k]
            rhs(x, 0.0, p, f0)
            jac = np.empty((others.size, others.size))
            for col, j in enumerate(others):
                h = 1e-7 * max(1.0, abs(x[j]))
                xj = x.copy()
                xj[j] += h
                rhs(xj, 0.0, p, f1)
                jac[:, col] = (f1[others] - f0[others]) / h
            if not np.all(np.isfinite(jac)):
                return math.inf
            fastest = max(fastest, float(np.max(np.abs(np.linalg.eigvals(jac)))))
    return fastest


def measure(mech: RenderedModel, p) -> dict:
    """What the checks read of the parameter vector ``p``: :func:`scan`'s answer, plus
    ``fastest`` (1/s) the other states' fastest rate (:func:`fastest_rate`) and
    ``gain`` (:meth:`RenderedModel.gain`). Tens of milliseconds: the loop keeps it for
    the set in force and judges it again at a measured period (:func:`judge`)."""
    s = scan(mech, p)
    s["fastest"] = fastest_rate(mech, p)
    s["gain"] = mech.gain(np.ascontiguousarray(p, dtype=np.float64))
    return s


def check_mechanism(mech: RenderedModel, p, damping: float, period: float) -> int:
    """The Runge-Kutta steps a cycle if the loop can render ``p`` at ``period`` (s) on a
    device of its own ``damping`` (N s/m); else a UserError in one line (see the module
    docstring). :func:`measure` then :func:`judge`."""
    return judge(mech, measure(mech, p), damping, period)


def judge(mech: RenderedModel, s: dict, damping: float, period: float) -> int:
    """:func:`check_mechanism` on what :func:`measure` found, ``s``."""
    mass = mech.device_mass(s["gain"])
    k_handle, k_name = s["K"], "the handle's stiffness"
    k = max(k_handle, K_ACROSS, K_PLANE)
    if k > k_handle:
        k_name = "the path's constraint"
    need = k * period / 2.0 + s["B"]
    ms = f"{period * 1e3:.3g} ms"
    if not damping > need:
        where = f" at {mech.coordinate(s['K_at'])}" if k == k_handle else ""
        made = f" ({s['K_param']})" if k == k_handle and s["K_param"] else ""
        raise UserError(
            f"mechanism refused: not passive at a {ms} loop period: {k_name} reaches "
            f"K = {k:.4g} N/m{where}{made}, negative damping |B| = {s['B']:.4g} N s/m, and "
            f"the device damping b = {damping:.4g} N s/m is not above K T / 2 + |B| = "
            f"{need:.4g} N s/m (lower it with --set NAME=VALUE, raise --rate, or state the "
            "device's damping with --device-damping)"
        )
    c = max(s["C"], C_ACROSS, C_PLANE)
    if c * period / mass > DAMPING_LIMIT:
        what = (
            f"the handle's damping at {mech.coordinate(s['C_at'])}"
            if c == s["C"]
            else ("the path's constraint damping")
        )
        raise UserError(
            f"mechanism refused: {what} C = {c:.4g} N s/m on a moving mass of {mass:.4g} kg "
            f"takes C T / m = {c * period / mass:.3g} of the speed a {ms} cycle, above "
            f"{DAMPING_LIMIT:g} (lower it with --set NAME=VALUE or raise --rate)"
        )
    fastest = s["fastest"]
    if mech.others.size == 0:
        return 0
    n = math.ceil(fastest * period / RK4_REACH) if math.isfinite(fastest) else -1
    n = max(n, 1) if n >= 0 else n
    if n < 0 or n > MAX_SUBSTEPS:
        raise UserError(
            f"mechanism refused: its states besides the handle are too stiff for the loop: "
            f"their fastest rate {fastest:.4g} 1/s needs more than {MAX_SUBSTEPS} "
            f"Runge-Kutta steps a {ms} cycle (lower the stiffness with --set NAME=VALUE)"
        )
    return n


def check_hands_off(mech: RenderedModel, params, limit: float) -> None:
    """A UserError unless the mechanism, released from rest anywhere in its range with no
    hand on it, stays under ``limit`` (rad/s; on a linear handle times
    :data:`HANDS_OFF_REACH`, m/s): the door's hands-off check
    (:mod:`evo_door.render.hands_off`), its duration and sample period, on the
    mechanism's own simulation (the other states at rest where it is released,
    :meth:`RenderedModel.rest`)."""
    from evo_door.render.hands_off import HANDS_OFF_DT, hands_off_duration

    lo, hi = mech.range
    fast = limit * HANDS_OFF_REACH if mech.linear else limit
    unit = f"{mech.unit}/s"
    duration = hands_off_duration(limit)
    force = np.zeros(int(round(duration / HANDS_OFF_DT)) + 1)
    speed, start = -1.0, lo
    for q0 in np.linspace(lo, hi, HANDS_OFF_PARTS + 1):
        x0 = mech.rest(param_vector(params, mech.model.params), float(q0))
        r = mech.model.plant.simulate(params, force, HANDS_OFF_DT, state=x0)
        fastest = float(np.max(np.abs(r.dtheta))) if r.ok else math.inf
        fastest = fastest if math.isfinite(fastest) else math.inf
        if fastest > speed:
            speed, start = fastest, float(q0)
    if speed > fast:
        reached = "blows up" if math.isinf(speed) else f"reaches {speed:.3g} {unit}"
        raise UserError(
            f"mechanism refused: released from rest at {mech.coordinate(start)} with no hand "
            f"on it, it {reached} within {duration:.3g} s, above the hands-off limit of "
            f"{fast:.3g} {unit} (the renderer's --hands-off-speed RAD_S sets the limit"
            + (f", times {HANDS_OFF_REACH:g} m on a linear handle)" if mech.linear else ")")
        )


class MechanismLoop(ServoLoop):
    """The servo loop rendering a state-vector ``model``'s parameter set ``params``
    (see the module docstring); the other arguments are :class:`ServoLoop`'s (no
    ``clamp``: a mechanism the loop cannot render is refused, not scaled)."""

    def __init__(self, device, model, params, rate: float = 2500.0, **kw):
        if kw.pop("clamp", False):
            raise UserError("--clamp scales the haptic model's springs; a mechanism is refused "
                            "instead (lower its stiffness with --set NAME=VALUE)")  # fmt: skip
        self.mech = RenderedModel(model)
        self._checked: tuple = (None, {})  # (the set last measured, what was found)
        self._nsub_of: tuple = (None, 0)  # (the set last judged, its Runge-Kutta steps)
        super().__init__(device, params, rate, friction="tanh", **kw)
        self._x = self.mech.state(self._p, self.mech.range[0], 0.0)
        self._fresh = True  # the other states start where the device is, at the first read

    # -- what the loop renders ---------------------------------------------------------
    def _check_model(self, params) -> None:
        if getattr(params, "model", None) != self.mech.model.params.model:
            raise UserError(f"the renderer takes a parameter set of {self.mech.model.name!r}")

    def _table(self, params):
        return self.mech.model.params

    def _renderable(self, params):
        table = self.mech.model.params
        for q, value in zip(table, param_vector(params, table), strict=True):
            q.check(value, "the set to render")
        return params

    def _passive(self, params):
        """:func:`check_mechanism` at the period in force (a set measured before is
        only judged again: the loop's recheck at the measured period runs in a cycle)."""
        checked, s = self._checked
        if checked is not params:
            s = measure(self.mech, param_vector(params, self.mech.model.params))
        self._nsub_of = (params, judge(self.mech, s, self.damping, self._check_period))
        self._checked = (params, s)
        if params is getattr(self, "params", None):  # the recheck at the measured period
            self._nsub = self._nsub_of[1]
        return params, {}

    def _hands_off(self, params) -> None:
        if self.hands_off_speed is not None:
            check_hands_off(self.mech, params, self.hands_off_speed)

    def _set_native(self) -> None:
        """Nothing: the host renders the path's constraint itself."""

    def _set_vectors(self) -> None:
        self._p = param_vector(self.params, self.mech.model.params)
        self._p_free = self._p
        self._geo = self.mech.geometry(self._p)
        checked, n = self._nsub_of
        if checked is not self.params:
            self._passive(self.params)
            n = self._nsub_of[1]
        self._nsub = n
        self._hs = np.zeros(5)
        self._work = np.zeros((N_WORK, self.mech.n))

    def _set_vector(self):
        return param_vector(self.params, self.mech.model.params)

    def _virtual_mass(self) -> float:
        return self.mech.device_mass(self.mech.gain(param_vector(self.params, self._table(None))))

    def _load_kernels(self) -> None:
        x = self._x.copy()
        work = np.zeros_like(self._work)
        m = self.mech
        mechanism_command(
            m.cycle_rhs, self._pos, self._vel, self._user, x, self._p, self._geo, m.ih, m.iv,
            self.period, self._nsub, self.limit, self._hs, work, self._cmd, self._row,
        )  # fmt: skip
        advance_others(m.cycle_rhs, x, self._p, m.ih, m.iv, 0.0, 0.0, 0.0, self.period, 0, work)

    def _log_law(self) -> None:
        m = self.mech
        path = "the device's y axis" if m.linear else f"the haptic model's circle of {RADIUS:g} m"
        self.log.event(
            0.0,
            "model",
            f"rendered the model {m.model.name!r} ({m.model.title}): handle {m.handle} "
            f"({m.unit}) on {path}; the force explicit, the other states integrated in the "
            f"loop ({self._nsub} Runge-Kutta steps a cycle)",
            model=m.model.name,
            handle=m.handle,
            unit=m.unit,
            substeps=self._nsub,
        )

    def _set_up(self) -> None:
        super()._set_up()
        self._fresh = True

    def travel(self, first: float, last: float) -> str:
        m = self.mech
        return f"model {m.model.name!r}, handle {m.handle} {first:.4g} -> {last:.4g} {m.unit}"

    # -- the cycle -----------------------------------------------------------------------
    def _command(self, t: float, now: float) -> None:
        m = self.mech
        if self._fresh:  # the handle where the device is, the other states at rest there
            handle_of(self._pos, self._vel, self._geo, self._hs)
            q, dq = float(self._hs[0]), float(self._hs[1])
            if math.isfinite(q) and math.isfinite(dq):
                self._x[:] = m.rest(self._p, q, dq)
                self._fresh = False
        cmd = self._cmd
        code = mechanism_command(
            m.cycle_rhs, self._pos, self._vel, self._user, self._x, self._p, self._geo, m.ih,
            m.iv, self._check_period, self._nsub, self.limit, self._hs, self._work, cmd,
            self._row,
        )  # fmt: skip
        self._send(t, now, code, cmd)

    @property
    def substeps(self) -> int:
        """Runge-Kutta steps of the other states a cycle (0: none)."""
        return self._nsub

    @property
    def state(self) -> np.ndarray:
        """The model's state vector now (a copy): the handle as last read, the others."""
        return self._x.copy()

    def _stats(self, cycles) -> dict:
        stats = super()._stats(cycles)
        stats.update(friction="explicit", model=self.mech.model.name)
        return stats
