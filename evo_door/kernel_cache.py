"""numba's disk cache of compiled kernels, invalidated by every source they depend on.

numba keeps a compiled function (``@njit(cache=True)``) on disk and reuses it while the
function's *own* file is unchanged. A kernel that calls a jitted function of another
module, or reads a constant from one, freezes that code into its own: after an edit (or
an upgrade) of the other module, numba would load the old machine code. The locators
here stamp a cached function instead with a digest of its file **and of every evo-door
module it imports, directly or through others** (the top-level import lines, read as
text). Any edit along that chain changes the stamp, and numba then compiles
afresh and overwrites its entry: nothing to delete by hand, nothing stale.

They serve every file that imports evo-door: the package's own kernels, a user's model
file, the tests' kernels. Other files keep numba's own locators. ``import evo_door``
names them to numba through ``NUMBA_CACHE_LOCATOR_CLASSES`` (numba imports this module
when it caches the first function), in front of numba's own list, so that
``NUMBA_CACHE_DIR`` still moves the cache.

The same import notes the compilations numba does (not its cache hits) for
:func:`announce`: the command line says what it compiles on a first run, instead of a
silent wait. Two changes to numba's plumbing, the same code run sooner: its inliner
copies a function's IR faster (:func:`share_inlined_scopes`), and a compiled function
handed to a kernel as an argument has its addresses looked up once, not at every call
(:func:`remember_addresses`).
"""

from __future__ import annotations

import copy
import functools
import hashlib
import os
import re
import sys
import threading
import time
from pathlib import Path

import numba
from numba.core import caching, event, inline_closurecall, ir
from numba.core.dispatcher import Dispatcher
from numba.experimental import function_type

#: The package's folder: the modules whose imports are followed.
ROOT = Path(__file__).resolve().parent
#: ``from evo_door.x import a, b`` and ``import evo_door.x``, at a module's top level
#: (a compiled function reads the globals its module has once imported; an import
#: inside a function runs later, in plain Python, and cannot reach compiled code).
_IMPORT = re.compile(
    r"^(?:from\s+(evo_door(?:\.\w+)*)\s+import\s+([^#\n]+)|import\s+(evo_door(?:\.\w+)*))",
    re.MULTILINE,
)


def module_file(name: str) -> Path | None:
    """The source file of the evo-door module ``name``, or ``None``."""
    rel = Path(*name.split(".")[1:])
    for path in (ROOT / rel / "__init__.py", (ROOT / rel).with_suffix(".py")):
        if path.is_file():
            return path
    return None


@functools.cache
def _imports(path: str, mtime_ns: int, size: int) -> tuple[bytes, tuple[str, ...]]:
    """The digest of one file and the evo-door files it imports (memoised on the
    file's time and size, so that an edit while running is seen)."""
    text = Path(path).read_bytes()
    found = []
    for m in _IMPORT.finditer(text.decode("utf-8", "replace")):
        package = m.group(1) or m.group(3)
        names = [package]
        if m.group(1):  # `from evo_door.x import y`: y may be a module of package x
            items = m.group(2).replace("(", " ").replace(")", " ").replace("\\", " ")
            names += [f"{package}.{n.split()[0]}" for n in items.split(",") if n.split()]
        parts = package.split(".")  # the parents' __init__ run first
        names += [".".join(parts[:k]) for k in range(1, len(parts))]
        found += [str(f) for f in map(module_file, names) if f is not None]
    return hashlib.sha256(text).digest(), tuple(sorted(set(found)))


def _file_digest(path: str) -> tuple[bytes, tuple[str, ...]]:
    st = os.stat(path)
    return _imports(path, st.st_mtime_ns, st.st_size)


def source_stamp(path: str | os.PathLike) -> bytes:
    """The digest of ``path`` and of every evo-door file it imports, transitively.

    Each file is named by its place in the package (``evo_door/sim/located.py``), or a
    user's file by its name, not by where it sits: a checkout or a model folder moved,
    copied or installed elsewhere keeps its compiled kernels (with the ``__pycache__``
    folders, or a copy of them)."""
    seen: set[str] = set()
    todo = [os.path.abspath(path)]
    while todo:
        p = todo.pop()
        if p not in seen:
            seen.add(p)
            todo += _file_digest(p)[1]
    h = hashlib.sha256()
    for p in sorted(seen):
        h.update(_stamp_name(p).encode() + b"\0" + _file_digest(p)[0])
    return h.digest()


