"""Helpers shared by the benchmark scripts: timing, a free port, the machine line of a report."""

from __future__ import annotations

import os
import platform
import socket
import statistics
import time
from pathlib import Path

import numpy as np


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
