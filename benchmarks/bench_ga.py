"""GA speed: evo-door's batched compiled GA against a plain scipy + DEAP loop.

For each model: one 5 s trial at 1024 Hz (a push from fully open and free decay, then a
pull), its target made by the model itself with its default parameters; a GA of
population 100 x 20 generations (AMESim's settings) on four free parameters, timed
end to end. The plain way (scipy ``solve_ivp`` with a Python right-hand side, one
simulation per DEAP individual) is timed on a few evaluations and extrapolated to the
same number of evaluations: running it would take minutes.

Then the scaling: time of one batched evaluation for trials x population, and of whole
GA runs for several generation counts; both should grow linearly.

    python benchmarks/bench_ga.py                  # haptic and door, writes benchmarks/ga.md
    python benchmarks/bench_ga.py --models tests.conftest:OSCILLATOR_MODEL --no-write
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._util import evo_door_command, half_sine_pulses  # noqa: E402
from evo_door.data.trial import Trial  # noqa: E402
from evo_door.errors import UserError  # noqa: E402
from evo_door.models import get_model  # noqa: E402
from evo_door.optim import GASettings, GeneticAlgorithm, Objective, Problem  # noqa: E402
from evo_door.sim import simulate  # noqa: E402

DT = 1.0 / 1024.0
SECONDS = 5.0

#: Free parameters of the benchmark per model (others: the first four declared
#: "specification" / "sensation" parameters with a non-zero default).
FREE = {
    "haptic": ["inertia", "friction_closing", "friction_opening", "viscous_damping"],
    "haptic_tanh": ["inertia", "friction_closing", "friction_opening", "viscous_damping"],
    "door": ["K", "F_load", "T_atO", "F_atD"],
    "oscillator": ["k", "c", "inertia"],
}


def force_profile(seconds=SECONDS, dt=DT):
    """A push toward closing from open (half-sine), free motion, a pull back, free motion."""
    t = np.arange(int(round(seconds / dt))) * dt
    return t, half_sine_pulses(t, ((0.2, 0.35, 25.0), (2.6, 0.35, -25.0)))


def choose_free(model):
    names = FREE.get(model.name)
    if names is None or not all(n in model.params for n in names):
        names = [
            p.name
            for p in model.params
            if p.group in ("specification", "sensation") and p.default != 0
        ][:4]
    return names


def make_problem(model, n_trials=1, seconds=SECONDS):
    t, f = force_profile(seconds)
    truth = model.params.defaults
    theta0 = model.theta0
    trials = []
    for k in range(n_trials):
        scale = 1.0 + 0.1 * k
        r = simulate(model, truth, f * scale, DT, theta0=theta0)
        if not r.ok:
            raise RuntimeError(f"{model.name}: the benchmark trial blows up with the defaults")
        trials.append(
            Trial(
                t,
                f * scale,
                r.theta,
                r.dtheta,
                r.ddtheta,
                trial_id=f"b{k}",
                theta0=theta0,
                dtheta0=0.0,
            )
        )
    free = choose_free(model)
    lo, hi = [], []
    for n in free:
        p = model.params[n]
        lo.append(max(p.lower, 0.5 * p.default))
        hi.append(min(p.upper, 1.5 * p.default))
    return Problem(model, free, lo, hi, truth, trials, Objective("max_square", 1))


def time_ga(problem, population=100, generations=20, seed=1):
    ga = GeneticAlgorithm(GASettings(population=population, generations=generations, seed=seed))
    t0 = time.perf_counter()
    state = ga.run(problem)
    return time.perf_counter() - t0, state


def time_plain(problem, n_eval=3):
    """Seconds per evaluation of the plain way: solve_ivp, Python RHS, force by np.interp."""
    from scipy.integrate import solve_ivp

    model = problem.model
    accel = getattr(model.accel, "py_func", model.accel)
    tr = problem.fit.trials[0]
    rng = np.random.default_rng(0)
    X = rng.uniform(problem.lower, problem.upper, (n_eval, problem.n_var))
    t0 = time.perf_counter()
    for x in X:
        p = problem.full(x)[0]

        def rhs(t, y, p=p):
            return (y[1], accel(y[0], y[1], float(np.interp(t, tr.t, tr.force)), p))

        sol = solve_ivp(
            rhs,
            (tr.t[0], tr.t[-1]),
            [tr.theta0, tr.dtheta0],
            t_eval=tr.t,
            rtol=1e-6,
            atol=1e-9,
            max_step=4 * tr.dt,
        )
        _ = np.max((sol.y[1] - tr.dtheta[: sol.y.shape[1]]) ** 2)
    return (time.perf_counter() - t0) / n_eval


def time_eval(problem, population, repeat=3):
    rng = np.random.default_rng(1)
    X = rng.uniform(problem.lower, problem.upper, (population, problem.n_var))
    problem.evaluate(X[:2])
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        problem.evaluate(X)
        best = min(best, time.perf_counter() - t0)
    return best


def linear_fit(x, y):
    """Slope, intercept and R^2 of y = a x + b."""
    a, b = np.polyfit(x, y, 1)
    pred = a * np.asarray(x) + b
    ss = np.sum((np.asarray(y) - np.mean(y)) ** 2)
    return a, b, 1.0 - np.sum((np.asarray(y) - pred) ** 2) / ss if ss > 0 else 1.0


def experiment_yaml(model, problem, population, generations, seed=1, run="bench") -> str:
    """The experiment file of ``problem``'s GA on the trials of ``trials.h5`` next to it."""
    free = "\n".join(
        f"  {n}: [{float(lo)!r}, {float(hi)!r}]"
        for n, lo, hi in zip(problem.free, problem.lower, problem.upper)
    )
    return (
        f"name: {run}\nmodel: {model}\ntarget: {{data: trials.h5}}\nfree:\n{free}\n"
        "objective: {kind: max_square, derivative: 1}\n"
        f"algorithm: {{population: {population}, generations: {generations}, seed: {seed}}}\n"
    )


