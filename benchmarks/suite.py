"""One benchmark suite: the workbench against the plain way, in one run on one machine.

``python -m benchmarks`` runs the sections below in one process (the command-line
ones in subprocesses, as a user types them), prints a table per section with times
and ratios, and writes ``suite-<timestamp>.json`` (every metric), ``suite-<timestamp>.png``
(the ratios and the scaling curves) and ``suite-<timestamp>.md`` in ``--out``
(default ``benchmarks/results/``), with a section's own figures beside them
(``suite-<timestamp>-work-precision.png``). A measured run (not ``--quick``) also
replaces those figures next to this file (``benchmarks/work-precision.png``) and the
pages that README.md and the docs quote (``benchmarks/trial.md``,
``benchmarks/casestudy.md``) for the sections it ran; a full run (not ``--quick``, not
``--only``) also replaces ``benchmarks/suite.md``.

Sections (``--only``):

``trial``
    work-precision: per model a smooth trial and two latch trials (one from the
    virtual rig), each by evo-door ``simulate`` (its default; ``dopri5`` over
    tolerances, ``rk4`` and ``semi_implicit`` over sub-steps) and by scipy
    ``solve_ivp`` (RK45, LSODA, Radau, DOP853 over rtol) around the compiled
    ``accel``, errors against a converged reference; a table per trial, the figure
    ``work-precision.png``, the targets (``precision.py``, ``precision_report.py``); a
    measured run also replaces ``benchmarks/trial.md``, the figures README quotes.
``ga``
    a 100 x 20 GA by the workbench and by the plain loop (the same DEAP-based GA, each
    individual one ``solve_ivp``), the plain one timed on a few generations and
    extrapolated per evaluation.
``scaling``
    one batched evaluation against population and trials, GA runs against
    generations, numba threads 1 and 2 (door model).
``executors``
    ``evo-door run --executor local|processes|dask`` and a Dask scheduler with 1 and
    2 workers (``tcp://``), end to end in subprocesses.
``device``
    the haptic device-force cost (from Python, from compiled code) and the servo loop
    on the simulated device, paced on the wall clock.
``startup``
    wall time of ``evo-door --help`` and ``evo-door params haptic`` (target < 0.3 s);
    cold start (an empty numba cache) and warm start of ``evo-door simulate haptic``
    (target: its first line, or its end, within 5 s) and of ``evo-door compile``.
``casestudy``
    the main job, ``evo-door run experiments/case_study.yaml``, once in a fresh
    process: wall time, each stage's time, evaluations and fit, each estimate's error
    against the virtual door's truth where the trials carry it, the perceptual check
    (``bench_casestudy.py``); a measured run (not ``--quick``) also replaces
    ``benchmarks/casestudy.md``, the figures README and ``docs/case-study.md`` quote.
``seeds``
    the main job with GA seeds 1, 2, 3 and on a generic CPU: each estimate's spread
    against the interval it states (``bench_seeds.py``); a measured run also writes
    ``benchmarks/seeds.md``.
``control``
    the servo loop's cycles on time with 200 clients flooding the control port, the
    renderer's memory growth and its log's session events (``bench_control.py``).
``fmu``
    the door FMU of ``examples/fmu`` built in the run: one trial's evaluation by the
    workbench (sandbox off and on) against ``fmpy.simulate_fmu`` called per
    evaluation, model exchange and co-simulation, each against a scipy reference;
    ``evo-door run --executor processes:2`` of a 100 x 20 GA on trials made by FMPy,
    against FMPy's cost extrapolated (``bench_fmu.py``); a measured run also writes
    ``benchmarks/fmu.md``.
``jnd``
    planning a JND session: many simulated sessions of a simulated participant per
    method and number of trials; the estimates' bias and spread, the share within
    +-20 % and the intervals' coverage (``bench_jnd.py``); a measured run also writes
    ``benchmarks/jnd.md``.
``pathsim``
    mechanisms from blocks side by side: the soft-close drawer of ``examples/blocks``
    in the workbench and as a PathSim block diagram (the optional extra ``bench``;
    skipped with its reason when PathSim is not installed), one trial at matched
    accuracy against a scipy reference, per trial and per GA evaluation
    (``bench_pathsim.py``); a measured run also writes ``benchmarks/pathsim.md``.

A ratio is the plain (or reference) way's value divided by the workbench's: how many
times faster the workbench is. ``--compare OLD.json [NEW.json]`` prints new / old per
metric (below 1: the new run is faster).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.probe import host_probe, probe_sentence  # noqa: E402
from evo_door.errors import UserError  # noqa: E402

SECTIONS = (
    "trial",
    "ga",
    "scaling",
    "executors",
    "device",
    "startup",
    "casestudy",
    "seeds",
    "control",
    "fmu",
    "jnd",
    "pathsim",
)
DEFAULT_OUT = HERE / "results"

#: targets: commands that do not simulate, the device force, the servo loop (the trial
#: section's: benchmarks/precision.py)
STARTUP_TARGET = 0.3
DEVICE_PY_TARGET = 2e-6
DEVICE_C_TARGET = 100e-9
ON_TIME_TARGET = 0.999


@dataclass
class Metric:
    """One measured figure. ``ratio`` = the value of ``ratio_to`` / this value for a
    workbench figure against its plain way (a speed-up), or as ``note`` says."""

    name: str
    section: str
    label: str
    value: float | None
    unit: str
    ratio: float | None = None
    ratio_to: str | None = None
    target: float | None = None
    target_text: str | None = None
    met: bool | None = None
    note: str | None = None


@dataclass
class Suite:
    quick: bool
    metrics: list[Metric] = field(default_factory=list)
    #: scaling curves for the figure: name -> {"x": [...], "y": [...], "xlabel", "ylabel"}
    curves: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    tables: dict = field(default_factory=dict)
    #: a section's own figures: name -> (section, matplotlib Figure, caption)
    figures: dict = field(default_factory=dict)
    #: the host probe's seconds at the run's start and end (:func:`benchmarks.probe.host_probe`;
    #: none in a --quick run)
    probe: list = field(default_factory=list)

    def add(self, name, section, label, value, unit, **kw) -> Metric:
        m = Metric(name, section, label, None if value is None else float(value), unit, **kw)
        if m.target is not None and m.value is not None and m.met is None:
            m.met = bool(m.value <= m.target)
        self.metrics.append(m)
        return m

    def get(self, name) -> Metric | None:
        return next((m for m in self.metrics if m.name == name), None)


# -- formatting ---------------------------------------------------------------------
def fmt(value, unit: str) -> str:
    """``value`` with its unit, seconds scaled to s / ms / us / ns."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "n/a"
    if unit == "s":
        a = abs(value)
        if a >= 1:
            return f"{value:.3g} s"
        if a >= 1e-3:
            return f"{value * 1e3:.3g} ms"
        if a >= 1e-6:
            return f"{value * 1e6:.3g} us"
        return f"{value * 1e9:.3g} ns"
    if unit == "1":
        return f"{value:.4g}"
    if unit == "%":
        return f"{value:.3f} %"
    return f"{value:.3g} {unit}"


def fmt_ratio(r) -> str:
    if r is None or not np.isfinite(r):
        return ""
    return f"{r:.3g}x" if r < 100 else f"{r:.0f}x"


def progress(text: str) -> None:
    print(f"[suite] {text}", file=sys.stderr, flush=True)


# -- section: work-precision of a trial -------------------------------------------------
def section_trial(suite: Suite) -> None:
    """Per model a smooth trial and two latch trials, each by every way at every
    setting, on one numba thread: error against time (:mod:`benchmarks.precision`),
    tables, the work-precision figure and the targets (:mod:`benchmarks.precision_report`)."""
    import numba

    from benchmarks import precision
    from benchmarks import precision_report as report

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    results = []
    try:
        for trial in precision.bench_trials():
            try:
                points, resolution = precision.measure(
                    trial, suite.quick, lambda text: progress(f"  {text}")
                )
            except (RuntimeError, AssertionError) as exc:  # a reference that cannot answer
                suite.notes.append(f"trial {trial.model} {trial.key} skipped: {exc}")
                continue
            report.record(suite, trial, points)
            results.append((trial, points, resolution))
    finally:
        numba.set_num_threads(threads)
    tables = [report.table(*r, quick=suite.quick) for r in results]
    suite.tables["trial"] = "\n\n".join([report.intro(suite.quick, load), *tables])
    suite.figures["work-precision"] = (
        "trial",
        report.figure(results, suite.quick),
        "work-precision: max |dtheta error| against seconds per trial",
    )


