"""Haptic model speed: one trial, and device-force calls, against the plain way.

Targets: one 5 s trial sampled at 1024 Hz in at most 2 ms on one core, where
scipy's ``solve_ivp`` with a Python right-hand side takes about 200 ms; one
device-space force evaluation from Python under 2 us, from compiled code under 100 ns.

    python benchmarks/bench_haptic.py             # writes benchmarks/haptic.md
    python benchmarks/bench_haptic.py --no-write
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numba  # noqa: E402
from numba import njit  # noqa: E402

from benchmarks._util import half_sine_pulses, machine_line, median_time, publish  # noqa: E402
from benchmarks.plain import pure_python_runs  # noqa: E402
from evo_door.models import get_model  # noqa: E402
from evo_door.models.haptic import device_force, device_force_vector, on_path  # noqa: E402
from evo_door.sim import simulate  # noqa: E402
from evo_door.sim.simulate import param_vector  # noqa: E402

DT = 1.0 / 1024.0
SECONDS = 5.0
#: CPU time (s) after which the plain way's run is stopped.
PLAIN_LIMIT = 60.0


def force_profile():
    """Pull the latched door open, let it run, push it back and latch it (the suite's
    latch trial of the haptic model)."""
    t = np.arange(int(round(SECONDS / DT))) * DT
    return t, half_sine_pulses(t, ((0.2, 1.0, -30.0), (2.5, 1.2, 25.0)))


#: Where :func:`swing_profile` starts: at rest, 0.3 rad from fully open.
SWING_THETA0 = 0.3


def swing_profile():
    """From :data:`SWING_THETA0` at rest, a 9 N push over 0.4 s swings the door to
    1.26 rad, where friction stops it short of the latch (1.54 rad); a 7 N pull over
    0.4 s brings it back to 0.37 rad (the suite's smooth trial of the haptic model)."""
    t = np.arange(int(round(SECONDS / DT))) * DT
    return t, half_sine_pulses(t, ((0.2, 0.4, 9.0), (2.6, 0.4, -7.0)))


@njit(cache=True)
def _servo_loop(y, z, p, out):
    """One device-force call per sampled handle position, as a compiled servo loop makes."""
    acc = 0.0
    for i in range(y.shape[0]):
        device_force(0.001, y[i], z[i], 0.0, 0.05, -0.02, p, out)
        acc += out[1]
    return acc


def device_force_costs(p, quick: bool = False) -> tuple[float, float]:
    """Seconds per device-force evaluation: from Python (the convenience wrapper, on
    floats) and from compiled code (a servo loop over a creeping handle)."""
    pos = on_path(0.7, 0.3)
    vel = (0.0, 0.05, -0.04)
    buf = np.empty(3)
    device_force_vector(pos, vel, p, buf)
    n_py = 10_000 if quick else 50_000
    py_call = (
        median_time(lambda: [device_force_vector(pos, vel, p, buf) for _ in range(n_py)], 5) / n_py
    )
    n_c = 200_000 if quick else 2_000_000
    angle = 0.5 + 1e-6 * np.arange(n_c)  # the handle creeping along its path
    y, z = 0.3 * np.sin(angle) - 0.158, 0.3 * np.cos(angle) - 0.138
    _servo_loop(y[:10], z[:10], p, buf)
    c_call = median_time(lambda: _servo_loop(y, z, p, buf), 5) / n_c
    return py_call, c_call


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    model = get_model("haptic")
    p = param_vector(model.load_params("seed_trial"))
    t, f = force_profile()
    r = simulate(model, p, f, DT)
    assert r.ok
    numba.set_num_threads(1)
    one = median_time(lambda: simulate(model, p, f, DT), 31)

    # the plain way: solve_ivp with the model's pure-Python right-hand side (its sign-law
    # friction can make it chatter at rest: stopped after PLAIN_LIMIT s of CPU time)
    plain_text = "n/a"
    plain = float("nan")
    try:
        run = pure_python_runs(
            "haptic", "seed_trial", f, DT, (model.theta0, 0.0), ("RK45",), PLAIN_LIMIT
        )["RK45"]
        if run.complete:
            plain = run.seconds
            plain_text = f"{plain * 1e3:.0f} ms"
        else:
            plain_text = f"no answer ({run.stopped} at t = {run.reached:.2f} s)"
    except RuntimeError as exc:
        print(exc)

    py_call, c_call = device_force_costs(p)

    rows = [
        (
            f"one 5 s trial at 1024 Hz, `simulate` ({model.method} x{model.substeps}, compiled)",
            f"{one * 1e3:.2f} ms",
            "<= 2 ms",
            one <= 2e-3,
        ),
        (
            "same trial, scipy `solve_ivp` RK45 + pure-Python model",
            plain_text,
            "~200 ms (reference)",
            None,
        ),
        (
            "speed-up over the plain way",
            f"{plain / one:.0f}x" if np.isfinite(plain) else "n/a",
            "(aimed at: ~200 ms vs 2 ms)",
            None,
        ),
        (
            "device force from Python (`device_force_vector`)",
            f"{py_call * 1e6:.2f} us",
            "< 2 us",
            py_call < 2e-6,
        ),
        (
            "device force from compiled code (servo loop)",
            f"{c_call * 1e9:.0f} ns",
            "< 100 ns",
            c_call < 100e-9,
        ),
    ]
    lines = [
        "# Haptic model benchmark (`benchmarks/bench_haptic.py`)",
        "",
        machine_line(" (one thread used)"),
        "",
        "Trial: preset `seed_trial`, a pull that unlocks the latched door, free motion, "
        "a push that latches it again (5120 samples).",
        "",
        "| what | measured | target | |",
        "|---|---|---|---|",
    ]
    for what, value, target, ok in rows:
        verdict = "" if ok is None else ("met" if ok else "**missed**")
        lines.append(f"| {what} | {value} | {target} | {verdict} |")
    publish("\n".join(lines) + "\n", "haptic.md", write=not args.no_write)


if __name__ == "__main__":
    main()
