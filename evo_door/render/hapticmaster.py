"""The MOOG HapticMaster as a render Device, over its TCP/IP string protocol.

The protocol (frames, answers, the commands sent) is :mod:`evo_door.render.hm_protocol`.

:class:`HapticMasterDevice` implements the render Device interface (``start``,
``read``, ``command``, ``step``, ``stop``). The force the host adds goes to the device
as a *bias force* it renders until told otherwise, even after the connection closes,
and the device has no timeout of its own: :meth:`~HapticMasterDevice.stop` sends the
commands that take the force off (one frame) before the socket closes, whatever went
wrong before, and a device that stops answering counts as stalled after milliseconds
(``stall_timeout``), not a socket timeout. The ``set`` of the force is pipelined: sent at
once, its acknowledgement read together with the next query's answer, so a cycle costs
one network round trip, which :attr:`HapticMasterDevice.round_trips` records (the
servo loop's passivity check needs the measured period, not the device's 0.4 ms).
"""

from __future__ import annotations

import math
import select
import socket
import time
from collections import deque

import numpy as np

from evo_door.errors import UserError
from evo_door.render.hm_protocol import (
    BIAS_NAME,
    CYCLE_QUERY,
    ERROR_PREFIX,
    NATIVE_PARAMS,
    PLANE_DAMPER,
    PLANE_SPRING,
    FrameReader,
    HapticMasterConnectionLost,
    HapticMasterError,
    encode,
    failsafe_commands,
    format_vector,
    native_commands,
    parse_vector,
    split_answers,
)

#: The shortest stall timeout (s). The loop's own budget (watchdog misses x period,
#: 4 ms at the defaults) is below what a busy machine's scheduler can delay an answer
#: by (a normal process waits tens of ms for a core under load), and a false stall
#: ends a participant's session.
STALL_FLOOR = 0.05
#: How long the fail-safe frame may take to be sent and acknowledged (s).
FAILSAFE_WAIT = 0.1
#: How long, after ``shutdown(SHUT_WR)``, the client reads what the device still sends
#: before it closes (s): a close with unread data would reset the connection.
FAILSAFE_DRAIN = 0.02


