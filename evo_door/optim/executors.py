"""Where the work runs: the GA's candidates and a batch's experiments, on one machine or many.

An executor is named by a string (an experiment's ``executor:``, ``--executor``):

``local`` (the default)
    In this process: a generation's fresh candidates in one compiled call, the loop
    over candidates on numba's threads (:meth:`Problem.evaluate`). A batch runs its
    experiments one after the other.
``processes`` or ``processes:N``
    A pool of N local worker processes (default: one per core), started for the run.
``dask`` or ``dask:N``
    A local Dask cluster of N single-threaded worker processes (default: one per
    core) on 127.0.0.1, started for the run and closed after it
    (``pip install 'evo-door[dask]'``).
``tcp://HOST:PORT``
    The Dask scheduler at that address, with the workers someone started
    (``dask scheduler``, ``dask worker tcp://HOST:PORT``); the run connects and leaves
    the cluster as it found it.

How the GA uses one (:meth:`Executor.bind`): the problem (model, trials, objective) is
shipped to the workers once, when it is bound: a Dask cluster gets it scattered to every
worker (``Client.scatter(..., broadcast=True)``), a process pool through a file its
workers read once each (cached by a token). Each generation's fresh candidates are then
cut in about two chunks per worker slot, evaluated remotely, and put back in candidate
order. A candidate's fitness depends on its genes only (the compiled kernel evaluates
each candidate on its own), so every executor gives the GA the same numbers: the same
seed ends with the same best parameters, logbook and evaluation counts.

A worker that dies mid-generation loses nothing: Dask gives its tasks to other workers
(a task is given up only after killing ``distributed.scheduler.allowed-failures``
workers, 3 by default); a broken process pool is restarted and what had not finished is
submitted again. The GA counts evaluations from its candidates, never from tasks, so a
chunk computed twice is never counted twice.

Threads: every executor but ``local`` runs numba single-threaded inside a task slot
(a pool process, a Dask worker thread; the local cluster's workers have one thread
each): the slots are the parallelism, one per core by default, and nothing is
oversubscribed. A pool or local cluster of fewer workers than cores gives each its
share of the cores as numba threads; a scheduler's workers get one numba thread per
worker thread (start them with ``--nthreads`` = their cores, or ``--nworkers`` = cores
and ``--nthreads 1``).

This module holds the names, their checks and the base class (with ``local``); the
process pool is in :mod:`evo_door.optim.executor_pool`, Dask in
:mod:`evo_door.optim.executor_dask`. None imports anything heavy: numpy, numba and
Dask are imported when used.
"""

from __future__ import annotations

import os
import re

from evo_door.errors import UserError

#: the executors by name (a Dask scheduler's address ``tcp://HOST:PORT`` is the fourth)
KINDS = ("local", "processes", "dask")
DEFAULT = "local"
#: how to get Dask when it is missing
DASK_HINT = "pip install 'evo-door[dask]'"
#: chunks per worker slot: two, so that a slow or lost worker's share is spread out
CHUNKS_PER_SLOT = 2
#: a process pool that breaks this many times without a task finishing in between is
#: given up (a task that kills its worker every time)
MAX_RESTARTS = 3
#: seconds to wait for a Dask scheduler to answer, and for its first worker
CONNECT_TIMEOUT = 10.0

_ADDRESS = re.compile(r"^tcp://(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(?P<port>\d{1,5})$")
_COUNTED = re.compile(r"^(?P<kind>processes|dask):(?P<n>\S*)$")


