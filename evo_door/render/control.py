"""The renderer's control port: change the parameters of a running renderer over TCP.

``evo-door render ... --control PORT`` starts a :class:`ControlServer` next to the
servo loop; ``evo-door push`` and the operator's web console (``evo-door console``) are
its clients.

Binding. The server binds to 127.0.0.1 unless told otherwise (``--control HOST:PORT``);
any address that is not a loopback one requires a token (``--token T``), else the
server refuses to start. With a token, every request must carry it.

Protocol. A TCP stream of lines, UTF-8, one JSON object per line, one answer line per
request, in order; a connection may send any number of requests, within the limits
below (:mod:`evo_door.render.messages`).

Requests::

    {"token": T, "set": {"NAME": VALUE, ...}}   change parameters (SI units)
    {"token": T, "get": "params"}               the set in force
    {"token": T, "get": "state"}                the device and door state
    {"token": T, "get": "declaration"}          names, units, bounds, groups
    {"token": T, "get": "health"}               the loop's timing so far
    {"token": T, "get": "rows", "since": K}     the log's door rows from row K, at 100 Hz
    {"token": T, "event": {"kind": KIND, ...}}  a session event, into the log

(``token`` only when the server has one.) Answers::

    {"ok": true, "applied": {NAME: VALUE}, "in_force": bool, "t": S}
    {"ok": true, "params": {NAME: VALUE}, "units": {NAME: UNIT}, "t": S}
    {"ok": true, "t": S, "theta": RAD, "dtheta": RAD_S, "force": N,
     "position": [M x3], "velocity": [M_S x3], "user_force": [N x3],
     "command": [N x3], "status": "running"}
    {"ok": true, "t": S, "status": ..., "rate_hz", "cycles", "missed_cycles",
     "on_time_fraction", "lateness_p99_s", "period_mean_s", "compute_p99_s",
     "faults", "saturated_cycles", "watchdog"}
    {"ok": true, "rows": [[t S, theta RAD, dtheta RAD_S, force N], ...], "next": K2}
    {"ok": true, "t": S}                         (an event recorded at loop time S)
    {"ok": false, "error": "one line: why"}

``rows`` hands out the 1 kHz log's rows ``K, K + 10, ...`` (100 Hz, for a live
display), at most :data:`MAX_ROWS` per answer; ask again with ``since`` = ``next``.
Session events (the web console's) are one of :data:`EVENT_KINDS`; those that carry
a parameter set (``params``) must give declared names with finite values within their
bounds. They go into the log's events and, through them, its session record
(:mod:`evo_door.render.session`).

A change goes through :meth:`ServoLoop.request_change`: it is checked against the
declaration, the passivity condition at the measured loop period and the hands-off
speed (:mod:`evo_door.render.hands_off`), and comes into
force whole between two cycles, or is refused and the set in force stays as it was;
``in_force`` says whether the loop had applied it when the answer left (it waits up
to 0.5 s; a loop that is not running yet applies it at its first cycle). The log
records each set with its time, up to its cap (see Limits). ``applied`` holds the
values after any clamp (``--clamp``). Changes are serialised: two clients never
interleave one.

Limits. The renderer's process runs the servo loop; whatever a client sends must cost
it little and bounded time and memory. Every refusal below is an answer
``{"ok": false, "error": ...}`` with the reason, and the connection goes on:

* a line of at most :data:`~evo_door.render.messages.MAX_LINE` bytes (a longer one is
  answered once and skipped to its newline), read by
  :func:`~evo_door.render.messages.parse_message` within the bounds of
  :mod:`evo_door.render.messages` (values, arrays and objects, digits, finite
  numbers), which the web console uses for its WebSocket too;
* per connection, :data:`~evo_door.render.messages.REQUESTS_PER_S` requests a second
  and :data:`~evo_door.render.messages.EVENTS_PER_S` events of each kind, in bursts
  (:class:`~evo_door.render.messages.ClientLimits`); past that the connection is also
  read more slowly;
* all connections together, :data:`SERVER_REQUESTS_PER_S` requests and
  :data:`BYTES_PER_S` bytes a second: past that a request waits for its turn;
* at most :data:`MAX_CLIENTS` connections at once: one more is answered with the
  reason and closed; a connection idle for :data:`IDLE_TIMEOUT` s is closed;
* the log keeps the session events and refused changes up to a cap
  (:data:`~evo_door.render.log.MAX_CLIENT_EVENTS`, :data:`~evo_door.render.log.MAX_CLIENT_BYTES`);
  one past it is answered ``ok: false`` and counted in the log's ``dropped`` event;
* the log keeps :data:`~evo_door.render.log.MAX_PARAM_SETS` parameter sets with their
  changes; a valid change past that still comes into force and is answered ``ok:
  true``, and the log counts it (its ``changes_dropped`` event) and keeps the set in
  force at each choice and at the end.
"""

