"""The renderer's supervisor: a process of its own that takes the force off the device
when the servo loop stops beating.

The HapticMaster keeps rendering its effects (the bias force through which the host
adds its force, springs, dampers) until told otherwise, and its public API documents
no timeout or watchdog on the host's connection (README, "When the renderer
stalls"). A renderer that freezes (SIGSTOP, a debugger, a stuck interpreter) or dies
(SIGKILL, a crash) would leave the last force on the handle. So, for a real device,
the renderer spawns this small process, which:

* opens **its own** connection to the device at start-up (a device that refuses it
  is reported, and ``render`` refuses to run unless ``--no-supervisor``);
* watches the loop's **heartbeat**: a shared memory page the loop writes every cycle
  (a sequence number and a CLOCK_MONOTONIC time stamp, two stores, no system call)
  and a pipe whose only writer is the renderer, so that its end of file means the
  renderer is gone;
* when the heartbeat is older than its **budget** (:data:`BUDGET`, 20 ms by
  default; ``render --supervisor-budget``) while the loop is armed, or when the pipe
  ends without the renderer's goodbye, sends ``set state stop;remove all`` in one
  frame through its own connection, latches (it acts once), says so on stderr and
  leaves a record in the heartbeat page that the renderer logs if it runs again;
* runs at a raised priority where permitted (real time above the loop's, on another
  core than the loop's), checking every :data:`TICK`;
* exits quietly when the render ends normally: the renderer disarms it first, then
  says goodbye (a ``q`` on the pipe), so a normal end is not taken for a stall.

It cannot help when the whole host stops (a paused virtual machine, a frozen
machine): then nothing of the host runs, and only the device's emergency stop can
take the force off.

This module is the process (``python -m evo_door.render.supervisor``) and the
renderer's side of it (:class:`Supervisor`). The process imports only the standard
library so that it starts in tens of milliseconds; it speaks the framing of
:mod:`evo_door.render.hapticmaster` itself (a test checks the two agree).
"""

from __future__ import annotations

import argparse
import mmap
import os
import select
import signal
import sys
import time

#: default budget (s): the heartbeat's age at which the supervisor takes the force off
BUDGET = 0.02
#: the budgets ``render --supervisor-budget`` accepts (s)
BUDGET_RANGE = (0.005, 1.0)
#: how often the supervisor looks at the heartbeat (s)
TICK = 0.001
#: how often it asks the device for its state on its own link, to keep it verified (s).
#: (It was once a second for a while: the emulator's scripted hand kept the emulator's
#: clock, which skipped a silence of the host's but not one these frames broke, so a
#: render began at another point of its script. The hand's clock now starts with the
#: force state: the viscous damping estimated from a swing log is 0.85 N s/rad at 1,
#: 10 and 100 Hz alike.)
KEEPALIVE = 0.1
#: an unanswered keep-alive older than this means the supervisor's link is lost (s)
KEEPALIVE_LOST = 1.0
#: time to connect and get a first answer, at start-up (s)
CONNECT_TIMEOUT = 2.0
#: how long the supervisor waits for the device's answer to its removal (s): the frame
#: is sent at once; a device that stalled answers when it resumes, and the renderer
#: waits for this process on its way out (a stalled device must end a render in 0.5 s)
ANSWER_WAIT = 0.1
#: what it sends: the state change first (surely global on the device, even if the
#: effects turned out to belong to the connection that made them), then every effect
REMOVAL = "set state stop;remove all"
#: real-time priority of the supervisor (SCHED_FIFO): above the loop's (10)
RT_PRIORITY = 20
#: the device's error answers begin so (as in :mod:`evo_door.render.hapticmaster`)
ERROR_PREFIX = "--- ERROR"

