"""An FMU as the model: evo-door's evaluations against FMPy's ``simulate_fmu``.

``python -m benchmarks --only fmu`` builds the project's door FMU (FMI 2.0, the tuned
layout, model exchange and co-simulation in one: ``examples/fmu``) into a temporary
folder and measures two things.

**One trial.** A 2 s trial at 1024 Hz (a 20 N half-sine push of 0.15 s from fully
open), its target made by FMPy's co-simulation at the true parameters :data:`TRUTH`.
One evaluation is the objective of one candidate (the truth) on it:

- the workbench's way: ``Problem.evaluate`` on the FMU model, in this process
  (sandbox off) and through the sandbox process (on, the default for an FMU), the FMU
  instance reused across evaluations;
- the plain way: what a user of FMPy writes in a fitness function, one
  ``simulate_fmu(path, start_values=..., input=...)`` per evaluation, the force given
  as a staircase (FMPy's model exchange applies it exactly only so: see
  ``examples/fmu/README.md``), model exchange at several CVode tolerances.

Each way's response is checked against an independent reference: scipy's DOP853 at
rtol 1e-10 of the FMU's equation of motion (written again here from the README),
restarted at every sample, with the force as that way applies it: linear between
samples for the workbench's model exchange, held over each sample for its
co-simulation and for FMPy. The plain setting the ratio is taken against is the
loosest tolerance within :data:`MATCH_FACTOR` times the workbench's error (or, when
none is, the most accurate tried: the ratio is then a lower bound).

**A GA.** ``evo-door run EXP.yaml`` (the ``local`` executor: one sandbox process per
core, each with a part of every batch) in a fresh process, as a user types it:
population 100 x 20 generations (``--quick``: 8 x 2) on the co-simulation (the
trials' own force convention), three free parameters, on two trials made by FMPy at
:data:`TRUTH` (pushes of 20 N and 15 N); its wall time, evaluations and each
estimate's error against the truth, and the plain way's cost extrapolated:
evaluations x FMPy's time per call / 2 cores.

A measured run writes ``benchmarks/fmu.md``. Needs CMake and a C compiler (the FMU is
built from source) and FMPy.
"""

from __future__ import annotations

import cProfile
import importlib.util
import io
import math
import pstats
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
BUILD_SCRIPT = ROOT / "examples" / "fmu" / "build.py"

DT = 1.0 / 1024.0  # s: the trials' sample time
SECONDS = 2.0  # s: one trial
PUSH_WIDTH = 0.15  # s: the half-sine push
#: the push of the timed trial, then the GA's second trial (N, toward closing)
PUSHES = (20.0, 15.0)
#: the parameters that make the trials (the others at the FMU's start values)
TRUTH = {"inertia": 0.9, "spring_stiffness": 8.3, "damping": 1.1}
#: the GA's search bounds
BOUNDS = {"inertia": (0.45, 1.8), "spring_stiffness": (4.0, 16.0), "damping": (0.4, 2.2)}
#: FMPy's model-exchange tolerances tried (None: FMPy's default)
RTOLS = (None, 1e-7, 1e-9, 1e-10)
#: a plain setting matches the workbench when its max |theta error| is within this factor
MATCH_FACTOR = 10.0
#: the GA: (population, generations), measured and --quick
GA_SIZE, GA_QUICK = (100, 20), (8, 2)
CORES = 2


# -- the FMU and the trials -----------------------------------------------------------
def load_build():
    """``examples/fmu/build.py`` as a module (it is no package)."""
    name = "door_fmu_build"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, BUILD_SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def build(folder: Path) -> Path:
    """The door FMU, FMI 2.0, tuned layout, both interfaces, built into ``folder``."""
    return load_build().build_fmu(
        folder / "door2.fmu", fmi=2, layout="tuned", interfaces=("me", "cs"), force=True
    )


def push(amplitude: float):
    """``(t, force)``: a half-sine push of ``amplitude`` N from t = 0, on a 2 s trial."""
    from benchmarks._util import half_sine_pulses

    t = np.arange(int(round(SECONDS / DT))) * DT
    return t, half_sine_pulses(t, ((0.0, PUSH_WIDTH, amplitude),))


def staircase(t, force, name="force") -> np.ndarray:
    """The force held over each sample, as FMPy's input signal (each time twice)."""
    ts = np.repeat(t, 2)[1:]
    fs = np.repeat(force, 2)[:-1]
    return np.array(list(zip(ts, fs)), dtype=[("time", np.float64), (name, np.float64)])


