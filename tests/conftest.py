"""Shared fixtures: small analytic test models that need no door physics; the bundled
models' usual parameter sets; the HapticMaster emulator; the FMUs built from the
project's C, once per suite run. What tests share that is not a fixture is in
``helpers.py``."""

import fcntl
import gc
import os
import resource
import shutil
from pathlib import Path

import pytest
from numba import njit

from benchmarks.slowest_tests import CPU_OWN, CPU_PROCESSES
from evo_door.models import get_model
from evo_door.models.base import Model
from evo_door.params import Param, ParamTable
from tests.helpers import (
    COLD_STORE,
    COMPILE_HANG_GUARD,
    ROOT,
    bytecode_warning,
    cli_process,
    cold_compile_key,
    copy_numba_cache,
    keep_cold_record,
    kept_cold_record,
    measured_tiers,
    noted_process,
    tier,
    write_compile_record,
)
from tests.xdist_schedule import (  # noqa: F401 (xdist's hooks: how the workers share the suite)
    pytest_xdist_auto_num_workers,
    pytest_xdist_make_scheduler,
)

#: The command line's notes of what numba compiles (evo_door.kernel_cache) would land in
#: the stderr that tests compare, whenever a test happens to compile first; quiet here
#: (tests/test_kernel_cache.py turns them on).
os.environ["EVO_DOOR_COMPILE_NOTES"] = "0"
#: a file :func:`pytest_sessionstart` makes once its compile has ended (CI's handshake)
COMPILED_MARK = "EVO_DOOR_TEST_COMPILED_MARK"
#: set to 1 where numba's cache is known to hold every kernel (CI's generic pass, on the
#: cache its cold-compile test filled and found complete): no compile before the workers
PRECOMPILED = "EVO_DOOR_TEST_PRECOMPILED"
#: set by :func:`pytest_sessionstart` for the workers where the checkout had no compiled
#: kernel (a fresh clone): the folder of that first compile's record, which the
#: cold-compile test reads (tests/test_kernel_cache.py) rather than compiling again
COLD_RECORD = "EVO_DOOR_TEST_COLD_RECORD"


def workers(config) -> int:
    """How many xdist workers this run starts (0: none, the tests run in this process)."""
    if hasattr(config, "workerinput"):  # a worker itself
        return 0
    n = getattr(config.option, "numprocesses", None)  # None: xdist not loaded or not asked
    return n if isinstance(n, int) and getattr(config.option, "dist", "no") != "no" else 0


def pytest_report_header(config):
    """The run's header (not shown with ``-q``) says where Python keeps no bytecode
    (:func:`tests.helpers.bytecode_warning`); :func:`pytest_terminal_summary` says it
    again at the end."""
    warning = bytecode_warning()
    return [warning] if warning else []


def pytest_terminal_summary(terminalreporter):
    """The end of the run says where Python keeps no bytecode (and why that is slow)."""
    warning = bytecode_warning()
    if warning:
        terminalreporter.write_line(warning)


def pytest_sessionstart(session):
    """With xdist workers, the package's kernels are compiled once, here, before the
    workers start (``evo-door compile``: about 3 s when numba's cache is warm). On a
    fresh clone or after an edit of a kernel, each worker would otherwise compile every
    kernel itself, at the same time as the others, and so would each command a test
    starts before the cache has them. Measured on a fresh clone, 2 cores, nothing
    beside: the suite took 699 s and 1233 s of CPU without this, 707 s and 1135 s with
    it; the CPU it saves goes to what runs beside the suite (CI's checks)."""
    config = session.config
    try:
        if workers(config) < 2 or config.option.collectonly:
            pass
        elif os.environ.get(PRECOMPILED) == "1":
            _say(config, f"evo-door compile, before the workers start: not run ({PRECOMPILED}=1)")
        else:
            _compile_before_the_workers(config)
    finally:
        # CI's main job, in a clone of its own, waits for this to copy the compiled
        # kernels (.ci/run): the file EVO_DOOR_TEST_COMPILED_MARK names, made once the
        # compile has ended, or at once where there is none to wait for
        mark = os.environ.get(COMPILED_MARK)
        if mark:
            Path(mark).touch()