from __future__ import annotations

import contextlib
import hmac
import ipaddress
import json
import math
import socket
import socketserver
import threading
import time

import numpy as np

from evo_door.errors import UserError
from evo_door.render.columns import COLUMNS
from evo_door.render.messages import (
    MAX_LINE,
    BadMessage,
    ClientLimits,
    RateLimit,
    checked_values,
    parse_message,
)

#: how long a change request waits to see the loop apply it (s)
APPLY_WAIT = 0.5


def parse_control(spec) -> tuple[str, int]:
    """``PORT`` or ``HOST:PORT`` of ``--control`` / ``--to`` -> (host, port)."""
    text = str(spec).strip()
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host, port_text = "127.0.0.1", text
    host = host.strip("[]") or "127.0.0.1"
    try:
        port = int(port_text)
    except ValueError:
        raise UserError(f"{text!r}: expected PORT or HOST:PORT") from None
    if not 0 <= port <= 65535:
        raise UserError(f"{text!r}: port must be in 0..65535")
    return host, port


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and ``localhost``."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _finite(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


# -- the caps of the server as a whole (a client's own: evo_door.render.messages) --
#: requests a second of all connections together, and at once: past that a request
#: waits for its turn (the connection is read no sooner). Each answer costs the loop's
#: process little, but every one is a few hand-overs of the interpreter lock, and a
#: flood of them (1,500 a second from 16 clients) cost a loaded machine's loop 12 % of
#: its cycles; the console asks about 45 a second
SERVER_REQUESTS_PER_S = 400.0
SERVER_REQUESTS_BURST = 100
#: bytes a second read from all connections together on average, and at once; past
#: that a connection is not read for a while, and TCP slows its sender down. Reading,
#: scanning and parsing cost in proportion (90 MB/s of long lines from 16 clients cost
#: a loaded machine's loop 1.2 % of its cycles); a console sends a few kB a second
BYTES_PER_S = 2 * 2**20
BYTES_BURST = 4 * 2**20
#: connections served at once; one more is told why and closed
MAX_CLIENTS = 16
#: a connection that sends nothing for this long is closed (s)
IDLE_TIMEOUT = 60.0


def _pause(seconds: float) -> None:
    if seconds > 0:  # no system call at all when there is nothing to wait for
        time.sleep(seconds)


class _Handler(socketserver.StreamRequestHandler):
    timeout = IDLE_TIMEOUT
    rbufsize = 65536  # a long line in few reads, each a hand-over of the interpreter lock

    def handle(self) -> None:
        server: ControlServer = self.server.control  # type: ignore[attr-defined]
        limits = ClientLimits(EVENT_KINDS)
        reading = server.reading
        while True:
            try:
                line = self.rfile.readline(MAX_LINE + 1)
            except (OSError, ValueError):  # idle too long, reset, closed
                return
            if not line:
                return
            _pause(reading.turn(len(line)))
            _pause(server.budget.turn())  # all connections together: wait for its turn
            if len(line) > MAX_LINE and not line.endswith(b"\n"):
                self._send({"ok": False, "error": f"a line takes at most {MAX_LINE} bytes"})
                if not self._skip_line(reading):
                    return
                continue
            if not line.strip():
                continue
            reason = limits.check_total()
            if reason is not None:
                self._send({"ok": False, "error": reason})
                _pause(limits.backoff())
                continue
            self._send(server.answer(line, limits))

    def _skip_line(self, reading: RateLimit) -> bool:
        """Read up to the end of a line too long to serve (resynchronise on the next
        newline); False when the connection ended first."""
        while True:
            try:
                chunk = self.rfile.readline(MAX_LINE)
            except (OSError, ValueError):
                return False
            if not chunk:
                return False
            _pause(reading.turn(len(chunk)))
            if chunk.endswith(b"\n"):
                return True

    def _send(self, answer: dict) -> None:
        try:
            self.wfile.write((json.dumps(answer) + "\n").encode())
            self.wfile.flush()
        except OSError:
            pass


class _TCPServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 64  # a burst of connections waits to be told, not to time out
    control: ControlServer

    def process_request(self, request, client_address) -> None:
        """Serve the connection in its own thread, or refuse it (at the cap) here: a
        line with the reason and closed, without a thread."""
        if not self.control._admit():
            # a refusal costs as much as an answer: it waits its turn in the budget
            _pause(self.control.budget.turn())
            _refuse_connection(request)
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self.control._leave()
            raise

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self.control._leave()


