"""Door model speed: one trial, and a population in one batched call, against scipy.

Targets: a 5 s trial at 1024 Hz in at most 10 ms on one core; a population
of 100 in one batched call scales with the cores available. The plain way is scipy's
``solve_ivp`` with a Python right-hand side calling the same door equations (the
kernels' pure-Python twins, ``py_func``), timed in the same run.

    python benchmarks/bench_door.py               # writes benchmarks/door.md
    python benchmarks/bench_door.py --no-write
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numba  # noqa: E402

from benchmarks._util import half_sine_pulses, machine_line, median_time, publish  # noqa: E402
from benchmarks.plain import pure_python_trials, solve_trial  # noqa: E402
from evo_door.models import get_model  # noqa: E402
from evo_door.sim import simulate, simulate_batch  # noqa: E402
from evo_door.sim.simulate import param_vector  # noqa: E402

DT = 1.0 / 1024.0
SECONDS = 5.0


def force_profile():
    """Push from fully open (half-sine 11 N), free decay, a pull back open: the latch is
    never reached (the suite's smooth door trial)."""
    t = np.arange(int(round(SECONDS / DT))) * DT
    return t, half_sine_pulses(t, ((0.2, 0.2, 11.0), (2.6, 0.4, -12.0)))


def latch_profile():
    """From latched shut: a 60 N pull over 1 s unlocks the door, which swings open onto
    its stop; a 40 N push over 1.2 s swings it back into the wall and latches it (the
    suite's latch trial of the door, started at rest on its latch)."""
    t = np.arange(int(round(SECONDS / DT))) * DT
    return t, half_sine_pulses(t, ((0.2, 1.0, -60.0), (2.5, 1.2, 40.0)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    model = get_model("door")
    p = param_vector(model.load_params("default"))
    t, f = force_profile()
    simulate(model, p, f, DT, theta0=0.0)  # compile / load the cache
    one = median_time(lambda: simulate(model, p, f, DT, theta0=0.0), 15)

    # plain way: solve_ivp around the compiled accel (what a user of numba alone would
    # write) and around pure Python (what scipy alone gives: NUMBA_DISABLE_JIT=1 in a
    # fresh process)
    y0 = (0.0, 0.0)
    solve_trial(model.accel, p, DT, f, y0, "RK45")
    compiled_rhs = median_time(lambda: solve_trial(model.accel, p, DT, f, y0, "RK45"), 3)
    python_rhs = None
    try:
        python_rhs = pure_python_trials("door", "default", f, DT, y0, ("RK45",))["RK45"][0]
    except RuntimeError as exc:  # reported, not fatal
        print(exc)

    # batch scaling with threads
    rng = np.random.default_rng(0)
    # vary the specifications +-20 %, keep geometry and numerics
    P = np.tile(p, (100, 1))
    for name in ("K", "F_load", "M", "I_z", "T_atO", "T_atA", "T_atB", "mu", "F_atC", "F_atD"):
        i = model.params.index(name)
        P[:, i] = p[i] * rng.uniform(0.8, 1.2, 100)
    simulate_batch(model, P[:2], f, DT, theta0=0.0)
    rows = []
    max_threads = numba.config.NUMBA_NUM_THREADS
    for n in sorted({1, 2, max_threads}):
        if n > max_threads:
            continue
        numba.set_num_threads(n)
        rows.append((n, median_time(lambda: simulate_batch(model, P, f, DT, theta0=0.0), 3)))
    numba.set_num_threads(max_threads)

    lines = [
        "# Door model benchmark (`benchmarks/bench_door.py`)",
        "",
        machine_line(),
        "",
        f"One 5 s trial at 1024 Hz ({t.size} samples), preset `default`, integrator "
        f"{model.method} x{model.substeps} sub-steps:",
        "",
        "| way | seconds per trial | ratio to evo-door |",
        "|---|---|---|",
        f"| evo-door `simulate` (compiled, fixed step) | {one * 1e3:.2f} ms | 1 |",
        f"| scipy `solve_ivp` RK45 rtol 1e-6, compiled `accel` | {compiled_rhs * 1e3:.0f} ms "
        f"| {compiled_rhs / one:.0f}x |",
    ]
    if python_rhs is not None:
        lines.append(
            f"| scipy `solve_ivp` RK45 rtol 1e-6, pure-Python model | "
            f"{python_rhs * 1e3:.0f} ms | {python_rhs / one:.0f}x |"
        )
    lines += [
        "",
        "Target: at most 10 ms per trial on one core: "
        + ("met" if one <= 0.010 else "**missed**")
        + ".",
        "",
        "A population of 100 parameter sets in one batched call (`simulate_batch`, "
        "numba `prange`):",
        "",
        "| threads | seconds | per individual | speed-up |",
        "|---|---|---|---|",
    ]
    for n, s in rows:
        lines.append(f"| {n} | {s:.3f} | {s / 100 * 1e3:.2f} ms | {rows[0][1] / s:.2f}x |")
    publish("\n".join(lines) + "\n", "door.md", write=not args.no_write)


if __name__ == "__main__":
    main()