# -- the heartbeat page: eight float64 slots -------------------------------------------
#: written by the renderer: cycles beaten, time of the last beat (CLOCK_MONOTONIC, s),
#: armed (1 while the loop renders)
SEQ, BEAT, ARMED = 0, 1, 2
#: written by the supervisor when it acts: latched (1), when (CLOCK_MONOTONIC, s), the
#: heartbeat's age then (s), the device's answer (1 acknowledged, -1 not), why (CAUSES)
LATCHED, ACTED_AT, AGE, ACK, CAUSE = 3, 4, 5, 6, 7
SLOTS = 8
CAUSES = {1: "the renderer stopped beating", 2: "the renderer died"}
STALL, DIED = 1, 2


def frame(text: str) -> bytes:
    """One frame of the device's protocol: the text's length (4 bytes, big-endian),
    four zero bytes, the ASCII text."""
    body = text.encode("ascii")
    return len(body).to_bytes(4, "big") + bytes(4) + body


def split_frames(buffer: bytearray) -> list[str]:
    """The texts of the whole frames at the start of ``buffer`` (removed from it)."""
    texts = []
    while len(buffer) >= 8:
        end = 8 + int.from_bytes(buffer[:4], "big")
        if len(buffer) < end:
            break
        texts.append(bytes(buffer[8:end]).decode("ascii", "replace").replace('"', "").strip())
        del buffer[:end]
    return texts


def _page(fd: int) -> tuple[mmap.mmap, memoryview]:
    """The heartbeat page of file ``fd`` as eight float64 slots (shared, both ways)."""
    mm = mmap.mmap(fd, mmap.PAGESIZE)
    return mm, memoryview(mm).cast("d")


# -- the renderer's side ------------------------------------------------------------------


class Supervisor:
    """The renderer's handle on its supervisor process (one per render).

    :meth:`start` spawns it and waits until it has its own connection to the device
    (a refusal raises a one-line UserError); the loop then calls :meth:`arm` before
    its first cycle, :meth:`beat` every cycle and :meth:`disarm` before it stops the
    device; :meth:`close` says goodbye and waits for the process to end.
    """

    def __init__(self, host: str, port: int, budget: float = BUDGET):
        self.host = host
        self.port = int(port)
        self.budget = float(budget)
        self.priority = ""  # what the process got, as it says
        self.proc = None  # the process (subprocess.Popen)
        self._mm = None
        self._v = None
        self._pipe = -1

    @property
    def address(self) -> str:
        return f"hapticmaster://{self.host}:{self.port}"

    def start(self, timeout: float = 10.0) -> Supervisor:
        import subprocess  # here: the command line imports this module for its constants

        from evo_door.errors import UserError

        # an unnamed file in memory: nothing to unlink, gone when both processes close it
        if hasattr(os, "memfd_create"):
            fd = os.memfd_create("evo-door-heartbeat")
        else:
            import tempfile

            fd = os.dup(tempfile.TemporaryFile().fileno())
        os.ftruncate(fd, mmap.PAGESIZE)
        self._mm, self._v = _page(fd)
        read_end, self._pipe = os.pipe()  # both not inherited, but for pass_fds
        command = [sys.executable, "-m", "evo_door.render.supervisor", self.host]
        command += [str(self.port), "--budget", repr(self.budget)]
        command += ["--page-fd", str(fd), "--pipe-fd", str(read_end)]
        try:
            # its own session: a Ctrl-C at the terminal is the renderer's to handle
            self.proc = subprocess.Popen(
                command,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                pass_fds=(fd, read_end),
                start_new_session=True,
                text=True,
            )
        finally:
            os.close(fd)
            os.close(read_end)
        line = self._first_line(timeout)
        self.proc.stdout.close()  # it says nothing more there; stderr is the renderer's
        if not line.startswith("ready"):
            self.close()
            why = line.removeprefix("refused ").strip() or "it did not start"
            raise UserError(
                f"--device {self.address}: the supervisor could not open its own "
                f"connection ({why}); it takes the force off if the renderer freezes or "
                "dies; --no-supervisor renders without it"
            )
        self.priority = line.removeprefix("ready").strip()
        return self

    def _first_line(self, timeout: float) -> str:
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        return self.proc.stdout.readline().strip() if ready else ""

    def arm(self) -> None:
        """The loop renders from now on: a heartbeat older than the budget is a stall."""
        self.beat()
        self._v[ARMED] = 1.0

    def beat(self) -> None:
        """One cycle done (every cycle: two stores and a clock read, no system call)."""
        v = self._v
        v[SEQ] += 1.0
        v[BEAT] = time.monotonic()

    @property
    def latched(self) -> bool:
        """The supervisor took the force off (the render must not go on)."""
        return self._v is not None and self._v[LATCHED] != 0.0

    def disarm(self) -> None:
        """The loop ends normally: no more beats are due."""
        if self._v is not None:
            self._v[ARMED] = 0.0

    def report(self) -> str:
        """What the supervisor did, for the log; empty if it did nothing."""
        v = self._v
        if v is None or v[LATCHED] == 0.0:
            return ""
        answer = "acknowledged" if v[ACK] > 0 else "not acknowledged"
        return (
            f"{CAUSES.get(int(v[CAUSE]), 'unknown')}: the supervisor sent '{REMOVAL}' "
            f"{v[AGE] * 1e3:.0f} ms after the last heartbeat ({answer})"
        )

    def close(self, timeout: float = 2.0) -> None:
        """Disarm, say goodbye, wait for the process (killed if it does not end)."""
        import subprocess

        self.disarm()
        if self._pipe >= 0:
            try:
                os.write(self._pipe, b"q")
            except OSError:  # already gone
                pass
            os.close(self._pipe)
            self._pipe = -1
        if self.proc is not None and self.proc.poll() is None:
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