def _refuse_connection(sock: socket.socket) -> None:
    """Tell a connection over the cap why it is closed. What it already sent is read
    first (without waiting): closing on unread data resets the connection, and the
    client would lose the answer."""
    answer = {
        "ok": False,
        "error": f"the control port serves at most {MAX_CLIENTS} connections at once: "
        "try again when one has closed",
    }
    try:
        sock.setblocking(False)
        with contextlib.suppress(BlockingIOError):
            while sock.recv(65536):
                pass
        sock.settimeout(0.5)
        sock.sendall((json.dumps(answer) + "\n").encode())
    except OSError:
        pass


class ControlServer:
    """Serves :mod:`the control protocol <evo_door.render.control>` for ``loop``.

    Parameters
    ----------
    loop : ServoLoop
        The running (or about to run) loop.
    host, port : str, int
        Where to listen; port 0 picks a free one (see :attr:`address`).
    token : str or None
        Required on every request when given; required to bind a non-loopback address.
    """

    def __init__(self, loop, host: str = "127.0.0.1", port: int = 0, token: str | None = None):
        if not is_loopback(host) and not token:
            raise UserError(
                f"--control {host}:{port}: a control port on a non-loopback address "
                "requires --token"
            )
        self.loop = loop
        self.token = token or None
        self._change_lock = threading.Lock()
        self._clients_lock = threading.Lock()
        self.clients = 0  # connections being served
        self.budget = RateLimit(SERVER_REQUESTS_PER_S, SERVER_REQUESTS_BURST)
        self.reading = RateLimit(BYTES_PER_S, BYTES_BURST)  # bytes
        cls = _TCPServer
        if ":" in host:
            cls = type("_TCPServer6", (_TCPServer,), {"address_family": socket.AF_INET6})
        try:
            self._server = cls((host, port), _Handler)
        except OSError as exc:
            raise UserError(f"--control {host}:{port}: cannot listen: {exc.strerror}") from None
        self._server.control = self
        self._thread: threading.Thread | None = None

    @property
    def address(self) -> tuple[str, int]:
        host, port = self._server.server_address[:2]
        return host, port

    def start(self) -> ControlServer:
        """Serve in a daemon thread."""
        self._thread = threading.Thread(
            target=self._server.serve_forever,
            kwargs={"poll_interval": 0.05},
            name="evo-door-control",
            daemon=True,
        )
        self._thread.start()
        return self

    def close(self) -> None:
        if self._thread is not None:
            self._server.shutdown()
            self._thread.join(timeout=5.0)
        self._server.server_close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()

    def _admit(self) -> bool:
        """Count one more connection, unless :data:`MAX_CLIENTS` are served."""
        with self._clients_lock:
            if self.clients >= MAX_CLIENTS:
                return False
            self.clients += 1
            return True

    def _leave(self) -> None:
        with self._clients_lock:
            self.clients -= 1

    # -- requests ------------------------------------------------------------------
    def answer(self, line: bytes | str, limits: ClientLimits | None = None) -> dict:
        """The answer to one request line (never raises); ``limits``: the client's, for
        its events."""
        try:
            request = parse_message(line)
        except BadMessage as exc:
            return {"ok": False, "error": str(exc)}
        if self.token is not None:
            given = request.get("token")
            if not isinstance(given, str) or not hmac.compare_digest(
                given.encode(), self.token.encode()
            ):
                return {"ok": False, "error": "missing or wrong token"}
        try:
            if "set" in request:
                return self._set(request["set"])
            if "event" in request:
                return self._event(request["event"], limits)
            what = request.get("get")
            if what == "health":
                return {"ok": True, "t": self.loop.snapshot()["t"], **self.loop.health()}
            if what == "rows":
                return self._rows(request.get("since", 0))
            if what == "params":
                return self._params()
            if what == "state":
                return self._state()
            if what == "declaration":
                return {"ok": True, "declaration": self.loop.params.table.rows()}
            return {
                "ok": False,
                "error": 'expected {"set": {...}}, {"event": {...}} or {"get": '
                '"params"|"state"|"health"|"rows"|"declaration"}',
            }
        except UserError as exc:
            return {"ok": False, "error": " ".join(str(exc).split())}

    def _set(self, values) -> dict:
        if not isinstance(values, dict) or not values:
            raise UserError('"set" takes a non-empty object {name: value}')
        for name, value in values.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise UserError(f"parameter {name!r}: {value!r} is not a number")
        loop = self.loop
        with self._change_lock:
            new = loop.request_change({str(k): float(v) for k, v in values.items()})
            applied = {name: new[name] for name in values}
            # the values the clamp changed too
            for name in loop.params.table.names:
                if name not in applied and new[name] != loop.params[name]:
                    applied[name] = new[name]
            deadline = time.monotonic() + APPLY_WAIT
            in_force = False
            while loop.status == "running" and time.monotonic() < deadline:
                if not loop.pending:
                    in_force = True
                    break
                time.sleep(0.0005)
        return {"ok": True, "applied": applied, "in_force": in_force, "t": loop.snapshot()["t"]}

    def _rows(self, since) -> dict:
        if isinstance(since, bool) or not isinstance(since, int) or since < 0:
            raise UserError('"since" must be a row index >= 0')
        log = self.loop.log
        n = log.n
        start = min(max(since, log.held_from), n)  # older rows: in the side file only
        start += (-start) % ROWS_EVERY  # on the 100 Hz grid: rows 0, 10, 20 ...
        if start >= n:
            return {"ok": True, "rows": [], "next": start}
        n = min(n, start + ROWS_EVERY * MAX_ROWS)  # a bounded answer: ask again for more
        rows = log.rows(start, n)[::ROWS_EVERY]
        col = [COLUMNS.index(c) for c in ("theta", "dtheta", "force")]
        t = (start + ROWS_EVERY * np.arange(len(rows))) / log.rate
        out = np.column_stack([t, rows[:, col]])
        out[~np.isfinite(out)] = 0.0
        return {"ok": True, "rows": out.tolist(), "next": start + ROWS_EVERY * len(rows)}

    def _event(self, event, limits: ClientLimits | None = None) -> dict:
        if not isinstance(event, dict) or event.get("kind") not in EVENT_KINDS:
            raise UserError(f"an event is an object with a kind among {', '.join(EVENT_KINDS)}")
        event = dict(event)
        kind = event.pop("kind")
        reason = limits.check(kind) if limits is not None else None
        if reason is not None:
            raise UserError(reason)
        if "params" in event:
            event["params"] = checked_values(event["params"], table=self.loop.params.table)
        if kind == "chosen":  # the whole set: what is not given is the set in force
            event["params"] = {**self.loop.params.as_dict(), **event.get("params", {})}
        text = json.dumps(event)
        if len(text) > 16_384:
            raise UserError("an event takes at most 16 KiB")
        t = self.loop.snapshot()["t"]
        if not self.loop.log.client_event(t, kind, f"session: {kind}", len(text), **event):
            raise UserError(
                f"the log holds its cap of session events ({self.loop.log.client_cap()}): "
                "this one is not recorded"
            )
        return {"ok": True, "t": t}

    def _params(self) -> dict:
        snap = self.loop.snapshot()
        return {
            "ok": True,
            "params": snap["params"].as_dict(),
            "model": snap["params"].model,
            "units": {q.name: q.unit for q in snap["params"].table},
            "t": snap["t"],
        }

    def _state(self) -> dict:
        snap = self.loop.snapshot()
        out = {"ok": True, "t": snap["t"], "status": snap["status"]}
        if not math.isfinite(snap["theta"]):  # no cycle yet
            return out
        out.update({k: _finite(snap[k]) for k in ("theta", "dtheta", "force")})
        for k in ("position", "velocity", "user_force", "command"):
            out[k] = [_finite(x) for x in snap[k]]
        return out


