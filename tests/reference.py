"""Converged reference solutions for the integration-accuracy tests.

A test that asserts an error below ``bound`` must judge it against a reference at least
ten times more accurate, or the test measures the reference's error: scipy's Radau at
rtol 1e-10 is off by ~1.5e-7 rad on a forced pendulum, which failed a 1e-7 bound on
one CPU and passed on another.

The input force is read as the compiled integrators read it, linear between samples, so
its slope jumps at every sample. One ``solve_ivp`` over the whole trial steps across
those kinks and converges badly (DOP853 at rtol 1e-12 still moves by 1e-8 rad when
tightened); :func:`converged` integrates sample interval by sample interval instead,
where the force is smooth, twice (tolerances of :data:`TOLERANCES`), and refuses to
answer unless the two agree to ``bound / 10``: the tighter one is then at least that
good, on any CPU.

Models with switching surfaces or stick-slip friction (``switches``, ``stick``) are
solved the same way, interval by interval, with the non-smooth points handled by
scipy itself, written without reference to :mod:`evo_door.sim.located` (which these
solutions check):

- **Switching surfaces.** Each of the model's ``n_switches`` functions (its compiled
  ``switches(theta, dtheta, force, p, g)``, read into a numpy array) is a terminal
  ``solve_ivp`` event. When one changes sign, the step that crossed it is thrown away
  and integrated again from its start to the located crossing (so the surface ends a
  step, and no step of the kept solution has it inside), and the interval goes on from
  the crossing in a new ``solve_ivp``. In that new segment the surface just crossed is
  only watched for the way back (its value at the crossing is zero to rounding, on
  either side), and so are those crossed at the same instant (within
  :data:`COINCIDENT` of the period: a stop's contact and its damper's switch); a
  surface that is exactly zero at a segment's start (a door starting on its stop)
  likewise, once the side it leaves to is known from a short Taylor probe of the
  motion.
- **Stick-slip** (``stick=True``, the model's ``stick_slip``: dry friction a sign law
  with ``sgn(0) = 0``). The speed's zero is one more terminal event; there the speed
  is set to exactly 0.0 and the set-valued Coulomb law decides: the door sticks while
  ``accel(theta, +CREEP, F) <= 0 <= accel(theta, -CREEP, F)`` (the friction's two
  sides at :data:`CREEP`). While it sticks, nothing is integrated: the angle is held
  and the speed is 0.0. The acceleration is affine in the force and the force linear
  in time, so the instant one side crosses zero is solved in closed form; the door
  then slips that way from a speed of ``+-CREEP``. While it slips, the segment's
  right-hand side keeps the friction of its side past the speed's zero (the model's
  law there, moved by the jump the friction makes at rest): the zero is then crossed
  smoothly and located like any surface, where with the sign law itself an adaptive
  solver would creep up to it in ever shorter steps (the Coulomb law's sliding mode)
  and never arrive.

A segment that keeps ending at events without getting anywhere (a chatter) stops the
test after :data:`MAX_SEGMENTS` in one interval, rather than answering wrongly.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

#: (rtol, atol) of the two solutions; the second is the reference
TOLERANCES = ((1e-10, 1e-12), (1e-13, 1e-15))
#: Speed (rad/s) at which a stick-slip model's friction is read at rest, either side.
CREEP = 1e-200
#: Most segments (stretches between events) in one sample interval.
MAX_SEGMENTS = 2000
#: Crossings closer in time than this fraction of the sample period are one instant.
COINCIDENT = 1e-9


def linear_force(force: np.ndarray, dt: float):
    """``f(t)``: the sampled force, linear between samples, held past the last one."""
    last = len(force) - 2

    def f(time: float) -> float:
        k = min(int(time / dt), last)
        return force[k] + (time / dt - k) * (force[k + 1] - force[k])

    return f


def converged(
    accel,
    p,
    force,
    dt,
    theta0,
    dtheta0=0.0,
    bound=None,
    method="DOP853",
    stick=False,
    switches=None,
    n_switches=0,
):
    """``(theta, dtheta)`` on the samples' grid, converged to ``bound / 10``.

    ``accel(theta, dtheta, force, p)`` is a model's right-hand side (compiled or not).
    With ``bound`` (the tightest error the caller asserts, in rad or rad/s), the two
    solutions of :data:`TOLERANCES` must agree within ``bound / 10`` in both angle and
    speed, else the test stops with an AssertionError that says the reference is too
    loose for what it is asked to judge. ``stick``, ``switches`` and ``n_switches`` are
    the model's ``stick_slip``, ``switches`` and ``n_switches`` (the module docstring).
    """
    force = np.asarray(force, dtype=float)
    if stick or n_switches:
        piecewise = Piecewise(accel, np.ascontiguousarray(p, dtype=float), switches, n_switches)
        piecewise.stick = bool(stick)
        solve = lambda rtol, atol: piecewise.trial(force, dt, theta0, dtheta0, method, rtol, atol)
    else:
        solve = lambda rtol, atol: _smooth(accel, p, force, dt, theta0, dtheta0, method, rtol, atol)
    loose, tight = (solve(rtol, atol) for rtol, atol in TOLERANCES)
    if bound is not None:
        spread = np.abs(loose - tight).max()
        assert spread < bound / 10, (
            f"the reference moves by {spread:.2e} between tolerances: too loose to judge "
            f"an error of {bound:.1e}"
        )
    return tight[0], tight[1]


def _smooth(accel, p, force, dt, theta0, dtheta0, method, rtol, atol):
    """A smooth model's solution, one ``solve_ivp`` per sample interval."""
    f = linear_force(force, dt)

    def rhs(time, x):
        return [x[1], accel(x[0], x[1], f(time), p)]

    y = np.empty((2, len(force)))
    y[:, 0] = theta0, dtheta0
    for k in range(len(force) - 1):
        sol = solve_ivp(rhs, (k * dt, (k + 1) * dt), y[:, k], method=method, rtol=rtol, atol=atol)
        assert sol.success, sol.message
        y[:, k + 1] = sol.y[:, -1]
    return y