@functools.cache
def _stamp_name(path: str) -> str:
    """``path`` within the package's parent folder for an evo-door file, else its name
    (a user's model file: its cache sits beside it, and moves with it)."""
    inside = Path(path).resolve()
    if inside.is_relative_to(ROOT):
        return inside.relative_to(ROOT.parent).as_posix()
    return inside.name


@functools.cache
def uses_evo_door(path: str) -> bool:
    """Whether a cached function's file is evo-door's or imports it (asked by each
    locator in turn for every cached function: once per file and process)."""
    if not os.path.isfile(path):
        return False
    if Path(path).resolve().is_relative_to(ROOT):
        return True
    return bool(_file_digest(os.path.abspath(path))[1])


class _ImportStamped:
    """A numba locator whose source stamp covers the file's evo-door imports."""

    @classmethod
    def from_function(cls, py_func, py_file):
        if not uses_evo_door(py_file):
            return None  # numba's own locators, further down the list
        return super().from_function(py_func, py_file)

    def get_source_stamp(self):
        return source_stamp(self._py_file)


class UserProvided(_ImportStamped, caching.UserProvidedCacheLocator):
    """``NUMBA_CACHE_DIR`` set: the cache there."""


class InTree(_ImportStamped, caching.InTreeCacheLocator):
    """The ``__pycache__`` folder beside the source, when writable."""


class UserWide(_ImportStamped, caching.UserWideCacheLocator):
    """A read-only install: the user's cache folder."""


#: The value of ``NUMBA_CACHE_LOCATOR_CLASSES``: these, then numba's own defaults.
LOCATORS = ",".join(
    [f"{__name__}.{c.__name__}" for c in (UserProvided, InTree, UserWide)]
    + [c.__name__ for c in caching.CacheImpl._locator_classes]
)


class _Compiles(event.Listener):
    """Counts numba's compilations (cache misses) and reports the outermost ones."""

    def __init__(self):
        self.depth = 0
        self.started = None
        self.report = None  # a callable(name, count, seconds) while announcing
        self.compiled: list[str] = []  # each outermost one: "module.name(argument types)"

    @property
    def count(self) -> int:
        """How many compiled since the count was last cleared (:meth:`clear`)."""
        return len(self.compiled)

    def clear(self) -> None:
        """Count afresh: nothing compiled, no start time."""
        self.compiled.clear()
        self.started = None

    def on_start(self, ev):
        self.depth += 1
        if self.depth == 1:
            if self.started is None:
                self.started = time.perf_counter()
            func = ev.data["dispatcher"].py_func
            name = f"{func.__module__}.{func.__qualname__}"
            self.compiled.append(f"{name}({', '.join(map(str, ev.data['args']))})")
            if self.report is not None:
                self.report(name, self.count, time.perf_counter() - self.started)

    def on_end(self, ev):
        self.depth -= 1


COMPILES = _Compiles()
event.register("numba:compile", COMPILES)


def announce(stream=None) -> None:
    """From now on, write a progress line to ``stream`` (stderr) for each compilation:
    what is compiled, how many so far and since when. On a terminal, one line redrawn;
    otherwise one line per kernel. Cache hits are silent."""
    stream = stream or sys.stderr
    tty = stream.isatty()
    COMPILES.clear()

    def report(name, count, seconds):
        if count == 1:
            stream.write(
                "evo-door: compiling numba kernels (the first run after an install or an "
                "edit; kept in numba's cache for the next runs)\n"
            )
        text = f"evo-door: compiling {name} (kernel {count}, {seconds:.0f} s so far)"
        stream.write("\r\033[K" + text if tty else text + "\n")
        stream.flush()

    COMPILES.report = report


def kernels(n: int) -> str:
    """``1 kernel``, ``3 kernels``.

    >>> kernels(1), kernels(2)
    ('1 kernel', '2 kernels')
    """
    return f"{n} kernel{'' if n == 1 else 's'}"


