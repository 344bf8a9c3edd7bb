"""numba's cache of compiled kernels: dropped when any source a kernel imports changes,
and a first run that says what it compiles (``evo_door.kernel_cache``, ``evo-door
compile``)."""

import ast
import io
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numba
import numpy as np
import pytest
from numba import njit

import evo_door
from evo_door import kernel_cache
from evo_door.commands.compile import default_jobs
from tests.helpers import (
    COMPILE_HANG_GUARD,
    DATA,
    ROOT,
    TINY_EXPERIMENT,
    cli_process,
    cold_compile_key,
    compile_notes,
    copy_numba_cache,
    keep_cold_record,
    kept_cold_record,
    noted_process,
    read_compile_record,
)


def test_the_package_names_its_locators_to_numba_in_front_of_numbas_own():
    assert evo_door.KERNEL_CACHE_LOCATORS == kernel_cache.LOCATORS
    assert numba.config.CACHE_LOCATOR_CLASSES.startswith(kernel_cache.LOCATORS)
    # a kernel of the package is stamped by its imports, not by its own file alone
    from evo_door.sim.integrators import integrate_batch

    locator = integrate_batch._cache._impl.locator
    assert isinstance(locator, (kernel_cache.InTree, kernel_cache.UserProvided))


def _tree(tmp_path, files: dict) -> Path:
    root = tmp_path / "evo_door"
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def eager_uncached(path: Path) -> list[str]:
    """The module-level functions of ``path`` that numba compiles at import (``@njit``
    with a signature) without its disk cache: ``file:line name``."""
    found = []
    for node in ast.parse(path.read_text()).body:
        if not isinstance(node, ast.FunctionDef):
            continue
        for dec in node.decorator_list:
            call = dec if isinstance(dec, ast.Call) else None
            name = call and getattr(call.func, "attr", getattr(call.func, "id", ""))
            if name in ("njit", "jit") and call.args:
                cached = any(k.arg == "cache" and getattr(k.value, "value", False) is True
                             for k in call.keywords)  # fmt: skip
                if not cached:
                    found.append(f"{path.name}:{node.lineno} {node.name}")
    return found


def test_eager_kernels_at_module_level_use_the_disk_cache(tmp_path):
    """A kernel with a signature compiles when its module is imported: in the package
    every command pays it, in a test file every process that collects the file (a
    kernel of tests/test_events.py did, in each). With ``cache=True`` it compiles
    once. The check reads the sources; it finds a kernel written without the cache."""
    files = sorted((ROOT / "evo_door").rglob("*.py")) + sorted((ROOT / "tests").glob("*.py"))
    assert len(files) > 100
    assert not [hit for f in files for hit in eager_uncached(f)]
    probe = tmp_path / "probe.py"  # the check itself, on a file it must flag
    probe.write_text("from numba import njit\n@njit('f8(f8)')\ndef twice(x):\n    return 2 * x\n")
    assert eager_uncached(probe) == ["probe.py:3 twice"]


def test_a_stamp_covers_the_modules_imported_at_top_level_through_others(tmp_path, monkeypatch):
    root = _tree(
        tmp_path,
        {
            "__init__.py": "",
            "sim/__init__.py": "",
            "sim/kernel.py": "from evo_door.sim import helpers\nfrom evo_door.consts import K\n",
            "sim/helpers.py": "from evo_door.laws import (\n    tanh,\n)\n",
            "laws.py": "def tanh(x): return x\n",
            "consts.py": "K = 1.0\n",
            "late.py": "X = 1\n",
            "other.py": "Y = 1\n",
        },
    )
    (root / "sim/kernel.py").write_text(
        (root / "sim/kernel.py").read_text() + "def f():\n    from evo_door.late import X\n"
    )
    monkeypatch.setattr(kernel_cache, "ROOT", root)
    kernel = root / "sim/kernel.py"
    before = kernel_cache.source_stamp(kernel)
    for name, changes in [
        ("laws.py", True),  # through helpers, a name of a parenthesised import list
        ("consts.py", True),  # a constant frozen into compiled code
        ("sim/__init__.py", True),  # a parent package runs first
        ("late.py", False),  # imported inside a function: plain Python, later
        ("other.py", False),  # not imported
    ]:
        (root / name).write_text((root / name).read_text() + "# edited\n")
        after = kernel_cache.source_stamp(kernel)
        assert (after != before) is changes, name
        before = after


def _copy_package(tmp_path) -> Path:
    shutil.copytree(
        ROOT / "evo_door", tmp_path / "evo_door", ignore=shutil.ignore_patterns("__pycache__")
    )
    return tmp_path


