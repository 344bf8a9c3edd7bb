"""Evaluations in a child process, each with a time limit: native code, contained.

A model that runs native code it did not compile with evo-door (an FMU's shared
library) can crash its process or hang in a loop. :class:`Sandbox` keeps that away
from the run: the problem's candidates are evaluated one by one in a child process
(spawned, one per process that evaluates: the run's own or an executor's worker), and
the parent waits for each at most ``time_limit`` seconds. A candidate whose evaluation
kills the child or overruns the limit is scored as a blow-up (fitness inf), the child
is replaced, and the other candidates go on; what happened is counted
(:attr:`Sandbox.lost`) and said once on stderr.

The child evaluates exactly what this process would (the same problem, unpickled with
the sandbox off), so a sandboxed run ends with the same numbers as one without.
"""

from __future__ import annotations

import atexit
import pickle
import sys
from typing import Any

import numpy as np

#: the time limit of one candidate's evaluation when the experiment gives none (s)
DEFAULT_TIME_LIMIT = 60.0
#: how long a child may take to start: import the package, load the model (s)
START_TIME = 120.0


def _serve(conn) -> None:  # pragma: no cover - runs in the child
    """The child's loop: receive candidate rows, send back ``(fitness, blown)`` each."""
    problem = pickle.loads(conn.recv_bytes())
    problem.sandboxed = False
    conn.send(("ready", None))
    while True:
        msg = conn.recv()
        if msg is None:
            return
        for row in msg:
            f, blown = problem.evaluate(row[None, :])
            conn.send(("done", (float(f[0]), bool(blown[0]))))


class Sandbox:
    """One child process evaluating one problem (see the module docstring)."""

    def __init__(self, problem, time_limit: float | None = None):
        self.blob = pickle.dumps(problem)
        self.time_limit = float(time_limit or DEFAULT_TIME_LIMIT)
        self.name = getattr(problem.model, "name", "model")
        self.proc: Any = None  # subprocess.Popen of the child
        self.conn: Any = None  # multiprocessing.connection.Connection to it
        self.lost = {"crashed": 0, "timed out": 0}
        self._said = False
        atexit.register(self.close)

    def _start(self) -> None:
        # a plain subprocess, not multiprocessing's: the workers of a Dask cluster are
        # daemons, which multiprocessing does not let have children
        import socket
        import subprocess
        from multiprocessing.connection import Connection

        ours, theirs = socket.socketpair()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "evo_door.optim.sandbox", str(theirs.fileno())],
            pass_fds=(theirs.fileno(),),
        )
        theirs.close()
        self.conn = parent = Connection(ours.detach())
        parent.send_bytes(self.blob)
        if not parent.poll(START_TIME):
            self._kill()
            raise RuntimeError(f"the sandbox for model {self.name!r} did not start")
        try:
            parent.recv()
        except EOFError:
            self._kill()
            raise RuntimeError(
                f"the sandbox for model {self.name!r} died while loading the model"
            ) from None

    def _kill(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait(5)
        if self.conn is not None:
            self.conn.close()
        self.proc = self.conn = None

    def close(self) -> None:
        """Stop the child (at exit, or when the problem is done)."""
        if self.conn is not None:
            try:
                self.conn.send(None)
            except (OSError, ValueError):
                pass
        if self.proc is not None:
            try:
                self.proc.wait(2)
            except Exception:  # subprocess.TimeoutExpired: killed below
                pass
        self._kill()

    def evaluate(self, X):
        """``(fitness, blown)`` of every row of ``X``, as ``Problem.evaluate``."""
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        fit = np.full(X.shape[0], np.inf)
        blown = np.ones(X.shape[0], dtype=bool)
        i = 0
        while i < X.shape[0]:
            if self.proc is None or self.proc.poll() is not None:
                self._kill()
                self._start()
            self.conn.send(X[i:])
            while i < X.shape[0]:
                why = self._wait()
                if why:
                    self.lost[why] += 1
                    self._say(why)
                    self._kill()
                    i += 1  # the candidate that crashed or hung is a blow-up
                    break
                _, (f, b) = self.conn.recv()
                fit[i], blown[i] = f, b
                i += 1
        return fit, blown

    def _wait(self) -> str:
        """``""`` when the child's next answer is there, else why there is none."""
        try:
            if self.conn.poll(self.time_limit):
                return ""
        except (EOFError, OSError):
            return "crashed"
        return "crashed" if self.proc.poll() is not None else "timed out"

    def _say(self, why: str) -> None:
        if not self._said:
            self._said = True
            print(
                f"evo-door: warning: model {self.name!r}: a candidate's evaluation "
                f"{why} (time limit {self.time_limit:g} s); it is scored as a blow-up "
                "and the run goes on in a new sandbox process",
                file=sys.stderr,
            )


#: this process's sandboxes, by the problem's identity: one child per problem
_SANDBOXES: dict = {}


def sandbox_for(problem, time_limit: float | None = None) -> Sandbox:
    """The sandbox this process keeps for ``problem`` (started on first use)."""
    key = id(problem)
    box = _SANDBOXES.get(key)
    if box is None or box.blob is None:
        for old in _SANDBOXES.values():
            old.close()
        _SANDBOXES.clear()  # one problem at a time: a run's problems follow each other
        box = _SANDBOXES[key] = Sandbox(problem, time_limit)
    return box


if __name__ == "__main__":  # pragma: no cover - the child: python -m evo_door.optim.sandbox FD
    from multiprocessing.connection import Connection

    _serve(Connection(int(sys.argv[1])))