# -- section: GA ----------------------------------------------------------------------
def section_ga(suite: Suite) -> None:
    """100 x 20 GA: workbench against the plain loop (extrapolated)."""
    from benchmarks.bench_ga import make_problem, time_eval, time_ga
    from benchmarks.plain import PlainProblem
    from evo_door.models import get_model
    from evo_door.optim import GASettings, GeneticAlgorithm

    plain_pop, plain_gens = (10, 1) if suite.quick else (100, 1)
    gens = 3 if suite.quick else 20  # --quick: the workbench's GA 100 x 3
    lines = [
        f"| model | workbench GA 100 x {gens} | evaluations | plain GA (extrapolated) | plain per "
        "evaluation | plain timed on | speed-up |",
        "|---|---:|---:|---:|---:|---|---:|",
    ]
    # the haptic model's dry friction is a sign law that solve_ivp cannot step through
    # (it chatters at rest for minutes): the GA comparison runs its tanh form, which
    # the plain way integrates as the seed wrote it
    for name, model_name in (("door", "door"), ("haptic", "haptic_tanh")):
        model = get_model(model_name)
        problem = make_problem(model)
        time_eval(problem, 4, repeat=1)  # compile / load caches
        # the median of three runs (one under --quick): one run of about a second moves
        # by a third from one run to the next on a shared machine; the runs are the same
        # GA, bit for bit (one seed)
        runs = [time_ga(problem, 100, gens) for _ in range(1 if suite.quick else 3)]
        secs, state = float(np.median([s for s, _ in runs])), runs[0][1]
        assert all(np.array_equal(st.best_x, state.best_x) for _, st in runs)
        plain = PlainProblem(problem)
        t0 = time.perf_counter()
        GeneticAlgorithm(GASettings(population=plain_pop, generations=plain_gens, seed=1)).run(
            plain
        )
        per_eval = (time.perf_counter() - t0) / plain.evaluations  # GA bookkeeping included
        plain_total = per_eval * state.evaluations
        key = f"ga.{name}"
        suite.add(f"{key}.workbench", "ga", f"{name}: workbench GA 100 x {gens}", secs, "s")
        suite.add(
            f"{key}.evaluations",
            "ga",
            f"{name}: evaluations of the 100 x {gens} GA",
            state.evaluations,
            "1",
        )
        suite.add(
            f"{key}.plain",
            "ga",
            f"{name}: plain scipy + DEAP GA 100 x {gens} (extrapolated)",
            plain_total,
            "s",
            ratio=plain_total / secs,
            ratio_to=f"{key}.workbench",
            note=f"timed on population {plain_pop} x generations 0-{plain_gens} "
            f"({plain.evaluations} evaluations), extrapolated per evaluation to "
            f"{state.evaluations}",
        )
        suite.add(
            f"{key}.plain_per_evaluation", "ga", f"{name}: plain, one evaluation", per_eval, "s"
        )
        lines.append(
            f"| {name} | {fmt(secs, 's')} | {state.evaluations} | {fmt(plain_total, 's')} | "
            f"{fmt(per_eval, 's')} | population {plain_pop}, generations 0-{plain_gens} "
            f"({plain.evaluations} evaluations) | {fmt_ratio(plain_total / secs)} |"
        )
    suite.tables["ga"] = (
        f"A GA of population 100 x {gens} generations "
        + ("(--quick; AMESim's settings are 100 x 20)" if suite.quick else "(AMESim's settings)")
        + " on one 5 s trial, "
        "max-square objective on angular speed, four free parameters (`bench_ga.py`); "
        "the workbench's time is the median of three runs of it. "
        "Plain: the same DEAP-based GA loop, each individual one `solve_ivp` (RK45, "
        "rtol 1e-6, Python right-hand side around the compiled `accel`); timed on the "
        "first generations shown, extrapolated per evaluation to the workbench's "
        "evaluation count. The haptic rows run `haptic_tanh` (the seed's tanh friction), "
        "which the plain way can integrate.\n\n" + "\n".join(lines)
    )


# -- section: scaling -----------------------------------------------------------------
def section_scaling(suite: Suite) -> None:
    """Batched evaluation against population and trials; GA against generations; threads."""
    import numba

    from benchmarks.bench_ga import linear_fit, make_problem, time_eval, time_ga
    from evo_door.models import get_model

    model = get_model("door")
    pops = (25, 50) if suite.quick else (25, 50, 100, 200)
    trials = (1, 2) if suite.quick else (1, 2, 4)
    gens = (2, 4) if suite.quick else (5, 10, 20, 40)
    ga_pop = 25 if suite.quick else 100
    repeat = 1 if suite.quick else 3
    problems = {k: make_problem(model, k) for k in trials}
    time_eval(problems[1], 4, repeat=1)
    lines = ["| what | seconds | per unit | ratio |", "|---|---:|---:|---:|"]
    base = None
    pop_x, pop_y = [], []
    for n in pops:
        s = time_eval(problems[1], n, repeat)
        base = base or s / n
        suite.add(
            f"scaling.population.{n}",
            "scaling",
            f"door, 1 trial, population {n}: one batched evaluation",
            s,
            "s",
        )
        lines.append(
            f"| population {n}, 1 trial | {fmt(s, 's')} | {fmt(s / n, 's')} per individual | |"
        )
        pop_x.append(n)
        pop_y.append(s)
    tr_x, tr_y = [], []
    n_pop = pops[-1] if suite.quick else 100
    for k in trials:
        s = time_eval(problems[k], n_pop, repeat)
        suite.add(
            f"scaling.trials.{k}",
            "scaling",
            f"door, population {n_pop}, {k} trial(s): one batched evaluation",
            s,
            "s",
        )
        lines.append(
            f"| {k} trial(s), population {n_pop} | {fmt(s, 's')} | {fmt(s / (k * n_pop), 's')} per trial-individual | |"
        )
        tr_x.append(k * n_pop)
        tr_y.append(s)
    a, b, r2 = (
        linear_fit(pop_x + tr_x, pop_y + tr_y)
        if len(pop_x + tr_x) > 2
        else (np.nan, np.nan, np.nan)
    )
    suite.add(
        "scaling.per_trial_individual",
        "scaling",
        "door: slope of evaluation time against trials x population",
        a,
        "s",
        note=f"R^2 = {r2:.4f}",
    )
    g_x, g_y = [], []
    for g in gens:
        s = time_ga(problems[1], ga_pop, g)[0]
        per = s / (g + 1)  # generation 0 is evaluated too
        suite.add(
            f"scaling.generations.{g}",
            "scaling",
            f"door GA population {ga_pop} x {g} generations",
            s,
            "s",
        )
        suite.add(
            f"scaling.generations.{g}.per_generation",
            "scaling",
            f"door GA, {g} generations: time per generation",
            per,
            "s",
        )
        lines.append(
            f"| GA {ga_pop} x {g} generations | {fmt(s, 's')} | {fmt(per, 's')} per generation | |"
        )
        g_x.append(g)
        g_y.append(per)
    flat = max(g_y) / min(g_y)
    suite.add(
        "scaling.generations.flatness",
        "scaling",
        "largest / smallest time per generation",
        flat,
        "1",
        note="1 = perfectly flat",
    )
    max_threads = numba.config.NUMBA_NUM_THREADS
    th = numba.get_num_threads()
    t_x, t_y = [], []
    try:
        for n in (1, 2):
            if n > max_threads:
                suite.add(
                    f"scaling.threads.{n}",
                    "scaling",
                    f"door, population 100: {n} numba threads",
                    None,
                    "s",
                    note="not available: fewer cores",
                )
                continue
            numba.set_num_threads(n)
            s = time_eval(problems[1], 100, repeat)
            t_x.append(n)
            t_y.append(s)
            one = suite.get("scaling.threads.1")
            suite.add(
                f"scaling.threads.{n}",
                "scaling",
                f"door, population 100, 1 trial: {n} numba thread(s)",
                s,
                "s",
                ratio=None if one is None else one.value / s,
                ratio_to=None if one is None else "scaling.threads.1",
            )
            r = "" if one is None else fmt_ratio(one.value / s)
            lines.append(
                f"| population 100, {n} numba thread(s) | {fmt(s, 's')} | {fmt(s / 100, 's')} per individual | {r} |"
            )
    finally:
        numba.set_num_threads(th)
    suite.curves["population"] = {"x": pop_x, "y": pop_y, "label": "1 trial, population n"}
    suite.curves["trials"] = {"x": tr_x, "y": tr_y, "label": f"population {n_pop}, 1/2/4 trials"}
    suite.curves["generations"] = {"x": g_x, "y": g_y}
    suite.curves["threads"] = {"x": t_x, "y": t_y}
    suite.tables["scaling"] = (
        f"Door model, one 5 s trial per trial. One batched evaluation (`Problem.evaluate`, "
        f"numba threads {th}) against population and trials: {fmt(a, 's')} per "
        f"trial-individual (linear fit, R^2 = {r2:.4f}). GA runs: time per generation "
        f"(generation 0 included) should stay flat: largest / smallest {flat:.2f}.\n\n"
        + "\n".join(lines)
    )


