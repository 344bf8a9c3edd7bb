"""Mechanisms from blocks, side by side with PathSim: the same drawer in both tools.

``python -m benchmarks --only pathsim`` runs the soft-close drawer of
``examples/blocks/soft_close_drawer.yaml`` (one linear body: sign-law dry friction that
sticks and slips, a viscous damper, an end stop, a soft-close damper engaging past
0.35 m) on one trial in two tools:

- **the workbench**: the mechanism file compiled into one numba right-hand side
  (``get_model("soft_close_drawer.yaml")``), ``simulate`` with ``dopri5``;
- **PathSim** (the PyPI package, the optional extra ``bench``): the same equations
  drawn from PathSim's blocks, as a user of a block-diagram tool builds them: two
  ``Integrator`` blocks (speed, position), ``Amplifier`` blocks (the damper, 1 / mass),
  ``Adder`` blocks, ``Function`` blocks for the soft-close and end-stop laws and for the
  friction, the hand's force a ``Source`` (linear between samples, as the workbench
  takes it), a ``Scope`` sampling at the trial's rate. Stick-slip is PathSim's own event
  mechanism: a ``ZeroCrossing`` on the speed while sliding (then the drawer sticks,
  its speed set to 0, or slips the other way), a ``ZeroCrossingUp`` on |the other
  forces| - the friction level while stuck (then it slips); the soft-close engagement,
  the stop's edge and its kink are ``ZeroCrossing`` events that locate the switches.
  PathSim's explicit adaptive Dormand-Prince pair ``RKDP54`` (the workbench's method)
  and ``RKDP87``.

The trial (:func:`trial`): 2 s at 1024 Hz from fully open at rest, a 40 N push toward
closed (sin^2, 0.15 s) that slides the drawer into the soft-close, where it stops and
sticks; at 1 s a 30 N pull (0.15 s) that breaks it away again, out of the soft-close,
until it sticks once more. Both tools are checked against an independent reference,
:func:`reference`: scipy's DOP853 at rtol 1e-12, sample interval by sample interval, the
switches and stick-slip as events (at rtol 1e-10 it agrees within
``reference_spread``).

**Matched accuracy.** Each tool runs at a ladder of tolerances; the one timed is the
loosest (fastest) that is within :data:`ACCURACY` of the reference on every sample
(position and speed). **Per trial**: the median wall time of one simulation (warm: the
workbench's numba compile and PathSim's first run are timed apart). **Per GA
evaluation**: the workbench's own evaluation path, ``Problem.evaluate`` of a population
of :data:`POPULATION` random candidates (mass, friction, damper, soft-close free) on
the trial, per candidate; PathSim: the diagram built once and re-parameterised (the
gains and the laws' parameters set, ``Simulation.reset``, ``run``), one simulation per
candidate, the same objective computed on its speeds, timed on a few candidates.

Size: the PathSim diagram, the scipy reference and the page are one comparison, kept
together so that the equations written three times can be read side by side.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
MECHANISM = ROOT / "examples" / "blocks" / "soft_close_drawer.yaml"

DT = 1.0 / 1024.0  # s: the trial's sample time
SECONDS = 2.0  # s
#: the hand: (start s, width s, amplitude N, + toward closed), each a sin^2 pulse
PULSES = ((0.0, 0.15, 40.0), (1.0, 0.15, -30.0))
#: matched accuracy: max |position error| (m) and max |speed error| (m/s) on the samples
ACCURACY = (1e-6, 1e-5)
#: the tolerances tried: the workbench's dopri5, PathSim's (relative; absolute 1e-3 of it)
WORKBENCH_TOLS = (1e-5, 1e-7, 1e-9)
WORKBENCH_SUBSTEPS = (1, 2, 4)  # steps of at most one sample / 1, 2, 4 (4: the default)
PATHSIM_TOLS = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9)
PATHSIM_SOLVERS = ("RKDP54", "RKDP87")
#: the GA evaluation: population, the free parameters and their bounds
POPULATION = 100
FREE = {
    "box.mass": (1.0, 9.0),
    "runners.level": (0.2, 4.0),
    "grease.c": (0.5, 10.0),
    "softie.c_fluid": (10.0, 300.0),
}
#: the speed-up the issue asks of the workbench, per trial at matched accuracy
RATIO_TARGET = 100.0
#: --quick: a shorter trial (the push only), fewer settings and repeats
QUICK_SECONDS = 0.8


def available() -> str | None:
    """None when PathSim can be imported, else the one-line reason to skip."""
    try:
        import pathsim  # noqa: F401
    except ImportError:
        return "PathSim is not installed (pip install -c constraints.txt -e '.[bench]')"
    return None


# -- the trial ----------------------------------------------------------------------------
def trial(seconds: float = SECONDS):
    """``(t, force)``: the hand's force (N) sampled at 1 / :data:`DT`."""
    t = DT * np.arange(int(round(seconds / DT)))
    force = np.zeros_like(t)
    for start, width, amp in PULSES:
        on = (t >= start) & (t < start + width)
        force[on] = amp * np.sin(np.pi * (t[on] - start) / width) ** 2
    return t, force


