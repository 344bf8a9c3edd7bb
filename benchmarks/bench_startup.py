"""Start-up of the command line: commands that do not simulate, against importing numba.

Target: ``evo-door --help`` and ``evo-door params haptic`` under 0.3 s. Each
command runs in a fresh interpreter (a subprocess, as a user types it), timed from
start to exit; ``python -c "import numba"`` is the cost the parser no longer pays, and
``python -c pass`` the interpreter's own floor.

    python benchmarks/bench_startup.py               # writes benchmarks/startup.md
    python benchmarks/bench_startup.py --no-write --repeat 9
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._util import machine_line, median_time, publish  # noqa: E402

#: Target wall time (s) of a command that does not simulate.
TARGET = 0.3
#: A first command after an install ends, or names what it compiles, within this (s).
FIRST_WORD = 5.0


def _evo_door() -> list[str]:
    """The installed console script, else ``python -m evo_door``."""
    exe = shutil.which("evo-door")
    return [exe] if exe else [sys.executable, "-m", "evo_door"]


def cases() -> list[tuple[str, list[str]]]:
    evo = _evo_door()
    return [
        ("`evo-door --help`", [*evo, "--help"]),
        ("`evo-door params haptic`", [*evo, "params", "haptic"]),
        ('`python -c "import numba"`', [sys.executable, "-c", "import numba"]),
        ("`python -c pass`", [sys.executable, "-c", "pass"]),
    ]


def wall_time(cmd: list[str], repeat: int) -> float:
    """Median wall time (s) of ``repeat`` runs of ``cmd``, after one untimed run (it
    writes the byte-code caches a user's second call finds)."""

    def once():
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)

    once()
    return median_time(once, repeat)


def first_run(cmd: list[str], cache: Path, cwd: Path) -> tuple[float, float, str]:
    """Run ``cmd`` in ``cwd`` on the numba cache folder ``cache`` (an empty one: as
    after an install): its wall time (s), the seconds until its first line on stderr (its
    end if it prints none) and that line."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    start = time.perf_counter()
    proc = subprocess.Popen(
        cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    assert proc.stderr is not None
    first, first_at, rest = "", None, []
    for line in proc.stderr:  # the command line's stderr is line-buffered
        if first_at is None:
            first, first_at = line.strip(), time.perf_counter() - start
        rest.append(line)
    code = proc.wait()
    wall = time.perf_counter() - start
    if code != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed ({code}): {''.join(rest)[-500:]}")
    return wall, wall if first_at is None else first_at, first


def cold_and_warm(cmd: list[str], cache: Path, cwd: Path, repeat: int) -> dict:
    """``cmd`` on the empty cache ``cache`` (it compiles what it runs), then ``repeat``
    times on the cache it filled: ``cold`` and ``first_word`` (s, :func:`first_run`),
    ``first_line``, ``warm`` (s, the median)."""
    cold, first_word, line = first_run(cmd, cache, cwd)
    warm = statistics.median(first_run(cmd, cache, cwd)[0] for _ in range(repeat))
    return {"cold": cold, "first_word": first_word, "first_line": line, "warm": warm}


def force_csv(path: Path, seconds: float = 2.0, rate: float = 1000.0) -> Path:
    """A constant 5 N push, ``t,force``, for ``simulate`` to run on."""
    n = int(seconds * rate)
    path.write_text("t,force\n" + "".join(f"{k / rate:.6f},5.0\n" for k in range(n)))
    return path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--repeat", type=int, default=5, help="runs per command (median)")
    args = ap.parse_args(argv)

    times = {label: wall_time(cmd, args.repeat) for label, cmd in cases()}
    numba_s = times['`python -c "import numba"`']
    lines = [
        "# Start-up of the command line",
        "",
        machine_line(),
        "",
        f"Wall time of a fresh process, median of {args.repeat} runs; target for commands "
        f"that do not simulate: under {TARGET:g} s.",
        "",
        "| command | wall time (s) | / import numba |",
        "|---|---:|---:|",
    ]
    for label, seconds in times.items():
        lines.append(f"| {label} | {seconds:.3f} | {seconds / numba_s:.2f} |")
    lines.append("")
    for label in ("`evo-door --help`", "`evo-door params haptic`"):
        verdict = "meets" if times[label] < TARGET else "misses"
        lines.append(f"- {label}: {times[label]:.3f} s, {verdict} the {TARGET:g} s target.")
    publish("\n".join(lines) + "\n", "startup.md", write=not args.no_write)


if __name__ == "__main__":
    main()