def _compile_before_the_workers(config) -> None:
    """``evo-door compile``, and a line of the run's output saying how it went.

    Where the checkout holds no compiled kernel and numba's cache is the checkout's own
    (a fresh clone: the README's test command), this compile is the cold one the
    cold-compile test checks: it runs as that test runs it (into an empty cache folder
    of its own, its notes kept) and the kernels are then copied into the checkout, for
    the workers. The test reads that record and runs its commands on that folder,
    which nothing else writes to, instead of compiling everything once more (about 90 s
    of CPU on 2 cores). That record, and the one the test makes where it compiles
    itself, is kept in pytest's cache under a digest of everything the compile depends
    on (:func:`tests.helpers.cold_compile_key`: the package's sources, the versions,
    the CPU); the next run with the same digest hands the test a copy of it instead
    (:func:`_reuse_cold_record`): a developer's runs between edits of the package
    compile everything once, not once a run. ``pytest --cache-clear`` or ``-p
    no:cacheprovider`` compiles afresh, and so does CI (a clean clone: no pytest cache)."""
    import time

    start = time.perf_counter()
    store = cold_store(config)
    key = cold_compile_key() if store else ""
    kept = kept_cold_record(store, key) if store else None
    reused = ""
    if kept is not None:
        reused = _reuse_cold_record(config, kept)
    if not reused and fresh_checkout():
        done = _cold_compile(config)
        if store and done.returncode == 0:
            keep_cold_record(store, key, Path(os.environ[COLD_RECORD]) / "cache", done.stderr)
    else:
        # the checkout's evo_door (cli_process puts it first on the path), as the workers
        # import it
        done = cli_process("compile", "--quiet", cwd=ROOT, timeout=COMPILE_HANG_GUARD)
    line = (done.stdout.strip().splitlines() or ["(no summary)"])[-1]
    if done.returncode:  # the tests that need the kernels will fail and say why
        _say(config, f"evo-door compile failed before the workers started:\n{done.stderr[-2000:]}")
    else:
        took = time.perf_counter() - start
        _say(config, f"evo-door compile, before the workers start: {line} ({took:.0f} s){reused}")


def cold_store(config) -> Path | None:
    """The folder of pytest's cache that keeps the cold compile's record, or None: no
    pytest cache (``-p no:cacheprovider``, or one that cannot be written), or an empty
    cache folder handed to the cold-compile test (``EVO_DOOR_TEST_EMPTY_CACHE``: it must
    compile there)."""
    cache = getattr(config, "cache", None)
    if cache is None or os.environ.get("EVO_DOOR_TEST_EMPTY_CACHE"):
        return None
    try:
        return cache.mkdir(COLD_STORE)
    except OSError:  # a read-only checkout: nothing kept, each run compiles
        return None


def _reuse_cold_record(config, kept: Path) -> str:
    """A copy of a kept cold compile's record for this session (the cold-compile test
    runs commands on its cache folder), named to the workers; on a fresh checkout its
    kernels are copied into the checkout, as :func:`_cold_compile` does. Returns the
    end of the line the run says (empty where the copy failed: the caller compiles)."""
    import time

    record = _session_record(config)
    try:
        shutil.copytree(kept, record, dirs_exist_ok=True)
    except OSError:
        return ""  # the session's folder is removed when it ends
    _hand_to_the_workers(record, into_checkout=fresh_checkout())
    when = time.strftime("%Y-%m-%d %H:%M", time.localtime((kept / "compile.json").stat().st_mtime))
    return f"; the cold-compile test reads the first compile kept from {when} (same sources)"