def finish_announce(stream=None, summary: bool = True) -> None:
    """Stop announcing; with ``summary``, end the progress line with what was compiled
    (if anything was)."""
    stream = stream or sys.stderr
    if summary and COMPILES.report is not None and COMPILES.count:
        seconds = time.perf_counter() - (COMPILES.started or time.perf_counter())
        end = "\r\033[K" if stream.isatty() else ""
        stream.write(
            f"{end}evo-door: compiled {kernels(COMPILES.count)} in {seconds:.1f} s "
            "(kept in numba's cache; the next run starts at once)\n"
        )
        stream.flush()
    COMPILES.report = None


if getattr(sys.modules.get("evo_door"), "compile_notes", False):  # a command is running
    announce()


# -- a faster copy of a function's IR in numba's inliner --------------------------------
# The integrators are small step functions that numba inlines into one kernel
# (``inline="always"``, evo_door.sim.integrators). For each call site it inlines,
# numba's inliner (``InlineWorker.inline_ir``) copies the callee's IR block by block,
# each with ``copy.deepcopy``. A block refers to the function's one scope, which lists
# every variable of the function, and each block's copy copies that whole scope again:
# a copy costs the function's blocks times its variables. On the integrators, whose
# inlined bodies run to hundreds of blocks, that copying is a large share of a cold
# ``evo-door compile`` (timed in the benchmark suite's start-up section). numba's issue
# tracker has the inliner's copying on record as a cost (its issues 8989 and 9204).
#
# share_inlined_scopes() gives numba's IR blocks a ``__deepcopy__`` that, within one
# call of the inliner, copies the scope once and lets every block's copy share it;
# outside the inliner a block is copied as before. The inliner then renames the
# callee's variables into the caller's scope by name and points every block at the
# caller's scope, so it builds the same IR: the compiled code is the same to the bit
# (tests/test_kernel_cache.py compares the assembly numba emits with and without). One
# method added to a numba class, one wrapped; only on the numba releases it was checked
# against, and not with EVO_DOOR_NUMBA_AS_SHIPPED=1 in the environment (numba's own
# copy, for comparing).

#: The numba releases (major, minor) whose inliner the shared scope copy was checked
#: against (the one constraints.txt pins): their ``inline_ir`` copies the callee block
#: by block and expects one scope in it. Any other release compiles with its own copy.
#: The same for :func:`remember_addresses`.
CHANGES_CHECKED = ((0, 68),)
#: The environment variable that, set to ``1``, leaves numba as shipped: neither
#: :func:`share_inlined_scopes` nor :func:`remember_addresses` (for comparing).
AS_SHIPPED = "EVO_DOOR_NUMBA_AS_SHIPPED"

#: Per thread, while the inliner runs: original scope's id -> (the scope, its copy).
_inlining = threading.local()


def _numba_release() -> tuple[int, int]:
    major, minor = numba.__version__.split(".")[:2]
    return int(major), int(minor)


def _copy_block(block, memo):
    """``copy.deepcopy`` of an IR block; within the inliner, the scope copied once."""
    shared = getattr(_inlining, "scopes", None)
    if shared is not None:
        entry = shared.get(id(block.scope))
        if entry is None:  # the first block of this callee: copy its scope
            entry = (block.scope, copy.deepcopy(block.scope, memo))
            shared[id(block.scope)] = entry  # holds the original: its id stays unique
        memo[id(block.scope)] = entry[1]
    new = ir.Block.__new__(ir.Block)
    memo[id(block)] = new
    for name, value in block.__dict__.items():
        setattr(new, name, copy.deepcopy(value, memo))
    return new


def _sharing_scopes(inline_ir):
    """numba's ``inline_ir``, with the blocks it copies sharing their scope's copy."""

    def inline_ir_sharing_scopes(self, *args, **kwargs):
        outer = getattr(_inlining, "scopes", None)
        _inlining.scopes = {}
        try:
            return inline_ir(self, *args, **kwargs)
        finally:
            _inlining.scopes = outer

    inline_ir_sharing_scopes.__wrapped__ = inline_ir  # type: ignore[attr-defined]
    return inline_ir_sharing_scopes