class Piecewise:
    """A model with switching surfaces and / or stick-slip friction, solved interval by
    interval with its non-smooth points as ``solve_ivp`` events (the module docstring).

    Time inside an interval is local (0 at its first sample), so that steps far
    shorter than a microsecond stay representable late in a trial.
    """

    def __init__(self, accel, p, switches, n_switches):
        self.accel = accel
        self.p = p
        self.switches = switches
        self.n = int(n_switches)
        self.stick = False
        self._g = np.empty(max(self.n, 1))
        self._key = None

    # -- the model's functions ----------------------------------------------------------
    def g(self, theta, dtheta, force):
        """The switching functions at a state (a copy of the cached values)."""
        key = (theta, dtheta, force)
        if key != self._key:
            self.switches(theta, dtheta, force, self.p, self._g)
            self._key = key
        return self._g

    def event_values(self, theta, dtheta, force):
        """Every event's value: the switching functions, then the speed (stick-slip)."""
        values = list(self.g(theta, dtheta, force)[: self.n]) if self.n else []
        if self.stick:
            values.append(dtheta)
        return np.array(values)

    # -- one trial ----------------------------------------------------------------------
    def trial(self, force, dt, theta0, dtheta0, method, rtol, atol):
        """``(2, len(force))``: angle and speed at every sample."""
        y = np.empty((2, len(force)))
        y[:, 0] = theta0, dtheta0
        for k in range(len(force) - 1):
            y[:, k + 1] = self.interval(
                y[0, k], y[1, k], force[k], force[k + 1], dt, method, rtol, atol
            )
        return y

    def interval(self, theta, dtheta, f0, f1, dt, method, rtol, atol):
        """The state one sample interval later, the force going linearly f0 -> f1."""
        slope = (f1 - f0) / dt
        s = 0.0
        back = {}  # event -> direction of the way back, for the surfaces just crossed
        settings = {"method": method, "rtol": rtol, "atol": atol}
        for _ in range(MAX_SEGMENTS):
            if self.stick and dtheta == 0.0:
                s, dtheta = self.stuck(theta, s, f0, slope, dt)
                if s >= dt:
                    return theta, 0.0
                back = {}
            rhs = self.rhs(f0, slope, np.sign(dtheta) if self.stick else 0.0)
            events = self.events(rhs, s, theta, dtheta, f0 + slope * s, slope, dt, back)
            sol = solve_ivp(rhs, (s, dt), [theta, dtheta], events=events, **settings)
            assert sol.status >= 0, sol.message
            if sol.status == 0:
                return sol.y[0, -1], sol.y[1, -1]
            hit = next(i for i, times in enumerate(sol.t_events) if len(times))
            t_hit = sol.t[-1]
            # the step that crossed, again from its start and ending at the crossing
            t_prev, y_prev = sol.t[-2], sol.y[:, -2]
            if t_hit > t_prev:
                redo = solve_ivp(rhs, (t_prev, t_hit), y_prev, **settings)
                assert redo.success, redo.message
                theta, dtheta = redo.y[0, -1], redo.y[1, -1]
            else:
                theta, dtheta = y_prev
            before = self.event_values(y_prev[0], y_prev[1], f0 + slope * t_prev)[hit]
            crossing = events[hit].direction or -np.sign(before)
            if t_hit - s > COINCIDENT * dt:
                back = {}  # (else: crossed together with the ones before, still watched)
            s = t_hit
            if self.stick and hit == self.n:
                dtheta = 0.0  # the speed's zero: stick or slip, decided above
                back = {}
            else:
                back[hit] = -crossing
        raise AssertionError(
            f"the reference ends {MAX_SEGMENTS} segments in one sample interval at "
            f"theta {theta:.6f} rad, dtheta {dtheta:.3e} rad/s: a chatter it cannot resolve"
        )

    def rhs(self, f0, slope, side):
        """The right-hand side of a segment, in local time; for a stick-slip model
        slipping to ``side`` (+1 or -1), the friction of that side held past the
        speed's zero, so that the segment's end there is a smooth crossing."""
        accel, p = self.accel, self.p

        def rhs(s, x):
            force = f0 + slope * s
            if side == 0.0 or x[1] * side > 0.0:
                return [x[1], accel(x[0], x[1], force, p)]
            # past the zero: the law there, moved by the friction's jump at rest
            held = accel(x[0], side * CREEP, force, p)
            if x[1] == 0.0:
                return [x[1], held]
            return [x[1], accel(x[0], x[1], force, p) + held - accel(x[0], -side * CREEP, force, p)]

        return rhs

    def stuck(self, theta, s, f0, slope, dt):
        """A door at rest at local time ``s``: ``(s, dtheta)`` where it slips, ``s >= dt``
        if it sticks to the interval's end (the set-valued Coulomb law)."""
        accel, p = self.accel, self.p
        force = f0 + slope * s
        forward = accel(theta, CREEP, force, p)
        backward = accel(theta, -CREEP, force, p)
        if forward > 0.0:
            return s, CREEP
        if backward < 0.0:
            return s, -CREEP
        # affine in the force, linear in time: each side's zero in closed form
        forward_end = accel(theta, CREEP, f0 + slope * dt, p)
        backward_end = accel(theta, -CREEP, f0 + slope * dt, p)
        t_slip, speed = dt, 0.0
        if forward_end > 0.0:
            t_slip, speed = s + (dt - s) * forward / (forward - forward_end), CREEP
        if backward_end < 0.0:
            t_back = s + (dt - s) * backward / (backward - backward_end)
            if t_back < t_slip:
                t_slip, speed = t_back, -CREEP
        return t_slip, speed

    def events(self, rhs, s, theta, dtheta, force, slope, dt, back):
        """The segment's terminal events, from local time ``s`` at ``(theta, dtheta)``.

        ``back``: the surfaces just crossed, watched only for the way back; a surface
        exactly zero here is watched only for the way back from the side the motion
        leaves to (a Taylor probe), or not at all in this segment if it stays on it.
        """
        start = self.event_values(theta, dtheta, force)
        probe = None
        events = []
        for i, value in enumerate(start):
            direction = 0.0
            if i in back:
                direction = back[i]
            elif value == 0.0:
                if probe is None:
                    tau = 1e-3 * (dt - s)
                    a = rhs(s, [theta, dtheta])[1]
                    th = theta + tau * dtheta + 0.5 * tau * tau * a
                    probe = self.event_values(th, dtheta + tau * a, force + slope * tau)
                direction = -np.sign(probe[i])
                if direction == 0.0:
                    events.append(_never)
                    continue
            events.append(self.event(i, direction, slope, force - slope * s))
        return events

    def event(self, i, direction, slope, f0):
        """Event ``i`` as ``solve_ivp`` takes it: terminal, with a direction."""

        def value(s, x):
            return self.event_values(x[0], x[1], f0 + slope * s)[i]

        value.terminal = True
        value.direction = direction
        return value


def _never(s, x):
    """A surface not watched in this segment."""
    return 1.0


# solve_ivp reads these attributes of an event function
_never.terminal = True  # type: ignore[attr-defined]
_never.direction = 0.0  # type: ignore[attr-defined]
