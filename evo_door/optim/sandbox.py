"""Evaluations in a child process, each with a time limit: native code, contained.

A model that runs native code it did not compile with evo-door (an FMU's shared
library) can crash its process or hang in a loop. :class:`Sandbox` keeps that away
from the run: the problem's candidates are evaluated one by one in a child process
(a plain subprocess over a socket pair, one per process that evaluates: the run's own
or an executor's worker; under the ``local`` executor one per numba thread, each with
a part of the batch: :class:`SandboxGroup`), and the parent waits for each at most ``time_limit`` seconds.
A candidate whose evaluation kills the child or overruns the limit is scored as a
blow-up (fitness inf), the child is replaced, and the other candidates go on; what
happened is counted (:attr:`Sandbox.lost`) and said once on stderr.

The child evaluates exactly what this process would (the same problem, unpickled with
the sandbox off), so a sandboxed run ends with the same numbers as one without. A
Python exception in the child is raised again here, as it would be without a sandbox:
only a dead or silent child makes a blow-up.

What keeps the child from outliving its purpose:

- it loads the model before it says it is ready (:func:`_prepare`), so that the time
  limit counts a candidate's own work, not the loading of a library or of compiled
  kernels;
- it dies with the parent (Linux: the parent-death signal, asked for by the child), so
  that a run killed while its child hangs in a loop leaves no loop behind; the child is
  started from one long-lived thread of the parent, because that signal follows the
  thread that started the child, not its process;
- its temporary files (an FMU is extracted into one) go in a folder of the parent's,
  removed when the child is stopped, whether the child could clean up or not;
- what it prints goes to stderr: an FMU's log is a diagnostic, and the run's stdout
  may be read by another program;
- an evaluation cut short in the parent (Ctrl-C) stops the child, whose answers to the
  rest of the batch would otherwise be read as those of the next batch.
"""

from __future__ import annotations

import atexit
import os
import pickle
import queue
import shutil
import signal
import sys
import threading
import weakref
from typing import Any

import numpy as np

#: the time limit of one candidate's evaluation when the experiment gives none (s)
DEFAULT_TIME_LIMIT = 60.0
#: how long a child may take to start: import the package, load the model (s)
START_TIME = 120.0
#: how many children in a row may die before a batch reaches them: then the model
#: cannot be evaluated here at all, and the run stops with the reason
MAX_FAILED_STARTS = 3


