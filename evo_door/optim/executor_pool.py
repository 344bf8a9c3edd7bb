"""The ``processes[:N]`` executor: a pool of local worker processes.

What an executor is, and what every one of them promises (the same numbers as in this
process, a lost worker costing nothing): :mod:`evo_door.optim.executors`.
"""

from __future__ import annotations

import os
import pickle
import shutil
import tempfile
import uuid

from evo_door.errors import UserError
from evo_door.optim.executors import (
    MAX_RESTARTS,
    BoundProblem,
    Executor,
    ExecutorSpec,
    _call,
    _set_threads,
    cores,
)

# -- what runs in a worker ------------------------------------------------------------
#: a pool worker's problem by token, read once from the file the parent wrote. State at
#: module level on purpose: a pool's task is a plain function, and this is the one place
#: a worker process keeps something between its tasks. Bounded: one problem (a run's
#: jobs follow one another, so a new token replaces the old one).
_SHIPPED: dict = {}


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
        self._context = WorkerRecordingContext()  # the current pool's (see _new_pool)

    def describe(self) -> str:
        return f"{self.name} ({self.slots} worker processes)"

    def start(self) -> None:
        self._dir = tempfile.mkdtemp(prefix="evo-door-executor-")
        self.pool = self._new_pool()

    def _new_pool(self):
        from concurrent.futures import ProcessPoolExecutor

        self._context = WorkerRecordingContext()
        return ProcessPoolExecutor(
            max_workers=self.slots,
            mp_context=self._context,
            initializer=_start_worker,
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

    def workers(self) -> list:
        """The running worker processes of the current pool (``multiprocessing`` ones)."""
        return self._context.workers()

    def interrupt(self) -> None:
        """Pass Ctrl-C on to the workers (their runs stop at a checkpoint) and stop."""
        import signal

        pool, self.pool = self.pool, None
        if pool is None:
            return
        for proc in self.workers():
            try:
                os.kill(proc.pid, signal.SIGINT)
            except OSError:  # it ended meanwhile
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


class WorkerRecordingContext:
    """The ``spawn`` start method, keeping the processes it starts: the pool's workers.

    The pool names its workers nowhere public, and Ctrl-C in a batch must reach them
    (:meth:`ProcessExecutor.interrupt`), so the pool is given this context, which it
    asks for each worker process (``mp_context.Process``); all else is ``spawn``'s.
    """

    def __init__(self):
        import multiprocessing

        self.spawn = multiprocessing.get_context("spawn")
        self.started: list = []

    def Process(self, *args, **kwargs):  # noqa: N802 - the name multiprocessing gives it
        proc = self.spawn.Process(*args, **kwargs)
        self.started.append(proc)
        return proc

    def workers(self) -> list:
        """The processes started for the pool that are still running."""
        return [proc for proc in self.started if proc.is_alive()]

    def __getattr__(self, name):
        return getattr(self.spawn, name)


def _start_worker(threads: int | None) -> None:
    """A pool worker's start: Ctrl-C taken back, numba's threads set.

    A process that ignored SIGINT when it started the pool (a test runner, a job a shell
    put in the background) passes the ignored disposition on across exec, and Python
    leaves an ignored SIGINT ignored: :meth:`ProcessExecutor.interrupt` would then not
    reach the worker's run. The worker raises KeyboardInterrupt on it, as any program.
    """
    import signal

    signal.signal(signal.SIGINT, signal.default_int_handler)
    _end_with_parent()
    _set_threads(threads)


def _end_with_parent() -> None:
    """Have the kernel end this worker when the process that started it dies, however
    it dies (SIGKILL too: nothing of the parent runs then to stop its pool). Linux's
    ``prctl(PR_SET_PDEATHSIG)``; elsewhere the pool's own shutdown is all there is. A
    parent already gone by now (the worker's parent is then init): end at once."""
    import os
    import signal
    import sys

    if not sys.platform.startswith("linux"):
        return
    import ctypes

    parent = os.getppid()
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):  # no prctl here: the pool's shutdown only
        return
    if parent == 1 or os.getppid() != parent:
        os._exit(1)


#: prctl's option that sends a signal to a process when its parent dies (linux/prctl.h)
PR_SET_PDEATHSIG = 1
