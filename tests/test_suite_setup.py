"""How the suite runs its workers: numba's OpenMP threads wait passively and OpenBLAS runs
on one thread, in the suite's processes and in every command a test starts
(tests/__init__.py); the workers share the files (tests/xdist_schedule.py); they share
the FMUs (tests/conftest.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numba
import pytest

from tests import SUITE_SET_BLAS, SUITE_SET_POLICY
from tests.helpers import bytecode_warning

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


def _printed(script: str, name: str, value: str | None) -> str:
    """What ``python -c script`` prints, run with this process's environment and, unless
    ``value`` is None, the variable ``name`` set to it."""
    env = dict(os.environ)
    if value is not None:
        env[name] = value
    done = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def _idle_cpu(policy: str | None) -> tuple[str, float]:
    layer, seconds = _printed(_IDLE_CPU, "OMP_WAIT_POLICY", policy).split()
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


# Three matrix products OpenBLAS spreads over its threads, then a sleep: the CPU time
# the process took while asleep is what OpenBLAS's idle threads spent spinning.
_IDLE_BLAS = """
import time
import numpy as np
a = np.ones((300, 300))
for _ in range(3):
    a @ a
start = time.process_time()
time.sleep(0.3)
print(time.process_time() - start)
"""


def _idle_blas_cpu(threads: str | None) -> float:
    return float(_printed(_IDLE_BLAS, "OPENBLAS_NUM_THREADS", threads))


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: OpenBLAS runs one thread")
def test_the_suites_commands_leave_no_blas_thread_spinning():
    """The suite's processes run OpenBLAS on one thread (unless the environment set a
    number before the suite started), and a command started with their environment
    sleeps after its matrix products without spinning; the same command on two threads
    spins through part of its sleep (about 0.1 s of the 0.3 s on a quiet machine here,
    44-49 ms with the suite running beside it, against under 0.1 ms on one thread: the
    bound is 5 ms)."""
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "")
    if os.environ.get(SUITE_SET_BLAS) != "1" and threads != "1":
        pytest.skip(f"the environment set OPENBLAS_NUM_THREADS={threads} before the suite")
    assert threads == "1"
    assert _idle_blas_cpu(None) < 0.003
    assert _idle_blas_cpu("2") > 0.005


def test_a_run_says_where_python_keeps_no_bytecode(monkeypatch):
    """A run where PYTHONDONTWRITEBYTECODE is set says so in its header and at its end,
    with what to do; where it is unset or empty (Python then writes bytecode), nothing."""
    from tests import conftest

    line = bytecode_warning({"PYTHONDONTWRITEBYTECODE": "1"})
    assert line is not None and "PYTHONDONTWRITEBYTECODE is set" in line
    assert "unset PYTHONDONTWRITEBYTECODE" in line
    assert bytecode_warning({}) is None
    assert bytecode_warning({"PYTHONDONTWRITEBYTECODE": ""}) is None
    written = []
    reporter = SimpleNamespace(write_line=written.append)
    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    assert conftest.pytest_report_header(None) == [line]
    conftest.pytest_terminal_summary(reporter)
    assert written == [line]
    monkeypatch.delenv("PYTHONDONTWRITEBYTECODE")
    assert conftest.pytest_report_header(None) == []
    conftest.pytest_terminal_summary(reporter)
    assert written == [line]


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


# -- how the workers share the suite (tests/xdist_schedule.py) -------------------------
def test_a_file_is_a_unit_and_the_paced_files_are_one():
    from tests.xdist_schedule import paced_units, unit_of

    assert unit_of("tests/test_fit.py::test_a[x::y]", 1) == "tests/test_fit.py"
    assert unit_of("evo_door/sim/core.py::evo_door.sim.core.step", 1) == "evo_door/sim/core.py"
    paced = [
        "tests/test_render_check.py::test_a",
        "tests/test_console_browser.py::test_b",
        "tests/test_hapticmaster_stall.py::test_c",
        "tests/test_jnd_device.py::test_d",
    ]
    assert {unit_of(n, 1) for n in paced} == {"paced-0"}
    # not paced: the renderer's unit tests, a file named like a paced one elsewhere
    assert unit_of("tests/test_render.py::test_e", 1) == "tests/test_render.py"
    assert unit_of("tests/test_blocks.py::test_render_console", 1) == "tests/test_blocks.py"
    # one unit on up to four workers (a third worker on two cores), then one per three
    assert [paced_units(n, 2) for n in (3, 4, 5, 8, 9)] == [1, 1, 2, 3, 3]
    # none with a worker per core (or fewer): a paced file is a unit as any other
    assert [paced_units(n, 2) for n in (1, 2)] == [0, 0] and paced_units(8, 8) == 0
    assert unit_of(paced[0], 0) == "tests/test_render_check.py"
    # with several, a file's tests stay together, and the files are spread
    assert unit_of(paced[0], 3) == unit_of(paced[0].replace("test_a", "test_z"), 3)
    assert len({unit_of(n, 3) for n in paced}) > 1


def test_the_paced_files_of_the_suite_exist():
    """The pattern names files that are there (a renamed file would drop out of the
    paced unit silently), and the suite's known wall-clock files among them."""
    from tests.xdist_schedule import PACED

    tests = Path(__file__).parent
    paced = {p.name for p in tests.glob("test_*.py") if PACED.search(f"tests/{p.name}")}
    assert {
        "test_render_check.py",
        "test_render_stall.py",
        "test_render_priority.py",
        "test_console_browser.py",
        "test_hapticmaster_stall.py",
        "test_jnd_device.py",
    } <= paced
    assert "test_render.py" not in paced and "test_suite_setup.py" not in paced