# -- the child ----------------------------------------------------------------------
def _die_with_parent(parent: int) -> None:  # pragma: no cover - runs in the child
    """Ask the kernel to kill this process when its parent ends (Linux), and end now if
    the parent has already gone."""
    if sys.platform.startswith("linux"):
        import ctypes

        pr_set_pdeathsig = 1
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(pr_set_pdeathsig, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:
        os._exit(0)


def _prepare(problem) -> None:  # pragma: no cover - runs in the child
    """Load what the model's plant loads on first use (an FMU: its library, one
    instance, the compiled kernels), without running a candidate."""
    problem.model.plant.prepare()


def _serve(conn, parent: int) -> None:  # pragma: no cover - runs in the child
    """The child's loop: receive batches of candidate rows, send back
    ``("done", (fitness, blown))`` per row, or ``("raised", exception)`` and wait for
    the next batch."""
    _die_with_parent(parent)
    # Ctrl-C is the parent's to handle: it stops this child when it stops
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        problem = pickle.loads(conn.recv_bytes())
        problem.sandboxed = False
        _prepare(problem)
    except EOFError:
        return
    except Exception as exc:
        conn.send(("failed", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(("ready", None))
    known: dict = {}  # the problems of calls (:func:`contained`), by their pickle's digest
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):  # the parent went away
            return
        if msg is None:
            return
        if isinstance(msg, tuple):  # ("call", digest, pickled problem, method, args)
            _call(conn, known, *msg[1:])
            continue
        for row in msg:
            try:
                f, blown = problem.evaluate(row[None, :])
            except Exception as exc:
                conn.send(("raised", _portable(exc)))
                break
            conn.send(("done", (float(f[0]), bool(blown[0]))))


def _call(conn, known: dict, digest, blob, name, args) -> None:  # pragma: no cover - child
    """Run ``problem.<name>(*args)`` here, for :func:`contained`; send ``("done", result)``
    or ``("raised", exception)``."""
    try:
        problem = known.get(digest)
        if problem is None:
            problem = pickle.loads(blob)
            problem.sandboxed = False
            known.clear()  # one problem at a time: a run's analysis takes them in turn
            known[digest] = problem
        result = getattr(problem, name)(*args)
    except Exception as exc:
        conn.send(("raised", _portable(exc)))
        return
    conn.send(("done", result))


def _portable(exc: BaseException) -> BaseException:  # pragma: no cover - in the child
    """``exc`` if it pickles, else a RuntimeError with its text."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


# -- starting children from one thread ----------------------------------------------
_SPAWN_REQUESTS: queue.Queue = queue.Queue()
_SPAWNER: list = []  # the spawner thread, once started
_SPAWNER_LOCK = threading.Lock()


def _spawner() -> None:
    import subprocess

    while True:
        args, kwargs, reply = _SPAWN_REQUESTS.get()
        try:
            reply.put(subprocess.Popen(args, **kwargs))
        except BaseException as exc:  # handed to the caller, raised there
            reply.put(exc)


def _spawn(args: list[str], **kwargs):
    """``subprocess.Popen(args, **kwargs)`` started by this process's spawner thread,
    which lives as long as the process (the child's parent-death signal follows the
    thread that started it, and an executor's worker thread may end before its
    process)."""
    with _SPAWNER_LOCK:
        if not _SPAWNER or not _SPAWNER[0].is_alive():
            thread = threading.Thread(target=_spawner, name="evo-door-sandbox", daemon=True)
            thread.start()
            _SPAWNER[:] = [thread]
    reply: queue.Queue = queue.Queue(maxsize=1)
    _SPAWN_REQUESTS.put((args, kwargs, reply))
    got = reply.get()
    if isinstance(got, BaseException):
        raise got
    return got


# -- the parent -----------------------------------------------------------------------
class Sandbox:
    """One child process evaluating one problem (see the module docstring).

    ``problem`` is copied (pickled) when the sandbox is made: later changes to it do
    not reach the child, except ``time_limit``, which :func:`sandbox_for` sets anew on
    every call. One thread at a time evaluates through a sandbox (others wait).
    """

    def __init__(self, problem, time_limit: float | None = None):
        self.blob = pickle.dumps(problem)
        self.time_limit = float(time_limit or DEFAULT_TIME_LIMIT)
        self.name = getattr(problem.model, "name", "model")
        self.proc: Any = None  # subprocess.Popen of the child
        self.conn: Any = None  # multiprocessing.connection.Connection to it
        self.folder: str | None = None  # the child's temporary folder
        #: candidates lost, by why: the child died, or overran the time limit
        self.lost = {"crashed": 0, "timed out": 0}
        #: children started so far (the first one and every replacement)
        self.starts = 0
        #: seconds the last child took to start: import, load the model, say ready
        self.start_seconds = 0.0
        self._said = False
        self._lock = threading.Lock()
        _LIVE.add(self)

    @property
    def pid(self) -> int | None:
        """The running child's process id (None before the first evaluation)."""
        return None if self.proc is None else self.proc.pid

    def _start(self) -> None:
        # a plain subprocess, not multiprocessing's: the workers of a Dask cluster are
        # daemons, which multiprocessing does not let have children
        import socket
        import subprocess
        import tempfile
        import time
        from multiprocessing.connection import Connection

        started = time.perf_counter()
        self.folder = tempfile.mkdtemp(prefix="evo-door-sandbox-")
        ours, theirs = socket.socketpair()
        try:
            self.proc = _spawn(
                [sys.executable, "-m", "evo_door.optim.sandbox"]
                + [str(theirs.fileno()), str(os.getpid())],
                pass_fds=(theirs.fileno(),),
                stdin=subprocess.DEVNULL,
                # what the model prints (an FMU's log) is a diagnostic: the run's stdout
                # may be a table or JSON another program reads
                stdout=2,
                env=dict(os.environ, TMPDIR=self.folder),
            )
        except BaseException:
            ours.close()
            self._kill()
            raise
        finally:
            theirs.close()
        self.starts += 1
        self.conn = parent = Connection(ours.detach())
        try:
            parent.send_bytes(self.blob)
            if not parent.poll(START_TIME):
                raise RuntimeError(
                    f"the sandbox for model {self.name!r} did not start in {START_TIME:g} s"
                )
            kind, what = parent.recv()
        except (EOFError, OSError):
            self._kill()
            raise RuntimeError(
                f"the sandbox for model {self.name!r} died while loading the model"
                f"{self._signal_text()}"
            ) from None
        except BaseException:
            self._kill()
            raise
        if kind != "ready":
            self._kill()
            raise RuntimeError(f"the sandbox for model {self.name!r} cannot load it: {what}")
        self.start_seconds = time.perf_counter() - started

    def _signal_text(self) -> str:
        code = getattr(self.proc, "returncode", None) if self.proc is not None else None
        if code is None or code >= 0:
            return "" if not code else f" (exit status {code})"
        try:
            return f" ({signal.Signals(-code).name})"
        except ValueError:
            return f" (signal {-code})"

    def _kill(self) -> None:
        """Stop the child at once and remove its folder."""
        if self.proc is not None:
            if self.proc.poll() is None:
                self.proc.kill()  # SIGKILL: also a stopped (SIGSTOP) child
            self.proc.wait()
        if self.conn is not None:
            self.conn.close()
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
        self.conn = self.folder = None

    def close(self) -> None:
        """Stop the child (at exit, or when the problem is done)."""
        if self.conn is not None:
            try:
                self.conn.send(None)
            except (OSError, ValueError):
                pass
        if self.proc is not None and self.proc.poll() is None:
            try:
                self.proc.wait(2)
            except Exception:  # subprocess.TimeoutExpired: killed below
                pass
        self._kill()
        self.proc = None

    def evaluate(self, X):
        """``(fitness, blown)`` of every row of ``X``, as ``Problem.evaluate``."""
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        fit = np.full(X.shape[0], np.inf)
        blown = np.ones(X.shape[0], dtype=bool)
        with self._lock:
            finished = False
            try:
                self._evaluate(X, fit, blown)
                finished = True
            finally:
                if not finished:  # its answers to the rest would be read as the next batch's
                    self._kill()
                    self.proc = None
        return fit, blown

    def _evaluate(self, X, fit, blown) -> None:
        i = 0
        refused = 0  # sends in a row to a child that had just died
        while i < X.shape[0]:
            if self.conn is None or self.proc.poll() is not None:
                self._kill()
                self._start()
            try:
                self.conn.send(X[i:])
            except OSError as exc:  # it died between the check and the send
                self._kill()
                refused += 1
                if refused > MAX_FAILED_STARTS:
                    raise RuntimeError(
                        f"the sandbox for model {self.name!r} dies as soon as it starts"
                    ) from exc
                continue
            refused = 0
            while i < X.shape[0]:
                why, answer = self._answer()
                if why:
                    self._lose(why)
                    i += 1  # the candidate that crashed or hung is a blow-up
                    break
                kind, value = answer
                if kind == "raised":
                    raise value
                fit[i], blown[i] = value
                i += 1

    def call(self, problem_blob: bytes, name: str, args: tuple, weight: int = 1):
        """``(True, problem.<name>(*args))`` run in the child, ``problem`` the pickled
        ``problem_blob`` (any problem of this model), or ``(False, None)`` if the child
        crashed or overran ``weight`` times the time limit (then counted and said as a
        candidate's evaluation is). A Python exception in the child is raised here."""
        import hashlib

        digest = hashlib.sha1(problem_blob).hexdigest()
        with self._lock:
            finished = False
            try:
                for attempt in range(MAX_FAILED_STARTS + 1):
                    if self.conn is None or self.proc.poll() is not None:
                        self._kill()
                        self._start()
                    try:
                        self.conn.send(("call", digest, problem_blob, name, args))
                        break
                    except OSError as exc:  # it died between the check and the send
                        self._kill()
                        if attempt == MAX_FAILED_STARTS:
                            raise RuntimeError(
                                f"the sandbox for model {self.name!r} dies as soon as it starts"
                            ) from exc
                limit, self.time_limit = self.time_limit, self.time_limit * max(1, int(weight))
                try:
                    why, answer = self._answer()
                finally:
                    self.time_limit = limit
                finished = True
            finally:
                if not finished:
                    self._kill()
                    self.proc = None
        if why:
            self._lose(why, "an analysis run of the answer")
            return False, None
        kind, value = answer
        if kind == "raised":
            raise value
        return True, value

    def _answer(self) -> tuple[str, Any]:
        """``("", message)`` with the child's next message, or ``(why, None)``: why
        there is none (``"crashed"``, ``"timed out"``)."""
        try:
            if self.conn.poll(self.time_limit):
                return "", self.conn.recv()
        except (EOFError, OSError):
            return "crashed", None
        return ("crashed" if self.proc.poll() is not None else "timed out"), None

    def _lose(self, why: str, what: str = "a candidate's evaluation") -> None:
        """The child crashed or overran: count it, stop the child, say it once."""
        self.lost[why] += 1
        self._kill()
        how = self._signal_text() if why == "crashed" else ""
        if not self._said:
            self._said = True
            print(
                f"evo-door: warning: model {self.name!r}: {what} "
                f"{why}{how} (time limit {self.time_limit:g} s); it is scored as a blow-up "
                "and the run goes on in a new sandbox process (said once)",
                file=sys.stderr,
            )


#: every sandbox not yet collected, to stop their children at exit
_LIVE: weakref.WeakSet = weakref.WeakSet()


@atexit.register
def _close_all() -> None:
    for box in list(_LIVE):
        box.close()


class SandboxGroup:
    """Several sandboxes for one problem, each with its child, evaluating a batch's rows
    side by side (contiguous parts, one per child): the ``local`` executor's cores. A
    row's result is the one a single sandbox gives (each candidate on its own)."""

    def __init__(self, problem, n: int, time_limit: float | None = None):
        self.boxes = [Sandbox(problem, time_limit) for _ in range(n)]

    @property
    def time_limit(self) -> float:
        return self.boxes[0].time_limit

    @time_limit.setter
    def time_limit(self, value: float) -> None:
        for box in self.boxes:
            box.time_limit = value

    @property
    def lost(self) -> dict:
        return {k: sum(b.lost[k] for b in self.boxes) for k in self.boxes[0].lost}

    @property
    def starts(self) -> int:
        return sum(b.starts for b in self.boxes)

    @property
    def pids(self) -> list:
        """The running children's process ids."""
        return [b.pid for b in self.boxes if b.pid is not None]

    @property
    def pid(self) -> int | None:
        return self.boxes[0].pid

    def evaluate(self, X):
        """``(fitness, blown)`` of every row of ``X``, as ``Problem.evaluate``."""
        from concurrent.futures import ThreadPoolExecutor

        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        parts = [p for p in np.array_split(np.arange(X.shape[0]), len(self.boxes)) if p.size]
        if len(parts) <= 1:
            return self.boxes[0].evaluate(X)
        with ThreadPoolExecutor(len(parts)) as pool:  # each waits on its child's socket
            done = list(pool.map(lambda bp: bp[0].evaluate(X[bp[1]]), zip(self.boxes, parts)))
        return np.concatenate([d[0] for d in done]), np.concatenate([d[1] for d in done])

    def close(self) -> None:
        for box in self.boxes:
            box.close()


#: children per sandbox: None takes numba's threads in the evaluating thread (the
#: ``local`` executor's cores; 1 in an executor's worker slot)
CHILDREN: int | None = None

#: this process's sandbox: ``(weak reference to its problem, sandbox)``. One problem at
#: a time (a run's problems follow each other); the reference is weak so that a new
#: problem made where a collected one was is never taken for it.
_CURRENT: list = [None, None]
_CURRENT_LOCK = threading.Lock()


def _children() -> int:
    if CHILDREN is not None:
        return max(1, int(CHILDREN))
    import numba

    return max(1, numba.get_num_threads())


def sandbox_for(problem, time_limit: float | None = None):
    """The sandbox this process keeps for ``problem`` (its children started on first
    use), with ``time_limit`` (s; :data:`DEFAULT_TIME_LIMIT` if None): a
    :class:`Sandbox`, or a :class:`SandboxGroup` of one per numba thread."""
    with _CURRENT_LOCK:
        ref, box = _CURRENT
        n = _children()
        size = len(box.boxes) if isinstance(box, SandboxGroup) else 1
        if ref is None or ref() is not problem or size != n:
            if box is not None:
                box.close()
            box = Sandbox(problem, time_limit) if n == 1 else SandboxGroup(problem, n, time_limit)
            _CURRENT[:] = [weakref.ref(problem), box]
        box.time_limit = float(time_limit or DEFAULT_TIME_LIMIT)
        return box


def current():
    """This process's sandbox (the last problem's), or None if it has made none."""
    return _CURRENT[1]


#: pickles of the problems :func:`contained` ran, by problem (made once per problem)
_BLOBS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def contained(problem, name: str, *args, weight: int = 1):
    """``(True, problem.<name>(*args))`` computed in a sandbox child, or ``(False,
    None)`` if the run crashed the child or overran ``weight`` times the problem's time
    limit: what a fit's analysis (its errors per trial, identifiability, stored
    responses) runs of a model that runs native code, so that the FMU is contained
    after the search as during it. The child of this process's sandbox serves it if it
    runs the same model (the search's, whichever problem of it); else one is made."""
    box = current()
    key = problem.model_name or problem.model.name
    if box is None or getattr(box, "key", None) != key:
        box = sandbox_for(problem, problem.time_limit)
    box.key = key
    one = box.boxes[0] if isinstance(box, SandboxGroup) else box
    blob = _BLOBS.get(problem)
    if blob is None:
        blob = _BLOBS[problem] = pickle.dumps(problem)
    return one.call(blob, name, args, weight)


if __name__ == "__main__":  # pragma: no cover - the child: python -m evo_door.optim.sandbox FD PID
    from multiprocessing.connection import Connection

    _serve(Connection(int(sys.argv[1])), int(sys.argv[2]))
