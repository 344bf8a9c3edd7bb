"""Renderer speed: the servo loop in real time, on the simulated device and over TCP.

Targets: with the simulated device the loop holds 2500 Hz for 60 s with at
least 99.9 % of its cycles on time; over the HapticMaster emulator on loopback, state
the achievable rate and the round trip. The emulator runs in its own process
(``evo-door emulate hapticmaster``), as a real device would be another machine.

    python benchmarks/bench_render.py                  # writes benchmarks/render.md
    python benchmarks/bench_render.py --seconds 10 --no-write
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._util import free_port, machine_line, publish  # noqa: E402
from evo_door.models import get_model  # noqa: E402
from evo_door.render.device import SimDevice  # noqa: E402
from evo_door.render.loop import ServoLoop  # noqa: E402

RATE = 2500.0
TCP_RATES = (2500.0, 2000.0, 1500.0, 1000.0, 500.0)
ON_TIME = 0.999


def sim_run(params, seconds: float, friction: str) -> dict:
    """The loop paced on the wall clock with the simulated device (user "open"); the
    tanh law samples the end stops explicitly and needs 40 N s/m of device damping."""
    damping = 40.0 if friction == "tanh" else 2.0
    loop = ServoLoop(
        SimDevice("open", seed=1, damping=damping),
        params,
        RATE,
        realtime=True,
        watchdog_misses=10**9,
        friction=friction,
    )
    loop.run(seconds)
    return loop.statistics


def log_growth(params, seconds: float, folder: Path) -> dict:
    """How fast a render's log grows: a render of ``seconds`` of simulated time (user
    "swing", 2500 Hz, the 1 kHz log; unpaced: the sizes depend on the rows, not the
    clock) with its side file, as ``render --log`` writes it. Returns bytes per hour of
    session of the side file while rendering (``partial``) and of the final log
    (``final``), and the bytes of rows the log holds in memory at the end (``held``)."""
    from evo_door.render.spill import partial_path

    out = Path(folder) / "growth.h5"
    for path in (out, partial_path(out)):
        path.unlink(missing_ok=True)
    loop = ServoLoop(SimDevice("swing", seed=1), params, RATE)
    loop.log.spill_to(out, loop_rate=loop.rate, device="sim")
    loop.run(seconds)
    loop.log.close()
    partial = partial_path(out).stat().st_size
    held = sum(b.nbytes for b in loop.log._blocks if b is not None)
    loop.write_log(out)
    final = out.stat().st_size
    out.unlink()
    per_hour = 3600.0 / seconds
    return {"partial": partial * per_hour, "final": final * per_hour, "held": held}


def _wait_listening(port: int, timeout: float = 20.0) -> None:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.05)
    raise RuntimeError(f"the emulator did not listen on port {port}")


def tcp_run(params, rate: float, seconds: float) -> dict:
    """The loop against ``evo-door emulate hapticmaster`` in a separate process."""
    from evo_door.render.hapticmaster import HapticMasterDevice

    port = free_port()
    code = "import sys; from evo_door.cli import main; sys.exit(main(sys.argv[1:]))"
    emu = subprocess.Popen(
        [sys.executable, "-c", code, "emulate", "hapticmaster", "--port", str(port)]
        + ["--user", "open", "--seconds", str(seconds + 30.0)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        _wait_listening(port)
        dev = HapticMasterDevice("127.0.0.1", port, damping=2.0, init_wait=0.0)  # the emulator's
        loop = ServoLoop(dev, params, rate, watchdog_misses=10**9, clamp=True)
        loop.run(seconds)
        return loop.statistics
    finally:
        emu.terminate()
        emu.wait(timeout=10)


def _row(what: str, s: dict) -> str:
    ok = s["on_time_fraction"] >= ON_TIME
    rtt = (
        f"{s['round_trip_mean_s'] * 1e3:.3g} / {s['round_trip_p99_s'] * 1e3:.3g} ms"
        if "round_trip_mean_s" in s
        else "-"
    )
    return (
        f"| {what} | {s['rate_hz']:g} Hz | {s['period_mean_s'] * 1e3:.4f} ms | "
        f"{s['on_time_fraction'] * 100:.3f} % | {s['missed_cycles']} | "
        f"{s['lateness_p99_s'] * 1e6:.0f} us | {s['compute_p99_s'] * 1e6:.0f} us | {rtt} | "
        f"{'yes' if ok else 'no'} |"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated-device run (s)")
    ap.add_argument("--tcp-seconds", type=float, default=10.0, help="each TCP run (s)")
    ap.add_argument("--no-write", action="store_true", help="print only")
    args = ap.parse_args(argv)

    params = get_model("haptic").load_params("seed_trial")
    for friction in ("implicit", "tanh"):  # compile / load the kernels
        sim_run(params, 0.2, friction)
    rows = []
    for friction in ("implicit", "tanh"):
        seconds = args.seconds if friction == "implicit" else min(args.seconds, 10.0)
        s = sim_run(params, seconds, friction)
        rows.append(_row(f"sim device, {seconds:g} s, {friction} friction", s))
        print(rows[-1], flush=True)
    achievable = None
    for rate in TCP_RATES:
        s = tcp_run(params, rate, args.tcp_seconds)
        rows.append(_row(f"emulator over TCP loopback, {args.tcp_seconds:g} s", s))
        print(rows[-1], flush=True)
        if achievable is None and s["on_time_fraction"] >= ON_TIME:
            achievable = rate
    lines = [
        "# Renderer benchmark (`benchmarks/bench_render.py`)",
        "",
        machine_line(),
        "",
        "Servo loop paced on the wall clock (`realtime`), preset `seed_trial`, virtual user "
        "`open` (a pull that unlocks the latched door, then a hold). The emulator runs as "
        "`evo-door emulate hapticmaster` in a separate process; each cycle is one batched "
        "query and one force command over TCP on 127.0.0.1.",
        "",
        "| run | rate | mean period | cycles on time | missed | p99 lateness "
        "| p99 cycle work | round trip mean / p99 | >= 99.9 % |",
        "|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        f"Highest rate of {', '.join(f'{r:g}' for r in TCP_RATES)} Hz held over TCP with "
        f">= 99.9 % of cycles on time: "
        + (f"**{achievable:g} Hz**." if achievable else "none of them."),
        "",
        "Target: sim device at 2500 Hz for 60 s with >= 99.9 % of cycles on "
        "time. A cycle is late when it starts more than one period after its slot; the "
        "lateness p99 is over all cycles run. The round trip is the batched query's, "
        "send to complete answer; the cycle work (read, model, command, log) includes it.",
    ]
    publish("\n".join(lines) + "\n", "render.md", write=not args.no_write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