# -- the process ----------------------------------------------------------------------


def _raise_priority() -> str:
    """Real time above the loop, on another core than the loop's, where permitted.

    The loop takes the highest-numbered core (:mod:`evo_door.render.priority`); the
    supervisor takes the others, so a loop spinning at real time cannot keep it off.
    """
    try:
        cpus = os.sched_getaffinity(0)
        if len(cpus) > 1:
            os.sched_setaffinity(0, cpus - {max(cpus)})
    except (OSError, AttributeError):
        pass
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
        return f"real-time (SCHED_FIFO, priority {RT_PRIORITY})"
    except (OSError, AttributeError) as exc:
        refused = exc
    try:
        os.setpriority(os.PRIO_PROCESS, 0, -20)
        return f"niceness -20 (real-time refused: {refused})"
    except (OSError, AttributeError):
        return f"normal priority (real-time refused: {refused})"


class _Link:
    """The supervisor's own connection to the device."""

    def __init__(self, host: str, port: int):
        import socket  # here: the command line imports this module for its constants

        self.sock = socket.create_connection((host, port), timeout=CONNECT_TIMEOUT)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.buffer = bytearray()
        self.due: list[float] = []  # send times of the keep-alives not yet answered
        self.lost = ""

    def ask(self, text: str, wait: float) -> str:
        """Send ``text``; its answer (the frames due before it are skipped)."""
        self.sock.sendall(frame(text))
        skip = len(self.due)
        self.due.clear()
        deadline = time.monotonic() + wait
        while True:
            texts = split_frames(self.buffer)
            if len(texts) > skip:
                return texts[skip]
            skip -= len(texts)
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no answer within {wait:g} s")
            self.sock.settimeout(left)
            data = self.sock.recv(4096)
            if not data:
                raise ConnectionError("closed by the device")
            self.buffer += data

    def keep_alive(self, now: float) -> None:
        """Ask for the state without waiting; answers are read by :meth:`read`."""
        if self.due and now - self.due[0] > KEEPALIVE_LOST and not self.lost:
            self.lost = f"no answer to 'get state' for {KEEPALIVE_LOST:g} s"
            _say(f"its connection to the device is silent ({self.lost})")
        self.sock.settimeout(0.05)
        self.sock.sendall(frame("get state"))
        self.due.append(now)

    def read(self) -> None:
        """Answers that came (keep-alives)."""
        self.sock.settimeout(0.0)
        try:
            data = self.sock.recv(4096)
        except BlockingIOError:
            return
        if not data:
            raise ConnectionError("closed by the device")
        self.buffer += data
        del self.due[: len(split_frames(self.buffer))]