def drawer():
    from evo_door.models import get_model

    return get_model(str(MECHANISM))


def contact_force(p: dict, x: float, v: float) -> float:
    """The soft-close and the end stop on the drawer (N), the laws of docs/blocks.md."""
    f = 0.0
    if x > p["softie.engage"]:
        f += p["softie.pull"] - p["softie.c_fluid"] * v
    if x > p["stop.at"]:
        f += min(-p["stop.k"] * (x - p["stop.at"]) - p["stop.c"] * v, 0.0)
    return f


# -- the independent reference ------------------------------------------------------------
def reference(p: dict, t, force, rtol: float = 1e-12):
    """``(x, v)`` at ``t`` from rest at 0: scipy DOP853, sample interval by sample
    interval (the force linear in each), a mode per stretch: stuck (the drawer still
    while |hand + contacts| <= the friction level, the break-away time solved exactly
    on the linear force) or sliding one way (events: the speed reaching 0, then it
    sticks or slips back; the soft-close engagement, the stop's edge and kink)."""
    from scipy.integrate import solve_ivp

    level, c, m = p["runners.level"], p["grease.c"], p["box.mass"]
    y = np.array([0.0, 0.0])
    mode = 0  # 0 stuck, +1 / -1 sliding toward closed / open
    out = np.empty((t.size, 2))
    out[0] = y

    def events_of(direction):
        def halt(s, y):
            return y[1]

        def engage(s, y):
            return y[0] - p["softie.engage"]

        def edge(s, y):
            return y[0] - p["stop.at"]

        def kink(s, y):
            return -p["stop.k"] * (y[0] - p["stop.at"]) - p["stop.c"] * y[1]

        for e in (halt, engage, edge, kink):
            e.terminal = True
        return (halt, engage, edge, kink)

    for k in range(t.size - 1):
        ta, tb = t[k], t[k + 1]
        slope = (force[k + 1] - force[k]) / DT

        def hand(s, ta=ta, f0=force[k], slope=slope):
            return f0 + slope * (s - ta)

        s = ta
        while s < tb:
            if mode == 0:
                rest = contact_force(p, y[0], 0.0)
                fa, fb = hand(s) + rest, hand(tb) + rest
                if abs(fb) <= level and abs(fa) <= level:
                    break
                if abs(fa) > level:
                    mode = 1 if fa > 0 else -1
                else:  # the force reaches the level within the interval: linear in time
                    edge_level = level if fb > 0 else -level
                    s = s + (edge_level - fa) / (fb - fa) * (tb - s)
                    mode = 1 if fb > 0 else -1
                continue

            def rhs(s, y, mode=mode):
                return (y[1], (hand(s) - level * mode - c * y[1] + contact_force(p, *y)) / m)

            evs = [e for e in events_of(mode) if abs(e(s, y)) > 1e-13]
            sol = solve_ivp(
                rhs, (s, tb), y, method="DOP853", rtol=rtol, atol=rtol * 1e-3, events=evs
            )
            y, s = sol.y[:, -1].copy(), float(sol.t[-1])
            if sol.status == 1 and any(
                e.__name__ == "halt" and te.size for e, te in zip(evs, sol.t_events)
            ):
                y[1] = 0.0
                other = hand(s) + contact_force(p, y[0], 0.0)
                mode = 0 if abs(other) <= level else (1 if other > 0 else -1)
        out[k + 1] = y
    return out[:, 0], out[:, 1]