USER_FILE = """\
from numba import njit
from evo_door.render.friction import tanh_friction

@njit(cache=True)
def braking(v):
    return tanh_friction(v, 2.0, 3.0)

print(braking(0.1), sum(braking.stats.cache_hits.values()))
"""


def test_a_checkout_moved_elsewhere_keeps_its_compiled_kernels(tmp_path):
    """The stamps name evo-door's files by their place in the package and a user's
    file by its name (not where they sit): a checkout and a model beside it, copied
    elsewhere with their ``__pycache__`` folders, load the kernels compiled before the
    copy (CI's main job runs on a copy of the suite's)."""
    first = _copy_package(tmp_path / "first")
    (first / "user.py").write_text(USER_FILE)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}  # in-tree caches

    def run(home):
        out = subprocess.run([sys.executable, "user.py"], cwd=home,
                             env={**env, "PYTHONPATH": str(home)}, capture_output=True,
                             text=True)  # fmt: skip
        assert out.returncode == 0, out.stderr
        value, hits = out.stdout.split()
        return float(value), int(hits)

    value, hits = run(first)
    assert hits == 0 and list((first / "__pycache__").glob("user.braking-*.nbi"))
    moved = tmp_path / "elsewhere" / "second"
    shutil.copytree(first, moved)
    assert run(moved) == (value, 1)  # from the cache it came with


def test_kernels_compiled_into_a_cache_folder_load_beside_their_sources_once_copied(tmp_path):
    """``tests.helpers.copy_numba_cache``: a kernel compiled with ``NUMBA_CACHE_DIR``,
    copied into the ``__pycache__`` beside its file, loads from there without it (the
    suite's first compile on a fresh clone, ``tests/conftest.py``, hands its kernels to
    the workers so)."""
    home = tmp_path / "home"
    home.mkdir()
    (home / "user.py").write_text(USER_FILE)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}

    def run(cache=None):
        extra = {"NUMBA_CACHE_DIR": str(cache)} if cache else {}
        out = subprocess.run([sys.executable, "user.py"], cwd=home, capture_output=True,
                             env={**env, **extra, "PYTHONPATH": str(ROOT)}, text=True)  # fmt: skip
        assert out.returncode == 0, out.stderr
        value, hits = out.stdout.split()
        return float(value), int(hits)

    value, hits = run(tmp_path / "cache")
    assert hits == 0 and not (home / "__pycache__").exists()
    assert copy_numba_cache(tmp_path / "cache", home) == 2  # the index and the code
    assert sorted(f.suffix for f in (home / "__pycache__").iterdir()) == [".nbc", ".nbi"]
    assert run() == (value, 1)


def test_a_fresh_checkout_compiles_before_the_workers_as_the_cold_compile_test_does(
    monkeypatch, tmp_path
):
    """On a checkout with no compiled kernel, the suite's compile before its workers is
    the cold-compile test's first command (an empty cache folder of its own, the notes
    on): its output is kept where the workers are told, its kernels copied into the
    checkout, the record removed when the session ends."""
    from tests import conftest

    root = tmp_path / "checkout"
    (root / "evo_door" / "sim" / "__pycache__").mkdir(parents=True)
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.delenv("EVO_DOOR_TEST_EMPTY_CACHE", raising=False)
    assert conftest.fresh_checkout(root)
    with monkeypatch.context() as m:
        m.setenv("NUMBA_CACHE_DIR", str(tmp_path))  # numba's cache elsewhere
        assert not conftest.fresh_checkout(root)
    with monkeypatch.context() as m:
        m.setattr(os, "access", lambda path, mode: False)  # a read-only checkout
        assert not conftest.fresh_checkout(root)
    (root / "evo_door" / "sim" / "__pycache__" / "a.f-1.py311.nbi").write_bytes(b"")
    assert not conftest.fresh_checkout(root)

    calls, copies = [], []

    def fake_run(cmd, **kwargs):
        calls.append((cmd, kwargs["env"]))
        return SimpleNamespace(returncode=0, stdout="compiled 45 kernels\n", stderr="notes\n")

    monkeypatch.setattr(subprocess, "run", fake_run)
    monkeypatch.setattr(
        conftest, "copy_numba_cache", lambda cache, tree: copies.append((cache, tree))
    )
    monkeypatch.setattr(conftest, "fresh_checkout", lambda: True)
    monkeypatch.setenv(conftest.COLD_RECORD, "")  # so that it is undone whatever it was
    monkeypatch.delenv(conftest.COLD_RECORD)
    monkeypatch.delenv(conftest.PRECOMPILED, raising=False)
    config = _Config(2)
    conftest.pytest_sessionstart(SimpleNamespace(config=config))
    record = Path(os.environ[conftest.COLD_RECORD])
    ((cmd, env),) = calls
    assert cmd == [sys.executable, "-m", "evo_door", "compile"]
    assert env["NUMBA_CACHE_DIR"] == str(record / "cache") and env["EVO_DOOR_COMPILE_NOTES"] == "1"
    assert copies == [(record / "cache", ROOT / "evo_door")]
    assert json.loads((record / "compile.json").read_text()) == {
        "returncode": 0,
        "stderr": "notes\n",
    }
    assert config.lines[0].startswith("evo-door compile, before the workers start: compiled 45")
    conftest.pytest_sessionfinish(SimpleNamespace(config=config))
    assert not record.exists()