def cores() -> int:
    """The cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


class ExecutorNameError(UserError):
    """A string that names no executor.

    ``given`` is the string (None when it is not a name at all) and ``reason`` what is
    wrong with it, beginning with the string as given. The message is ``executor
    REASON``; an experiment's key says ``FILE:LINE: executor: REASON`` from the fields.
    """

    def __init__(self, given: str | None, reason: str):
        self.given = given
        self.reason = reason
        super().__init__(f"executor {reason}" if given is not None else f"executor: {reason}")


class ExecutorSpec:
    """A checked executor string: ``kind`` (local, processes, dask, scheduler),
    ``workers`` (None: one per core) and, for a scheduler, ``address``.

    >>> ExecutorSpec.parse("processes:3").workers
    3
    >>> ExecutorSpec.parse("tcp://127.0.0.1:8786").kind
    'scheduler'
    """

    def __init__(self, text: str, kind: str, workers: int | None = None, address=None):
        self.text = text
        self.kind = kind
        self.workers = workers
        self.address = address

    def __repr__(self) -> str:
        return f"ExecutorSpec({self.text!r})"

    @classmethod
    def parse(cls, text) -> ExecutorSpec:
        """The executor named by ``text``, or a one-line :class:`UserError`."""
        if isinstance(text, ExecutorSpec):
            return text
        if not isinstance(text, str) or not text.strip():
            raise ExecutorNameError(None, f"expected a name, got {text!r}; {_CHOICES}")
        s = text.strip()
        if s in KINDS:
            return cls(s, s)
        m = _COUNTED.match(s)
        if m:
            n = m.group("n")
            if not n.isdigit() or int(n) < 1:
                raise ExecutorNameError(
                    s,
                    f"{s!r}: the number of workers after ':' must be a whole "
                    f"number >= 1 (e.g. {m.group('kind')}:2)",
                )
            return cls(s, m.group("kind"), int(n))
        if s.startswith("tcp://"):
            m = _ADDRESS.match(s)
            if not m or not 0 < int(m.group("port")) < 65536:
                raise ExecutorNameError(
                    s,
                    f"{s!r}: a Dask scheduler's address is tcp://HOST:PORT "
                    "(e.g. tcp://127.0.0.1:8786)",
                )
            return cls(s, "scheduler", address=s)
        from evo_door.params.declaration import suggest

        raise ExecutorNameError(s, f"{s!r} is unknown" + suggest(s, list(KINDS)) + f"; {_CHOICES}")


_CHOICES = "use local, processes[:N], dask[:N] or tcp://HOST:PORT (a Dask scheduler)"


def check_executor(text) -> str:
    """``text`` stripped, if it names an executor (else a one-line :class:`UserError`)."""
    return ExecutorSpec.parse(text).text


def preflight(text) -> str:
    """Check what can be checked before a run writes anything: the name, that Dask is
    installed for ``dask`` and ``tcp://``, and that something listens at a scheduler's
    address (whether it is a Dask scheduler is checked when the run connects)."""
    spec = ExecutorSpec.parse(text)
    if spec.kind in ("dask", "scheduler"):
        import importlib.util

        if importlib.util.find_spec("distributed") is None:
            raise UserError(
                f"executor {spec.text} needs Dask distributed, which is not installed: {DASK_HINT}"
            )
    if spec.kind == "scheduler":
        _check_listening(spec)
    return spec.text


def _check_listening(spec: ExecutorSpec) -> None:
    """A one-line :class:`UserError` if nothing accepts a TCP connection at a scheduler's
    address (refused at once, or no answer within ``CONNECT_TIMEOUT``)."""
    import socket

    m = _ADDRESS.match(spec.address)
    host = m.group("host").strip("[]")
    try:
        with socket.create_connection((host, int(m.group("port"))), timeout=CONNECT_TIMEOUT):
            pass
    except OSError as exc:
        raise _no_scheduler(spec.text, exc.strerror or exc) from None


def _no_scheduler(name: str, why) -> UserError:
    """The one-line error for a scheduler address nobody answers at."""
    why = " ".join(str(why).split())[:120]
    return UserError(
        f"executor {name}: no Dask scheduler answers there ({why}); "
        "start one (dask scheduler) or check the address"
    )


def open_executor(text) -> Executor:
    """The executor named by ``text``, not started yet: use it as a context manager
    (``with open_executor("dask") as ex: ...``), which starts it and closes it."""
    spec = ExecutorSpec.parse(text)
    if spec.kind == "local":
        return LocalExecutor(spec)
    if spec.kind == "processes":
        from evo_door.optim.executor_pool import ProcessExecutor

        return ProcessExecutor(spec)
    from evo_door.optim.executor_dask import DaskExecutor

    return DaskExecutor(spec)


# -- what runs in a worker ------------------------------------------------------------
def _set_threads(threads: int | None) -> None:
    """Numba's threads for this worker thread (numba keeps the setting per thread)."""
    if threads:
        import numba

        numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))