def fresh_checkout(root: Path = ROOT) -> bool:
    """Whether numba's cache is the checkout's own (no ``NUMBA_CACHE_DIR``, the package's
    folder writable) and holds no kernel of the package yet, as on a fresh clone."""
    if os.environ.get("NUMBA_CACHE_DIR") or os.environ.get("EVO_DOOR_TEST_EMPTY_CACHE"):
        return False
    if not os.access(root / "evo_door", os.W_OK):  # numba keeps its cache elsewhere then
        return False
    return not any((root / "evo_door").rglob("__pycache__/*.nbi"))


def _cold_compile(config):
    """``evo-door compile`` into an empty cache folder, as the cold-compile test runs it;
    its output kept in a folder the workers are told of (:data:`COLD_RECORD`), its
    kernels copied into the checkout. Returns the finished process."""
    record = _session_record(config)
    cache, home = record / "cache", record / "home"
    cache.mkdir()
    home.mkdir()
    done = noted_process("compile", cache=cache, cwd=home)
    write_compile_record(record, done.returncode, done.stderr)
    _hand_to_the_workers(record, into_checkout=True)
    return done


def _session_record(config) -> Path:
    """A new temporary folder for this session's cold-compile record, removed when the
    session ends (:func:`pytest_sessionfinish`)."""
    import tempfile

    record = Path(tempfile.mkdtemp(prefix="evo-door-cold-"))
    config._evo_door_cold_record = record
    return record


def _hand_to_the_workers(record: Path, into_checkout: bool) -> None:
    """Name the record to the workers (:data:`COLD_RECORD`; they start next and inherit
    it), its kernels first copied into the checkout where ``into_checkout`` (a fresh
    clone's workers load them from there)."""
    if into_checkout:
        copy_numba_cache(record / "cache", ROOT / "evo_door")
    os.environ[COLD_RECORD] = str(record)


def pytest_sessionfinish(session):
    """The cold compile's record (:func:`_cold_compile`), once every worker is done."""
    record = getattr(session.config, "_evo_door_cold_record", None)
    if record is not None:
        shutil.rmtree(record, ignore_errors=True)


def pytest_collection_finish(session):
    """What a process holds once its tests are collected (the package, numba's compiler
    and typing tables, the test modules) moved out of the garbage collector's sight
    (``gc.freeze``): it lives to the process's end, and every full collection of a
    worker traversed all of it again (about a tenth of a worker's CPU time on
    ``tests/test_[a-c]*.py``, by ``gc.callbacks``; after the freeze, three fifths of it)."""
    gc.collect()
    gc.freeze()


#: The CPU time of a test (set-up and tear-down included), in seconds, as its report's
#: properties (pytest's JUnit XML keeps them on the test case; benchmarks/slowest_tests.py
#: reads them, and names them: ``CPU_OWN``, ``CPU_PROCESSES``): its worker's own, all
#: threads, and that of the processes it started and waited for. Under ``pytest -n auto``
#: a test's wall time also counts the time it waited for a core; CI's wall time follows
#: the CPU time of everything it runs.
_CPU_AT_SETUP = pytest.StashKey[tuple[float, float]]()


def _cpu_seconds() -> tuple[float, float]:
    """(this process's CPU time, its waited-for children's), in seconds."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, children.ru_utime + children.ru_stime


@pytest.hookimpl(tryfirst=True)  # before the test's fixtures are set up
def pytest_runtest_setup(item):
    item.stash[_CPU_AT_SETUP] = _cpu_seconds()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    """:data:`CPU_OWN` and :data:`CPU_PROCESSES` into the test's last report, once its
    tear-down has run. A process is counted where a test waits for it: a server that a
    module's fixture started counts in the test whose tear-down stops it."""
    if call.when == "teardown" and _CPU_AT_SETUP in item.stash:
        (own0, children0), (own, children) = item.stash[_CPU_AT_SETUP], _cpu_seconds()
        item.user_properties.append((CPU_OWN, f"{own - own0:.3f}"))
        item.user_properties.append((CPU_PROCESSES, f"{children - children0:.3f}"))
    return (yield)


