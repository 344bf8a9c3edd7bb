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
from dataclasses import dataclass
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


class TimeLimit(Exception):
    """A ``solve_ivp`` run stopped because it took longer than its time limit."""


@dataclass
class PlainRun:
    """One ``solve_ivp`` run over a sampled trial.

    ``theta`` (rad) and ``dtheta`` (rad/s) at the samples, NaN from where the solver
    stopped; ``seconds`` its wall time; ``reached`` how far into the trial it got (s,
    the latest time it asked the right-hand side for); ``stopped`` why it did not reach
    the end ("" when it did): the solver's message, or ``"time limit"``.
    """

    theta: np.ndarray
    dtheta: np.ndarray
    seconds: float
    reached: float
    stopped: str = ""

    @property
    def complete(self) -> bool:
        return not self.stopped


def run_plain(accel, p, dt, force, y0, method, rtol=RTOL, atol=None, time_limit=None):
    """``solve_ivp`` over a sampled trial, the plain way: rtol ``rtol`` (default 1e-6),
    atol ``atol`` (default ``rtol`` / 1000, 1e-9 at the default), a step of at most 4
    samples; stopped after ``time_limit`` seconds of this process's CPU time if given
    (a dry friction's sign law can make a solver chatter at rest for minutes; CPU time,
    so that other processes on the machine do not move the cut)."""
    from scipy.integrate import solve_ivp

    t = dt * np.arange(len(force))
    rhs = linear_rhs(accel, p, dt, force)
    latest = [t[0]]
    deadline = np.inf if time_limit is None else time.process_time() + time_limit
    t0 = time.perf_counter()

    def limited(time_, y):
        latest[0] = max(latest[0], time_)
        if time.process_time() > deadline:
            raise TimeLimit
        return rhs(time_, y)

    out = np.full((2, t.size), np.nan)
    try:
        sol = solve_ivp(
            limited,
            (t[0], t[-1]),
            list(y0),
            method=method,
            t_eval=t,
            rtol=rtol,
            atol=rtol * 1e-3 if atol is None else atol,
            max_step=4 * dt,
        )
    except TimeLimit:
        return PlainRun(out[0], out[1], time.perf_counter() - t0, latest[0], "time limit")
    seconds = time.perf_counter() - t0
    out[:, : sol.y.shape[1]] = sol.y
    stopped = "" if sol.status == 0 else " ".join(str(sol.message).split())
    return PlainRun(out[0], out[1], seconds, latest[0], stopped)


def solve_trial(accel, p, dt, force, y0, method, reference=False):
    """``solve_ivp`` over a sampled trial; returns ``(theta, dtheta)`` at the samples
    (NaN where the solver stopped early).

    ``reference`` uses the test suite's tolerances (rtol 1e-10, atol 1e-12, a step of
    at most one sample); otherwise rtol 1e-6, atol 1e-9, a step of at most 4 samples.
    """
    from scipy.integrate import solve_ivp

    if not reference:
        run = run_plain(accel, p, dt, force, y0, method)
        return run.theta, run.dtheta
    t = dt * np.arange(len(force))
    sol = solve_ivp(
        linear_rhs(accel, p, dt, force),
        (t[0], t[-1]),
        list(y0),
        method=method,
        t_eval=t,
        rtol=REF_RTOL,
        atol=REF_ATOL,
        max_step=dt,
    )
    out = np.full((2, t.size), np.nan)
    out[:, : sol.y.shape[1]] = sol.y
    return out[0], out[1]


_PURE = """
import json, sys
import numpy as np
sys.path.insert(0, {root!r})
from benchmarks.plain import run_plain
from evo_door.models import get_model
from evo_door.sim.simulate import param_vector
m = get_model({model!r})
p = param_vector(m.load_params({preset!r}))
data = np.load({npz!r})
force, dt, y0 = data["force"], float(data["dt"]), data["y0"]
runs, sols = {{}}, {{}}
for method in {methods!r}:
    run = run_plain(m.accel, p, dt, force, y0, method, time_limit={limit!r})
    runs[method] = {{"seconds": run.seconds, "reached": run.reached, "stopped": run.stopped}}
    sols[method + "_theta"], sols[method + "_dtheta"] = run.theta, run.dtheta
np.savez({out!r}, **sols)
print(json.dumps(runs))
"""


def pure_python_runs(
    model, preset, force, dt, y0, methods=("RK45", "LSODA"), time_limit=None
) -> dict:
    """``solve_ivp`` (rtol 1e-6) on the model run as pure Python (``NUMBA_DISABLE_JIT=1``,
    a fresh process), each method stopped after ``time_limit`` s if given. Returns
    ``{method: PlainRun}``; a failure of the process raises ``RuntimeError`` with the
    child's last line."""
    with tempfile.TemporaryDirectory() as tmp:
        npz, out = str(Path(tmp) / "in.npz"), str(Path(tmp) / "out.npz")
        np.savez(npz, force=np.asarray(force, float), dt=dt, y0=np.asarray(y0, float))
        code = _PURE.format(
            root=str(ROOT),
            model=model,
            preset=preset,
            npz=npz,
            out=out,
            methods=tuple(methods),
            limit=time_limit,
        )
        env = dict(os.environ, NUMBA_DISABLE_JIT="1")
        done = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=1800
        )
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or ["no output"])[-1]
            raise RuntimeError(f"pure-Python solve_ivp failed: {last}")
        runs = json.loads(done.stdout.strip().splitlines()[-1])
        sols = np.load(out)
        return {
            m: PlainRun(sols[m + "_theta"].copy(), sols[m + "_dtheta"].copy(), **runs[m])
            for m in methods
        }


def pure_python_trials(model, preset, force, dt, y0, methods=("RK45", "LSODA")) -> dict:
    """:func:`pure_python_runs` as ``{method: (seconds, theta, dtheta)}``."""
    runs = pure_python_runs(model, preset, force, dt, y0, methods)
    return {m: (r.seconds, r.theta, r.dtheta) for m, r in runs.items()}


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