# -- section: executors ---------------------------------------------------------------
def run_experiment_cli(exp: Path, out: Path, executor: str | None) -> dict:
    """``evo-door run EXP --out OUT [--executor X] --quiet`` in a fresh process: wall
    time, the run's own total time and best parameters (``evo-door show --json``)."""
    from benchmarks._util import evo_door_command
    from evo_door.files import open_h5
    from evo_door.files.metadata import read_attrs

    args = ["run", exp, "--out", out, "--quiet"]
    if executor is not None:
        args += ["--executor", executor]
    wall, _ = evo_door_command(args, cwd=exp.parent, timeout=1200)
    # the run is the suite's own: the model it names (an FMU, say) is the one it ran
    with open_h5(out) as f:
        model = str(read_attrs(f).get("model", ""))
    _, shown = evo_door_command(["show", out, "--json", "--allow-model", model])
    info = json.loads(shown)
    return {
        "wall": wall,
        "run": info.get("seconds"),
        "params": info.get("best"),
        "evaluations": info.get("evaluations"),
    }


REFUSED = "unrecognized arguments: --executor"


def section_executors(suite: Suite) -> None:
    """``evo-door run --executor X`` end to end, each in a fresh process."""
    from benchmarks.bench_ga import experiment_yaml, make_problem
    from evo_door.data.io import write_trials
    from evo_door.models import get_model

    pop, gens = (20, 2) if suite.quick else (100, 5)
    model = get_model("door")
    problem = make_problem(model, 2)
    text = experiment_yaml("door", problem, pop, gens, run="bench_executors")
    # (metric key, --executor, what it is)
    cases = [
        ("local", "local", "local (compiled batch on numba threads)"),
        ("processes", "processes", "processes (a pool, one per core)"),
        ("dask_1_worker", "dask:1", "Dask, local cluster of 1 worker"),
        ("dask_2_workers", "dask:2", "Dask, local cluster of 2 workers"),
    ]
    if suite.quick:
        cases = cases[:2]
        suite.notes.append("executors: --quick runs local and processes only")
    lines = [
        "| executor | `--executor` | wall time of `evo-door run` | run's own time | "
        "local / this | same best as local |",
        "|---|---|---:|---:|---:|---|",
    ]
    results = {}
    refused = None
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_trials(tmp / "trials.h5", problem.fit.trials)
        exp = tmp / "bench.yaml"
        exp.write_text(text)
        for key, executor, label in cases:
            why = res = None
            if refused and key != "local":
                why = refused
            else:
                try:
                    res = run_experiment_cli(exp, tmp / f"{key}.h5", executor)
                except RuntimeError as exc:
                    if REFUSED in str(exc) and key == "local":
                        refused = "not available: `evo-door run` refuses `--executor`"
                        res = run_experiment_cli(exp, tmp / f"{key}.h5", None)
                    else:
                        why = f"not available: {exc}"
            results[key] = res
            local = results.get("local")
            name = f"executors.{key}"
            if res is None:
                suite.add(name, "executors", f"`evo-door run` on {label}", None, "s", note=why)
                lines.append(f"| {label} | `{executor}` | n/a | n/a | | {why} |")
                continue
            ratio = None if local is None or key == "local" else local["wall"] / res["wall"]
            same = (
                None
                if local is None or key == "local"
                else (res["params"], res["evaluations"]) == (local["params"], local["evaluations"])
            )
            suite.add(
                name,
                "executors",
                f"`evo-door run` (door GA {pop} x {gens}, 2 trials) on {label}: wall time",
                res["wall"],
                "s",
                ratio=ratio,
                ratio_to=None if ratio is None else "executors.local",
                note=None
                if same is None
                else f"same best parameters and evaluation count as local: {same}",
            )
            suite.add(
                f"{name}.run",
                "executors",
                f"{label}: the run's own time (results file)",
                res["run"],
                "s",
            )
            lines.append(
                f"| {label} | `{executor}` | {fmt(res['wall'], 's')} | {fmt(res['run'], 's')} | "
                f"{fmt_ratio(ratio)} | {'' if same is None else ('yes' if same else '**no**')} |"
            )
    if refused:
        suite.notes.append(f"executors: {refused}")
    suite.tables["executors"] = (
        f"`evo-door run` of a door GA (population {pop} x {gens} generations, two 5 s "
        "trials) in a fresh process per executor, start-up included (a Dask cluster is "
        "started and closed inside the run); the run's own time is the results file's. "
        "local / this above 1: faster than local.\n\n" + "\n".join(lines)
    )


# -- section: device ------------------------------------------------------------------
def section_device(suite: Suite) -> None:
    """Device-force cost and the servo loop on the simulated device."""
    from benchmarks.bench_haptic import device_force_costs
    from benchmarks.bench_render import RATE, sim_run
    from evo_door.models import get_model
    from evo_door.sim.simulate import param_vector

    model = get_model("haptic")
    params = model.load_params("seed_trial")
    py_call, c_call = device_force_costs(param_vector(params), quick=suite.quick)
    suite.add(
        "device.force_python",
        "device",
        "device force from Python (`device_force_vector`)",
        py_call,
        "s",
        target=DEVICE_PY_TARGET,
        target_text="< 2 us",
    )
    suite.add(
        "device.force_compiled",
        "device",
        "device force from compiled code (servo loop)",
        c_call,
        "s",
        target=DEVICE_C_TARGET,
        target_text="< 100 ns",
    )
    seconds = 1.0 if suite.quick else 10.0
    sim_run(params, 0.2, "implicit")  # compile / load
    s = sim_run(params, seconds, "implicit")
    on_time = s["on_time_fraction"]
    suite.add(
        "device.servo.on_time",
        "device",
        f"servo loop, sim device, {RATE:g} Hz, {seconds:g} s: cycles on time",
        on_time * 100,
        "%",
        target_text=">= 99.9 %",
        met=on_time >= ON_TIME_TARGET,
    )
    suite.add(
        "device.servo.period_mean",
        "device",
        "servo loop: mean period",
        s["period_mean_s"],
        "s",
        note=f"nominal {1 / RATE * 1e3:g} ms",
    )
    suite.add(
        "device.servo.lateness_p99", "device", "servo loop: p99 lateness", s["lateness_p99_s"], "s"
    )
    suite.add(
        "device.servo.compute_p99", "device", "servo loop: p99 cycle work", s["compute_p99_s"], "s"
    )
    suite.add("device.servo.missed", "device", "servo loop: missed cycles", s["missed_cycles"], "1")
    _log_growth(suite, params)
    suite.tables["device"] = (
        f"Haptic model `seed_trial`. Servo loop paced on the wall clock with the simulated "
        f"device (user `open`, implicit friction) for {seconds:g} s (`bench_render.py`). "
        "The render log's growth: a `swing` render on the simulated device, 2500 Hz, "
        "1 kHz log, extrapolated to an hour of session.\n\n"
        + _generic_table([m for m in suite.metrics if m.section == "device"])
    )