def time_run(name, problem, population=100, generations=20, seed=1):
    """Seconds of ``run_experiment`` for the same GA: checkpoint to HDF5 every generation.

    What ``evo-door run`` spends after start-up (imports, numba cache loading): the GA
    plus writing the results file after every generation, and the final responses.
    """
    import tempfile

    from evo_door.data.io import write_trials
    from evo_door.experiment import load_experiment, run_experiment

    text = experiment_yaml(name, problem, population, generations, seed)
    with tempfile.TemporaryDirectory() as tmp:
        write_trials(Path(tmp) / "trials.h5", problem.fit.trials)
        (Path(tmp) / "bench.yaml").write_text(text)
        exp = load_experiment(Path(tmp) / "bench.yaml")
        t0 = time.perf_counter()
        run = run_experiment(exp, Path(tmp) / "run.h5")
        secs = time.perf_counter() - t0
        size = (Path(tmp) / "run.h5").stat().st_size
        # the whole command from a shell: interpreter, imports, numba's cache, the run
        cli = ["run", Path(tmp) / "bench.yaml", "--out", Path(tmp) / "cli.h5", "--quiet"]
        cli_secs, _ = evo_door_command(cli, cwd=tmp)
    return secs, run, size, cli_secs


def bench_model(name, quick=False):
    model = get_model(name)
    out = {"model": model.name, "method": model.method, "substeps": model.substeps}
    problem = make_problem(model)
    out["free"] = problem.free
    time_eval(problem, 4, repeat=1)  # compile / load caches
    secs, state = time_ga(problem)
    out["ga_s"] = secs
    out["run_s"], run, out["run_bytes"], out["cli_s"] = time_run(name, problem)
    assert np.array_equal(run.jobs[0].ga.best_x, state.best_x)  # the same GA, bit for bit
    out["evaluations"] = state.evaluations
    out["blowups"] = state.blowups
    out["best"] = state.best_fitness
    out["eval_s"] = float(np.sum(state.eval_times))
    plain = time_plain(problem, n_eval=2 if quick else 3)
    out["plain_eval_s"] = plain
    out["plain_ga_s"] = plain * state.evaluations
    # scaling with trials x population: one batched evaluation
    rows = []
    for n_trials in (1, 2, 4):
        prob = make_problem(model, n_trials)
        for pop in (50, 100) if quick else (50, 100, 200):
            rows.append((n_trials, pop, n_trials * pop, time_eval(prob, pop)))
    out["eval_scaling"] = rows
    gens = []
    for g in (5, 10) if quick else (5, 10, 20, 40):
        gens.append((g, time_ga(problem, 100, g)[0]))
    out["gen_scaling"] = gens
    return out