def errors(x, v, ref) -> tuple[float, float]:
    return float(np.abs(x - ref[0]).max()), float(np.abs(v - ref[1]).max())


# -- the workbench ------------------------------------------------------------------------
def workbench_run(model, params, force, tol, substeps=None):
    from evo_door.sim import simulate

    r = simulate(
        model, params, force, DT, theta0=0.0, method="dopri5", tolerance=tol, substeps=substeps
    )
    return r.theta, r.dtheta


# -- PathSim ------------------------------------------------------------------------------
class PathSimDrawer:
    """The drawer as a PathSim block diagram, built once; :meth:`run` re-parameterises it
    (gains and the laws' parameters), resets and runs it."""

    def __init__(self, p: dict, t, force, solver: str = "RKDP54", tol: float = 1e-6):
        # long: one block diagram, its blocks, connections and events, read in one place
        import pathsim.solvers as solvers
        from pathsim import Connection, Simulation
        from pathsim.blocks import Adder, Amplifier, Function, Integrator, Scope, Source
        from pathsim.events import ZeroCrossing, ZeroCrossingUp

        self.p = dict(p)
        self.n = t.size
        self.duration = float(t[-1])
        f = np.asarray(force, dtype=float)
        rate, last = 1.0 / DT, t.size - 2

        def hand(s):  # the force linear between samples, as the workbench takes it
            u = s * rate
            k = min(int(u), last)
            return f[k] + (f[k + 1] - f[k]) * (u - k)

        self.mode = 0  # 0 stuck, +1 / -1 sliding
        P = self.p
        self.src = Source(hand)
        self.position = Integrator(0.0)
        self.speed = Integrator(0.0)
        self.damper = Amplifier(-P["grease.c"])
        self.soft = Function(
            lambda x, v: (
                P["softie.pull"] - P["softie.c_fluid"] * v if x > P["softie.engage"] else 0.0
            )
        )
        self.stop = Function(
            lambda x, v: (
                min(-P["stop.k"] * (x - P["stop.at"]) - P["stop.c"] * v, 0.0)
                if x > P["stop.at"]
                else 0.0
            )
        )
        self.others = Adder()  # hand + damper + soft-close + stop
        self.friction = Function(
            lambda other: -other if self.mode == 0 else -P["runners.level"] * self.mode
        )
        self.total = Adder()
        self.inverse_mass = Amplifier(1.0 / P["box.mass"])
        self.scope = Scope(sampling_period=DT)
        blocks = [
            self.src, self.position, self.speed, self.damper, self.soft, self.stop,
            self.others, self.friction, self.total, self.inverse_mass, self.scope,
        ]  # fmt: skip
        x, v = self.position, self.speed
        connections = [
            Connection(self.src, self.others[0]),
            Connection(v, self.damper, self.soft[1], self.stop[1], self.scope[1]),
            Connection(x, self.soft[0], self.stop[0], self.scope[0]),
            Connection(self.damper, self.others[1]),
            Connection(self.soft, self.others[2]),
            Connection(self.stop, self.others[3]),
            Connection(self.others, self.friction, self.total[0]),
            Connection(self.friction, self.total[1]),
            Connection(self.total, self.inverse_mass),
            Connection(self.inverse_mass, v),
            Connection(v, x),
        ]

        def other():
            return float(self.others.outputs[0])

        def slip(_t):
            self.mode = 1 if other() > 0 else -1
            self.slip.off()
            self.stick.on()

        def stick(_t):
            if abs(other()) <= P["runners.level"]:
                self.mode = 0
                self.speed.engine.state = 0.0
                self.stick.off()
                self.slip.on()
            else:
                self.mode = 1 if other() > 0 else -1

        tol_evt = tol * 1e-3
        self.slip = ZeroCrossingUp(
            func_evt=lambda _t: abs(other()) - P["runners.level"], func_act=slip, tolerance=tol_evt
        )
        self.stick = ZeroCrossing(
            func_evt=lambda _t: float(v.outputs[0]), func_act=stick, tolerance=tol_evt
        )
        switches = [
            ZeroCrossing(
                func_evt=lambda _t: float(x.outputs[0]) - P["softie.engage"], tolerance=tol_evt
            ),
            ZeroCrossing(func_evt=lambda _t: float(x.outputs[0]) - P["stop.at"], tolerance=tol_evt),
            ZeroCrossing(
                func_evt=lambda _t: (
                    -P["stop.k"] * (float(x.outputs[0]) - P["stop.at"])
                    - P["stop.c"] * float(v.outputs[0])
                ),
                tolerance=tol_evt,
            ),
        ]
        self.sim = Simulation(
            blocks,
            connections,
            [self.slip, self.stick, *switches],
            dt=DT,
            dt_max=DT,
            Solver=getattr(solvers, solver),
            tolerance_lte_rel=tol,
            tolerance_lte_abs=tol * 1e-3,
            log=False,
        )

    def run(self, params: dict | None = None):
        """``(x, v)`` at the trial's samples, from rest at 0, at ``params`` (the
        parameters it was built with where not given)."""
        if params:
            self.p.update(params)
        self.damper.gain = -self.p["grease.c"]
        self.inverse_mass.gain = 1.0 / self.p["box.mass"]
        self.sim.reset()
        self.mode = 0
        self.stick.off()
        self.sim.run(self.duration + 0.5 * DT)
        ts, data = self.scope.read()
        if ts.size < self.n or abs(ts[self.n - 1] - (self.n - 1) * DT) > 1e-9:
            raise RuntimeError(f"PathSim's scope recorded {ts.size} samples, not {self.n}")
        return data[0][: self.n], data[1][: self.n]


