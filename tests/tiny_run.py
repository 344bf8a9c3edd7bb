"""A tiny experiment on the bundled trials (one door parameter, a 6 x 1 GA: a results
file in a few seconds) and the command line in a fresh process, for the tests of what
a command may read and write."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "experiments" / "data" / "default.h5"

EXPERIMENT = f"""\
name: tiny
model: door
params: default
target: {{data: {DATA}, kinds: [impulse]}}
free: {{F_atD: [5.0, 70.0]}}
objective: {{kind: ise, derivative: 1}}
algorithm: {{population: 6, generations: 1, seed: 1}}
"""


def cli(*args, cwd):
    """``evo-door ARGS`` in a fresh process in ``cwd`` (this checkout's code)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    return subprocess.run(
        [sys.executable, "-m", "evo_door", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=300,
    )