def _say(text: str) -> None:
    print(f"evo-door: supervisor: {text}", file=sys.stderr, flush=True)


def _act(link: _Link | None, v, cause: int) -> None:
    """Take the force off through the supervisor's own connection; record and say it."""
    now = time.monotonic()
    v[LATCHED] = 1.0  # first: a renderer that runs again sees it before its next command
    v[ACTED_AT] = now
    v[AGE] = now - v[BEAT]
    v[CAUSE] = float(cause)
    answer = "no connection"
    try:
        if link is None:
            raise ConnectionError("no connection")
        answer = link.ask(REMOVAL, ANSWER_WAIT)
        v[ACK] = -1.0 if ERROR_PREFIX in answer else 1.0
    except OSError as exc:
        v[ACK] = -1.0
        answer = str(exc) or type(exc).__name__
    _say(
        f"{CAUSES[cause]} ({v[AGE] * 1e3:.0f} ms since its last heartbeat): sent "
        f"'{REMOVAL}' to the device; it answered: {answer}"
    )


def watch(link: _Link, v, pipe: int, budget: float) -> int:
    """Watch the heartbeat page ``v`` and the renderer's ``pipe`` until the render ends."""
    poller = select.poll()
    poller.register(pipe, select.POLLIN)
    poller.register(link.sock, select.POLLIN)
    tick_ms = max(1, int(TICK * 1e3))
    next_keep_alive = time.monotonic() + KEEPALIVE
    while True:
        events = dict(poller.poll(tick_ms))
        if pipe in events:
            data = os.read(pipe, 64)
            if b"q" in data:  # the renderer's goodbye: a normal end
                return 0
            if not data:  # the renderer is gone without a goodbye
                if not v[LATCHED]:
                    _act(link, v, DIED)
                return 0
        now = time.monotonic()
        if v[ARMED] and not v[LATCHED] and now - v[BEAT] > budget:
            _act(link, v, STALL)
        try:
            if link.sock.fileno() in events:
                link.read()
            if now >= next_keep_alive and not v[LATCHED]:
                link.keep_alive(now)
                next_keep_alive = now + KEEPALIVE
        except OSError as exc:  # the link is gone: say so once, keep watching the pipe
            _say(f"lost its connection to the device ({exc}); it cannot take the force off")
            link.sock.close()
            return _watch_without_link(v, pipe, budget)


def _watch_without_link(v, pipe: int, budget: float) -> int:
    """The link is gone: still record a stall or a death, for the renderer's log."""
    while True:
        ready, _, _ = select.select([pipe], [], [], TICK)
        if ready:
            data = os.read(pipe, 64)
            if b"q" in data:
                return 0
            if not data:
                if not v[LATCHED]:
                    _act(None, v, DIED)
                return 0
        if v[ARMED] and not v[LATCHED] and time.monotonic() - v[BEAT] > budget:
            _act(None, v, STALL)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m evo_door.render.supervisor")
    parser.add_argument("host")
    parser.add_argument("port", type=int)
    parser.add_argument("--budget", type=float, default=BUDGET)
    parser.add_argument("--page-fd", type=int, required=True)
    parser.add_argument("--pipe-fd", type=int, required=True)
    args = parser.parse_args(argv)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the renderer decides when it ends
    _, v = _page(args.page_fd)
    priority = _raise_priority()
    try:
        link = _Link(args.host, args.port)
        answer = link.ask("get state", CONNECT_TIMEOUT)
        if answer.startswith(ERROR_PREFIX):
            raise ConnectionError(f"'get state' answered {answer!r}")
    except OSError as exc:
        print(f"refused {exc.strerror or exc or type(exc).__name__}", flush=True)
        return 3
    print(f"ready {priority}", flush=True)
    return watch(link, v, args.pipe_fd, args.budget)


if __name__ == "__main__":
    sys.exit(main())