def start_values(changed: dict) -> dict:
    """Every parameter of the FMU: its start value, or the one ``changed`` gives."""
    return {p.name: float(changed.get(p.name, p.start)) for p in load_build().PARAMETERS}


# -- the independent reference -----------------------------------------------------------
def door_accel(theta, omega, force, p) -> float:
    """The FMU's equation of motion (rad/s^2), from examples/fmu/README.md."""
    torque = (
        p["lever_arm"] * force
        + p["spring_preload"]
        + p["spring_stiffness"] * (math.pi / 2 - theta)
        - p["weight_moment"] * math.cos(theta)
        - p["damping"] * omega
        - p["friction"] * math.tanh(omega / p["friction_speed"])
    )
    if theta < 0.0:
        torque += -p["stop_stiffness"] * theta - p["stop_damping"] * omega
    elif theta > math.pi / 2:
        torque += -p["stop_stiffness"] * (theta - math.pi / 2) - p["stop_damping"] * omega
    return torque / p["inertia"]


def reference(values: dict, t, force, hold: bool):
    """``(theta, dtheta)`` at ``t`` from fully open at rest: scipy DOP853 at rtol 1e-10,
    restarted at every sample; the force held over each sample (``hold``) or linear
    between samples."""
    from scipy.integrate import solve_ivp

    p = start_values(values)
    y = np.array([0.0, 0.0])
    out = np.empty((t.size, 2))
    out[0] = y
    for k in range(t.size - 1):
        f0 = force[k]
        slope = 0.0 if hold else (force[k + 1] - force[k]) / DT
        t0 = t[k]

        def rhs(s, y, f0=f0, slope=slope, t0=t0):
            return (y[1], door_accel(y[0], y[1], f0 + slope * (s - t0), p))

        y = solve_ivp(rhs, (t[k], t[k + 1]), y, method="DOP853", rtol=1e-10, atol=1e-12).y[:, -1]
        out[k + 1] = y
    return out[:, 0], out[:, 1]


# -- the plain way --------------------------------------------------------------------
def fmpy_run(fmu, interface: str, values: dict, t, force, rtol=None, model_description=None):
    """``(theta, dtheta)`` at ``t``: one ``fmpy.simulate_fmu`` call (``fmu`` a file or
    an extracted folder), the force as a staircase."""
    from fmpy import simulate_fmu

    res = simulate_fmu(
        str(fmu),
        start_time=0.0,
        stop_time=float(t[-1]),
        fmi_type="ModelExchange" if interface == "me" else "CoSimulation",
        start_values=values,
        input=staircase(t, force),
        output=["theta", "dtheta"],
        output_interval=DT,
        relative_tolerance=rtol,
        model_description=model_description,
    )
    # model exchange records twice at each input step: the last row at each sample
    rows = np.searchsorted(res["time"], t, side="right") - 1
    return res["theta"][rows], res["dtheta"][rows]


def plain_fitness(fmu, interface, free, t, force, target, rtol=None, model_description=None):
    """The fitness function a user of FMPy writes: candidate -> max square dtheta error."""

    def fitness(x) -> float:
        _, dtheta = fmpy_run(
            fmu, interface, dict(zip(free, map(float, x))), t, force, rtol, model_description
        )
        return float(np.max((dtheta - target) ** 2))

    return fitness


# -- the workbench's way ----------------------------------------------------------------
def make_trial(fmu, amplitude: float, model_name: str, trial_id: str):
    """A trial made by FMPy's co-simulation at :data:`TRUTH`, the truth stored with it."""
    from evo_door.data.trial import Trial

    t, f = push(amplitude)
    theta, dtheta = fmpy_run(fmu, "cs", TRUTH, t, f)
    return Trial(
        t,
        f,
        theta,
        dtheta,
        np.gradient(dtheta, DT),
        trial_id=trial_id,
        theta0=0.0,
        dtheta0=0.0,
        truth={"model": model_name, "params": dict(TRUTH)},
        source="FMPy co-simulation of the door FMU",
    )


def make_problem(spec: str, trials):
    """The estimation problem: the FMU ``spec`` names, :data:`BOUNDS` free, max square
    on dtheta (as ``benchmarks/bench_ga.py``)."""
    from evo_door.models import get_model
    from evo_door.optim import Objective, Problem

    model = get_model(spec)
    free = list(BOUNDS)
    lo, hi = zip(*BOUNDS.values())
    return Problem(
        model,
        free,
        lo,
        hi,
        model.params.defaults,
        trials,
        Objective("max_square", 1),
        model_name=spec,
    )