#: the render log of an hour of session must fit a day of sessions on a laptop's disk
LOG_PER_HOUR_TARGET = 200e6


def _log_growth(suite: Suite, params) -> None:
    """The render log's growth per hour of session (``bench_render.log_growth``)."""
    from benchmarks.bench_render import log_growth

    seconds = 5.0 if suite.quick else 60.0
    with tempfile.TemporaryDirectory() as folder:
        g = log_growth(params, seconds, Path(folder))
    suite.add(
        "device.log.final_per_hour",
        "device",
        f"render log (.h5) per hour of session (from {seconds:g} s)",
        g["final"] / 1e6,
        "MB/h",
        target=LOG_PER_HOUR_TARGET / 1e6,
        target_text="< 200 MB/h",
        met=g["final"] < LOG_PER_HOUR_TARGET,
    )
    suite.add(
        "device.log.partial_per_hour",
        "device",
        "its side file (.partial) per hour while rendering (removed at the end)",
        g["partial"] / 1e6,
        "MB/h",
    )
    suite.add(
        "device.log.held",
        "device",
        "rows the log holds in memory at the end (any length of session)",
        g["held"] / 1e6,
        "MB",
    )


# -- section: start-up ----------------------------------------------------------------
def section_startup(suite: Suite) -> None:
    from benchmarks.bench_startup import cases, wall_time

    repeat = 2 if suite.quick else 7
    keys = {
        "`evo-door --help`": "startup.help",
        "`evo-door params haptic`": "startup.params_haptic",
        '`python -c "import numba"`': "startup.import_numba",
        "`python -c pass`": "startup.python",
    }
    for label, cmd in cases():
        target = (
            STARTUP_TARGET if keys[label] in ("startup.help", "startup.params_haptic") else None
        )
        suite.add(
            keys[label],
            "startup",
            f"{label}, fresh process",
            wall_time(cmd, repeat),
            "s",
            target=target,
            target_text=None if target is None else "< 0.3 s",
        )
    _cold_and_warm_start(suite, repeat)
    suite.tables["startup"] = (
        f"Wall time of a fresh process, median of {repeat} runs after one untimed run. "
        "Cold: on an empty numba cache, as after an install (`NUMBA_CACHE_DIR` a new "
        "folder): the command compiles what it runs; its first line is the time until it "
        "says what it compiles (or ends). Warm: the same command again, on the cache it "
        f"filled (median of {repeat}).\n\n"
        + _generic_table([m for m in suite.metrics if m.section == "startup"])
    )


def _cold_and_warm_start(suite: Suite, repeat: int) -> None:
    """The first ``evo-door simulate haptic`` after an install and the next ones; in a
    measured run also ``evo-door compile`` (every kernel) cold and warm. --quick times
    ``params haptic`` the same way (it compiles nothing)."""
    from benchmarks.bench_startup import FIRST_WORD, _evo_door, cold_and_warm, force_csv

    evo = _evo_door()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        force_csv(folder / "push.csv")
        sim = [*evo, "simulate", "haptic", "--input", "push.csv", "--out", "out.csv"]
        cases = [("simulate", "`evo-door simulate haptic` (2 s trial)", sim)]
        if suite.quick:
            cases = [("params", "`evo-door params haptic`", [*evo, "params", "haptic"])]
        else:
            cases.append(("compile", "`evo-door compile` (every kernel)", [*evo, "compile"]))
        for key, label, cmd in cases:
            got = cold_and_warm(cmd, folder / f"cache-{key}", folder, repeat)
            name = f"startup.{key}"
            suite.add(f"{name}.cold", "startup", f"{label}, cold", got["cold"], "s")
            if key != "compile":  # (compile names each kernel as it starts it)
                suite.add(
                    f"{name}.first_word",
                    "startup",
                    f"{label}, cold: its first line on stderr, or its end",
                    got["first_word"],
                    "s",
                    target=FIRST_WORD,
                    target_text=f"<= {FIRST_WORD:g} s",
                    note=repr(got["first_line"][:70]) if got["first_line"] else "no line",
                )
            suite.add(
                f"{name}.warm",
                "startup",
                f"{label}, warm",
                got["warm"],
                "s",
                ratio=got["cold"] / got["warm"],
                ratio_to=f"{name}.cold",
            )


# -- section: the main job -----------------------------------------------------------
def section_casestudy(suite: Suite) -> None:
    """``evo-door run experiments/case_study.yaml`` once: times, fits, errors."""
    from benchmarks.bench_casestudy import figures, markdown, run_pipeline

    load_start = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "case-study.h5"
        wall = run_pipeline(out, suite.quick)
        fig = figures(out, wall, suite.quick)
    load_end = os.getloadavg()[0]
    suite.add("casestudy.wall", "casestudy", "main job: wall time of `evo-door run`", wall, "s")
    suite.add(
        "casestudy.total", "casestudy", "main job: the pipeline's own time", fig["total"], "s"
    )
    for s in fig["stages"]:
        key = f"casestudy.{s['stage']}"
        suite.add(f"{key}.seconds", "casestudy", f"stage {s['stage']}: time", s["seconds"], "s")
        suite.add(
            f"{key}.evaluations",
            "casestudy",
            f"stage {s['stage']}: evaluations",
            s["evaluations"],
            "1",
        )
        suite.add(
            f"{key}.fitness",
            "casestudy",
            f"stage {s['stage']}: fitness",
            s["fitness"],
            s["fitness_unit"],
        )
        if s["rms_fit"]:
            suite.add(
                f"{key}.rms_fit_max",
                "casestudy",
                f"stage {s['stage']}: largest RMS {s['channel']} error over the fit trials",
                max(s["rms_fit"]),
                s["channel_unit"],
            )
        for p in s["params"]:
            suite.add(
                f"{key}.{p['name']}",
                "casestudy",
                f"stage {s['stage']}: {p['name']}",
                p["value"],
                p["unit"],
            )
            if p["error_pct"] is not None:
                suite.add(
                    f"{key}.{p['name']}.error",
                    "casestudy",
                    f"stage {s['stage']}: {p['name']}, error against the truth",
                    p["error_pct"],
                    "%",
                )
    for pc in fig["perceptual"]:
        for d in ("opening", "closing"):
            suite.add(
                f"casestudy.{pc['stage']}.perceptual.{d}",
                "casestudy",
                f"stage {pc['stage']}: perceptual check, {d}: largest difference",
                pc[d]["worst_jnd"],
                "JND",
            )
    for sp in fig["specification"]:
        key = f"casestudy.{sp['stage']}.yield"
        suite.add(
            key, "casestudy", f"stage {sp['stage']}: yield", 100 * sp["yield"]["estimate"], "%"
        )
        suite.add(
            f"{key}.independent",
            "casestudy",
            f"stage {sp['stage']}: yield, independent check of fresh doors",
            100 * sp["independent"]["estimate"],
            "%",
        )
    how = (
        "--quick: every stage's GA 8 x 1, two SLSQP iterations, a smoke test, not a measurement"
        if suite.quick
        else "the pipeline as the file states it"
    )
    suite.tables["casestudy"] = (
        f"The main job ({how}), on the bundled trials. Load average (1 min) "
        f"{load_start:.2f} before the run (other processes' load) and {load_end:.2f} at "
        f"its end (the run's own threads included): with other processes on the "
        f"{os.cpu_count()} cores, the times are longer than on a quiet machine.\n\n" + markdown(fig)
    )


