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

This module imports nothing heavy: numpy, numba and Dask are imported when used.
"""

from __future__ import annotations

import os
import pickle
import re
import shutil
import tempfile
import uuid

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
            raise UserError(f"executor: expected a name, got {text!r}; {_CHOICES}")
        s = text.strip()
        if s in KINDS:
            return cls(s, s)
        m = _COUNTED.match(s)
        if m:
            n = m.group("n")
            if not n.isdigit() or int(n) < 1:
                raise UserError(
                    f"executor {s!r}: the number of workers after ':' must be a whole "
                    f"number >= 1 (e.g. {m.group('kind')}:2)"
                )
            return cls(s, m.group("kind"), int(n))
        if s.startswith("tcp://"):
            m = _ADDRESS.match(s)
            if not m or not 0 < int(m.group("port")) < 65536:
                raise UserError(
                    f"executor {s!r}: a Dask scheduler's address is tcp://HOST:PORT "
                    "(e.g. tcp://127.0.0.1:8786)"
                )
            return cls(s, "scheduler", address=s)
        from evo_door.params.declaration import suggest

        raise UserError(f"executor {s!r} is unknown" + suggest(s, list(KINDS)) + f"; {_CHOICES}")


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
        return ProcessExecutor(spec)
    return DaskExecutor(spec)


# -- what runs in a worker ------------------------------------------------------------
#: a pool worker's problems by token (read once from the file the parent wrote)
_SHIPPED: dict = {}


def _set_threads(threads: int | None) -> None:
    """Numba's threads for this worker thread (numba keeps the setting per thread)."""
    if threads:
        import numba

        numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))


def _evaluate_chunk(problem, X, threads):
    """``problem.evaluate(X)`` in a worker (the task of a Dask executor)."""
    _set_threads(threads)
    return problem.evaluate(X)


def _load_shipped(token: str, path: str):
    problem = _SHIPPED.get(token)
    if problem is None:
        with open(path, "rb") as fh:
            problem = pickle.load(fh)
        _SHIPPED.clear()  # one problem at a time: a run's jobs follow one another
        _SHIPPED[token] = problem
    return problem


def _evaluate_shipped(token: str, path: str, X):
    """``evaluate(X)`` of the problem a pool's parent shipped in ``path`` (pool task)."""
    return _load_shipped(token, path).evaluate(X)


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

    #: numba threads per task in a worker (None: leave numba as it is)
    threads: int | None = None

    def __init__(self, spec: ExecutorSpec):
        self.spec = spec
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