def changes_apply() -> bool:
    """Whether :func:`share_inlined_scopes` and :func:`remember_addresses` change numba
    here (or did): a checked release, a block class without a copy of its own, not
    :data:`AS_SHIPPED`."""
    return (
        os.environ.get(AS_SHIPPED, "") != "1"
        and _numba_release() in CHANGES_CHECKED
        and vars(ir.Block).get("__deepcopy__", _copy_block) is _copy_block
        and hasattr(inline_closurecall.InlineWorker, "inline_ir")
    )


def share_inlined_scopes() -> bool:
    """Install the shared scope copy in numba's inliner (once per process; this module
    does when imported); whether it is in place."""
    worker = inline_closurecall.InlineWorker
    if vars(ir.Block).get("__deepcopy__") is not _copy_block and changes_apply():
        worker.inline_ir = _sharing_scopes(worker.inline_ir)  # type: ignore[method-assign]
        ir.Block.__deepcopy__ = _copy_block  # type: ignore[attr-defined]
    return vars(ir.Block).get("__deepcopy__") is _copy_block


share_inlined_scopes()


# -- a compiled function's addresses, looked up once -------------------------------------
# A kernel that takes a compiled function as an argument (a model's right-hand side, its
# switching functions, its hold force: numba's first-class functions) asks, at every
# call and for every such argument, numba.experimental.function_type for the function's
# two entry points (_get_wrapper_address, _get_jit_address: the dispatcher's compile
# result for the signature, then its symbol's address in the JIT): as much Python as
# the rest of a short simulate() call. A compiled overload of a dispatcher stays where
# it is while the dispatcher lives (numba never moves or frees it; the memo keeps the
# dispatcher alive), so both lookups are memoised per dispatcher and signature (a
# dispatcher's recompile(), which evo-door never calls, would leave the memo stale).
# numba reads the two functions off its module at every call (by name), so wrapping
# them is enough; other callables go to numba's own.


def _remembered(lookup):
    """numba's address ``lookup(func, sig)``, memoised for dispatchers."""
    found: dict[int, tuple[object, list]] = {}  # id -> (dispatcher, [(sig, address)])

    def remembered_address(func, sig):
        if not isinstance(func, Dispatcher):
            return lookup(func, sig)
        entry = found.get(id(func))
        if entry is None or entry[0] is not func:
            entry = found[id(func)] = (func, [])
        for known, address in entry[1]:
            if known is sig or known == sig:  # numba hands the same object at a call site
                return address
        address = lookup(func, sig)
        entry[1].append((sig, address))
        return address

    remembered_address.__wrapped__ = lookup  # type: ignore[attr-defined]
    return remembered_address


def remember_addresses() -> bool:
    """Memoise numba's address lookups of first-class functions (once per process;
    this module does when imported), on the releases :func:`changes_apply`
    admits; whether they are memoised."""
    names = ("_get_wrapper_address", "_get_jit_address")
    done = all(hasattr(getattr(function_type, n, None), "__wrapped__") for n in names)
    if not done and changes_apply() and all(hasattr(function_type, n) for n in names):
        for name in names:
            setattr(function_type, name, _remembered(getattr(function_type, name)))
        done = True
    return done


remember_addresses()


class TypedFunction:
    """A compiled function ``func`` (a dispatcher) handed to kernels as a first-class
    function of numba type ``ftype``, its entry point looked up once, here.

    Given the dispatcher itself, numba types it and converts it to ``ftype`` at every
    call of the kernel, even with the addresses memoised (above): a Python call of the
    renderer's cycle on a mechanism took about twice as long. numba reads this
    object's type from ``_numba_type_`` and its address from ``__wrapper_address__``
    (its wrapper-address protocol); the object keeps ``func`` alive, so the address
    stays valid."""

    def __init__(self, func, ftype):
        self.func = func
        self._numba_type_ = ftype
        self._address = function_type._get_wrapper_address(func, ftype.signature)

    def __wrapper_address__(self) -> int:
        return self._address