def median_per_call(fn, repeat: int) -> float:
    """Median seconds of ``fn()`` over ``repeat`` calls, after one untimed call."""
    from benchmarks._util import median_time

    fn()
    return median_time(fn, repeat)


def max_errors(theta, dtheta, ref) -> tuple[float, float]:
    return float(np.abs(theta - ref[0]).max()), float(np.abs(dtheta - ref[1]).max())


# -- one trial ----------------------------------------------------------------------
def workbench_rows(fmu, trial, ref, repeat: int) -> list[dict]:
    """Per interface, the workbench's evaluation with the sandbox off and on."""
    x = np.array([TRUTH[n] for n in BOUNDS])
    rows = []
    for interface in ("me", "cs"):
        problem = make_problem(f"{fmu}:{interface}", [trial])
        (r,) = problem.responses(x)
        err = max_errors(r.theta, r.dtheta, ref["linear" if interface == "me" else "held"])
        for sandbox in (False, True):
            problem.sandboxed = sandbox
            fitness = float(problem.evaluate(x[None, :])[0][0])
            secs = median_per_call(lambda p=problem: p.evaluate(x[None, :]), repeat)
            rows.append(
                {
                    "interface": interface,
                    "way": "workbench",
                    "setting": f"{'RK4 x4' if interface == 'me' else 'DoStep'}, sandbox "
                    + ("on" if sandbox else "off"),
                    "key": f"workbench.sandbox_{'on' if sandbox else 'off'}",
                    "seconds": secs,
                    "error_theta": err[0],
                    "error_dtheta": err[1],
                    "fitness": fitness,
                }
            )
        problem.sandboxed = True
        from evo_door.optim.sandbox import sandbox_for

        sandbox_for(problem).close()
    return rows


def plain_rows(fmu, trial, ref, repeat: int, rtols) -> list[dict]:
    """Per interface and setting, ``simulate_fmu`` called once per evaluation; at the
    loosest setting also on a folder extracted once, the description read once."""
    from fmpy import extract, read_model_description

    free = list(BOUNDS)
    x = [TRUTH[n] for n in free]
    t, f, target = trial.t, trial.force, trial.dtheta
    folder = extract(str(fmu))
    md = read_model_description(str(fmu))
    rows = []
    for interface, settings in (("me", rtols), ("cs", (None,))):
        for rtol in settings:
            theta, dtheta = fmpy_run(fmu, interface, TRUTH, t, f, rtol)
            err = max_errors(theta, dtheta, ref["held"])
            label = "DoStep" if interface == "cs" else f"CVode rtol {rtol or 'default'}"
            for extracted in (False, True):
                if extracted and rtol != settings[0]:
                    continue
                fit = plain_fitness(
                    folder if extracted else fmu,
                    interface,
                    free,
                    t,
                    f,
                    target,
                    rtol,
                    md if extracted else None,
                )
                rows.append(
                    {
                        "interface": interface,
                        "way": "FMPy",
                        "setting": label + (", extracted once" if extracted else ""),
                        "key": "plain."
                        + ("default" if rtol is None else f"rtol{rtol:.0e}")
                        + (".extracted" if extracted else ""),
                        "seconds": median_per_call(lambda fit=fit: fit(x), repeat),
                        "error_theta": err[0],
                        "error_dtheta": err[1],
                        "fitness": fit(x),
                        "rtol": rtol,
                        "extracted": extracted,
                    }
                )
    return rows


def matched(rows: list[dict], interface: str) -> tuple[dict, dict, bool]:
    """The workbench's sandboxed row and the plain row its ratio is taken against (the
    loosest setting within :data:`MATCH_FACTOR` times its error, else the most
    accurate); whether that one matched."""
    wb = next(r for r in rows if r["interface"] == interface and r["key"].endswith("on"))
    plain = [
        r for r in rows if r["interface"] == interface and r["way"] == "FMPy" and not r["extracted"]
    ]
    good = [r for r in plain if r["error_theta"] <= MATCH_FACTOR * wb["error_theta"]]
    if good:
        return wb, min(good, key=lambda r: r["seconds"]), True
    return wb, min(plain, key=lambda r: r["error_theta"]), False