def report(results) -> str:
    import numba

    lines = [
        "# GA benchmark (`benchmarks/bench_ga.py`)",
        "",
        f"Machine: {platform.platform()}, {os.cpu_count()} CPUs, numba threads "
        f"{numba.get_num_threads()}, Python {platform.python_version()}, "
        f"numba {numba.__version__}. Measured {time.strftime('%Y-%m-%d %H:%M')}; "
        "other processes may have shared the cores.",
        "",
        "One 5 s trial at 1024 Hz, population 100 x 20 generations (AMESim's settings), "
        "max-square objective on angular speed, four free parameters. Plain = scipy "
        "`solve_ivp` (RK45, rtol 1e-6, Python right-hand side, force by `np.interp`), "
        "one call per individual as in a plain DEAP loop: a few calls timed, "
        "extrapolated to the same number of evaluations.",
        "",
        "GA 100 x 20: the engine alone (`GeneticAlgorithm.run`). With HDF5: the same GA "
        "through `run_experiment`, writing the results file after every generation. "
        "Command: `evo-door run` from a shell, start-up included (interpreter, imports, "
        "loading numba's cached kernels: about 1 s).",
        "",
        "| model | integrator | GA 100 x 20 | with HDF5 | command | evaluations | per evaluation "
        "| plain per evaluation | plain GA (extrapolated) | speed-up | target |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    targets = {"haptic": 2.0, "door": 10.0}
    for r in results:
        tgt = targets.get(r["model"])

        def ok(secs, tgt=tgt):
            return "met" if secs < tgt else "**missed**"

        verdict = (
            ""
            if tgt is None
            else (
                f"< {tgt:g} s: GA {ok(r['ga_s'])}, "
                f"with HDF5 {ok(r['run_s'])}, "
                f"command {ok(r['cli_s'])}"
            )
        )
        lines.append(
            f"| {r['model']} | {r['method']} x{r['substeps']} | {r['ga_s']:.2f} s | "
            f"{r['run_s']:.2f} s | {r['cli_s']:.2f} s | {r['evaluations']} | "
            f"{1e3 * r['eval_s'] / r['evaluations']:.3f} ms | "
            f"{1e3 * r['plain_eval_s']:.0f} ms | {r['plain_ga_s']:.0f} s | "
            f"{r['plain_ga_s'] / r['ga_s']:.0f}x | {verdict} |"
        )
    lines += [
        "",
        "## Scaling",
        "",
        "Cost of one batched evaluation against trials x population (each trial 5 s):",
        "",
    ]
    for r in results:
        rows = r["eval_scaling"]
        a, b, r2 = linear_fit([x[2] for x in rows], [x[3] for x in rows])
        lines += [
            f"**{r['model']}**: {1e3 * a:.3f} ms per trial-individual, offset "
            f"{1e3 * b:.2f} ms, R^2 = {r2:.4f}",
            "",
            "| trials | population | trials x population | seconds |",
            "|---|---|---|---|",
        ]
        lines += [f"| {t} | {p} | {tp} | {s:.4f} |" for t, p, tp, s in rows]
        g = r["gen_scaling"]
        a, b, r2 = linear_fit([x[0] for x in g], [x[1] for x in g])
        lines += [
            "",
            f"GA runs (population 100) against generations: {a:.3f} s per generation, "
            f"offset {b:.3f} s, R^2 = {r2:.4f}",
            "",
            "| generations | seconds |",
            "|---|---|",
        ]
        lines += [f"| {gg} | {s:.3f} |" for gg, s in g]
        lines.append("")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=["haptic", "door"])
    ap.add_argument("--quick", action="store_true", help="fewer scaling points")
    ap.add_argument("--no-write", action="store_true", help="print, do not write benchmarks/ga.md")
    args = ap.parse_args(argv)
    results = []
    for name in args.models:
        try:
            r = bench_model(name, args.quick)
        except UserError as exc:
            print(f"{name}: skipped ({exc})")
            continue
        print(
            f"{r['model']}: GA 100x20 {r['ga_s']:.2f} s, run with checkpoints "
            f"{r['run_s']:.2f} s, command {r['cli_s']:.2f} s ({r['evaluations']} evaluations, "
            f"{r['blowups']} blow-ups), plain {1e3 * r['plain_eval_s']:.0f} ms per evaluation "
            f"-> {r['plain_ga_s']:.0f} s"
        )
        results.append(r)
    text = report(results)
    print(text)
    if not args.no_write and results:
        (Path(__file__).parent / "ga.md").write_text(text)
        print(f"wrote {Path(__file__).parent / 'ga.md'}")


if __name__ == "__main__":
    main()