def _say(config, line: str) -> None:
    """A line of the run's output (pytest's terminal reporter where there is one)."""
    reporter = config.pluginmanager.get_plugin("terminalreporter")
    (reporter.write_line if reporter else print)(line)


@pytest.hookimpl(tryfirst=True)  # before -m selects by marker
def pytest_collection_modifyitems(config, items):
    """The tiers (docs/testing.md): a test not marked ``slow`` is ``integration`` if
    ``tests/tiers.txt`` lists it (measured at 0.5 s or more) or if it asks for a fixture
    of its file's, shared by its module or the session, that a test of another tier asks
    for too (whichever test asks first pays for it: most are a fit, a run or a corpus);
    else ``unit``."""
    measured = measured_tiers()
    kinds = [tier(i.nodeid, i.get_closest_marker("slow") is not None, measured) for i in items]
    shared = {f for item, kind in zip(items, kinds) if kind != "unit" for f in _own_shared(item)}
    for item, kind in zip(items, kinds):
        if kind == "unit" and shared.intersection(_own_shared(item)):
            kind = "integration"
        if kind != "slow":
            item.add_marker(kind)


def _file(item) -> str:
    """The test file of ``item``, as its node id names it (``tests/test_x.py``)."""
    return item.nodeid.split("::")[0]


def _own_shared(item) -> set[tuple[str, str]]:
    """``(file, name)`` of the module- or session-scoped fixtures a test asks for that its
    own file defines."""
    info = getattr(item, "_fixtureinfo", None)  # a docstring example has none
    here = _file(item)
    return {
        (here, name)
        for name, defs in (info.name2fixturedefs.items() if info else ())
        if defs[-1].scope in ("module", "session") and defs[-1].baseid == here
    }


@njit(cache=True)
def oscillator_accel(theta, dtheta, force, p):
    """I ddtheta = -k (theta - theta_eq) - c dtheta + force."""
    return (-p[0] * (theta - p[3]) - p[1] * dtheta + force) / p[2]


OSCILLATOR_PARAMS = ParamTable(
    "oscillator",
    [
        Param("k", "N/rad", 100.0, 0.0, 1e7, "specification", "spring stiffness"),
        Param("c", "N s/rad", 1.0, 0.0, 1e4, "specification", "viscous damping"),
        Param("inertia", "kg m", 1.0, 1e-3, 100.0, "specification", "inertia"),
        Param("theta_eq", "rad", 0.0, -10.0, 10.0, "geometry", "equilibrium angle"),
    ],
)


@pytest.fixture(scope="session")
def door():
    """The physical door model."""
    return get_model("door")


@pytest.fixture(scope="session")
def default(door):
    """The door's ``default`` preset (parameter sets are read-only)."""
    return door.load_params("default")


@pytest.fixture(scope="session")
def seed_trial():
    """The haptic model's ``seed_trial`` preset."""
    return get_model("haptic").load_params("seed_trial")


@pytest.fixture(scope="session")
def oscillator():
    return Model(
        "oscillator",
        "linear oscillator",
        OSCILLATOR_PARAMS,
        oscillator_accel,
        method="rk4",
        substeps=1,
    )


#: Importable as "tests.conftest:OSCILLATOR_MODEL" wherever a model name is accepted.
OSCILLATOR_MODEL = Model(
    "oscillator", "linear oscillator", OSCILLATOR_PARAMS, oscillator_accel, method="rk4", substeps=1
)


# -- the HapticMaster emulator (tests/test_hapticmaster.py, test_render_native.py) ----
@pytest.fixture
def emulator():
    """An emulated HapticMaster on 127.0.0.1 that advances only when told (tests)."""
    from evo_door.render.emulator import HapticMasterEmulator

    emu = HapticMasterEmulator(port=0, clock="query", steps_per_query=0)
    yield emu
    emu.close()


