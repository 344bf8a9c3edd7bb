"""Haptic model speed: one trial, and device-force calls, against the plain way.

Targets (issue 3): one 5 s trial sampled at 1024 Hz in at most 2 ms on one core, where
scipy's ``solve_ivp`` with a Python right-hand side takes about 200 ms; one
device-space force evaluation from Python under 2 us, from compiled code under 100 ns.

    python benchmarks/bench_haptic.py             # writes benchmarks/haptic.md
    python benchmarks/bench_haptic.py --no-write
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numba  # noqa: E402
from numba import njit  # noqa: E402

from benchmarks._util import half_sine_pulses, machine_line, median_time  # noqa: E402
from evo_door.models import get_model  # noqa: E402
from evo_door.models.haptic import device_force, device_force_vector, on_path  # noqa: E402
from evo_door.sim import simulate  # noqa: E402
from evo_door.sim.simulate import param_vector  # noqa: E402

DT = 1.0 / 1024.0
SECONDS = 5.0


def force_profile():
    """Pull the latched door open, let it run, push it back and latch it."""
    t = np.arange(int(round(SECONDS / DT))) * DT
    return t, half_sine_pulses(t, ((0.2, 1.0, -30.0), (2.5, 1.2, 25.0)))


@njit(cache=True)
def _servo_loop(y, z, p, out):
    """One device-force call per sampled handle position, as a compiled servo loop makes."""
    acc = 0.0
    for i in range(y.shape[0]):
        device_force(0.001, y[i], z[i], 0.0, 0.05, -0.02, p, out)
        acc += out[1]
    return acc


PLAIN_CODE = """
import sys, time, numpy as np
sys.path.insert(0, {root!r})
from benchmarks.bench_haptic import force_profile, DT
from evo_door.models import get_model
from evo_door.sim.simulate import param_vector
from scipy.integrate import solve_ivp
m = get_model('haptic'); p = param_vector(m.load_params('seed_trial'))
t, f = force_profile()
rhs = lambda s, y: (y[1], m.accel(y[0], y[1], float(np.interp(s, t, f)), p))
t0 = time.perf_counter()
solve_ivp(rhs, (t[0], t[-1]), [np.pi / 2, 0.0], t_eval=t, method='RK45', rtol=1e-6, atol=1e-9, max_step=4 * DT)
print(time.perf_counter() - t0)
"""


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

    # the plain way: solve_ivp with the model's pure-Python right-hand side
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    out = subprocess.run(
        [sys.executable, "-c", PLAIN_CODE.format(root=str(ROOT))],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    plain = float(out.stdout.strip().splitlines()[-1]) if out.returncode == 0 else float("nan")

    # device force from Python (the convenience wrapper, on floats) and from compiled code
    pos = on_path(0.7, 0.3)
    vel = (0.0, 0.05, -0.04)
    buf = np.empty(3)
    device_force_vector(pos, vel, p, buf)
    n_py = 50_000
    py_call = (
        median_time(lambda: [device_force_vector(pos, vel, p, buf) for _ in range(n_py)], 5) / n_py
    )
    n_c = 2_000_000
    angle = 0.5 + 1e-6 * np.arange(n_c)  # the handle creeping along its path
    y, z = 0.3 * np.sin(angle) - 0.158, 0.3 * np.cos(angle) - 0.138
    _servo_loop(y[:10], z[:10], p, buf)
    c_call = median_time(lambda: _servo_loop(y, z, p, buf), 5) / n_c

    rows = [
        (
            "one 5 s trial at 1024 Hz, `simulate` (ROS2 x2, compiled)",
            f"{one * 1e3:.2f} ms",
            "<= 2 ms",
            one <= 2e-3,
        ),
        (
            "same trial, scipy `solve_ivp` RK45 + pure-Python model",
            f"{plain * 1e3:.0f} ms",
            "~200 ms (reference)",
            None,
        ),
        ("speed-up over the plain way", f"{plain / one:.0f}x", "(issue: ~200 ms vs 2 ms)", None),
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
    text = "\n".join(lines) + "\n"
    print(text)
    if not args.no_write:
        (Path(__file__).parent / "haptic.md").write_text(text)
        print(f"wrote {Path(__file__).parent / 'haptic.md'}")


if __name__ == "__main__":
    main()