def one_trial(fmu: Path, quick: bool) -> dict:
    """Every row of the one-trial comparison, the references' settings included."""
    from evo_door.models import get_model

    model_name = get_model(str(fmu)).name
    trial = make_trial(fmu, PUSHES[0], model_name, "push20")
    ref = {
        "held": reference(TRUTH, trial.t, trial.force, hold=True),
        "linear": reference(TRUTH, trial.t, trial.force, hold=False),
    }
    rows = workbench_rows(fmu, trial, ref, 5 if quick else 50)
    rows += plain_rows(fmu, trial, ref, 1 if quick else 3, RTOLS[:1] if quick else RTOLS)
    return {"rows": rows, "trial": trial}


# -- where an evaluation's time goes ------------------------------------------------------
def profile_evaluation(fmu: Path, trial, population: int = 20, top: int = 8) -> dict:
    """A population's evaluation on the model exchange, sandbox off, under cProfile:
    seconds per candidate and the functions that take the most time (own time)."""
    problem = make_problem(f"{fmu}:me", [trial])
    problem.sandboxed = False
    rng = np.random.default_rng(3)
    X = rng.uniform(problem.lower, problem.upper, (population, problem.n_var))
    problem.evaluate(X[:2])
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.enable()
    problem.evaluate(X)
    prof.disable()
    wall = time.perf_counter() - t0
    stats = pstats.Stats(prof, stream=io.StringIO())
    raw = stats.stats  # type: ignore[attr-defined]
    rows = sorted(
        (
            (tt, ct, nc, f"{Path(fn).name}:{line}({name})")
            for (fn, line, name), (_, nc, tt, ct, _) in raw.items()
        ),
        reverse=True,
    )[:top]
    return {"population": population, "per_candidate": wall / population, "rows": rows}


# -- the GA ---------------------------------------------------------------------------
def ga_run(fmu: Path, quick: bool, per_call_plain: float) -> dict:
    """``evo-door run EXP.yaml --executor local`` on two trials made by FMPy."""
    from benchmarks.bench_ga import experiment_yaml
    from benchmarks.suite import run_experiment_cli
    from evo_door.data.io import write_trials
    from evo_door.models import get_model

    population, generations = GA_QUICK if quick else GA_SIZE
    spec = f"{fmu.name}:cs"
    model_name = get_model(str(fmu)).name
    trials = [make_trial(fmu, a, model_name, f"push{a:g}") for a in PUSHES]
    problem = make_problem(f"{fmu}:cs", trials)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / fmu.name).write_bytes(fmu.read_bytes())
        write_trials(folder / "trials.h5", trials)
        exp = folder / "fmu_ga.yaml"
        exp.write_text(experiment_yaml(spec, problem, population, generations, run="bench_fmu"))
        done = run_experiment_cli(exp, folder / "run.h5", "local")
    best = done["params"]
    errors = {n: 100.0 * (float(best[n]) - v) / v for n, v in TRUTH.items()}
    plain = done["evaluations"] * len(trials) * per_call_plain / CORES
    return {
        "population": population,
        "generations": generations,
        "spec": spec,
        "wall": done["wall"],
        "run": done["run"],
        "evaluations": done["evaluations"],
        "best": {n: float(best[n]) for n in TRUTH},
        "errors": errors,
        "plain": plain,
        "per_call_plain": per_call_plain,
        "trials": len(trials),
    }


# -- the page -------------------------------------------------------------------------
def _ms(s: float) -> str:
    return f"{s * 1e3:.3g} ms"