# -- the FMUs built from the project's C (tests/test_fmu*.py) -------------------------
class SharedFMUs:
    """The test FMUs, each built at most once per suite run, into ``folder``, which every
    xdist worker of the run shares: the first worker to ask for an FMU builds it while
    holding a lock on its name; another that asks meanwhile waits for the lock, then
    takes the file. The files are shared: a test that changes one works on a copy.

    A fixture that needs several asks for them at once (:meth:`many`): it builds first
    those no other worker is building and waits for the others last, so that two
    workers asking for the same four build two each at the same time rather than one
    building while the other waits for each in turn."""

    def __init__(self, folder: Path):
        self.folder = folder

    def door(self, fmi: int, layout: str = "tuned", faults: bool = False) -> Path:
        """The door of examples/fmu, both interfaces: ``build_fmu(path, fmi, layout,
        faults=faults)``."""
        return self.once(*self.door_job(fmi, layout, faults))

    def hinge(self, fmi: int, theta_start=None, rename=None) -> Path:
        """The hybrid hinge of tests/fmu_events (model exchange), or a variant of it:
        ``build_hinge_fmu(path, fmi, theta_start, rename)``."""
        return self.once(*self.hinge_job(fmi, theta_start, rename))

    @staticmethod
    def door_job(fmi: int, layout: str = "tuned", faults: bool = False):
        """``(file name, make)`` of :meth:`door`, for :meth:`many`."""
        from tests.helpers import door_fmu_builder

        def make(out):
            door_fmu_builder().build_fmu(out, fmi, layout, faults=faults, force=True)

        return f"door{fmi}_{layout}{'_faulty' if faults else ''}.fmu", make

    @staticmethod
    def hinge_job(fmi: int, theta_start=None, rename=None):
        """``(file name, make)`` of :meth:`hinge`, for :meth:`many`."""
        from tests.fmu_events.hinge_fmu import build_hinge_fmu

        name = f"hinge{fmi}" + ("" if theta_start is None else f"_start{theta_start!r}")
        name += "".join(f"_{old}-as-{new}" for old, new in sorted((rename or {}).items()))
        return f"{name}.fmu", lambda out: build_hinge_fmu(out, fmi, theta_start, rename)

    def once(self, name: str, make) -> Path:
        """``folder/name``, made by ``make(out)`` unless a worker has made it already.
        ``out`` is another name, renamed once ``make`` returns, so that the file is there
        only when whole."""
        self._make(name, make, wait=True)
        return self.folder / name

    def doors(self) -> dict:
        """Every build of the door, both interfaces each: ``{(fmi, layout): path}``."""
        from tests.helpers import door_fmu_builder

        layouts = door_fmu_builder().LAYOUT_NAMES
        return self.many({(fmi, lay): self.door_job(fmi, lay) for fmi in (2, 3) for lay in layouts})

    def many(self, jobs: dict) -> dict:
        """``{key: (name, make)}`` -> ``{key: folder/name}``, each as :meth:`once` makes
        it; those another worker holds the lock of are left for last."""
        later = [job for job in jobs.values() if not self._make(*job, wait=False)]
        for job in later:
            self._make(*job, wait=True)
        return {key: self.folder / name for key, (name, _) in jobs.items()}

    def _make(self, name: str, make, wait: bool) -> bool:
        """Make ``folder/name`` unless it is there; False, without waiting, where
        ``wait`` is False and another worker holds its lock (it is building it)."""
        path = self.folder / name
        with open(self.folder / f".{name}.lock", "w") as lock:
            try:  # let go on close
                fcntl.flock(lock, fcntl.LOCK_EX if wait else fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return False
            if not path.exists():
                partial = self.folder / f".{name}.building"
                make(partial)
                os.replace(partial, path)
        return True


@pytest.fixture(scope="session")
def shared_fmus(tmp_path_factory) -> SharedFMUs:
    """The FMUs of the tests, built once per suite run (:class:`SharedFMUs`), in the
    run's temporary folder: under xdist the parent of each worker's own."""
    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed")
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent
    folder = base / "shared-fmus"
    folder.mkdir(exist_ok=True)
    return SharedFMUs(folder)