class ProcessExecutor(Executor):
    """A pool of local worker processes (``processes[:N]``), started by :meth:`start`.

    Workers are spawned (not forked: numba's OpenMP threads do not survive a fork) and
    import the package; the problem goes through a file in a private temporary folder,
    read once per worker. A pool broken by a dead worker is replaced and what had not
    finished is submitted again.
    """

    def __init__(self, spec: ExecutorSpec):
        super().__init__(spec)
        self.slots = spec.workers or cores()
        self.threads = max(1, cores() // self.slots)
        self.pool = None
        self.restarts = 0
        self._dir = None

    def describe(self) -> str:
        return f"{self.name} ({self.slots} worker processes)"

    def start(self) -> None:
        self._dir = tempfile.mkdtemp(prefix="evo-door-executor-")
        self.pool = self._new_pool()

    def _new_pool(self):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        return ProcessPoolExecutor(
            max_workers=self.slots,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_set_threads,
            initargs=(self.threads,),
        )

    def _restart(self) -> None:
        self.restarts += 1
        if self.pool is not None:
            self.pool.shutdown(wait=False, cancel_futures=True)
        self.pool = self._new_pool()

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None
        super().close()

    def interrupt(self) -> None:
        """Pass Ctrl-C on to the workers (their runs stop at a checkpoint) and stop."""
        import signal

        pool, self.pool = self.pool, None
        if pool is None:
            return
        for proc in list(getattr(pool, "_processes", {}).values()):
            try:
                os.kill(proc.pid, signal.SIGINT)
            except (OSError, AttributeError):
                pass
        pool.shutdown(wait=True, cancel_futures=True)

    def bind(self, problem) -> BoundProblem:
        if self.pool is None:
            raise RuntimeError("start the executor first (use it as a context manager)")
        token = uuid.uuid4().hex
        path = os.path.join(self._dir, f"{token}.pickle")
        with open(path, "wb") as fh:
            pickle.dump(problem, fh, protocol=pickle.HIGHEST_PROTOCOL)
        return BoundProblem(self, problem, (token, path))

    def release(self, bound: BoundProblem) -> None:
        try:
            os.remove(bound.handle[1])
        except OSError:
            pass

    def evaluate(self, bound: BoundProblem, X):
        chunks = self._split(X)
        token, path = bound.handle
        parts = [None] * len(chunks)
        for i, part, error in self._run(_evaluate_shipped, [(token, path, c) for c in chunks]):
            if error is not None:
                raise error
            parts[i] = part
        return self._join(parts, len(X))

    def imap(self, fn, items):
        return self._run(_call, [(fn, item, self.threads) for item in items])

    def _run(self, fn, arglists):
        """Yield ``(index, result, error)`` of ``fn(*args)`` per argument list as they
        end; a broken pool is replaced and its unfinished tasks submitted again."""
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool

        pending = set(range(len(arglists)))
        broken_in_a_row = 0
        while pending:
            futures = {}
            try:
                for i in sorted(pending):
                    futures[self.pool.submit(fn, *arglists[i])] = i
            except BrokenProcessPool:
                pass
            broken = len(futures) < len(pending)
            waiting = set(futures)
            while waiting:
                done, waiting = wait(waiting, return_when=FIRST_COMPLETED)
                for fut in done:
                    i = futures[fut]
                    try:
                        result = fut.result()
                    except BrokenProcessPool:
                        broken = True
                        continue
                    except Exception as exc:
                        pending.discard(i)
                        broken_in_a_row = 0
                        yield i, None, exc
                        continue
                    pending.discard(i)
                    broken_in_a_row = 0
                    yield i, result, None
            if broken and pending:
                broken_in_a_row += 1
                if broken_in_a_row > MAX_RESTARTS:
                    raise UserError(
                        f"executor {self.name}: a worker process died {broken_in_a_row} "
                        "times in a row on the same tasks (out of memory?); run with "
                        "--executor local to see the error"
                    )
                self._restart()


class DaskExecutor(Executor):
    """Dask distributed: a local cluster started for the run (``dask[:N]``) or the
    scheduler at ``tcp://HOST:PORT`` (connected to, never closed)."""

    def __init__(self, spec: ExecutorSpec):
        super().__init__(spec)
        self.client = None
        self.cluster = None
        self.threads = 1

    def describe(self) -> str:
        where = "a local Dask cluster" if self.cluster is not None else "Dask"
        return f"{self.name} ({where}, {self.slots} worker threads)"

    def start(self) -> None:
        try:
            import distributed
        except ImportError:
            raise UserError(
                f"executor {self.name} needs Dask distributed, which is not installed: {DASK_HINT}"
            ) from None
        if self.spec.kind == "dask":
            import logging

            n = self.spec.workers or cores()
            self.threads = max(1, cores() // n)  # fewer workers than cores: their share
            self.cluster = distributed.LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                scheduler_port=0,
                dashboard_address=None,
                silence_logs=logging.ERROR,
            )
            try:
                self.client = distributed.Client(self.cluster, set_as_default=False)
            except BaseException:
                self.cluster.close()
                self.cluster = None
                raise
        else:
            try:
                self.client = distributed.Client(
                    self.spec.address, timeout=CONNECT_TIMEOUT, set_as_default=False
                )
            except (OSError, TimeoutError) as exc:
                raise _no_scheduler(self.name, exc) from None
            try:
                self.client.wait_for_workers(1, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError):
                self.client.close()
                self.client = None
                raise UserError(
                    f"executor {self.name}: the scheduler has no worker; start some "
                    f"(dask worker {self.spec.address})"
                ) from None
        self.slots = max(1, sum(self.client.nthreads().values()))

    def close(self) -> None:
        client, cluster = self.client, self.cluster
        self.client = self.cluster = None
        try:
            if client is not None:
                client.close()
        finally:
            if cluster is not None:  # ours: started for the run
                cluster.close()
        super().close()

    def interrupt(self) -> None:
        self.close()

    def bind(self, problem) -> BoundProblem:
        if self.client is None:
            raise RuntimeError("start the executor first (use it as a context manager)")
        future = self.client.scatter(problem, broadcast=True, hash=False)
        return BoundProblem(self, problem, future)

    def release(self, bound: BoundProblem) -> None:
        try:
            bound.handle.release()
        except Exception:  # pragma: no cover - the client is gone already
            pass

    def evaluate(self, bound: BoundProblem, X):
        chunks = self._split(X)
        if not chunks:
            return self._join([], 0)
        # workers may have come and gone since the last generation
        self.slots = max(1, sum(self.client.nthreads().values()))
        for attempt in range(2):
            futures = [
                self.client.submit(_evaluate_chunk, bound.handle, c, self.threads, pure=False)
                for c in chunks
            ]
            try:
                parts = self.client.gather(futures)
                return self._join(parts, len(X))
            except Exception as exc:
                if _killed_worker(exc):
                    raise UserError(
                        f"executor {self.name}: a chunk of candidates killed "
                        f"{_allowed_failures()} workers in a row; run with --executor "
                        "local to see why"
                    ) from None
                if attempt or not _lost(exc):
                    raise
                # every copy of the problem went with its workers: ship it again
                bound.handle = self.client.scatter(bound.problem, broadcast=True, hash=False)
        raise AssertionError("unreachable")  # pragma: no cover

    def imap(self, fn, items):
        import distributed

        futures = [self.client.submit(_call, fn, item, self.threads, pure=False) for item in items]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in distributed.as_completed(futures, loop=self.client.loop):
                i = index[fut.key]
                try:
                    result = fut.result()
                except Exception as exc:
                    if _killed_worker(exc):
                        exc = RuntimeError(
                            f"killed {_allowed_failures()} Dask workers in a row (out of memory?)"
                        )
                    yield i, None, exc
                    continue
                yield i, result, None
        finally:
            for fut in futures:
                fut.release()


def _killed_worker(exc) -> bool:
    return type(exc).__name__ == "KilledWorker"


def _lost(exc) -> bool:
    return "Cancelled" in type(exc).__name__ or "lost" in str(exc).lower()


def _allowed_failures() -> int:
    import dask

    return int(dask.config.get("distributed.scheduler.allowed-failures", 3)) + 1