def test_the_cold_compiles_key_follows_the_sources_the_place_and_numbas_settings(
    tmp_path, monkeypatch
):
    """``tests.helpers.cold_compile_key``: the same checkout gives the same key; an edit
    of any of the package's files, another place, or a numba setting in the
    environment gives another (a kept cold compile is then not reused)."""
    root = _copy_package(tmp_path / "a")
    key = cold_compile_key(root)
    assert cold_compile_key(root) == key
    friction = root / "evo_door/render/friction.py"
    text = friction.read_text()
    friction.write_text(text + "\n# an edit\n")
    assert cold_compile_key(root) != key
    friction.write_text(text)
    assert cold_compile_key(root) == key
    assert cold_compile_key(_copy_package(tmp_path / "b")) != key  # numba's folders move
    monkeypatch.setenv("NUMBA_OPT", "1")
    assert cold_compile_key(root) != key


def test_a_cold_compile_is_kept_and_the_next_run_of_the_same_sources_reads_it(
    monkeypatch, tmp_path
):
    """The suite's cold compile on a fresh checkout is kept in pytest's cache under its
    key; the next run with that key compiles nothing cold: the workers are named a copy
    of the kept record (the cold-compile test's commands may not touch the kept one),
    and the run's line says so. A run with another key compiles cold again and its
    record replaces the older one; a failed compile, or a damaged record, is not
    reused; without a pytest cache that can be written nothing is kept."""
    from tests import conftest

    store = tmp_path / "pytest-cache" / "evo-door-cold-compile"
    calls = []

    def fake_run(cmd, **kwargs):  # a compile that fills the cache folder it is given
        calls.append(cmd)
        cache = kwargs["env"].get("NUMBA_CACHE_DIR")
        if cache and cmd[-1] == "compile":
            (Path(cache) / "sim_1a2b").mkdir(parents=True)
            (Path(cache) / "sim_1a2b" / "states.f-1.py311.nbi").write_text("index")
        return SimpleNamespace(returncode=0, stdout="compiled 45 kernels\n", stderr="notes\n")

    def session(key, fresh):
        calls.clear()
        monkeypatch.setattr(conftest, "cold_compile_key", lambda: key)
        monkeypatch.setattr(conftest, "fresh_checkout", lambda: fresh)
        config = _Config(2)
        config.cache = SimpleNamespace(mkdir=lambda name: _made(store.parent / name))
        conftest.pytest_sessionstart(SimpleNamespace(config=config))
        record = Path(os.environ[conftest.COLD_RECORD])
        kernel = (record / "cache/sim_1a2b/states.f-1.py311.nbi").read_text()
        notes = json.loads((record / "compile.json").read_text())
        conftest.pytest_sessionfinish(SimpleNamespace(config=config))
        assert not record.exists()
        monkeypatch.delenv(conftest.COLD_RECORD)
        return config.lines[0], list(calls), kernel, notes

    monkeypatch.setattr(subprocess, "run", fake_run)
    monkeypatch.setattr(conftest, "copy_numba_cache", lambda cache, tree: 0)
    monkeypatch.delenv(conftest.PRECOMPILED, raising=False)
    monkeypatch.delenv("EVO_DOOR_TEST_EMPTY_CACHE", raising=False)
    monkeypatch.setenv(conftest.COLD_RECORD, "")  # so that it is undone whatever it was
    monkeypatch.delenv(conftest.COLD_RECORD)
    cold = [sys.executable, "-m", "evo_door", "compile"]
    line, ran, kernel, notes = session("k1", fresh=True)
    assert ran == [cold] and "kept from" not in line
    assert kernel == "index" and notes == {"returncode": 0, "stderr": "notes\n"}
    assert [d.name for d in store.iterdir()] == ["k1"]
    line, ran, kernel, notes = session("k1", fresh=False)  # the same sources, warm
    assert ran == [[*cold, "--quiet"]] and kernel == "index" and notes["stderr"] == "notes\n"
    assert "; the cold-compile test reads the first compile kept from " in line
    line, ran, _, _ = session("k2", fresh=True)  # an edit: compiled cold again
    assert ran == [cold] and [d.name for d in store.iterdir()] == ["k2"]
    assert kept_cold_record(store, "k2") == store / "k2"
    (store / "k2" / "compile.json").write_text('{"returncode": 1')  # damaged
    assert kept_cold_record(store, "k2") is None
    (store / "k2" / "compile.json").write_text('{"returncode": 1, "stderr": ""}')
    assert kept_cold_record(store, "k2") is None
    assert kept_cold_record(store, "k3") is None

    def read_only(name):
        raise PermissionError(13, "Read-only file system", name)

    assert conftest.cold_store(SimpleNamespace(cache=SimpleNamespace(mkdir=read_only))) is None
    assert conftest.cold_store(SimpleNamespace()) is None  # -p no:cacheprovider


