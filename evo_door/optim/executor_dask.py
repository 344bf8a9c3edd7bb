"""The Dask executors: a local cluster started for the run (``dask[:N]``), or a
scheduler someone started (``tcp://HOST:PORT``).

What an executor is, and what every one of them promises (the same numbers as in this
process, a lost worker costing nothing): :mod:`evo_door.optim.executors`.
"""

from __future__ import annotations

from evo_door.errors import UserError
from evo_door.optim import executors
from evo_door.optim.executors import (
    DASK_HINT,
    BoundProblem,
    Executor,
    ExecutorSpec,
    _call,
    _no_scheduler,
    _set_threads,
    cores,
)


# -- what runs in a worker ------------------------------------------------------------
def _evaluate_chunk(problem, X, threads):
    """``problem.evaluate(X)`` in a worker (the task of a Dask executor)."""
    _set_threads(threads)
    return problem.evaluate(X)


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
                    # read through the module: a test shortens it
                    self.spec.address,
                    timeout=executors.CONNECT_TIMEOUT,
                    set_as_default=False,
                )
            except (OSError, TimeoutError) as exc:
                raise _no_scheduler(self.name, exc) from None
            try:
                self.client.wait_for_workers(1, timeout=executors.CONNECT_TIMEOUT)
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
