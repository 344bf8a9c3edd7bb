"""How the suite runs its workers (tests/__init__.py): numba's OpenMP threads wait
passively, in the suite's processes and in every command a test starts."""

from __future__ import annotations

import os
import subprocess
import sys

import numba
import pytest

from tests import SUITE_SET_POLICY

# A parallel kernel, run once; then the process sleeps and reports the CPU time it
# took while asleep: what its idle OpenMP threads spent spinning.
_IDLE_CPU = """
import time
import numpy as np
from numba import njit, prange, threading_layer

@njit(parallel=True)
def total(a):
    s = 0.0
    for i in prange(a.size):
        s += a[i]
    return s

total(np.ones(100000))
start = time.process_time()
time.sleep(0.3)
print(threading_layer(), time.process_time() - start)
"""


def _idle_cpu(policy: str | None) -> tuple[str, float]:
    env = dict(os.environ)
    if policy is not None:
        env["OMP_WAIT_POLICY"] = policy
    done = subprocess.run(
        [sys.executable, "-c", _IDLE_CPU], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    layer, seconds = done.stdout.split()
    return layer, float(seconds)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="one numba thread: no team")
def test_the_suites_commands_do_not_spin_where_openmp_would():
    """The suite's own processes carry passive waiting (unless the environment set a
    policy before the suite started), and a command started with their environment sleeps
    without spinning; the same command told to wait actively spins through its sleep.
    (OpenMP's default spins some 8 ms of CPU after each parallel region on this machine,
    against under 0.1 ms passive; told to wait actively, a thread spins up to the whole
    0.3 s, less on a loaded machine, where it shares its core (under 0.15 s once here,
    with three more processes busy on the two cores): the bound is 0.05 s, still 17
    times the passive one.)"""
    policy = os.environ.get("OMP_WAIT_POLICY", "")
    if os.environ.get(SUITE_SET_POLICY) != "1" and policy.upper() != "PASSIVE":
        pytest.skip(f"the environment set OMP_WAIT_POLICY={policy} before the suite")
    assert policy.upper() == "PASSIVE"
    layer, passive = _idle_cpu(None)
    if layer != "omp":
        pytest.skip(f"numba's threading layer here is {layer}, not OpenMP")
    _, active = _idle_cpu("ACTIVE")
    assert passive < 0.003, passive
    assert active > 0.05, active


def test_two_workers_asking_for_the_same_fmus_build_different_ones_at_once(tmp_path):
    """tests/conftest.py's SharedFMUs.many: a worker asking for several FMUs builds
    first those no other is building, so two asking at once share the work and each
    file is built once (a stand-in ``make`` that names its builder and ends only once
    the other worker builds too)."""
    import threading

    from tests.conftest import SharedFMUs

    built: list[tuple[str, str]] = []
    start = threading.Barrier(2)
    together = threading.Barrier(2, timeout=10.0)  # s; broken: one waited for the other

    def make(name):
        def write(out):
            built.append((name, threading.current_thread().name))
            together.wait()  # each build ends only once a second one has begun
            out.write_text(name)

        return f"{name}.fmu", write

    shared = SharedFMUs(tmp_path)
    got: dict[str, dict] = {}

    def worker():
        start.wait()
        got[threading.current_thread().name] = shared.many({k: make(k) for k in ("a", "b")})

    threads = [threading.Thread(target=worker, name=n) for n in ("gw0", "gw1")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(name for name, _ in built) == ["a", "b"]  # each built once
    assert {who for _, who in built} == {"gw0", "gw1"}  # by one worker each
    for paths in got.values():
        assert {k: p.read_text() for k, p in paths.items()} == {"a": "a", "b": "b"}