# -- the measurement --------------------------------------------------------------------------
def ladder(run, settings, ref, repeat: int, screen: int = 1, first_only: bool = False):
    """Each setting's errors and time (the median of ``screen`` runs); the fastest
    setting within :data:`ACCURACY` timed again (median of ``repeat``) and marked
    ``timed``. With ``first_only`` the settings (loosest first) stop at the first that
    matches."""
    from benchmarks._util import median_time

    rows = []
    for setting in settings:
        t0 = time.perf_counter()
        x, v = run(setting)
        once = time.perf_counter() - t0
        if screen > 1:
            once = median_time(lambda setting=setting: run(setting), screen)
        ex, ev = errors(x, v, ref)
        ok = ex <= ACCURACY[0] and ev <= ACCURACY[1]
        rows.append(
            {"setting": setting, "error_x": ex, "error_v": ev, "matched": ok, "seconds": once}
        )
        if ok and first_only:
            break
    good = [r for r in rows if r["matched"]]
    if good:
        best = min(good, key=lambda r: r["seconds"])
        best["seconds"] = median_time(lambda: run(best["setting"]), repeat)
        best["timed"] = True
    return rows


def interleaved(workbench, pathsim, pairs: int) -> dict:
    """The two timed settings run in turn, ``pairs`` times (the workbench's time of a pair
    the median of 5 calls): the median of the pairs' ratios, which a load that comes
    and goes on a shared machine moves less than a ratio of medians taken apart."""
    from benchmarks._util import median_time

    wb, ps = [], []
    for _ in range(pairs):
        wb.append(median_time(workbench, 5))
        t0 = time.perf_counter()
        pathsim()
        ps.append(time.perf_counter() - t0)
    ratios = np.array(ps) / np.array(wb)
    return {
        "pairs": pairs,
        "ratio": float(np.median(ratios)),
        "ratio_range": (float(ratios.min()), float(ratios.max())),
        "workbench": float(np.median(wb)),
        "pathsim": float(np.median(ps)),
    }