def test_costliest_units_go_first():
    from tests.xdist_schedule import MEASURED_WEIGHT, unit_cost

    measured = frozenset({"a.py::slow"})
    assert unit_cost(["a.py::slow", "a.py::quick"], measured) == MEASURED_WEIGHT + 1
    assert unit_cost([f"b.py::t{i}" for i in range(5)], measured) == 5


# Each test appends (worker, file, start, end) to a shared file, sleeping while it holds
# the core as a paced render would.
_RECORDING_TEST = """
import os, time
def _record(name):
    start = time.monotonic()
    time.sleep({pause})
    with open({log!r}, "a") as f:
        f.write(f"{{os.environ['PYTEST_XDIST_WORKER']}} {{os.environ['PYTEST_XDIST_WORKER_COUNT']}} "
                f"{{__file__.rsplit('/', 1)[-1]}} {{start}} {{time.monotonic()}}\\n")
"""


@pytest.mark.slow
def test_paced_files_run_one_after_another_on_one_worker(pytester, monkeypatch, tmp_path):
    """A small suite on three workers with xdist's own ``-n``: the two paced files' tests
    on one worker, never two at once, each file of the others on one worker; ``-n auto``
    starts a worker more than the cores."""
    log = tmp_path / "log.txt"
    files = ["test_render_a", "test_console_b", "test_fit_c", "test_fit_d", "test_fit_e"]
    for name in files:
        body = _RECORDING_TEST.format(pause=0.15, log=str(log))
        body += "".join(f"\ndef test_{i}():\n    _record('{i}')\n" for i in range(4))
        pytester.makepyfile(**{name: body})
    monkeypatch.setenv("PYTHONPATH", str(Path(__file__).resolve().parents[1]))
    monkeypatch.delenv("PYTEST_XDIST_AUTO_NUM_WORKERS", raising=False)
    monkeypatch.delenv("PYTEST_ADDOPTS", raising=False)
    done = pytester.runpytest_subprocess("-n", "auto", "-p", "tests.xdist_schedule", "-q")
    done.assert_outcomes(passed=20)
    rows = [line.split() for line in log.read_text().splitlines()]
    assert {int(count) for _, count, *_ in rows} == {len(os.sched_getaffinity(0)) + 1}
    worker_of = {}
    for worker, _, name, _, _ in rows:
        worker_of.setdefault(name, set()).add(worker)
    assert all(len(workers) == 1 for workers in worker_of.values()), worker_of
    assert worker_of["test_render_a.py"] == worker_of["test_console_b.py"]
    spans = sorted((float(s), float(e)) for _, _, name, s, e in rows if "_fit_" not in name)
    assert all(end <= next_start for (_, end), (next_start, _) in zip(spans, spans[1:]))


def test_the_suite_collects_without_xdist():
    """xdist's hooks in tests/conftest.py are optional: ``-p no:xdist`` (or no xdist)
    collects as plain pytest does."""
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "no:xdist", "-p", "no:cacheprovider",
         "--collect-only", "-q", "tests/test_suite_setup.py"],
        cwd=Path(__file__).resolve().parents[1],
        env={k: v for k, v in os.environ.items() if k != "PYTEST_ADDOPTS"},  # CI's --dist
        capture_output=True,
        text=True,
        timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