def _made(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def test_an_edit_of_a_module_a_cached_kernel_calls_compiles_it_afresh(tmp_path):
    """numba alone would load the old machine code: it watches the kernel's own file."""
    home = _copy_package(tmp_path)
    (home / "user.py").write_text(USER_FILE)
    env = {**os.environ, "PYTHONPATH": str(home), "NUMBA_CACHE_DIR": str(home / "cache")}

    def run():
        out = subprocess.run(
            [sys.executable, "user.py"], cwd=home, env=env, capture_output=True, text=True
        )
        assert out.returncode == 0, out.stderr
        value, hits = out.stdout.split()
        return float(value), int(hits)

    first, hits = run()
    assert hits == 0
    assert run() == (first, 1)  # unchanged: from the cache
    friction = home / "evo_door/render/friction.py"
    text = friction.read_text()
    body = "def tanh_friction(velocity, f_c, slope):"
    assert body in text
    friction.write_text(text.replace(body, body + "\n    f_c = 2.0 * f_c"))
    edited, hits = run()
    assert hits == 0 and edited == pytest.approx(2.0 * first, rel=1e-12)


def test_the_notes_name_each_kernel_compiled_and_end_with_a_summary():
    out = io.StringIO()
    kernel_cache.announce(out)
    try:

        @njit
        def fresh(x):
            return x + 1.5

        assert fresh(1.0) == 2.5
        assert fresh(2.0) == 3.5  # compiled once: one note
    finally:
        kernel_cache.finish_announce(out)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("evo-door: compiling numba kernels (the first run")
    named = [line for line in lines if "fresh" in line]
    assert len(named) == 1 and named[0].startswith("evo-door: compiling tests.")
    assert named[0].endswith("<locals>.fresh (kernel 1, 0 s so far)")
    assert lines[-1].startswith("evo-door: compiled 1 kernel in ")
    kernel_cache.announce(out)  # nothing compiled: no summary
    kernel_cache.finish_announce(out)
    assert out.getvalue().splitlines() == lines


def _cli(args, cache, cwd):
    """The compile notes of ``evo-door ARGS`` on the numba cache ``cache``."""
    out = noted_process(*args, cache=cache, cwd=cwd)
    assert out.returncode == 0, out.stderr
    return compile_notes(out.stderr)


def _empty_cache(tmp_path) -> Path:
    """A numba cache folder to fill: ``EVO_DOOR_TEST_EMPTY_CACHE`` when set (CI's
    generic-CPU pass hands its own cache, which it then tests on; it must be empty), else
    a temporary one."""
    given = os.environ.get("EVO_DOOR_TEST_EMPTY_CACHE")
    if not given:
        return tmp_path / "cache"
    cache = Path(given)
    assert cache.is_dir() and not any(cache.iterdir()), f"{cache} is not an empty folder"
    return cache


def _first_compile(tmp_path) -> tuple[Path, list[str], bool]:
    """The cache folder a first ``evo-door compile`` filled, that command's compile
    notes, and whether it ran here: on a fresh checkout, the one the suite ran before
    its workers started, into a folder nothing else writes to (``tests/conftest.py``,
    ``EVO_DOOR_TEST_COLD_RECORD``), or a copy of the one kept from an earlier run of the
    same sources; else this test's own, into an empty folder."""
    from tests.conftest import COLD_RECORD

    record = os.environ.get(COLD_RECORD)
    if not record:
        cache = _empty_cache(tmp_path)
        return cache, _cli(["compile"], cache, tmp_path), True
    done = read_compile_record(Path(record))
    assert done is not None and done["returncode"] == 0, done
    return Path(record) / "cache", compile_notes(done["stderr"]), False


@pytest.mark.slow
@pytest.mark.cold_compile
def test_a_first_command_says_what_it_compiles_and_compile_leaves_nothing_to_compile(
    tmp_path, pytestconfig
):
    """A fresh cache (an install): the first command, ``evo-door compile``, names each
    kernel it compiles as it starts (any command does: the notes are the command line's,
    ``evo_door.cli.compile_notes``); then ``simulate haptic``, a GA run, a render and
    the HapticMaster emulator compile nothing. On a fresh checkout the first compile is
    the one the suite ran before its workers (:func:`_first_compile`); one this test
    ran itself is kept in pytest's cache for the next run of the same sources
    (``tests/conftest.py``)."""
    cache, notes, here = _first_compile(tmp_path)
    assert notes[0].startswith("evo-door: compiling numba kernels (the first run")
    named = "\n".join(notes)
    for kernel in ("evo_door.models.haptic.accel", "evo_door.sim.objective._population_errors"):
        assert f"evo-door: compiling {kernel} (kernel " in named, kernel
    if default_jobs() == 2:  # two cores: a second process took its part, and no kernel
        # was compiled by both (each process's own notes name its kernels)
        for kernel in ("evo_door.sim.states.integrate_trial", "evo_door.models.fmu.kernels.run_me"):
            assert f"evo-door: compiling {kernel} (second process, kernel " in named, kernel
        assert "evo-door: compiled in both processes" not in named, named
    t = 0.001 * np.arange(2000)
    (tmp_path / "in.csv").write_text("t,force\n" + "".join(f"{x},{5.0}\n" for x in t))
    assert (
        _cli(["simulate", "haptic", "--input", "in.csv", "--out", "o.csv"], cache, tmp_path) == []
    )
    (tmp_path / "tiny.yaml").write_text(TINY_EXPERIMENT)
    assert DATA.exists()
    assert _cli(["run", "tiny.yaml", "--out", "tiny.h5"], cache, tmp_path) == []
    # a session's render, in simulated time, with a log (its resampling is compiled too)
    render = ["render", "--user", "open", "--duration", "0.2", "--log", "r.h5"]
    assert _cli(render, cache, tmp_path) == []
    tanh = [*render[:-1], "r2.h5", "--friction", "tanh", "--clamp"]  # passive at the period
    assert _cli(tanh, cache, tmp_path) == []
    emulate = ["emulate", "hapticmaster", "--port", "0", "--seconds", "0.2"]
    assert _cli(emulate, cache, tmp_path) == []  # the device's physics and its model's
    assert _cli(["compile"], cache, tmp_path) == []  # its own summary goes to stdout
    from tests.conftest import cold_store

    store = cold_store(pytestconfig)
    if here and store is not None:
        keep_cold_record(store, cold_compile_key(), cache, "\n".join(notes) + "\n")


class _Config:
    """What ``tests/conftest.py``'s hooks read of a pytest config."""

    def __init__(self, numprocesses, dist="load", collectonly=False, worker=False):
        self.option = SimpleNamespace(numprocesses=numprocesses, dist=dist, collectonly=collectonly)
        if worker:
            self.workerinput = {}
        self.lines = []
        self.pluginmanager = SimpleNamespace(
            get_plugin=lambda name: SimpleNamespace(write_line=self.lines.append)
        )


@pytest.mark.parametrize(
    "config, runs",
    [
        (_Config(2), True),
        (_Config(4), True),
        (_Config(1), False),  # one worker compiles alone: nothing to share
        (_Config(None, dist="no"), False),  # no xdist: the tests compile what they use
        (_Config(2, collectonly=True), False),
        (_Config(2, worker=True), False),  # a worker: the controller compiled
    ],
)
def test_the_suite_compiles_once_before_its_workers_start(monkeypatch, config, runs, tmp_path):
    """With two or more xdist workers, the controller runs ``evo-door compile`` once and
    says so; otherwise nothing runs. Either way it then makes the file CI's main job
    waits for."""
    from tests import conftest

    calls = []

    def fake_run(cmd, **kwargs):
        calls.append(cmd)
        return SimpleNamespace(returncode=0, stdout="compiled 22 kernels in 9.0 s\n", stderr="")

    monkeypatch.setattr(subprocess, "run", fake_run)
    monkeypatch.setattr(conftest, "fresh_checkout", lambda: False)  # a compiled checkout
    monkeypatch.delenv(conftest.PRECOMPILED, raising=False)
    mark = tmp_path / "compiled"  # CI's main job waits for it (.ci/run)
    monkeypatch.setenv(conftest.COMPILED_MARK, str(mark))
    conftest.pytest_sessionstart(SimpleNamespace(config=config))
    if runs:
        assert calls == [[sys.executable, "-m", "evo_door", "compile", "--quiet"]]
        assert config.lines[0].startswith(
            "evo-door compile, before the workers start: compiled 22 kernels in 9.0 s"
        )
    else:
        assert calls == [] and config.lines == []
    assert mark.is_file()  # made after the compile, or at once: the main job never waits in vain


def test_a_cache_known_complete_is_not_compiled_before_the_workers(monkeypatch, tmp_path):
    """``EVO_DOOR_TEST_PRECOMPILED=1`` (CI's generic pass, on the cache its cold-compile
    test filled and found complete): no ``evo-door compile`` before the workers, said in
    a line; the file CI's main job waits for is still made."""
    from tests import conftest

    calls = []
    monkeypatch.setattr(subprocess, "run", lambda cmd, **kwargs: calls.append(cmd))
    monkeypatch.setenv(conftest.PRECOMPILED, "1")
    monkeypatch.setenv(conftest.COMPILED_MARK, str(tmp_path / "compiled"))
    config = _Config(2)
    conftest.pytest_sessionstart(SimpleNamespace(config=config))
    assert calls == [] and (tmp_path / "compiled").is_file()
    assert config.lines == [
        "evo-door compile, before the workers start: not run (EVO_DOOR_TEST_PRECOMPILED=1)"
    ]


def test_a_model_folder_copied_with_its_compiled_cache_still_loads(tmp_path):
    """numba's cache beside a model file names the module its functions were compiled
    in: a folder copied with its ``__pycache__`` (``cp -r``) must load in the copy.

    Not a numerical test (``-m numerics``): without ``NUMBA_CACHE_DIR`` the package's
    own kernels load from this checkout's ``__pycache__`` too, which the generic-CPU
    pass would fill with a second compilation of all of them."""
    example = ROOT / "examples" / "drawer"
    args = ("curve", "drawer.py:MODEL", "--params", "soft_close", "--points", "50")

    def curve(folder: Path, out: str):
        done = cli_process(*args, "--out", out, cwd=folder, unset=["NUMBA_CACHE_DIR"],
                           timeout=COMPILE_HANG_GUARD)  # fmt: skip
        assert done.returncode == 0, done.stderr
        return (folder / out).read_text()

    first = tmp_path / "first"
    shutil.copytree(example, first, ignore=shutil.ignore_patterns("__pycache__", "*.h5"))
    made = curve(first, "a.csv")
    assert list((first / "__pycache__").glob("drawer.*.nbi"))  # the cache was written
    copy = tmp_path / "copy"
    shutil.copytree(first, copy)
    assert curve(copy, "b.csv") == made


# -- the faster copy of a function's IR in numba's inliner ---------------------------------

#: A small tree of ``inline="always"`` steps, shaped as the integrators are: loops and
#: branches in each step, steps inlined into steps, and a kernel that calls them.
KERNELS = """
import math
from numba import njit

@njit(inline="always", error_model="numpy")
def stage(x, v, h):
    if x > 0.0:
        return v, -4.0 * x - 0.1 * v
    return v, -9.0 * x - 0.2 * v * abs(v)

@njit(inline="always", error_model="numpy")
def step(x, v, h):
    k1x, k1v = stage(x, v, h)
    k2x, k2v = stage(x + 0.5 * h * k1x, v + 0.5 * h * k1v, h)
    k3x, k3v = stage(x + 0.5 * h * k2x, v + 0.5 * h * k2v, h)
    k4x, k4v = stage(x + h * k3x, v + h * k3v, h)
    return x + h * (k1x + 2 * k2x + 2 * k3x + k4x) / 6, v + h * (k1v + 2 * k2v + 2 * k3v + k4v) / 6

@njit(inline="always", error_model="numpy")
def period(x, v, dt, n):
    for _ in range(n):
        x, v = step(x, v, dt / n)
        if not math.isfinite(x):
            break
    return x, v

@njit("float64(float64, float64, float64, int64)", error_model="numpy")
def kernel(x, v, dt, samples):
    total = 0.0
    for k in range(samples):
        x, v = period(x, v, dt, 1 + k % 3)
        total += x if k % 2 else v
    return total
"""

#: Compiles :data:`KERNELS` (no disk cache), counting the scope copies numba makes; prints
#: whether the faster copy is in place, the count, the result and the assembly.
PROBE = """
import copy, json, sys
from numba.core import ir
from evo_door import kernel_cache
installed = kernel_cache.share_inlined_scopes()
copies = [0]
def counted(self, memo):
    copies[0] += 1
    new = ir.Scope.__new__(ir.Scope)
    memo[id(self)] = new
    for name, value in self.__dict__.items():
        setattr(new, name, copy.deepcopy(value, memo))
    return new
ir.Scope.__deepcopy__ = counted
sys.path.insert(0, sys.argv[1])
import kernels
value = kernels.kernel(0.1, 0.0, 1 / 1024, 200)
(asm,) = kernels.kernel.inspect_asm().values()
print(json.dumps({"installed": installed, "copies": copies[0], "value": value, "asm": asm}))
"""


def _compiled(tmp_path, as_shipped: str) -> dict:
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "kernels.py").write_text(KERNELS)
    env = {**os.environ, kernel_cache.AS_SHIPPED: as_shipped, "NUMBA_DISABLE_JIT": "0"}
    done = subprocess.run(
        [sys.executable, "-c", PROBE, str(tmp_path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        check=True,
    )
    return json.loads(done.stdout)


def _code(asm: str) -> str:
    """The assembly without the names of numba's pickled constants (hashes of their
    bytes) and those bytes (numba's type numbers, which vary from process to process)."""
    asm = re.sub(r"pickledata\.[0-9a-f]+", "pickledata", asm)
    return "\n".join(line for line in asm.splitlines() if ".ascii" not in line)


@pytest.mark.skipif(not kernel_cache.changes_apply(), reason="numba's own inliner copy here")
def test_the_inliner_copies_a_scope_once_per_call_and_compiles_the_same_code(tmp_path):
    ours = _compiled(tmp_path / "ours", "")
    numbas = _compiled(tmp_path / "numbas", "1")
    assert ours["installed"] and not numbas["installed"]
    assert ours["value"] == numbas["value"]  # bit for bit
    assert _code(ours["asm"]) == _code(numbas["asm"])
    # numba copies the function's scope (and its parent, the global scope) for every
    # block it copies: the blocks of every inlined call, twice (the callee, and a copy
    # it keeps unchanged); here, once per copy of a callee. `step` inlines 4 stages,
    # `period` 1 step, `kernel` 1 period: 6 calls, 2 copies each, 2 scopes a copy
    assert ours["copies"] <= 2 * 2 * 6, ours["copies"]
    assert numbas["copies"] >= 5 * ours["copies"], (numbas["copies"], ours["copies"])


def test_a_release_it_was_not_checked_against_keeps_numbas_own_copy(monkeypatch):
    monkeypatch.setattr(kernel_cache, "_numba_release", lambda: (0, 99))
    assert not kernel_cache.changes_apply()
    monkeypatch.setattr(kernel_cache, "_numba_release", lambda: (0, 68))
    monkeypatch.setenv(kernel_cache.AS_SHIPPED, "1")
    assert not kernel_cache.changes_apply()


def test_the_package_runs_with_the_faster_copy_on_the_pinned_numba():
    """With the release constraints.txt pins, the copy is in place: a bump of the pin
    past the checked releases would slow every cold compile without failing a test."""
    pinned = re.search(r"^numba==(\S+)", (ROOT / "constraints.txt").read_text(), re.M)
    assert pinned, "constraints.txt pins numba"
    if numba.__version__ != pinned.group(1):
        pytest.skip(f"numba {numba.__version__} here, not the pinned {pinned.group(1)}")
    assert kernel_cache.changes_apply() and kernel_cache.share_inlined_scopes()


@njit(cache=True)
def _slope(x):
    return 2.0 * x


@njit(cache=True)
def _cube(x):
    return x * x * x


_UNARY = numba.types.FunctionType(numba.types.float64(numba.types.float64))


@njit(numba.types.float64(_UNARY, numba.types.float64), cache=True)
def _apply(f, x):
    return f(x)


@pytest.mark.skipif(not kernel_cache.changes_apply(), reason="numba as shipped here")
def test_a_function_handed_to_a_kernel_is_looked_up_once_and_each_its_own(monkeypatch):
    """numba looks up a first-class function's addresses at every call of the kernel it
    is handed to; remembered per function, they are looked up once, and two functions
    of one signature each keep their own."""
    assert kernel_cache.remember_addresses()
    assert _apply(_slope, 3.0) == 6.0 and _apply(_cube, 3.0) == 27.0
    lookups = []
    original = numba.core.dispatcher.Dispatcher.get_compile_result
    monkeypatch.setattr(
        numba.core.dispatcher.Dispatcher,
        "get_compile_result",
        lambda self, sig: lookups.append(self) or original(self, sig),
    )
    for x in range(50):  # alternating: each call must reach its own function
        assert _apply(_slope, float(x)) == 2.0 * x
        assert _apply(_cube, float(x)) == float(x) ** 3
    assert lookups == []


@pytest.mark.parametrize(
    "jobs, said", [("0", "at least 1 process, not 0"), ("two", "not a whole number: 'two'")]
)
def test_compile_refuses_jobs_that_are_not_a_whole_number_of_at_least_one(jobs, said, tmp_path):
    out = cli_process("compile", "--jobs", jobs, cwd=tmp_path)
    assert out.returncode == 2 and said in out.stderr.splitlines()[-1], out.stderr


def test_the_second_process_run_from_a_terminal_is_refused_in_one_line(monkeypatch, capsys):
    """``compile --second-part`` is the first process's helper and waits for its word on
    stdin: typed at a terminal it says so at once, before compiling anything."""
    from evo_door import cli
    from evo_door.commands import compile as command

    monkeypatch.setattr(sys, "stdin", SimpleNamespace(isatty=lambda: True))
    monkeypatch.setattr(command, "_fmu_runners", lambda: pytest.fail("compiled"))
    assert cli.main(["compile", "--second-part"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert "--second-part is evo-door compile's own second process: run evo-door compile" in line


#: the first process's part of ``evo-door compile --jobs 2`` up to its wait for the
#: second, and the second's part up to its go: the modules each then has imported
SPLIT = """
import json, sys
from evo_door.commands import compile as c

class Second:
    failure = ""
    def go(self):
        pass
    def more(self):
        pass
    def wait(self):
        raise SystemExit(json.dumps(sorted(m for m in sys.modules if m.startswith("evo_door"))))

if sys.argv[1] == "first":
    for what, work in c.steps(Second()):
        work()
c._fmu_runners()
c._emulator()
print(json.dumps(sorted(m for m in sys.modules if m.startswith("evo_door"))))
"""


@pytest.mark.slow
def test_the_two_processes_of_compile_import_nothing_the_other_compiles(tmp_path):
    """What keeps ``evo-door compile``'s two processes from compiling a kernel twice:
    until the first has waited for the second, it imports neither the state-vector
    integrators nor the FMU runners nor the emulator's physics nor the renderer's
    kernels nor the modules the second imports last (the second's part); until told to
    go on, the second imports no module of ``evo_door.sim`` (the first compiles the
    one-coordinate integrators, which the state-vector ones import)."""
    from evo_door.commands.compile import LATER

    script = tmp_path / "split.py"
    script.write_text(SPLIT)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    first = subprocess.run([sys.executable, str(script), "first"], capture_output=True,
                           text=True, env=env, cwd=tmp_path, timeout=COMPILE_HANG_GUARD)  # fmt: skip
    assert first.returncode == 1, first.stderr  # SystemExit with its text: the wait
    imported = json.loads(first.stderr.strip().splitlines()[-1])
    assert "evo_door.sim.integrators" in imported and "evo_door.models.door" in imported
    for theirs in ("evo_door.sim.states", "evo_door.models.fmu.kernels",
                   "evo_door.render.emulator_physics", "evo_door.render.kernels", *LATER):  # fmt: skip
        assert theirs not in imported, theirs
    second = subprocess.run([sys.executable, str(script), "second"], capture_output=True,
                            text=True, env=env, cwd=tmp_path, timeout=COMPILE_HANG_GUARD)  # fmt: skip
    assert second.returncode == 0, second.stderr
    imported = json.loads(second.stdout.strip().splitlines()[-1])
    assert "evo_door.models.fmu.kernels" in imported
    assert not [m for m in imported if m.startswith("evo_door.sim")], imported


def test_a_failed_second_process_leaves_its_part_to_the_first():
    """The second process of ``evo-door compile`` ends at once with an error: waiting for
    it says so, and the first's steps after the wait hold the second's part (the render,
    then every module: the state-vector integrators and the rest; the FMU runners, the
    emulator's physics)."""
    from evo_door.commands import compile as compile_cmd

    class Failing(compile_cmd.SecondProcess):
        def __init__(self, quiet):
            self.proc = subprocess.Popen([sys.executable, "-c", "import sys; sys.exit(3)"],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         stderr=subprocess.PIPE, text=True)  # fmt: skip
            self.compiled, self.failure = [], ""

    second = Failing(quiet=True)
    second.proc.wait()
    second.go()  # to a process that has ended: no error
    assert second.wait() == "the second process failed (exit 3); what it left compiles here"
    assert second.compiled == [] and second.failure
    names = [what for what, _ in compile_cmd.steps(second)]
    after = names[names.index(f"waiting for the second process ({compile_cmd.SECOND_PART})") :]
    assert after[1:] == [
        "a render of the haptic model on the simulated device",
        "importing every module",
        "the FMU runners (FMI 2 and 3, model exchange and co-simulation)",
        "the HapticMaster emulator's physics",
    ]
    assert [w for w, _ in compile_cmd.steps(None)] == [n for n in names if n != after[0]]