def ga_workbench(model, params, t, force, target, setting, repeat: int) -> dict:
    """``Problem.evaluate`` of a population on the trial (max square speed error), the GA's
    own evaluation path: seconds per candidate."""
    from evo_door.data.trial import Trial
    from evo_door.optim import Objective, Problem

    tr = Trial(
        t, force, target[0], target[1], np.gradient(target[1], DT), trial_id="drawer",
        theta0=0.0, dtheta0=0.0,
    )  # fmt: skip
    free = list(FREE)
    lo, hi = zip(*FREE.values())
    substeps, tol = setting
    problem = Problem(
        model, free, lo, hi, params.vector, [tr], Objective("max_square", 1),
        method="dopri5", substeps=substeps, tolerance=tol, model_name=model.name,
    )  # fmt: skip
    X = np.random.default_rng(39).uniform(lo, hi, (POPULATION, len(free)))
    problem.evaluate(X[:2])
    from benchmarks._util import median_time

    secs = median_time(lambda: problem.evaluate(X), repeat)
    fit = problem.evaluate(X)[0]
    return {"per_candidate": secs / POPULATION, "X": X, "fitness": np.asarray(fit, float)}


def ga_pathsim(drawer_ps, X, target, count: int) -> dict:
    """One PathSim simulation per candidate (the diagram built once, re-parameterised),
    the same objective on its speeds: seconds per candidate over ``count`` candidates."""
    free = list(FREE)
    fits, t0 = [], time.perf_counter()
    for row in X[:count]:
        _, v = drawer_ps.run(dict(zip(free, map(float, row))))
        fits.append(float(np.max((v - target[1]) ** 2)))
    return {"per_candidate": (time.perf_counter() - t0) / count, "fitness": np.array(fits)}


def measure(quick: bool) -> dict:
    """Every figure of the section (see the module's docstring)."""
    import pathsim

    model = drawer()
    params = model.load_params()
    p = params.as_dict()
    t, force = trial(QUICK_SECONDS if quick else SECONDS)
    t0 = time.perf_counter()
    ref = reference(p, t, force)
    ref_seconds = time.perf_counter() - t0
    coarse = reference(p, t, force, rtol=1e-10)
    spread = errors(coarse[0], coarse[1], ref)
    t0 = time.perf_counter()
    workbench_run(model, params, force, 1e-9, 4)
    compile_seconds = time.perf_counter() - t0
    wb = ladder(
        lambda st: workbench_run(model, params, force, st[1], st[0]),
        [(sub, tol) for sub in WORKBENCH_SUBSTEPS for tol in WORKBENCH_TOLS],
        ref,
        11 if quick else 51,
        screen=3 if quick else 7,
    )
    built = {}

    def ps_run(setting):
        if setting not in built:
            built[setting] = PathSimDrawer(p, t, force, *setting)
        return built[setting].run()

    ps = {}
    for solver in PATHSIM_SOLVERS[:1] if quick else PATHSIM_SOLVERS:
        tols = PATHSIM_TOLS[2:4] if quick else PATHSIM_TOLS
        ps[solver] = ladder(
            ps_run, [(solver, tol) for tol in tols], ref, 1 if quick else 5, first_only=quick
        )
    best = {s: r for s, rows in ps.items() for r in rows if r.get("timed")}
    best_solver = min(best, key=lambda s: best[s]["seconds"], default=None)
    wb_best = next((r for r in wb if r.get("timed")), None)
    ga = paired = None
    if best_solver is not None and wb_best is not None:
        paired = interleaved(
            lambda: workbench_run(
                model, params, force, wb_best["setting"][1], wb_best["setting"][0]
            ),
            lambda: ps_run(best[best_solver]["setting"]),
            3 if quick else 7,
        )
        ga_wb = ga_workbench(model, params, t, force, ref, wb_best["setting"], 3 if quick else 11)
        drawer_ps = PathSimDrawer(p, t, force, *best[best_solver]["setting"])
        ga_ps = ga_pathsim(drawer_ps, ga_wb["X"], ref, 2 if quick else 10)
        ga = {"workbench": ga_wb, "pathsim": ga_ps, "solver": best_solver}
    return {
        "quick": quick,
        "seconds": float(t[-1] + DT),
        "samples": t.size,
        "reference_seconds": ref_seconds,
        "reference_spread": spread,
        "compile_seconds": compile_seconds,
        "workbench": wb,
        "pathsim": ps,
        "pathsim_best": best_solver,
        "paired": paired,
        "ga": ga,
        "versions": {"pathsim": getattr(pathsim, "__version__", "?")},
        "travel": (float(ref[0].min()), float(ref[0].max())),
        "load": _load(),
    }