# -- section: the main job across seeds and CPUs ---------------------------------------
def section_seeds(suite: Suite) -> None:
    """The main job four times (seeds 1-3, a generic CPU): do the estimates agree?"""
    from benchmarks.bench_seeds import agreement, markdown, measure

    done = measure(suite.quick)
    rows = agreement(done)
    for label, (wall, _) in done.items():
        key = label.replace(" ", "_").replace(",", "")
        suite.add(f"seeds.{key}.wall", "seeds", f"main job, {label}: wall time", wall, "s")
    for r in rows:
        suite.add(
            f"seeds.{r['stage']}.{r['name']}.spread",
            "seeds",
            f"stage {r['stage']}: {r['name']}, half its spread over the runs",
            100.0 * r["spread"],
            "%",
        )
    suite.add(
        "seeds.claims_failing",
        "seeds",
        "estimates whose spread beats their claim",
        sum(r["fails"] for r in rows),
        "1",
    )
    suite.tables["seeds"] = markdown(done, rows)


# -- section: control port under a flood -----------------------------------------------
def section_control(suite: Suite) -> None:
    """The servo loop with 200 clients flooding its control port."""
    import tempfile

    from benchmarks.bench_control import (
        CLIENTS,
        QUICK_SECONDS,
        RSS_TARGET_MIB,
        SECONDS,
        flood_run,
    )
    from evo_door.render.log import MAX_CLIENT_EVENTS

    seconds = QUICK_SECONDS if suite.quick else SECONDS
    with tempfile.TemporaryDirectory() as tmp:
        alone = flood_run(seconds, 0, Path(tmp))
        s = flood_run(seconds, CLIENTS, Path(tmp))
    suite.add(
        "control.alone.on_time",
        "control",
        f"servo loop, {seconds:g} s, no client: cycles on time",
        alone["on_time_fraction"] * 100,
        "%",
    )
    suite.add(
        "control.flood.on_time",
        "control",
        f"servo loop, {seconds:g} s, {CLIENTS} clients flooding the control port: cycles on time",
        s["on_time_fraction"] * 100,
        "%",
        target_text=">= 99.9 %",
        met=s["on_time_fraction"] >= ON_TIME_TARGET,
    )
    suite.add(
        "control.flood.memory_growth",
        "control",
        "flood: the renderer's resident memory growth",
        s["rss_growth_mib"],
        "MiB",
        target_text=f"<= {RSS_TARGET_MIB:g} MiB",
        met=s["rss_growth_mib"] <= RSS_TARGET_MIB,
    )
    suite.add(
        "control.flood.events_kept",
        "control",
        "flood: session events the log kept",
        s["events_kept"],
        "1",
        target_text=f"<= {MAX_CLIENT_EVENTS}",
        met=s["events_kept"] <= MAX_CLIENT_EVENTS,
    )
    suite.add(
        "control.flood.events_dropped",
        "control",
        "flood: events dropped, counted",
        s["events_dropped"],
        "1",
    )
    suite.add("control.flood.log_size", "control", "flood: the log's size", s["log_mib"], "MiB")
    for kind in ("ok", "refused_rate", "refused_client_cap", "refused_log_cap", "refused_input"):
        suite.add(f"control.flood.{kind}", "control", f"flood: answers {kind}", s[kind], "1")
    suite.tables["control"] = (
        f"`evo-door render --params seed_trial --device sim --user swing --realtime` for "
        f"{seconds:g} s in its own process with `--control`, alone and with {CLIENTS} "
        "clients flooding the port (session events of 16 kB, absurd lines; "
        "`bench_control.py`).\n\n"
        + _generic_table([m for m in suite.metrics if m.section == "control"])
    )


# -- section: an FMU as the model ------------------------------------------------------
#: the workbench's time per evaluation of one trial against FMPy's (target: at least)
FMU_RATIO_TARGET = 5.0


def section_fmu(suite: Suite) -> None:
    """The door FMU: one trial per evaluation against FMPy, and a GA on 2 cores."""
    from benchmarks import bench_fmu as bf

    with tempfile.TemporaryDirectory() as tmp:
        fmu = bf.build(Path(tmp))
        trial = bf.one_trial(fmu, suite.quick)
        rows = trial["rows"]
        prof = bf.profile_evaluation(fmu, trial["trial"], 8 if suite.quick else 50)
        (cs_plain,) = [
            r for r in rows if r["interface"] == "cs" and r["way"] == "FMPy" and not r["extracted"]
        ]
        ga = bf.ga_run(fmu, suite.quick, cs_plain["seconds"])
    for r in rows:
        key = f"fmu.trial.{r['interface']}.{r['key']}"
        wb_key = f"fmu.trial.{r['interface']}.workbench.sandbox_on"
        wb_metric = suite.get(wb_key)
        is_plain = r["way"] == "FMPy" and wb_metric is not None and bool(wb_metric.value)
        suite.add(
            key,
            "fmu",
            f"FMU {r['interface'].upper()}, one 2 s trial, {r['way']} {r['setting']}: per evaluation",
            r["seconds"],
            "s",
            ratio=r["seconds"] / wb_metric.value
            if is_plain and wb_metric and wb_metric.value
            else None,
            ratio_to=wb_key if is_plain else None,
        )
        suite.add(
            f"{key}.error_theta",
            "fmu",
            f"  {r['setting']}: max theta error",
            r["error_theta"],
            "rad",
        )
        suite.add(
            f"{key}.error_dtheta",
            "fmu",
            f"  {r['setting']}: max dtheta error",
            r["error_dtheta"],
            "rad/s",
        )
    for interface in ("me", "cs"):
        wb, plain, ok = bf.matched(rows, interface)
        ratio = plain["seconds"] / wb["seconds"]
        suite.add(
            f"fmu.trial.{interface}.speedup",
            "fmu",
            f"FMU {interface.upper()}: FMPy ({plain['setting']}) / workbench (sandbox on), "
            "one trial per evaluation",
            ratio,
            "1",
            target_text=f">= {FMU_RATIO_TARGET:g}x",
            met=ratio >= FMU_RATIO_TARGET,
            note="matched accuracy" if ok else "FMPy less accurate: a lower bound",
        )
    suite.add(
        "fmu.ga.workbench",
        "fmu",
        f"FMU GA {ga['population']} x {ga['generations']}, "
        f"`evo-door run` ({bf.CORES} sandboxes): wall time",
        ga["wall"],
        "s",
    )
    suite.add("fmu.ga.evaluations", "fmu", "FMU GA: evaluations", ga["evaluations"], "1")
    suite.add(
        "fmu.ga.plain",
        "fmu",
        f"FMU GA: FMPy per evaluation, extrapolated to {bf.CORES} cores",
        ga["plain"],
        "s",
        ratio=ga["plain"] / ga["wall"],
        ratio_to="fmu.ga.workbench",
    )
    for name, err in ga["errors"].items():
        suite.add(
            f"fmu.ga.{name}.error", "fmu", f"FMU GA: {name}, error against the truth", err, "%"
        )
    suite.add(
        "fmu.profile.per_candidate",
        "fmu",
        "FMU ME: one candidate under cProfile",
        prof["per_candidate"],
        "s",
    )
    suite.tables["fmu"] = bf.markdown(trial, ga, prof, suite.quick)


# -- section: planning a JND session ---------------------------------------------------
#: a 95 % interval that covers the truth in fewer sessions than this (%) overstates
#: what the session knows
JND_COVERAGE_TARGET = 90.0