class HapticMasterDevice:
    """A MOOG HapticMaster at ``host:port`` as a render Device.

    Parameters
    ----------
    host, port
        The device's address (the emulator listens on 127.0.0.1).
    max_force
        Saturation of the force the host commands (N); the client clips to it too.
    timeout
        Seconds to connect and to wait for each answer of the start-up sequence.
    stall_timeout
        Seconds an answer may take once rendering before the device counts as
        stalled. Default: what the servo loop gives (:meth:`watch_stalls`, its
        watchdog's budget), at least :data:`STALL_FLOOR`.
    init_wait
        Seconds between ``set state init`` and ``set state force`` (a real device
        homes in between; several seconds).
    damping
        The device's own physical damping (N s/m) as configured on it, for the
        loop's passivity check (0 unless you know it).
    native
        Commands sent after start-up to configure what the device renders itself at
        2.5 kHz (``set inertia 2.0``, ``set coulombfriction 1.5``, springs, dampers),
        so the host loop only adds what the device cannot express.

    The socket is non-blocking: every wait is a ``poll`` with a deadline, so a device
    that stops answering is noticed within ``stall_timeout``, not a socket timeout.
    Whatever ends the connection (a stall, the device closing, an error, an
    exception, the end of the render), :meth:`stop` sends :func:`failsafe_commands`
    before the socket closes; :attr:`failsafe` says what came of them and
    :attr:`failsafe_warning` is the one line to show when the device may still hold
    a force.
    """

    def __init__(
        self,
        host: str,
        port: int,
        *,
        max_force: float = 200.0,
        damping: float = 0.0,
        timeout: float = 1.0,
        stall_timeout: float | None = None,
        init_wait: float = 2.0,
        native: list[str] | tuple[str, ...] = (),
        history: int = 1 << 16,
    ) -> None:
        if stall_timeout is not None and not (0 < stall_timeout < math.inf):
            raise UserError(f"stall timeout {stall_timeout!r} s: must be > 0 and finite")
        self.host = host
        self.port = int(port)
        self.max_force = float(max_force)
        self.damping = float(damping)
        self.timeout = float(timeout)
        self.stall_timeout = STALL_FLOOR if stall_timeout is None else float(stall_timeout)
        self._stall_fixed = stall_timeout is not None
        self.init_wait = float(init_wait)
        self.native = list(native)
        self._sock: socket.socket | None = None
        self._rtt = np.zeros(int(history))
        self._n_rtt = 0
        self._force = np.zeros(3)
        self._cmd_prefix = f"set {BIAS_NAME} force "
        #: what the fail-safe of the last :meth:`stop` came to: "" (nothing was
        #: connected), "acknowledged", "unacknowledged" (sent, no answer: it waits
        #: in the connection), "undelivered" or "refused"
        self.failsafe = ""
        #: one line when the device may still hold a force after :meth:`stop`, else ""
        self.failsafe_warning = ""
        self._reset()

    def _reset(self) -> None:
        """The state of one connection, fresh."""
        self._reader = FrameReader()
        self._inbox: deque[str] = deque()
        self._unacked: deque[str] = deque()  # pipelined commands whose answer is due
        self._out = bytearray()  # bytes of whole frames not yet taken by the kernel
        self._sent = 0  # frames queued to the device
        self._got = 0  # answer frames received
        self._since = 0.0  # monotonic time of the last answer, or of a request to an idle device
        self._broken: str | None = None  # why the connection can no longer be used
        self._running = False  # through start(): answers must come within stall_timeout
        self._bias_created = False
        self._native_created = False  # the plane's effects exist on the device

    #: real time: the loop paces itself on the wall clock
    simulated = False

    def watch_stalls(self, budget: float) -> float:
        """The servo loop's budget for a missing answer (s): the stall timeout, at least
        :data:`STALL_FLOOR`, unless one was given. Returns the timeout in use."""
        if not self._stall_fixed:
            self.stall_timeout = max(STALL_FLOOR, float(budget))
        return self.stall_timeout

    # -- connection ---------------------------------------------------------------

    @property
    def address(self) -> str:
        return f"hapticmaster://{self.host}:{self.port}"

    @property
    def connected(self) -> bool:
        """Connected and usable (a lost connection stays open for :meth:`stop` only)."""
        return self._sock is not None and self._broken is None

    def connect(self) -> None:
        if self._sock is not None:
            return
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        except OSError as exc:
            raise HapticMasterConnectionLost(
                f"cannot connect to {self.address}: {exc.strerror or exc}"
            ) from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)  # every wait is a poll with a deadline (_ready)
        self._sock = sock
        self._reset()
        self.failsafe = self.failsafe_warning = ""

    def close(self) -> None:
        """:meth:`stop`: the connection never closes without the fail-safe first."""
        self.stop()

    def _close(self) -> None:
        """Close the socket: only :meth:`stop` does, after the fail-safe."""
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass

    def _lost(self, why: str) -> HapticMasterConnectionLost:
        """Mark the connection unusable; the socket stays open, so that :meth:`stop`
        can still send the fail-safe on it (a device that resumes reads it)."""
        if self._broken is None:
            self._broken = why
        return HapticMasterConnectionLost(f"connection to {self.address} lost: {why}")

    def _usable(self) -> None:
        if self._sock is None:
            raise HapticMasterConnectionLost(f"not connected to {self.address}")
        if self._broken is not None:
            raise HapticMasterConnectionLost(f"connection to {self.address} lost: {self._broken}")

    def _ready(self, events: int, deadline: float) -> bool:
        """Wait until the socket is ready for ``events`` or ``deadline`` (monotonic s)."""
        poller = select.poll()
        poller.register(self._sock, events)
        left = max(deadline - time.monotonic(), 0.0)
        return bool(poller.poll(left * 1e3))

    def _wait_for_answer(self) -> float:
        """Seconds an answer may take: the start-up's ``timeout``, then ``stall_timeout``."""
        return self.stall_timeout if self._running else self.timeout

    def _flush(self, deadline: float) -> None:
        """Hand the queued bytes to the kernel by ``deadline``; a full send buffer
        that long means the device reads nothing: lost."""
        while self._out:
            try:
                n = self._sock.send(self._out)
            except BlockingIOError:
                n = 0
            except OSError as exc:
                raise self._lost(exc.strerror or str(exc) or type(exc).__name__) from None
            del self._out[:n]
            if self._out and not self._ready(select.POLLOUT, deadline):
                raise self._lost("the device takes no more data (stalled?)")

    def _send(self, text: str) -> None:
        self._usable()
        frame = encode(text)
        now = time.monotonic()
        if self._sent == self._got:  # nothing was due: the wait for an answer starts now
            self._since = now
        self._out += frame
        self._sent += 1
        self._flush(now + self._wait_for_answer())

    def _recv(self, deadline: float) -> bytes | None:
        """What the socket has by ``deadline`` (None: nothing; b"": closed); may raise
        OSError."""
        while self._ready(select.POLLIN, deadline):
            try:
                return self._sock.recv(65536)
            except BlockingIOError:  # a spurious wake-up
                continue
        return None

    def _take(self, data: bytes) -> None:
        texts = self._reader.feed(data)
        if texts:
            self._got += len(texts)
            self._since = time.monotonic()
            self._inbox.extend(texts)

    def _receive(self) -> str:
        """The text of the next whole frame. The device counts as stalled when no
        answer came for the wait (:meth:`_wait_for_answer`) since the last answer, or
        since a request to a device that owed none: elapsed time, not the pause of a
        host that did not ask."""
        while not self._inbox:
            self._usable()
            wait = self._wait_for_answer()
            try:
                data = self._recv(self._since + wait)
            except OSError as exc:
                raise self._lost(exc.strerror or str(exc) or type(exc).__name__) from None
            if data is None:
                raise self._lost(f"no answer within {wait * 1e3:.0f} ms (stalled?)")
            if not data:
                raise self._lost("closed by the device")
            try:
                self._take(data)
            except HapticMasterError as exc:  # a corrupt stream cannot be read on
                self._lost(str(exc))
                raise
        return self._inbox.popleft()

    def _drain(self) -> None:
        """Read the answers of pipelined commands; a refusal is raised."""
        while self._unacked:
            command = self._unacked.popleft()
            split_answers(self._receive(), [command])

    def request(self, *commands: str) -> list[str]:
        """Send ``commands`` as one batched frame and return their answers."""
        self._drain()
        self._send(";".join(commands))
        return split_answers(self._receive(), list(commands))

    # -- Device interface -----------------------------------------------------------

    def start(self) -> None:
        """Connect and run the device's start-up sequence, ending in force state.

        ``remove all``, the calibration check, ``set state init``, a wait, ``set state
        force``, then the bias force (created at zero, enabled) and the native effects.
        Each answer may take ``timeout``; from then on ``stall_timeout``.
        """
        self.connect()
        try:
            self.request("remove all")
            self._native_created = False
            pos_ok, force_ok = self.request("get position_calibrated", "get force_calibrated")
            if pos_ok.lower() != "true" or force_ok.lower() != "true":
                raise HapticMasterError(
                    f"{self.address} is not calibrated (position: {pos_ok}, force: "
                    f"{force_ok}): calibrate it with its own tools before rendering"
                )
            self.request("set state init")
            time.sleep(self.init_wait)
            self.request("set state force")
            self.request(f"create biasforce {BIAS_NAME}")
            self._bias_created = True
            self.request(f"set {BIAS_NAME} force [0,0,0]", f"set {BIAS_NAME} enable")
            for command in self.native:
                self.request(command)
        except BaseException:
            self.stop()
            raise
        self._force[:] = 0.0
        self._running = True

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (m), velocity (m/s), measured user force (N) in one round trip."""
        t0 = time.perf_counter()
        pos, vel, force = self.request(*CYCLE_QUERY.split(";"))
        self._rtt[self._n_rtt % self._rtt.size] = time.perf_counter() - t0
        self._n_rtt += 1
        return (
            parse_vector(pos, "get modelpos"),
            parse_vector(vel, "get modelvel"),
            parse_vector(force, "get measforce"),
        )

    def command(self, force) -> None:
        """Set the bias force (N): sent now, its acknowledgement read with the next query.

        A non-finite force becomes zero and a force over :attr:`max_force` is scaled
        down to it: the last guard before the motors.
        """
        f = np.asarray(force, dtype=np.float64).reshape(3)
        norm = math.sqrt(float(f @ f))
        if not math.isfinite(norm):
            f = np.zeros(3)
        elif norm > self.max_force:
            f = f * (self.max_force / norm)
        self._force[:] = f
        text = self._cmd_prefix + format_vector(f)
        if len(self._unacked) >= 8:  # a loop commanding without reading: catch up
            self._drain()
        self._send(text)
        self._unacked.append(text)

    def set_mass(self, mass: float) -> None:
        """The moving mass (kg) the device renders natively (``set inertia``)."""
        self.request(f"set inertia {float(mass):.9g}")

    def render_natively(self, params) -> tuple[str, ...]:
        """Let the device render what it can of the haptic set ``params`` itself.

        Configures the plane constraint as the device's own spring and damper
        (:func:`native_commands`): the first call after :meth:`start` creates
        :data:`PLANE_SPRING` and :data:`PLANE_DAMPER`, sets them and enables them, all
        in one frame; later calls (a parameter change) only set their values, in one
        frame. Returns the names of the parameters the device now renders
        (:data:`NATIVE_PARAMS`): the host must leave them out of its own force and of
        its passivity check, since the device's 2.5 kHz loop renders them. A refusal
        raises :class:`HapticMasterError`.
        """
        commands = native_commands(params, self.max_force)
        if not self._native_created:
            commands = [
                f"create spring {PLANE_SPRING}",
                f"create damper {PLANE_DAMPER}",
                *commands,
                f"set {PLANE_SPRING} enable",
                f"set {PLANE_DAMPER} enable",
            ]
        self.request(*commands)
        self._native_created = True
        return NATIVE_PARAMS

    def step(self, dt: float) -> None:
        """The real device runs its own physics: nothing to do."""

    def stop(self) -> None:
        """Take the force off the handle, then close: the end of every exit path.

        :func:`failsafe_commands` go in one frame before the socket closes, whatever
        state the connection is in (a stall, the device closing, an error): a device
        that stalled reads them from the connection when it resumes, in order after
        what it had not read yet. The frame has :data:`FAILSAFE_WAIT` to be sent and
        answered; then ``shutdown(SHUT_WR)``, :data:`FAILSAFE_DRAIN` of reading what
        is left (a close with unread data would reset the connection and could make
        the device drop the frame), and the close. :attr:`failsafe` and
        :attr:`failsafe_warning` say how it went. Idempotent; never raises.
        """
        if self._sock is None:
            return
        try:
            self.failsafe, self.failsafe_warning = self._fail_safe()
        except Exception as exc:  # never let the way out raise: say it instead
            self.failsafe = "undelivered"
            self.failsafe_warning = self._undelivered(f"{type(exc).__name__}: {exc}")
        finally:
            try:
                self._sock.shutdown(socket.SHUT_WR)
                self._discard(time.monotonic() + FAILSAFE_DRAIN)
            except OSError:
                pass
            self._close()
            self._running = False
            self._force[:] = 0.0

    def _fail_safe(self) -> tuple[str, str]:
        """Send the fail-safe frame and wait for its answer; (outcome, warning)."""
        deadline = time.monotonic() + FAILSAFE_WAIT
        frame = encode(";".join(failsafe_commands(self._bias_created)))
        # after whole frames only: a frame cut by a full buffer is completed first,
        # else the device would read the fail-safe as the rest of it
        self._out += frame
        self._sent += 1
        target = self._sent  # the answer to this frame is the target-th received
        try:
            self._flush(deadline)
        except HapticMasterConnectionLost:
            return "undelivered", self._undelivered(self._broken)
        answer = None
        while answer is None:
            try:
                data = self._recv(deadline)
            except OSError as exc:
                return "undelivered", self._undelivered(exc.strerror or str(exc))
            if data is None:
                return "unacknowledged", (
                    f"{self.address} did not answer the commands that take its force off "
                    f"within {FAILSAFE_WAIT * 1e3:.0f} ms: they wait in the connection and "
                    "take effect if it resumes; until then it may still hold a force (its "
                    "emergency stop clears it)"
                )
            if not data:
                return "undelivered", self._undelivered("closed by the device")
            try:
                self._take(data)
            except HapticMasterError as exc:
                return "undelivered", self._undelivered(str(exc))
            if self._got >= target:
                answer = self._inbox[len(self._inbox) - 1 - (self._got - target)]
        if ERROR_PREFIX in answer:
            return "refused", (
                f"{self.address} refused the commands that take its force off ({answer}): "
                "it may still hold a force; clear it with its emergency stop"
            )
        return "acknowledged", ""

    def _undelivered(self, why: str | None) -> str:
        return (
            f"{self.address}: the commands that take its force off could not be delivered "
            f"({why or 'connection lost'}): the device may still hold a force; clear it "
            "with its emergency stop"
        )

    def _discard(self, deadline: float) -> None:
        """Read and drop what the device sends until it closes or ``deadline``."""
        while True:
            data = self._recv(deadline)
            if not data:
                return

    # -- measurements ---------------------------------------------------------------

    @property
    def last_round_trip(self) -> float:
        """The last cycle's round trip (s), NaN before the first."""
        if self._n_rtt == 0:
            return math.nan
        return float(self._rtt[(self._n_rtt - 1) % self._rtt.size])

    @property
    def round_trips(self) -> np.ndarray:
        """The round trips of the recent cycles (s), oldest first."""
        n = min(self._n_rtt, self._rtt.size)
        if self._n_rtt <= self._rtt.size:
            return self._rtt[:n].copy()
        k = self._n_rtt % self._rtt.size
        return np.concatenate([self._rtt[k:], self._rtt[:k]])

    def __enter__(self) -> HapticMasterDevice:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
