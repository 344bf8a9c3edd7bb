"""The plain way, shared by the benchmark scripts and the suite.

What a user without the workbench writes: scipy's ``solve_ivp`` with a Python
right-hand side around the model's acceleration (the compiled ``accel``, or the same
code run as pure Python with ``NUMBA_DISABLE_JIT=1`` in a fresh process), one call per
trial, and a GA that evaluates its individuals one at a time.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

#: scipy settings of the plain way (the same in every benchmark)
RTOL, ATOL = 1e-6, 1e-9
#: settings of the reference solution (the test suite's)
REF_RTOL, REF_ATOL = 1e-10, 1e-12


def linear_rhs(accel, p, dt, force):
    """``f(t, y)`` of the first-order system, the force interpolated linearly between
    samples (as the compiled integrators read it)."""
    last = len(force) - 2

    def rhs(time_, y):
        k = min(int(time_ / dt), last)
        frac = time_ / dt - k
        return (y[1], accel(y[0], y[1], force[k] + frac * (force[k + 1] - force[k]), p))

    return rhs


def solve_trial(accel, p, dt, force, y0, method, reference=False):
    """``solve_ivp`` over a sampled trial; returns ``(theta, dtheta)`` at the samples
    (NaN where the solver stopped early).

    ``reference`` uses the test suite's tolerances (rtol 1e-10, atol 1e-12, a step of
    at most one sample); otherwise rtol 1e-6, atol 1e-9, a step of at most 4 samples.
    """
    from scipy.integrate import solve_ivp

    t = dt * np.arange(len(force))
    rtol, atol, max_step = (REF_RTOL, REF_ATOL, dt) if reference else (RTOL, ATOL, 4 * dt)
    sol = solve_ivp(
        linear_rhs(accel, p, dt, force),
        (t[0], t[-1]),
        list(y0),
        method=method,
        t_eval=t,
        rtol=rtol,
        atol=atol,
        max_step=max_step,
    )
    out = np.full((2, t.size), np.nan)
    out[:, : sol.y.shape[1]] = sol.y
    return out[0], out[1]


_PURE = """
import json, sys, time
import numpy as np
sys.path.insert(0, {root!r})
from benchmarks.plain import solve_trial
from evo_door.models import get_model
from evo_door.sim.simulate import param_vector
m = get_model({model!r})
p = param_vector(m.load_params({preset!r}))
data = np.load({npz!r})
force, dt, y0 = data["force"], float(data["dt"]), data["y0"]
times, sols = {{}}, {{}}
for method in {methods!r}:
    t0 = time.perf_counter()
    theta, dtheta = solve_trial(m.accel, p, dt, force, y0, method)
    times[method] = time.perf_counter() - t0
    sols[method + "_theta"], sols[method + "_dtheta"] = theta, dtheta
np.savez({out!r}, **sols)
print(json.dumps(times))
"""


def pure_python_trials(model, preset, force, dt, y0, methods=("RK45", "LSODA")) -> dict:
    """Time ``solve_ivp`` on the model run as pure Python (``NUMBA_DISABLE_JIT=1``, a fresh
    process). Returns ``{method: (seconds, theta, dtheta)}``; a failure raises
    ``RuntimeError`` with the child's last line."""
    with tempfile.TemporaryDirectory() as tmp:
        npz, out = str(Path(tmp) / "in.npz"), str(Path(tmp) / "out.npz")
        np.savez(npz, force=np.asarray(force, float), dt=dt, y0=np.asarray(y0, float))
        code = _PURE.format(
            root=str(ROOT), model=model, preset=preset, npz=npz, out=out, methods=tuple(methods)
        )
        env = dict(os.environ, NUMBA_DISABLE_JIT="1")
        done = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=1800
        )
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or ["no output"])[-1]
            raise RuntimeError(f"pure-Python solve_ivp failed: {last}")
        times = json.loads(done.stdout.strip().splitlines()[-1])
        sols = np.load(out)
        return {
            m: (times[m], sols[m + "_theta"].copy(), sols[m + "_dtheta"].copy()) for m in methods
        }


class PlainProblem:
    """A :class:`~evo_door.optim.Problem`'s fitness computed the plain way: one
    ``solve_ivp`` (RK45, rtol 1e-6, Python right-hand side around the compiled
    ``accel``) per individual and trial, the max-square error on angular speed summed
    over trials. Drives the workbench's own DEAP-based GA, so the plain loop and the
    workbench make the same generations and differ only in how they evaluate."""

    def __init__(self, problem):
        self.problem = problem
        self.lower, self.upper, self.n_var = problem.lower, problem.upper, problem.n_var
        self.evaluations = 0
        self.seconds = 0.0

    def evaluate(self, X):
        t0 = time.perf_counter()
        model = self.problem.model
        fitness = np.zeros(len(X))
        blown = np.zeros(len(X), dtype=bool)
        for i, p in enumerate(self.problem.full(np.atleast_2d(X))):
            for tr in self.problem.fit.trials:
                _, dtheta = solve_trial(
                    model.accel, p, tr.dt, tr.force, (tr.theta0, tr.dtheta0), "RK45"
                )
                err = np.max((dtheta - tr.dtheta) ** 2)
                if not np.isfinite(err):
                    blown[i], err = True, np.inf
                fitness[i] += err
        self.evaluations += len(X)
        self.seconds += time.perf_counter() - t0
        return fitness, blown