def section_jnd(suite: Suite) -> None:
    """Simulated JND sessions: bias, spread and coverage against the number of trials."""
    from benchmarks import bench_jnd as bj

    rows = bj.measure(suite.quick)
    for r in rows:
        key = f"jnd.{r['method']}.{r['trials']}"
        what = f"JND {r['method']}, {r['trials']} trials"
        suite.add(f"{key}.bias", "jnd", f"{what}: median estimate's bias", 100 * r["bias"], "%")
        suite.add(f"{key}.within", "jnd", f"{what}: sessions within +-20 %", 100 * r["within"], "%")
        suite.add(
            f"{key}.coverage",
            "jnd",
            f"{what}: 95 % intervals covering the truth",
            100 * r["coverage"],
            "%",
            target_text=f">= {JND_COVERAGE_TARGET:g} %",
            met=100 * r["coverage"] >= JND_COVERAGE_TARGET,
        )
        suite.add(f"{key}.seconds", "jnd", f"{what}: per session (no device)", r["seconds"], "s")
    for method, k in bj.trials_needed(rows).items():
        suite.add(
            f"jnd.{method}.trials_for_20_percent",
            "jnd",
            f"JND {method}: fewest trials with 90 % of sessions within +-20 %",
            k,
            "1",
            note=None if k else "none of those tried",
        )
    suite.tables["jnd"] = bj.markdown(rows, suite.quick)
    suite.figures["jnd-planning"] = (
        "jnd",
        bj.figure(rows),
        "JND sessions within +-20 % and intervals covering the truth, against trials",
    )


def jnd_markdown(suite: Suite, info: dict) -> str:
    """``benchmarks/jnd.md``: how many trials a JND session needs."""
    return targets_page(
        suite,
        info,
        "jnd",
        "# Planning a JND session (`python -m benchmarks --only jnd`)",
        [suite.tables["jnd"], "", "![sessions within +-20 % against trials](jnd-planning.png)"],
    )


# -- section: mechanisms from blocks, side by side with PathSim ---------------------------
def section_pathsim(suite: Suite) -> None:
    """The soft-close drawer in the workbench and in PathSim, at matched accuracy."""
    # long: one metric per figure of the page, each with its label and unit
    from benchmarks import bench_pathsim as bp

    reason = bp.available()
    if reason:  # an optional dependency: the section says why it measured nothing
        suite.add(
            "pathsim.trial.speedup",
            "pathsim",
            "PathSim side by side",
            None,
            "1",
            note=f"skipped: {reason}",
        )
        suite.notes.append(f"section pathsim skipped: {reason}")
        suite.tables["pathsim"] = f"Skipped: {reason}."
        return
    result = bp.measure(suite.quick)
    wb, ps = bp.per_trial(result)
    if wb:
        suite.add(
            "pathsim.trial.workbench",
            "pathsim",
            f"drawer, one {result['seconds']:g} s trial, workbench "
            f"({bp.setting_text('workbench', wb['setting'])})",
            wb["seconds"],
            "s",
        )
        suite.add(
            "pathsim.trial.workbench.error_x",
            "pathsim",
            "  workbench: max position error",
            wb["error_x"],
            "m",
        )
        suite.add(
            "pathsim.trial.workbench.error_v",
            "pathsim",
            "  workbench: max speed error",
            wb["error_v"],
            "m/s",
        )
    if ps:
        suite.add(
            "pathsim.trial.pathsim",
            "pathsim",
            f"drawer, one trial, PathSim ({bp.setting_text('PathSim', ps['setting'])})",
            ps["seconds"],
            "s",
            ratio=ps["seconds"] / wb["seconds"] if wb else None,
            ratio_to="pathsim.trial.workbench" if wb else None,
        )
        suite.add(
            "pathsim.trial.pathsim.error_x",
            "pathsim",
            "  PathSim: max position error",
            ps["error_x"],
            "m",
        )
        suite.add(
            "pathsim.trial.pathsim.error_v",
            "pathsim",
            "  PathSim: max speed error",
            ps["error_v"],
            "m/s",
        )
    ratio = bp.trial_ratio(result)
    suite.add(
        "pathsim.trial.speedup",
        "pathsim",
        "drawer: PathSim / workbench per trial at matched accuracy",
        ratio,
        "1",
        target_text=f">= {bp.RATIO_TARGET:g}x",
        met=None if ratio is None else ratio >= bp.RATIO_TARGET,
        note="median of interleaved runs" if ratio else "no setting of one tool met the accuracy",
    )
    suite.add(
        "pathsim.compile",
        "pathsim",
        "workbench: first call (compile or cache load)",
        result["compile_seconds"],
        "s",
    )
    ga = result["ga"]
    if ga:
        w, p = ga["workbench"]["per_candidate"], ga["pathsim"]["per_candidate"]
        suite.add(
            "pathsim.ga.workbench",
            "pathsim",
            f"drawer GA evaluation, workbench (population {bp.POPULATION}), per candidate",
            w,
            "s",
        )
        suite.add(
            "pathsim.ga.pathsim",
            "pathsim",
            "drawer GA evaluation, PathSim (built once, re-parameterised), per candidate",
            p,
            "s",
            ratio=p / w,
            ratio_to="pathsim.ga.workbench",
        )
    suite.tables["pathsim"] = bp.markdown(result)


def pathsim_markdown(suite: Suite, info: dict) -> str:
    """``benchmarks/pathsim.md``: the drawer in the workbench and in PathSim."""
    return targets_page(
        suite,
        info,
        "pathsim",
        "# Mechanisms from blocks, side by side with PathSim "
        "(`python -m benchmarks --only pathsim`)",
        [suite.tables["pathsim"]],
    )


RUNNERS = {
    "trial": section_trial,
    "ga": section_ga,
    "scaling": section_scaling,
    "executors": section_executors,
    "device": section_device,
    "startup": section_startup,
    "casestudy": section_casestudy,
    "seeds": section_seeds,
    "control": section_control,
    "fmu": section_fmu,
    "jnd": section_jnd,
    "pathsim": section_pathsim,
}


# -- output ---------------------------------------------------------------------------
def _generic_table(metrics) -> str:
    lines = ["| metric | value | ratio | target | |", "|---|---:|---:|---|---|"]
    for m in metrics:
        verdict = "" if m.met is None else ("met" if m.met else "**not met**")
        value = fmt(m.value, m.unit) if m.value is not None else f"n/a ({m.note})"
        lines.append(
            f"| {m.label} | {value} | {fmt_ratio(m.ratio)} | {m.target_text or ''} | {verdict} |"
        )
    return "\n".join(lines)


def targets_table(suite: Suite) -> str:
    lines = ["| target | measured | | ", "|---|---:|---|"]
    for m in suite.metrics:
        if m.met is None and not m.target_text:
            continue
        verdict = "met" if m.met else "**not met**"
        if m.met is None:
            verdict = f"not measured ({m.note})" if m.note else "not measured"
        measured = fmt(m.value, m.unit) + (f" ({m.note})" if m.note and m.met is not None else "")
        lines.append(f"| {m.label}: {m.target_text} | {measured} | {verdict} |")
    return "\n".join(lines)


def machine(probe=()) -> dict:
    """The machine, versions and commit of a run, and its host probe's seconds
    (:func:`benchmarks.probe.host_probe`, at the run's start and end; none given: [])."""
    import numba
    import scipy

    import evo_door

    versions = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "evo_door": evo_door.__version__,
    }
    for mod in ("deap", "distributed", "matplotlib", "pathsim"):
        try:
            versions[mod] = __import__(mod).__version__
        except ImportError:
            versions[mod] = None
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return {
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "cpus": os.cpu_count(),
        "numba_threads": numba.config.NUMBA_NUM_THREADS,
        "versions": versions,
        "commit": commit or None,
        "probe": list(probe),
    }


def cpu_model() -> str:
    """The processor's name (Linux: /proc/cpuinfo), else what platform knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def page_machine(info: dict, how: str = "medians of repeats") -> str:
    """A page's first line: the machine (:func:`machine`), how and when it measured, the
    commit, and the host probe at the run's start and end where it made one."""
    from benchmarks._util import machine_line

    line = machine_line(f" ({info['cpu']}), numba threads {info['numba_threads']}", how=how)
    line += f" Commit {info['commit']}." * bool(info["commit"])
    return line + probe_sentence(info.get("probe"))


def casestudy_markdown(suite: Suite, info: dict) -> str:
    """``benchmarks/casestudy.md``: the main job's figures that the README and
    ``docs/case-study.md`` quote, with the machine that made them."""
    return "\n".join(
        [
            "# The main job, measured (`python -m benchmarks --only casestudy`)",
            "",
            page_machine(info, how="one run"),
            "",
            suite.tables["casestudy"],
            "",
        ]
    )


