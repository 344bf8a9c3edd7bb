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
silent wait.
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
import sys
import time
from pathlib import Path

from numba.core import caching, event

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
    """The digest of ``path`` and of every evo-door file it imports, transitively."""
    seen: set[str] = set()
    todo = [os.path.abspath(path)]
    while todo:
        p = todo.pop()
        if p not in seen:
            seen.add(p)
            todo += _file_digest(p)[1]
    h = hashlib.sha256()
    for p in sorted(seen):
        h.update(p.encode() + b"\0" + _file_digest(p)[0])
    return h.digest()


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
        self.count = 0
        self.started = None
        self.report = None  # a callable(name, count, seconds) while announcing

    def on_start(self, ev):
        self.depth += 1
        if self.depth == 1:
            self.count += 1
            if self.started is None:
                self.started = time.perf_counter()
            if self.report is not None:
                func = ev.data["dispatcher"].py_func
                name = f"{func.__module__}.{func.__qualname__}"
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
    COMPILES.count, COMPILES.started = 0, None

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


def finish_announce(stream=None, summary: bool = True) -> None:
    """Stop announcing; with ``summary``, end the progress line with what was compiled
    (if anything was)."""
    stream = stream or sys.stderr
    if summary and COMPILES.report is not None and COMPILES.count:
        seconds = time.perf_counter() - (COMPILES.started or time.perf_counter())
        end = "\r\033[K" if stream.isatty() else ""
        stream.write(
            f"{end}evo-door: compiled {COMPILES.count} kernels in {seconds:.1f} s "
            "(kept in numba's cache; the next run starts at once)\n"
        )
        stream.flush()
    COMPILES.report = None


if getattr(sys.modules.get("evo_door"), "compile_notes", False):  # a command is running
    announce()
