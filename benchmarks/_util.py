"""Helpers shared by the benchmark scripts: timing, a free port, a command in a fresh
process, the machine line of a report."""

from __future__ import annotations

import os
import platform
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def median_time(fn, repeat: int) -> float:
    """Median wall time (s) of ``repeat`` calls of ``fn()``."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now (for a server to take)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def evo_door_command(args, env=None, cwd=None, timeout: float = 3600) -> tuple[float, str]:
    """``evo-door ARGS`` in a fresh process, as a user types it (start-up and numba's
    cache loading included), this checkout's ``evo_door`` first on the path and ``env``
    added to the environment: its wall time (s) and its standard output. A failure
    raises RuntimeError with the last line of its standard error."""
    env = {
        **os.environ,
        **(env or {}),
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    command = [sys.executable, "-m", "evo_door", *map(str, args)]
    t0 = time.perf_counter()
    done = subprocess.run(
        command, capture_output=True, text=True, env=env, cwd=cwd, timeout=timeout
    )
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError((done.stderr.strip().splitlines() or ["no output"])[-1])
    return wall, done.stdout


def machine_line(extra: str = "", how: str = "medians of repeats") -> str:
    """Where and when a benchmark ran, for the first lines of its report."""
    import numba

    return (
        f"Machine: {platform.platform()}, {os.cpu_count()} CPUs{extra}, Python "
        f"{platform.python_version()}, numba {numba.__version__}. Measured "
        f"{time.strftime('%Y-%m-%d %H:%M')}, {how}; other processes may "
        "have shared the cores."
    )


def half_sine_pulses(t, pulses) -> np.ndarray:
    """A force trace (N) of half-sine pulses ``(start s, width s, amplitude N)`` on ``t``."""
    f = np.zeros_like(t)
    for start, width, amp in pulses:
        on = (t >= start) & (t < start + width)
        f[on] = amp * np.sin(np.pi * (t[on] - start) / width)
    return f


def publish(text: str, name: str, write: bool = True) -> None:
    """Print a benchmark's Markdown report and, unless asked not to, write it to
    ``benchmarks/NAME`` (through the project's atomic writer)."""
    print(text)
    if write:
        from evo_door.files import write_text

        write_text(Path(__file__).with_name(name), text)
