"""What several test files share that is not a fixture (those are in ``conftest.py``):

- a tiny experiment on the bundled trials (one door parameter, a 6 x 1 GA: a results
  file in a few seconds) and the command line in a fresh process (:func:`cli_process`),
  for the tests of what a command may read and write;
- devices for loops run in a thread (:func:`yielding_sim`), a HapticMaster client
  started on the emulator (:func:`started`) and haptic parameter vectors drawn within
  their bounds (:func:`random_kernel_vectors`);
- a servo loop served on its control port in a thread (:func:`served_loop`) and the
  answers read back from a connection to it (:func:`answer_lines`);
- a process stopped for sure (:func:`freeze`: SIGSTOP, then its threads seen stopped);
- the example door FMU's builder, ``examples/fmu/build.py``, as a module
  (:func:`door_fmu_builder`; conftest's ``shared_fmus`` builds the FMUs themselves);
- the first compile of every kernel as the cold-compile test and ``conftest.py`` run
  it (:func:`noted_process`, :func:`compile_notes`), its kernels copied beside their
  sources (:func:`copy_numba_cache`) and its record kept between runs of the same
  sources (:func:`cold_compile_key`, :func:`keep_cold_record`, :func:`kept_cold_record`).

The independent statements of the science that tests compare against are
``reference.py`` (converged integrations) and ``feel_reference.py`` (the perceptual
check).
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "experiments" / "data" / "default.h5"

TINY_EXPERIMENT = f"""\
name: tiny
model: door
params: default
target: {{data: {DATA}, kinds: [impulse]}}
free: {{F_atD: [5.0, 70.0]}}
objective: {{kind: ise, derivative: 1}}
algorithm: {{population: 6, generations: 1, seed: 1}}
"""

# The render's safety limits for a test that needs a whole session over real TCP on a
# loaded machine (the suite runs a worker per core, CI runs jobs beside it): the widest
# the commands accept, so that a descheduled test process does not end the session. The
# limits themselves are tested where they must trip (test_render_stall and the like).
LOADED_MACHINE_WATCHDOG = ["--watchdog-misses", "1000"]  # any device
LOADED_MACHINE_SUPERVISOR = ["--supervisor-budget", "1000"]  # a HapticMaster's, in ms
LOADED_MACHINE_LIMITS = [*LOADED_MACHINE_WATCHDOG, *LOADED_MACHINE_SUPERVISOR]
#: Seconds a command that compiles every kernel (``evo-door compile`` on an empty cache)
#: may take before a test calls it hung: a guard against a hang, not a speed limit (CI
#: runs one at idle priority beside the suite, where its compilation waits).
COMPILE_HANG_GUARD = 2400


def bytecode_warning(environ=os.environ) -> str | None:
    """The line a run says in its header and at its end where
    ``PYTHONDONTWRITEBYTECODE`` is set (None where it is not): Python then keeps no
    bytecode, so every command a test starts compiles everything it imports again
    (numpy, scipy, numba, evo-door). Measured on a fresh clone, 2 cores, the README's
    test command 15 minutes apart in one hour: 742 s and 1390 s of CPU with it set,
    453 s and 828 s without (the processes the tests started 787 s of CPU against 332
    s). CI unsets it (``.ci/run``); a user's machine does not usually set it, some
    container images do."""
    if not environ.get("PYTHONDONTWRITEBYTECODE"):
        return None
    return (
        "PYTHONDONTWRITEBYTECODE is set: every command a test starts compiles what it "
        "imports again, and the suite takes markedly longer (docs/testing.md); "
        "`unset PYTHONDONTWRITEBYTECODE` before pytest for a faster run"
    )


def assert_kept_time(summary: str, period_ms: float) -> None:
    """A paced render's printed summary kept its ``period_ms`` (ms) schedule.

    On a loaded machine a paced loop misses slots and skips them, keeping its schedule:
    the slots are served by fewer cycles, so the mean period between them grows by the
    ratio it counts (0.4631 ms for 0.4 with 68 of 500 missed, on CI). The mean is never
    shorter than the schedule (unpaced it would be microseconds), and any slowness is
    the missed slots the summary reports.
    """
    assert "unpaced" not in summary, summary
    mean = float(summary.split("period mean ")[1].split(" ms")[0])
    slots = int(summary.split("rendered ")[1].split(" cycles")[0])
    missed = int(summary.split("missed ")[1].split(" cycles")[0])
    served = max(slots - 1 - missed, 1)
    assert 0.975 * period_ms <= mean <= period_ms * (slots - 1) / served * 1.02, summary


def measured_tiers(path: Path = ROOT / "tests" / "tiers.txt") -> frozenset[str]:
    """The ids of the tests ``tests/tiers.txt`` lists (measured at 0.5 s or more: not
    ``unit``; written by ``benchmarks/slowest_tests.py --tiers``)."""
    if not path.exists():
        return frozenset()
    lines = (line.strip() for line in path.read_text(encoding="utf-8").splitlines())
    return frozenset(line for line in lines if line and not line.startswith("#"))


def tier(node_id: str, slow: bool, measured: frozenset[str]) -> str:
    """A test's tier: ``slow`` as marked, ``integration`` if measured at 0.5 s or more,
    else ``unit``."""
    if slow:
        return "slow"
    return "integration" if node_id in measured else "unit"


def noted_process(*args, cache: Path, cwd):
    """``evo-door ARGS`` in a fresh process on the numba cache folder ``cache``, with the
    compile notes on (what the cold-compile test reads, ``tests/test_kernel_cache.py``;
    ``tests/conftest.py`` runs a fresh clone's first compile so for it)."""
    env = {"NUMBA_CACHE_DIR": str(cache), "EVO_DOOR_COMPILE_NOTES": "1"}
    return cli_process(*args, cwd=cwd, env=env, timeout=COMPILE_HANG_GUARD)


def compile_notes(stderr: str) -> list[str]:
    """The compile notes among a command's stderr lines."""
    return [line for line in stderr.splitlines() if line.startswith("evo-door: compil")]


def copy_numba_cache(cache: Path, tree: Path) -> int:
    """Copy the kernels numba compiled into the cache folder ``cache`` (as with
    ``NUMBA_CACHE_DIR``) for the sources under ``tree`` into the ``__pycache__`` folders
    beside those sources, where numba looks without ``NUMBA_CACHE_DIR``. numba names a
    source folder's place in such a cache by the folder's name and a digest of its path
    (``_CacheLocator.get_suitable_cache_subpath``); the files themselves are the same in
    both places (their stamps name evo-door's files by their place in the package).
    Returns how many files were copied."""
    import shutil

    from numba.core.caching import _CacheLocator

    copied = 0
    for folder in [tree, *(d for d in tree.rglob("*") if d.is_dir())]:
        if folder.name == "__pycache__":
            continue
        there = cache / _CacheLocator.get_suitable_cache_subpath(str(folder / "x.py"))
        files = list(there.glob("*.nb[ic]")) if there.is_dir() else []
        if files:
            (folder / "__pycache__").mkdir(exist_ok=True)
        for f in files:  # each whole or not at all, as numba writes them: a process may
            # be loading the kernels beside (another pytest session's workers)
            part = folder / "__pycache__" / f"{f.name}.{os.getpid()}.part"
            shutil.copy2(f, part)
            os.replace(part, folder / "__pycache__" / f.name)
            copied += 1
    return copied


#: The folder of pytest's cache (``.pytest_cache``) that keeps the last cold compile's
#: record (:func:`keep_cold_record`).
COLD_STORE = "evo-door-cold-compile"


def cold_compile_key(root: Path = ROOT) -> str:
    """A digest of everything a first ``evo-door compile`` into an empty cache depends
    on: every source file of the package, the checkout's place (numba names a cache
    folder by its source folder's path), the versions of Python, numpy, numba and
    llvmlite, the CPU numba compiles for, the processes the compile splits over,
    numba's settings from the environment, and this file (how the compile is run).
    Two runs with the same key compile the same kernels into the same files."""
    import hashlib
    import platform

    import llvmlite
    import numba
    import numpy
    from llvmlite import binding

    from evo_door.commands.compile import default_jobs

    digest = hashlib.sha256()
    facts = [str(root), sys.version, platform.machine(), numpy.__version__, numba.__version__,
             llvmlite.__version__, binding.get_host_cpu_name(),
             binding.get_host_cpu_features().flatten(), str(default_jobs())]  # fmt: skip
    facts += sorted(f"{k}={v}" for k, v in os.environ.items() if k.startswith("NUMBA_"))
    for path in sorted((root / "evo_door").rglob("*.py")):
        facts += [path.relative_to(root).as_posix(), path.read_text(encoding="utf-8")]
    facts.append(Path(__file__).read_text(encoding="utf-8"))
    for fact in facts:
        digest.update(fact.encode("utf-8") + b"\0")
    return digest.hexdigest()[:24]


def write_compile_record(folder: Path, returncode: int, stderr: str) -> None:
    """A first compile's exit status and stderr, ``compile.json`` in its record's folder
    (beside ``cache``, the numba cache folder it filled)."""
    (folder / "compile.json").write_text(json.dumps({"returncode": returncode, "stderr": stderr}))


def read_compile_record(folder: Path) -> dict | None:
    """What :func:`write_compile_record` wrote in ``folder``; None where it is missing or
    damaged."""
    try:
        done = json.loads((folder / "compile.json").read_text())
    except (OSError, ValueError):
        return None
    return done if isinstance(done, dict) else None


def kept_cold_record(store: Path, key: str) -> Path | None:
    """The record :func:`keep_cold_record` kept under ``key`` in ``store``, or None."""
    record = store / key
    done = read_compile_record(record)
    ok = done is not None and done.get("returncode") == 0 and (record / "cache").is_dir()
    return record if ok else None


def keep_cold_record(store: Path, key: str, cache: Path, stderr: str) -> bool:
    """Keep a successful first compile's record in ``store`` under ``key``: a copy of the
    cache folder it filled and its stderr (:func:`write_compile_record`), in place of
    any other key's (a record is some megabytes; an older one holds kernels of sources
    since edited). Written under a temporary name, then renamed
    whole: another session may be reading or keeping one. Returns whether it was kept
    (not when the key is kept already or the copy fails: the next run compiles again)."""
    import shutil

    if (store / key).exists():
        return False
    part = store / f".{key}.{os.getpid()}.part"
    try:
        shutil.copytree(cache, part / "cache")
        write_compile_record(part, 0, stderr)
        os.replace(part, store / key)
    except OSError:
        shutil.rmtree(part, ignore_errors=True)
        return False
    for other in store.iterdir():
        if other.name != key and not other.name.startswith("."):
            shutil.rmtree(other, ignore_errors=True)
    return True


def door_fmu_builder():
    """``examples/fmu/build.py`` as a module (it is no package), loaded once per process
    under the name ``door_fmu_build``: its dataclasses look their module up there."""
    name = "door_fmu_build"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, ROOT / "examples/fmu/build.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


def cli_process(*args, cwd, env=None, unset=(), timeout=300):
    """``evo-door ARGS`` in a fresh process in ``cwd`` (this checkout's code); ``env``:
    variables set on top of this process's; ``unset``: variables of this process's left
    out."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg", **(env or {})}
    for name in unset:
        env.pop(name, None)
    return subprocess.run(
        [sys.executable, "-m", "evo_door", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=timeout,
    )


def console_url(stdout) -> str:
    """The URL ``render --console`` prints on its line ``console URL``, read from its
    stdout up to that line (the rest stays to be read); "" when the output ends first."""
    for line in stdout:
        if line.startswith("console "):
            return line.split()[1]
    return ""


def freeze(pid: int, timeout: float = 5.0) -> None:
    """SIGSTOP ``pid`` and wait until every thread of it is stopped. The signal is
    delivered asynchronously: on a loaded machine the process may still answer a
    request or two after ``os.kill`` returns, which a stall test must not count on."""
    import signal

    os.kill(pid, signal.SIGSTOP)
    tasks = Path(f"/proc/{pid}/task")
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        states = []
        for stat in tasks.glob("*/stat"):
            with contextlib.suppress(OSError):  # a thread that just ended
                states.append(stat.read_text().rsplit(")", 1)[1].split()[0])
        if states and all(s in "tT" for s in states):
            return
        time.sleep(0.001)
    raise AssertionError(f"process {pid} not stopped {timeout} s after SIGSTOP")


# -- devices ------------------------------------------------------------------------------
def yielding_sim(*args, **kwargs):
    """A SimDevice that gives up the GIL each cycle, as a paced loop does while it
    waits (an unpaced simulated loop in a thread never blocks and would starve the
    test's own thread)."""
    from evo_door.render.device import SimDevice

    class YieldingSim(SimDevice):
        def step(self, dt):
            super().step(dt)
            time.sleep(0)

    return YieldingSim(*args, **kwargs)


def started(emu, **kwargs):
    """A HapticMasterDevice connected to ``emu`` and through its start-up sequence."""
    from evo_door.render.hapticmaster import HapticMasterDevice

    device = HapticMasterDevice("127.0.0.1", emu.port, init_wait=0.0, timeout=2.0, **kwargs)
    device.start()
    return device


def random_kernel_vectors(n: int, rng):
    """``n`` haptic parameter vectors drawn uniformly within the declared bounds."""
    from evo_door.models.haptic import PARAMS

    lo, hi = PARAMS.lower, PARAMS.upper
    return lo + (hi - lo) * rng.random((n, len(PARAMS)))


# -- a loop served on its control port ----------------------------------------------------
@contextlib.contextmanager
def served_loop(params, token: str):
    """A ServoLoop on the simulated device (opening, seed 3) with ``params`` in its own
    thread, its control server on a free loopback port with ``token``, some cycles run:
    yields ``(loop, server, end)``, ``end()`` stopping the loop early."""
    from evo_door.cli import build_parser
    from evo_door.render.loop import ServoLoop

    build_parser()  # import every command before the loop competes for the GIL
    loop = ServoLoop(yielding_sim("open", radius=params["radius"], seed=3), params)
    with serving(loop, token) as served:
        yield served


@contextlib.contextmanager
def serving(loop, token: str, wait: float = 10.0):
    """``loop`` (a ServoLoop, or a MechanismLoop) run in its own thread, its control
    server on a free loopback port with ``token``, once some cycles have run (at most
    ``wait`` s): yields ``(loop, server, end)``, ``end()`` stopping the loop early."""
    from evo_door.cli import build_parser
    from evo_door.render.control import ControlServer

    build_parser()  # import every command before the loop competes for the GIL
    stop = threading.Event()
    thread = threading.Thread(target=loop.run, kwargs={"stop": stop}, daemon=True)
    server = ControlServer(loop, "127.0.0.1", 0, token=token).start()
    thread.start()
    deadline = time.monotonic() + wait
    while loop.log.n < 10 and time.monotonic() < deadline:  # some cycles have run
        time.sleep(0.001)
    try:
        yield loop, server, lambda: (stop.set(), thread.join(10.0))
    finally:
        stop.set()
        thread.join(10.0)
        server.close()


class ServedConsole:
    """A console server (``ConsoleServer``) running its asyncio loop in a thread:
    ``url`` its page with the token, ``base`` its root, ``call(coro)`` runs a
    coroutine there."""

    def __init__(self, server):
        import asyncio

        self.server = server
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.url = self.call(server.start())
        self.base = f"http://127.0.0.1:{server.port}/"

    def call(self, coro, timeout: float = 60.0):
        import asyncio

        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def close(self) -> None:
        self.call(self.server.stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5.0)
        self.loop.close()


def answer_lines(sock, n: int, timeout: float = 30.0) -> list[dict]:
    """The next ``n`` answer lines on ``sock`` (JSON objects; fewer if it closes)."""
    sock.settimeout(timeout)
    data = b""
    while data.count(b"\n") < n:
        chunk = sock.recv(65536)
        if not chunk:
            break
        data += chunk
    return [json.loads(x) for x in data.splitlines()]