def markdown(trial: dict, ga: dict, prof: dict, quick: bool) -> str:
    """The section's tables: one trial each way, the GA, where the time goes."""
    rows = trial["rows"]
    lines = [
        f"The door FMU of `examples/fmu` (FMI 2.0, tuned layout, built from source in the "
        f"run). One {SECONDS:g} s trial at {1 / DT:g} Hz: a {PUSHES[0]:g} N half-sine push "
        f"of {PUSH_WIDTH} s from fully open, its target made by FMPy's co-simulation at "
        + ", ".join(f"{k} = {v:g}" for k, v in TRUTH.items())
        + ". One evaluation = the objective (max square dtheta error) of that candidate. "
        "Workbench: `Problem.evaluate` on the FMU model, the instance reused, in this "
        "process (sandbox off) or through the sandbox process (on: what a run does). "
        "FMPy: one `simulate_fmu(path, start_values=..., input=...)` per evaluation, the "
        "force as a staircase (FMPy's model exchange applies it exactly only so); "
        '"extracted once" passes the unzipped folder and the description read once. '
        "Errors: max over the trial against scipy DOP853 at rtol 1e-10 of the FMU's "
        "equation, restarted at every sample, the force as each way applies it (the "
        "workbench's model exchange: linear between samples; its co-simulation and "
        "FMPy: held over each sample). **ratio**: FMPy's time / the sandboxed "
        "workbench's, same interface.",
        "",
        "| interface | way | setting | per evaluation | max theta error | max dtheta error "
        "| fitness of the truth | ratio |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        wb = next(w for w in rows if w["interface"] == r["interface"] and w["key"].endswith("on"))
        ratio = "" if r["way"] != "FMPy" else f"{r['seconds'] / wb['seconds']:.3g}x"
        lines.append(
            f"| {'model exchange' if r['interface'] == 'me' else 'co-simulation'} | {r['way']} "
            f"| {r['setting']} | {_ms(r['seconds'])} | {r['error_theta']:.2g} rad | "
            f"{r['error_dtheta']:.2g} rad/s | {r['fitness']:.3g} (rad/s)^2 | {ratio} |"
        )
    for interface in ("me", "cs"):
        wb, plain, ok = matched(rows, interface)
        lines += [
            "",
            f"{'Model exchange' if interface == 'me' else 'Co-simulation'}: the workbench "
            f"(sandbox on) {_ms(wb['seconds'])} per evaluation against FMPy's "
            f"{plain['setting']} {_ms(plain['seconds'])}: **{plain['seconds'] / wb['seconds']:.3g}x**"
            + (
                f" at matched accuracy (within {MATCH_FACTOR:g}x of the workbench's theta error)."
                if ok
                else " against FMPy's most accurate setting tried, still less accurate than "
                "the workbench: a lower bound."
            ),
        ]
        fastest = min(
            (r for r in rows if r["interface"] == interface and r["way"] == "FMPy"),
            key=lambda r: r["seconds"],
        )
        if fastest is not plain:
            lines[-1] += (
                f" Against FMPy's fastest setting ({fastest['setting']}, "
                f"{fastest['error_theta']:.2g} rad): {fastest['seconds'] / wb['seconds']:.3g}x."
            )
    lines += [
        "",
        f"A GA of population {ga['population']} x {ga['generations']} generations"
        + (" (--quick: a smoke run, not a measurement)" if quick else "")
        + ": `evo-door run fmu_ga.yaml` (the `local` executor: one sandbox process per core, "
        f"{CORES} here) in a fresh process (start-up and the sandboxes' start included), model "
        f"`{ga['spec']}`, {ga['trials']} trials made by FMPy's co-simulation at the truth "
        f"(pushes of {', '.join(f'{a:g}' for a in PUSHES)} N), free "
        + ", ".join(f"{n} in [{lo:g}, {hi:g}]" for n, (lo, hi) in BOUNDS.items())
        + ". Plain, extrapolated: evaluations x trials x FMPy's co-simulation per call / "
        f"{CORES} cores.",
        "",
        "| what | value |",
        "|---|---:|",
        f"| wall time of `evo-door run` | {ga['wall']:.3g} s |",
        f"| the run's own time (results file) | {ga['run']:.3g} s |",
        f"| evaluations (candidates) | {ga['evaluations']} |",
        f"| wall time per evaluation ({ga['trials']} trials) | {_ms(ga['wall'] / ga['evaluations'])} |",
        f"| plain way, extrapolated | {ga['plain']:.3g} s |",
        f"| ratio | {ga['plain'] / ga['wall']:.3g}x |",
        "",
        "| parameter | truth | estimate | error |",
        "|---|---:|---:|---:|",
        *[
            f"| {n} | {v:g} | {ga['best'][n]:.5g} | {ga['errors'][n]:+.3g} % |"
            for n, v in TRUTH.items()
        ],
        "",
        f"Where an evaluation's time goes: {prof['population']} candidates on the model "
        f"exchange, sandbox off, under cProfile ({_ms(prof['per_candidate'])} per "
        "candidate with the profiler's overhead), by own time:",
        "",
        "| function | own time | calls |",
        "|---|---:|---:|",
        *[f"| `{name}` | {_ms(tt)} | {nc} |" for tt, _, nc, name in prof["rows"]],
    ]
    return "\n".join(lines)