#: rows of the 1 kHz log per row that ``{"get": "rows"}`` hands out (100 Hz)
ROWS_EVERY = 10

#: rows per ``rows`` answer at most (0.5 s at 100 Hz): the renderer's process holds the
#: interpreter lock while it encodes one (about 0.15 ms for 50 rows, 0.7 ms for 200),
#: and the servo loop, waiting for it, must not miss its 0.4 ms slot; a console that
#: starts 10 s back catches up in well under a second at its 30 requests a second
MAX_ROWS = 50

#: the session events of the operator's web console that the log records
EVENT_KINDS = (
    "participant",
    "ab_store",
    "ab_switch",
    "ab_choice",
    "undo",
    "reset",
    "save",
    "chosen",
    "note",
    "jnd_start",
    "jnd_trial",
    "jnd_answer",
    "jnd_end",
    "jnd_save",
)


def request(host: str, port: int, message: dict, timeout: float = 5.0) -> dict:
    """Send one request, return the answer (a UserError when the port cannot answer)."""
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            sock.sendall((json.dumps(message) + "\n").encode())
            data = b""
            while not data.endswith(b"\n"):
                chunk = sock.recv(65536)
                if not chunk:
                    break
                data += chunk
    except TimeoutError:
        raise UserError(f"the renderer at {host}:{port} did not answer in {timeout:g} s") from None
    except OSError as exc:
        raise UserError(
            f"cannot reach the renderer at {host}:{port}: {exc.strerror or exc}"
        ) from None
    try:
        answer = json.loads(data)
    except ValueError:
        raise UserError(f"{host}:{port} did not answer with the control protocol") from None
    if not isinstance(answer, dict) or "ok" not in answer:
        raise UserError(f"{host}:{port} did not answer with the control protocol")
    return answer