def _load() -> str:
    try:
        import os

        return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "load average n/a"


def per_trial(result: dict) -> tuple[dict | None, dict | None]:
    """The workbench's and PathSim's timed rows at matched accuracy (None: none matched)."""
    wb = next((r for r in result["workbench"] if r.get("timed")), None)
    s = result["pathsim_best"]
    ps = next((r for r in result["pathsim"][s] if r.get("timed")), None) if s else None
    return wb, ps


def trial_ratio(result: dict) -> float | None:
    """PathSim's time / the workbench's per trial at matched accuracy: the median of the
    interleaved pairs' ratios."""
    return result["paired"]["ratio"] if result.get("paired") else None


def equal_accuracy(result: dict):
    """PathSim's fastest setting (by its one timed run) at least as accurate as the
    workbench's timed one, and that run's time / the workbench's (None: none was)."""
    wb, _ = per_trial(result)
    if wb is None:
        return None, None
    rows = [
        r
        for each in result["pathsim"].values()
        for r in each
        if r["error_x"] <= wb["error_x"] and r["error_v"] <= wb["error_v"]
    ]
    if not rows:
        return None, None
    r = min(rows, key=lambda r: r["seconds"])
    return r, r["seconds"] / wb["seconds"]


# -- the page ---------------------------------------------------------------------------------
def _ms(s: float) -> str:
    return f"{s * 1e3:.3g} ms"


def setting_text(tool: str, setting) -> str:
    if tool == "workbench":
        sub, tol = setting
        return f"dopri5 tol {tol:.0e}, {sub} sub-step{'s' * (sub > 1)}"
    return f"{setting[0]} tol {setting[1]:.0e}"