def _call(fn, item, threads):
    """``fn(item)`` in a worker with numba's threads set (a batch's task)."""
    _set_threads(threads)
    return fn(item)


# -- the executors --------------------------------------------------------------------
class BoundProblem:
    """A problem whose :meth:`evaluate` runs on an executor; what the GA is given.

    Everything else (bounds, names, :meth:`Problem.responses`...) is the problem's own,
    in this process. Close it (or use it as a context manager) to free what the
    workers keep of it.
    """

    def __init__(self, executor: Executor, problem, handle):
        self.executor = executor
        self.problem = problem
        self.handle = handle

    def __getattr__(self, name):
        return getattr(self.problem, name)

    def evaluate(self, X):
        """``(fitness, blown)`` per row of ``X``, as :meth:`Problem.evaluate` gives them."""
        return self.executor.evaluate(self, X)

    def close(self) -> None:
        if self.handle is not None:
            self.executor.release(self)
            self.handle = None

    def __enter__(self) -> BoundProblem:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Executor:
    """Base of the executors (see the module docstring): a context manager that
    evaluates a bound problem's candidates (:meth:`bind`) and runs a batch's tasks
    (:meth:`imap`)."""

    def __init__(self, spec: ExecutorSpec):
        self.spec = spec
        #: numba threads per task in a worker (None: leave numba as it is)
        self.threads: int | None = None
        self.name = spec.text
        self.slots = 1
        self.started = False

    def __enter__(self) -> Executor:
        if not self.started:
            self.start()
            self.started = True
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self) -> None:
        pass

    def close(self) -> None:
        self.started = False

    def describe(self) -> str:
        """One line for a progress display: what runs where."""
        return self.name

    # -- the GA ---------------------------------------------------------------------
    def bind(self, problem) -> BoundProblem:
        """Ship ``problem`` to the workers (once); its evaluations then run on them."""
        return BoundProblem(self, problem, None)

    def release(self, bound: BoundProblem) -> None:
        pass

    def evaluate(self, bound: BoundProblem, X):
        return bound.problem.evaluate(X)

    def _split(self, X):
        import numpy as np

        X = np.ascontiguousarray(X, dtype=np.float64)
        n = min(len(X), max(1, CHUNKS_PER_SLOT * self.slots))
        return [c for c in np.array_split(X, n) if len(c)] if len(X) else []

    @staticmethod
    def _join(parts, n: int):
        import numpy as np

        if not parts:
            return np.zeros(0), np.zeros(0, dtype=bool)
        fitness = np.concatenate([np.asarray(f, dtype=np.float64) for f, _ in parts])
        blown = np.concatenate([np.asarray(b, dtype=bool) for _, b in parts])
        if len(fitness) != n:  # pragma: no cover - a chunk came back short
            raise RuntimeError(f"executor {n} candidates sent, {len(fitness)} answers")
        return fitness, blown

    # -- a batch ----------------------------------------------------------------------
    def imap(self, fn, items):
        """Run ``fn(item)`` for every item; yield ``(index, result, error)`` as each
        ends (``error`` the exception, or None). ``fn`` must be importable by the
        workers (a module-level function) and safe to run again on an item whose
        worker died."""
        for i, item in enumerate(items):
            try:
                yield i, fn(item), None
            except Exception as exc:  # a failed item never stops the others
                yield i, None, exc


class LocalExecutor(Executor):
    """In this process, as without an executor (``local``)."""

    def __init__(self, spec: ExecutorSpec):
        super().__init__(spec)
        self.slots = 1
