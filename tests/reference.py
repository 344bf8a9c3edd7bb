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
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

#: (rtol, atol) of the two solutions; the second is the reference
TOLERANCES = ((1e-10, 1e-12), (1e-13, 1e-15))


def linear_force(force: np.ndarray, dt: float):
    """``f(t)``: the sampled force, linear between samples, held past the last one."""
    last = len(force) - 2

    def f(time: float) -> float:
        k = min(int(time / dt), last)
        return force[k] + (time / dt - k) * (force[k + 1] - force[k])

    return f


def converged(accel, p, force, dt, theta0, dtheta0=0.0, bound=None, method="DOP853"):
    """``(theta, dtheta)`` on the samples' grid, converged to ``bound / 10``.

    ``accel(theta, dtheta, force, p)`` is a model's right-hand side (compiled or not).
    With ``bound`` (the tightest error the caller asserts, in rad or rad/s), the two
    solutions of :data:`TOLERANCES` must agree within ``bound / 10`` in both angle and
    speed, else the test stops with an AssertionError that says the reference is too
    loose for what it is asked to judge.
    """
    force = np.asarray(force, dtype=float)
    f = linear_force(force, dt)

    def rhs(time, x):
        return [x[1], accel(x[0], x[1], f(time), p)]

    solutions = []
    for rtol, atol in TOLERANCES:
        y = np.empty((2, len(force)))
        y[:, 0] = theta0, dtheta0
        for k in range(len(force) - 1):
            sol = solve_ivp(
                rhs, (k * dt, (k + 1) * dt), y[:, k], method=method, rtol=rtol, atol=atol
            )
            assert sol.success, sol.message
            y[:, k + 1] = sol.y[:, -1]
        solutions.append(y)
    loose, tight = solutions
    if bound is not None:
        spread = np.abs(loose - tight).max()
        assert spread < bound / 10, (
            f"the reference moves by {spread:.2e} between tolerances: too loose to judge "
            f"an error of {bound:.1e}"
        )
    return tight[0], tight[1]