def seeds_markdown(suite: Suite, info: dict) -> str:
    """``benchmarks/seeds.md``: the main job's estimates across seeds and CPUs."""
    return "\n".join(
        [
            "# The main job across GA seeds and CPUs (`python -m benchmarks --only seeds`)",
            "",
            page_machine(info, how="four runs"),
            "",
            suite.tables["seeds"],
            "",
        ]
    )


def fmu_markdown(suite: Suite, info: dict) -> str:
    """``benchmarks/fmu.md``: an FMU as the model, against FMPy."""
    return targets_page(
        suite,
        info,
        "fmu",
        "# An FMU as the model, against FMPy (`python -m benchmarks --only fmu`)",
        [suite.tables["fmu"]],
    )


def targets_page(suite: Suite, info: dict, section: str, title: str, body: list[str]) -> str:
    """A section's page: its title, the machine, its targets, then ``body``."""
    own = Suite(quick=suite.quick, metrics=[m for m in suite.metrics if m.section == section])
    return "\n".join(
        [
            title,
            "",
            page_machine(info),
            "",
            "## Targets",
            "",
            targets_table(own),
            "",
            *body,
            "",
        ]
    )


#: the markers of the block of docs/case-study.md that the casestudy section writes
GENERATED_BEGIN = "<!-- generated by python -m benchmarks --only casestudy: do not edit -->"
GENERATED_END = "<!-- end of the generated block -->"


def replace_generated(path: Path, page: str) -> Path:
    """Put ``page`` (``benchmarks/casestudy.md``'s text, its title left out) between the
    generated-block markers of ``path``; a page without them is an error."""
    from evo_door.files import write_text

    text = path.read_text(encoding="utf-8")
    if GENERATED_BEGIN not in text or GENERATED_END not in text:
        raise RuntimeError(f"{path}: no generated block ({GENERATED_BEGIN} ... {GENERATED_END})")
    head, rest = text.split(GENERATED_BEGIN, 1)
    _, tail = rest.split(GENERATED_END, 1)
    body = page.split("\n", 1)[1].strip()  # without the page's own title
    write_text(path, f"{head}{GENERATED_BEGIN}\n{body}\n{GENERATED_END}{tail}")
    return path


def trial_markdown(suite: Suite, info: dict) -> str:
    """``benchmarks/trial.md``: the work-precision figures that the README quotes, with
    the machine that made them, its targets and its figure (``work-precision.png``)."""
    return targets_page(
        suite,
        info,
        "trial",
        "# Work-precision of a trial, measured (`python -m benchmarks --only trial`)",
        [
            f"![{suite.figures['work-precision'][2]}](work-precision.png)",
            "",
            suite.tables["trial"],
        ],
    )


def to_markdown(suite: Suite, info: dict, sections, seconds: float, figures=None) -> str:
    """The suite's Markdown; ``figures`` maps a section figure's name to the path its
    link gives (relative to the Markdown file)."""
    lines = [
        "# Benchmark suite (`python -m benchmarks`)",
        "",
        page_machine(info),
        "",
        f"Sections: {', '.join(sections)}{' (--quick: smoke run, not a measurement)' if suite.quick else ''}; "
        f"{seconds:.0f} s in all. A ratio is the plain (or reference) way's time over the "
        "workbench's: how many times faster the workbench is.",
        "",
    ]
    if any(m.met is not None or m.target_text for m in suite.metrics):
        lines += ["## Targets", "", targets_table(suite), ""]
    for s in sections:
        if s in suite.tables:
            lines += [f"## {s}", ""]
            for name, (section, _, caption) in suite.figures.items():
                if section == s and figures and name in figures:
                    lines += [f"![{caption}]({figures[name]})", ""]
            lines += [suite.tables[s], ""]
    if suite.notes:
        lines += ["## Notes", ""] + [f"- {n}" for n in suite.notes] + [""]
    return "\n".join(lines)