def markdown(result: dict) -> str:
    """The section's tables."""
    # long: the page's sentences and tables, in the order they are read
    wb, ps = per_trial(result)
    lines = [
        "The soft-close drawer of `examples/blocks/soft_close_drawer.yaml` (sign-law dry "
        "friction that sticks and slips, damper, end stop, soft-close past 0.35 m), the same "
        "equations in the workbench (the mechanism file compiled into one numba right-hand "
        f"side, `simulate`, dopri5) and in PathSim {result['versions']['pathsim']} (the "
        "diagram drawn from its blocks: integrators, amplifiers, adders, function blocks for "
        "the nonlinear laws, its zero-crossing events for stick-slip and the switches, the "
        "force a source linear between samples, a scope at the trial's rate; "
        "`benchmarks/bench_pathsim.py`). "
        f"One {result['seconds']:g} s trial at {1 / DT:g} Hz from rest"
        + (
            ": a 40 N push into the soft-close, where the drawer sticks, then a 30 N pull out of it"
            if not result["quick"]
            else " (--quick: the push only; a smoke run, not a measurement)"
        )
        + f" (travel {result['travel'][0]:.3g} .. {result['travel'][1]:.4g} m). Errors: max "
        "over the samples against scipy DOP853 at rtol 1e-12, sample interval by sample "
        "interval, the switches and stick-slip as events (at rtol 1e-10 it differs by "
        f"{result['reference_spread'][0]:.1g} m, {result['reference_spread'][1]:.1g} m/s). "
        f"Matched accuracy: within {ACCURACY[0]:g} m and {ACCURACY[1]:g} m/s on every sample; "
        "each tool runs once at each setting (the workbench: dopri5 at each tolerance with "
        "steps of at most 1, 1/2, 1/4 sample; PathSim: each solver at each relative tolerance, "
        "absolute 1e-3 of it, events located within 1e-3 of it, steps of at most one sample), "
        "and the fastest setting that matches is timed again: **bold**, the median of "
        "repeats, warm. "
        f"The workbench's first call (numba's compile or cache load) took "
        f"{result['compile_seconds']:.3g} s, apart. Measured at {result['load']}.",
        "",
        "| tool | setting | max position error | max speed error | matched | per trial |",
        "|---|---|---:|---:|---|---:|",
    ]
    rows = [("workbench", r) for r in result["workbench"]]
    rows += [("PathSim", r) for each in result["pathsim"].values() for r in each]
    for tool, r in rows:
        secs = f"**{_ms(r['seconds'])}**" if r.get("timed") else f"{_ms(r['seconds'])} (once)"
        lines.append(
            f"| {tool} | {setting_text(tool, r['setting'])} | {r['error_x']:.2g} m | "
            f"{r['error_v']:.2g} m/s | {'yes' if r['matched'] else 'no'} | {secs} |"
        )
    lines.append("")
    if wb and ps:
        lines.append(
            f"Per trial at matched accuracy: the workbench {_ms(wb['seconds'])} "
            f"({setting_text('workbench', wb['setting'])}; errors {wb['error_x']:.2g} m, "
            f"{wb['error_v']:.2g} m/s) against PathSim's {_ms(ps['seconds'])} "
            f"({setting_text('PathSim', ps['setting'])}; errors {ps['error_x']:.2g} m, "
            f"{ps['error_v']:.2g} m/s): **{trial_ratio(result):.3g}x** (target "
            f">= {RATIO_TARGET:g}x): the median ratio of {result['paired']['pairs']} runs of "
            "the two in turn (from "
            + " to ".join(f"{x:.3g}x" for x in result["paired"]["ratio_range"])
            + f"; medians {_ms(result['paired']['workbench'])} and "
            f"{_ms(result['paired']['pathsim'])})."
        )
        same, ratio = equal_accuracy(result)
        lines.append("")
        lines.append(
            "The workbench's loosest setting is already well inside the bound. "
            + (
                f"PathSim at least as accurate as it ({setting_text('PathSim', same['setting'])}"
                f": {same['error_x']:.2g} m, {same['error_v']:.2g} m/s) took "
                f"{_ms(same['seconds'])} in its one run: {ratio:.3g}x."
                if same
                else "No PathSim setting tried was as accurate."
            )
        )
    else:
        lines.append("No setting of one of the tools met the accuracy: no ratio.")
    ga = result["ga"]
    if ga:
        w, s = ga["workbench"], ga["pathsim"]
        agree = np.abs(w["fitness"][: s["fitness"].size] - s["fitness"])
        lines += [
            "",
            f"Per GA evaluation: the workbench's `Problem.evaluate` (the GA's own path, at the "
            f"setting above) of {POPULATION} random candidates ("
            + ", ".join(f"{n} in [{lo:g}, {hi:g}]" for n, (lo, hi) in FREE.items())
            + ") on the trial, max square speed error against the reference, per candidate: "
            f"{_ms(w['per_candidate'])}; PathSim ({ga['solver']}), the diagram built once and "
            f"re-parameterised, one simulation per candidate, timed on "
            f"{s['fitness'].size}: {_ms(s['per_candidate'])} per candidate: "
            f"**{s['per_candidate'] / w['per_candidate']:.3g}x**. The two fitnesses agree "
            f"within {agree.max():.2g} (m/s)^2 on those candidates.",
        ]
    return "\n".join(lines)


def main() -> None:  # pragma: no cover - run by hand
    reason = available()
    if reason:
        print(f"bench_pathsim: skipped: {reason}")
        return
    print(markdown(measure(quick=False)))


if __name__ == "__main__":  # pragma: no cover
    main()
