"""What is checked and claimed before a run starts, so that a refusal writes nothing.

The results file: named (``<output>/<name>-<date>-<time>.h5`` by default), locked for
the run, an existing results file replaced only with ``--force`` and any other file
never (:func:`claim_output`). The memory: a GA keeps every generation for an exact
resume, and a population that cannot fit is refused before the start
(:func:`check_memory`). A pipeline claims its file the same way.
"""

from __future__ import annotations

import os
from datetime import datetime
from pathlib import Path

from evo_door.errors import UserError, WriteError
from evo_door.experiment import store
from evo_door.experiment.config_algorithm import AlgorithmSpec
from evo_door.files import ATTRS, FileLock, remove_stale_temporaries, write_reason

#: what a locked results file says to another process
_LOCKED = "a run is writing it"


def _refuse_to_replace(path: Path, overwrite: bool) -> None:
    """An existing file at a new run's ``--out``: what it is and what to do instead."""
    try:
        pipeline = store.pipeline_attrs(path)
        status = (pipeline or store.peek(path)[ATTRS]).get("status")
    except UserError:
        raise UserError(
            f"{path}: exists and is not an evo-door results file; evo-door will not "
            "replace it: give another --out"
        ) from None
    if overwrite:
        return
    what = "pipeline" if pipeline else "run"
    if status == "complete":
        raise UserError(
            f"{path}: holds a complete {what}; give another --out, or --force to replace it"
        )
    raise UserError(
        f"{path}: holds an interrupted {what}; continue it with evo-door resume {path}, "
        "or give --force to start it over"
    )


def check_memory(algorithm: AlgorithmSpec, n_free: int, available=None) -> int:
    """Refuse a run whose GA could not fit in memory; return the estimate (bytes).

    A GA run keeps every generation's population and fitness (exact resume) and, per
    generation, DEAP's individuals (Python lists of floats: ~56 + 32 bytes a gene,
    offspring and clones included, counted three times over) and the results file's
    copy while it is written. ``available`` (bytes) defaults to the memory the system
    says is available.
    """
    ga = algorithm.ga
    if not algorithm.population_based:
        return 0
    # one job in memory at a time, per_trial or not
    history = (ga.generations + 1) * ga.population * (n_free + 1) * 8 * 2
    live = 3 * ga.population * (200 + 32 * n_free)
    need = history + live
    available = _available_memory() if available is None else available
    if available and need > 0.8 * available:
        raise UserError(
            f"algorithm.population {ga.population:,} x {ga.generations + 1} generations of "
            f"{n_free} free parameters needs about {_gib(need)} of memory (every "
            f"generation is kept for an exact resume); this machine has {_gib(available)} "
            "available: lower population or generations"
        )
    return need


def check_stored_memory(algorithm: AlgorithmSpec, n_free: int, path) -> int:
    """:func:`check_memory` of a run read back from ``path``, before anything of the
    sizes it states is allocated (a file is data: its numbers may be anything)."""
    try:
        return check_memory(algorithm, n_free)
    except UserError as exc:
        raise UserError(f"{path}: {exc}") from None
    except (TypeError, ValueError):
        raise UserError(f"{path}: damaged results file: its algorithm settings") from None


def _gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


def _available_memory() -> int:
    """Bytes of memory available to a new allocation (0 when the system does not say)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return 0


def claim_output(path: Path, overwrite: bool, start):
    """Lock the results file ``path`` of a new run and ``start(path, lock)`` it.

    An existing results file is replaced only with ``overwrite``, any other file never;
    if the run cannot start, the lock is let go and the folders made for ``path`` are
    removed again (only if empty: never what someone else put there).
    """
    if path.suffix.lower() not in (".h5", ".hdf5"):
        raise UserError(f"{path}: results files are HDF5, name them .h5")
    made = [p for p in (path.parent, *path.parent.parents) if not p.exists()]  # deepest first
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = FileLock(path).acquire(_LOCKED)
    except OSError as exc:  # a read-only or full file system
        _remove_empty(made)
        raise WriteError(path, write_reason(exc) or str(exc)) from None
    except BaseException:
        _remove_empty(made)
        raise
    try:
        if path.exists():
            _refuse_to_replace(path, overwrite)
        # a killed run's half-written copies of this file (their process is gone):
        # the new run owns the name now, and cleans them as resume does
        remove_stale_temporaries(path)
        return start(path, lock)
    except BaseException:
        lock.release()
        _remove_empty(made)
        raise


def _remove_empty(folders: list[Path]) -> None:
    """Remove ``folders`` (deepest first), each only if empty: never what someone else
    put there."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:
            break


def default_output(exp) -> Path:
    """``<output>/<name>-<YYYYmmdd-HHMMSS>.h5``, not overwriting anything."""
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    base = Path(exp.output) / f"{exp.name}-{stamp}"
    path, k = base.with_suffix(".h5"), 1
    while path.exists():
        k += 1
        path = Path(f"{base}-{k}.h5")
    return path