def figure(suite: Suite):
    """The ratios (log scale), the scaling curves and the targets, as a matplotlib Figure."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(15, 8.5), layout="constrained")
    axes = fig.subplots(2, 3)
    ax = axes[0, 0]
    ratios = [
        m
        for m in suite.metrics
        if m.ratio is not None and m.ratio_to and m.ratio_to.endswith(".workbench")
    ]
    if ratios:
        y = range(len(ratios))
        ax.barh(y, [m.ratio for m in ratios], color="tab:blue")
        for i, m in enumerate(ratios):
            ax.text(m.ratio, i, f" {fmt_ratio(m.ratio)}", va="center", fontsize=7)
        names = [m.name.replace("trial.", "trial ").replace("ga.", "GA ") for m in ratios]
        ax.set_yticks(list(y), names, fontsize=7)
        ax.set_xscale("log")
        ax.axvline(1.0, color="k", lw=0.8)
        ax.invert_yaxis()
    ax.set_xlabel("plain way's time / workbench's (log scale)")
    ax.set_title("Speed-up over the plain way")
    ax = axes[0, 1]
    for key in ("population", "trials"):
        c = suite.curves.get(key)
        if c and c["x"]:
            ax.plot(c["x"], c["y"], "o-", label=c["label"])
    ax.set_xlabel("trials x population")
    ax.set_ylabel("one batched evaluation (s)")
    ax.set_title("Door: evaluation cost against batch size")
    if ax.lines:
        ax.legend(fontsize=8)
        ax.set_ylim(bottom=0)
    ax = axes[0, 2]
    c = suite.curves.get("generations")
    if c and c["x"]:
        ax.plot(c["x"], np.asarray(c["y"]) * 1e3, "o-")
        ax.set_ylim(0, 1.3e3 * max(c["y"]))
    ax.set_xlabel("generations")
    ax.set_ylabel("time per generation (ms)")
    ax.set_title("Door GA: time per generation (flat)")
    ax = axes[1, 0]
    c = suite.curves.get("threads")
    if c and c["x"]:
        ax.bar([str(n) for n in c["x"]], c["y"], color="tab:green")
    ax.set_xlabel("numba threads")
    ax.set_ylabel("one batched evaluation, population 100 (s)")
    ax.set_title("Door: threads")
    ax = axes[1, 1]
    ex = [
        (m.name.split(".", 1)[1].replace("_", " "), m.value)
        for m in suite.metrics
        if m.section == "executors" and m.name.count(".") == 1 and m.value is not None
    ]
    if ex:
        ax.bar(range(len(ex)), [e[1] for e in ex], color="tab:orange")
        ax.set_xticks(range(len(ex)), [e[0] for e in ex], fontsize=8)
    ax.set_ylabel("wall time of evo-door run (s)")
    ax.set_title("Executors (start-up and cluster included)")
    ax = axes[1, 2]
    tg = [m for m in suite.metrics if m.target and m.value is not None]
    if tg:
        frac = [max(m.value / m.target, 1e-6) for m in tg]  # an exact 0 drawn at 1e-6
        colors = ["tab:green" if m.met else "tab:red" for m in tg]
        y = list(range(len(tg)))
        ax.hlines(y, 1.0, frac, colors=colors, lw=6)
        ax.scatter(frac, y, color=colors, zorder=3)
        for i, (f, m) in enumerate(zip(frac, tg)):
            ax.text(f, i - 0.3, f" {fmt(m.value, m.unit)}", fontsize=7)
        ax.set_yticks(y, [m.name for m in tg], fontsize=7)
        ax.axvline(1.0, color="k", lw=0.8)
        ax.set_xscale("log")
        ax.set_xlim(min(0.1, min(frac) / 2), max(10.0, max(frac) * 2))
        ax.set_ylim(len(tg) - 0.5, -0.7)
    ax.set_xlabel("measured / target (log scale; below 1: met)")
    ax.set_title("Targets")
    return fig


def save(suite: Suite, out: Path, sections, seconds: float, write_md: bool) -> dict:
    from evo_door.files import save_figure, write_text

    info = machine(suite.probe)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    doc = {
        "suite": "evo-door benchmarks",
        "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "quick": suite.quick,
        "sections": list(sections),
        "seconds": seconds,
        "machine": info,
        "machine_line": _machine_line(info),
        "ratio_meaning": "the ratio_to metric's value divided by this one's (for a plain way: "
        "how many times slower than the workbench)",
        "metrics": [asdict(m) for m in suite.metrics],
        "curves": suite.curves,
        "notes": suite.notes,
    }
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "json": out / f"suite-{stamp}.json",
        "png": out / f"suite-{stamp}.png",
        "md": out / f"suite-{stamp}.md",
    }
    write_text(paths["json"], json.dumps(doc, indent=1, default=_json_default) + "\n")
    save_figure(figure(suite), paths["png"])
    for name, (_, fig, _) in suite.figures.items():
        paths[name] = out / f"suite-{stamp}-{name}.png"
        save_figure(fig, paths[name])
    md = to_markdown(
        suite, info, sections, seconds, {n: f"suite-{stamp}-{n}.png" for n in suite.figures}
    )
    write_text(paths["md"], md)
    if not suite.quick:  # measured: the latest figures, next to benchmarks/suite.md
        for name, (_, fig, _) in suite.figures.items():
            paths[f"{name} (latest)"] = HERE / f"{name}.png"
            save_figure(fig, HERE / f"{name}.png")
    if write_md:
        links = {n: f"{n}.png" for n in suite.figures}
        write_text(HERE / "suite.md", to_markdown(suite, info, sections, seconds, links))
        paths["summary"] = HERE / "suite.md"
    if not suite.quick and "trial" in suite.tables:  # measured: the figures docs quote
        write_text(HERE / "trial.md", trial_markdown(suite, info))
        paths["trial"] = HERE / "trial.md"
    if not suite.quick and "seeds" in suite.tables:
        write_text(HERE / "seeds.md", seeds_markdown(suite, info))
        paths["seeds"] = HERE / "seeds.md"
    if not suite.quick and "fmu" in suite.tables:
        write_text(HERE / "fmu.md", fmu_markdown(suite, info))
        paths["fmu"] = HERE / "fmu.md"
    if not suite.quick and "jnd" in suite.tables:
        write_text(HERE / "jnd.md", jnd_markdown(suite, info))
        paths["jnd"] = HERE / "jnd.md"
    if not suite.quick and suite.get("pathsim.trial.speedup") and "pathsim" in suite.tables:
        write_text(HERE / "pathsim.md", pathsim_markdown(suite, info))
        paths["pathsim"] = HERE / "pathsim.md"
    if not suite.quick and "casestudy" in suite.tables:  # measured: the figures docs quote
        text = casestudy_markdown(suite, info)
        write_text(HERE / "casestudy.md", text)
        paths["casestudy"] = HERE / "casestudy.md"
        # docs/case-study.md quotes the same tables between its markers
        paths["case-study doc"] = replace_generated(ROOT / "docs" / "case-study.md", text)
    return paths


def _machine_line(info) -> str:
    v = info["versions"]
    return f"{info['platform']}, {info['cpus']} CPUs, Python {v['python']}, numba {v['numba']}"


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(type(x).__name__)


# -- compare --------------------------------------------------------------------------
def load_json(path) -> dict:
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except FileNotFoundError:
        raise UserError(f"{p}: no such file") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{p}: not a suite JSON file ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("metrics"), list):
        raise UserError(f"{p}: not a suite JSON file (no metrics list)")
    return doc


def compare(old: dict, new: dict) -> str:
    """A table of new / old per metric both runs have (below 1: smaller now)."""
    before = {m["name"]: m for m in old["metrics"]}
    lines = [
        f"old: {old.get('date')} ({old.get('machine_line', '')})",
        f"new: {new.get('date')} ({new.get('machine_line', '')})",
        "",
        f"{'metric':<52} {'old':>12} {'new':>12} {'new/old':>8}",
    ]
    shared = 0
    for m in new["metrics"]:
        o = before.get(m["name"])
        if o is None:
            continue
        shared += 1
        a, b = o["value"], m["value"]
        r = f"{b / a:.3f}" if a not in (None, 0) and b is not None else "n/a"
        lines.append(f"{m['name']:<52} {fmt(a, o['unit']):>12} {fmt(b, m['unit']):>12} {r:>8}")
    only = sorted(set(before) ^ {m["name"] for m in new["metrics"]})
    if only:
        lines.append(
            f"\n{len(only)} metric(s) in one run only: {', '.join(only[:8])}{' ...' * (len(only) > 8)}"
        )
    if not shared:
        lines.append("no metric in common")
    return "\n".join(lines)


# -- command line ---------------------------------------------------------------------
def parse_sections(text: str | None) -> list[str]:
    if not text:
        return list(SECTIONS)
    names = [s.strip() for s in text.split(",") if s.strip()]
    bad = [s for s in names if s not in SECTIONS]
    if bad or not names:
        raise UserError(
            f"--only: unknown section {', '.join(map(repr, bad)) or repr(text)} (choose from {', '.join(SECTIONS)})"
        )
    return [s for s in SECTIONS if s in names]


def build_parser(prog: str = "python -m benchmarks") -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog=prog,
        description="Run evo-door's benchmarks as one suite: times and ratios against the "
        "plain way (scipy solve_ivp, a plain GA loop), scaling, targets.",
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: fewer repeats and points, small GAs; not a measurement",
    )
    ap.add_argument(
        "--only",
        metavar="SECTION[,SECTION]",
        help=f"run only these sections ({', '.join(SECTIONS)})",
    )
    ap.add_argument(
        "--out",
        metavar="DIR",
        default=None,
        help="folder of the JSON, PNG and Markdown (default benchmarks/results/)",
    )
    ap.add_argument(
        "--compare",
        metavar="JSON",
        nargs="+",
        help="OLD.json: run, then print new / old per metric; OLD.json NEW.json: compare two runs without running",
    )
    return ap


def main(argv=None, prog: str = "python -m benchmarks") -> int:
    args = build_parser(prog).parse_args(argv)
    try:
        return _main(args)
    except UserError as exc:
        name = "evo-door" if prog.startswith("evo-door") else "benchmarks"
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 2


def _main(args) -> int:
    old = None
    if args.compare:
        if len(args.compare) > 2:
            raise UserError("--compare takes OLD.json, or OLD.json NEW.json")
        old = load_json(args.compare[0])
        if len(args.compare) == 2:
            print(compare(old, load_json(args.compare[1])))
            return 0
    sections = parse_sections(args.only)
    out = Path(args.out) if args.out else DEFAULT_OUT
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: not a folder")
    suite = Suite(quick=args.quick)
    if not suite.quick:  # the host's speed at the hour, beside the figures (not in a smoke run)
        suite.probe.append(host_probe())
    t_start = time.perf_counter()
    failed = []
    for i, name in enumerate(sections, 1):
        progress(f"{i}/{len(sections)} {name} ...")
        t0 = time.perf_counter()
        try:
            RUNNERS[name](suite)
        except Exception as exc:  # one broken section does not lose the others' figures
            failed.append(name)
            line = " ".join(f"{type(exc).__name__}: {exc}".split())[:300]
            suite.notes.append(f"section {name} failed: {line}")
            progress(f"{i}/{len(sections)} {name} FAILED: {line}")
            continue
        progress(f"{i}/{len(sections)} {name} done in {time.perf_counter() - t0:.0f} s")
    seconds = time.perf_counter() - t_start
    if not suite.quick:
        suite.probe.append(host_probe())
    write_md = not args.quick and args.only is None and not failed
    paths = save(suite, out, sections, seconds, write_md)
    info = machine(suite.probe)
    links = {n: str(paths[n]) for n in suite.figures}
    print(to_markdown(suite, info, sections, seconds, links))
    for p in paths.values():
        print(f"wrote {p}")
    if old is not None:
        new = json.loads(paths["json"].read_text())
        print()
        print(compare(old, new))
    if failed:
        print(f"benchmarks: {len(failed)} section(s) failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0
