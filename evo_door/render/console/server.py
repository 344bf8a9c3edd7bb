"""The web console's server: the page, its API and WebSocket, one control-port client.

The console runs in its own process (``evo-door console``) and reaches the renderer
only through its control port (:mod:`evo_door.render.control`), over one persistent
TCP connection, one request (or one batch of pipelined requests) at a time. A
background task asks for the new log rows, the state and the loop's health about 30
times a second while a page is open and sends them to every page as a ``tick``;
another asks for the set in force 4 times a second and tells the pages when it
changed (``source`` ``"push"`` when no page caused it, ``evo-door push`` for one).

Every change a page asks for is checked here first (declared sensation names, finite
numbers within their bounds), then sent as a control-port ``set``, which the renderer
checks again (bounds, passivity) and applies between two cycles, or refuses: the
page then gets ``refused`` with the reason and nothing changes. The undo stack (the
whole sets in force before each accepted change), the A/B slots and the participant
live here; each session step goes to the renderer's log as an ``event``.

Security: the server binds 127.0.0.1 unless told otherwise, and any other address
requires a token. With a token, every request needs it, in the query (``?token=T``)
or in the cookie that ``GET /?token=T`` sets (HttpOnly, SameSite=Strict). The
WebSocket and any request other than GET / HEAD are refused (403) when their
``Origin`` header is present and is not the server's own; on a loopback bind a
request whose ``Host`` is not a loopback name of the server is refused too (DNS
rebinding). Responses carry a Content-Security-Policy that allows only the page's
own origin and socket, and no CORS headers.

The HTTP and WebSocket API (every number in SI units)::

    GET /, /static/NAME          the page
    GET /api/declaration         the sensation parameters: bounds, step, two keys each
    GET /api/curve               quasi-static force-angle curve of the set in force
    GET /ws                      WebSocket, JSON messages:
        server -> page: hello, tick (~30/s), params (source slider, key, undo, reset,
                        ab or push), refused, saved, ab, participant, chosen, error;
                        hello and tick carry ``health`` (the control port's health
                        answer: status, rate_hz, cycles, missed_cycles,
                        on_time_fraction, lateness_p99_s, faults, saturated_cycles,
                        watchdog: "" or why it tripped) and ``state``
        page -> server: set {values, source}, undo, reset, save {name},
                        participant {id}, ab_store / ab_switch / ab_choice {slot},
                        ab_blind {blind}, choose

Limits: a page's messages are read by the control port's rules
(:func:`~evo_door.render.messages.parse_message`: size, values, nesting, bounded
numbers) and rate-limited per page and per message type, and all pages' actions
together (:data:`ACTIONS_PER_S`); a refusal is an ``error`` (a ``refused`` for a
``set``) with ``"ok": false`` and the reason, and the socket goes on. At most
:data:`MAX_PAGES` pages at once: one more is told why and closed (1013, try again
later). A frame over :data:`MAX_FRAME` bytes is not read at all: the socket is closed
(1009, message too big).
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import hmac
import json
import math
import os
import re
from pathlib import Path

from aiohttp import WSCloseCode, WSMsgType, web

from evo_door.errors import UserError
from evo_door.models.haptic import PARAMS
from evo_door.render.control import is_loopback
from evo_door.render.keys import GROUP, key_map, nice_step
from evo_door.render.messages import (
    MAX_LINE,
    BadMessage,
    ClientLimits,
    RateLimit,
    checked_values,
    parse_message,
)

#: the page's files (index.html, console.js, console.css)
STATIC = Path(__file__).parent / "static"
#: ticks (rows, state, health) a second while a page is open
TICK_HZ = 30.0
#: ticks per reading of the loop's health (10 a second)
HEALTH_EVERY = 3
#: reads of the set in force a second (changes made by evo-door push)
PARAMS_HZ = 4.0
#: how long the console tries to reach the renderer at start (s)
CONNECT_WAIT = 10.0
#: answer timeout of one control-port request (s)
REQUEST_TIMEOUT = 5.0
#: sets kept for undo
UNDO_DEPTH = 1000
#: seconds of rows a page gets in its hello
HISTORY_S = 10.0
#: log rows per second the control port counts in (its ``since``)
LOG_ROWS_HZ = 1000.0
#: the largest message a page may send (bytes): the control port's line
MAX_PAGE_MESSAGE = MAX_LINE
#: the largest WebSocket frame read at all (bytes); up to it, a message over
#: MAX_PAGE_MESSAGE is answered and the socket goes on; past it aiohttp closes the socket
MAX_FRAME = 16 * 2**20
#: pages served at once
MAX_PAGES = 8
#: messages a second one page may send on average, and at once (a held key sends 10)
PAGE_PER_S = 30.0
PAGE_BURST = 60
#: messages of one type a second one page may send on average, and at once
PAGE_KIND_PER_S = 15.0
PAGE_KIND_BURST = 30
#: actions a second of all pages together, and at once: each is one to three requests
#: to the control port, which takes 200 a second from the console (it polls about 45)
ACTIONS_PER_S = 30.0
ACTIONS_BURST = 60
#: the message types a page sends (each rate-limited on its own)
PAGE_KINDS = (
    "set",
    "undo",
    "reset",
    "save",
    "participant",
    "ab_store",
    "ab_switch",
    "ab_blind",
    "ab_choice",
    "choose",
)
#: messages waiting for a slow page before ticks are dropped for it
TICK_BACKLOG = 8
#: longest participant id and file stem (characters)
MAX_ID = 64
SLOTS = ("A", "B")
SOURCES = ("slider", "key")
_STEM = re.compile(r"[^A-Za-z0-9_-]+")
_STATIC_NAME = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9_.-]*$")
_STATE_KEYS = ("t", "status", "theta", "dtheta", "force")


def _one_line(text) -> str:
    return " ".join(str(text).split())


def _clean(value):
    """``value`` for JSON: non-finite floats become None (JavaScript cannot parse NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def _dumps(message: dict) -> str:
    return json.dumps(_clean(message), separators=(",", ":"))


def _error(text) -> dict:
    """An ``error`` message to a page: the reason on one line."""
    return {"type": "error", "ok": False, "error": _one_line(text)}


def _refused(text, values) -> dict:
    """A ``refused`` message to a page: the change it asked for did not happen."""
    return {
        "type": "refused",
        "ok": False,
        "error": _one_line(text),
        "values": values if isinstance(values, dict) else {},
    }


def sensation_names() -> list[str]:
    """The parameters a page may change: the declaration's ``sensation`` group."""
    return [p.name for p in PARAMS if p.group == GROUP]


def declaration() -> dict:
    """The body of ``GET /api/declaration``."""
    keys: dict[str, list[str]] = {}
    for key, (name, step) in key_map().items():
        pair = keys.setdefault(name, ["", ""])
        pair[0 if step < 0 else 1] = key
    rows = []
    for p in PARAMS:
        if p.group != GROUP:
            continue
        rows.append(
            {
                "name": p.name,
                "unit": p.unit,
                "lower": p.lower,
                "upper": p.upper,
                "default": p.default,
                "group": p.group,
                "meaning": p.meaning,
                "step": nice_step(p.upper - p.lower),
                "keys": keys[p.name],
            }
        )
    return {"params": rows, "display": {"rad": "deg"}}


def check_values(values) -> dict[str, float]:
    """A page's change {name: SI value}, checked: declared sensation names, finite
    numbers within their bounds (a UserError with the reason otherwise)."""
    return checked_values(
        values, "values", set(sensation_names()), "sensation parameter of the declaration"
    )


def safe_stem(name) -> str:
    """A file stem of letters, digits, ``_`` and ``-`` only (``console`` if none is left).

    >>> safe_stem("../x"), safe_stem("P07 soft/door"), safe_stem("..")
    ('x', 'P07_soft_door', 'console')
    """
    stem = _STEM.sub("_", str(name)).strip("_-")[:MAX_ID]
    return stem or "console"


def unused_path(folder: Path, stem: str, suffix: str = ".yaml") -> Path:
    """``folder/stem.yaml``, or ``stem-2``, ``stem-3`` ... when taken, reserved by an
    empty file created exclusively (so two saves never pick one name)."""
    for k in range(1, 100000):
        path = folder / (f"{stem}{suffix}" if k == 1 else f"{stem}-{k}{suffix}")
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            continue
        os.close(fd)
        return path
    raise UserError(f"no free file name for {stem!r} in {folder}")


def force_curve(values: dict) -> dict:
    """The quasi-static (Coulomb) force-angle curve of the haptic set ``values``."""
    from evo_door.models import get_model
    from evo_door.params.sets import ParamSet
    from evo_door.sim.simulate import force_angle_curve

    model = get_model("haptic")
    curve = force_angle_curve(model, ParamSet.from_mapping(model.params, values))
    return {
        "theta_deg": [math.degrees(x) for x in curve["theta"]],
        "opening": [float(x) for x in curve["opening"]],
        "closing": [float(x) for x in curve["closing"]],
    }


# -- the control-port client -----------------------------------------------------------
class ControlClient:
    """One persistent connection to a renderer's control port (JSON lines).

    :meth:`ask` sends a batch of requests on one write and reads their answers, in
    order, one batch at a time; a dropped connection is opened again once per batch.
    Raises a UserError when the renderer cannot be reached or does not answer.
    """

    def __init__(self, host: str, port: int, token: str | None = None, timeout=REQUEST_TIMEOUT):
        self.host, self.port = host, port
        self.token = token or None
        self.timeout = timeout
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._lock = asyncio.Lock()

    @property
    def where(self) -> str:
        return f"{self.host}:{self.port}"

    async def close(self) -> None:
        writer, self._reader, self._writer = self._writer, None, None
        if writer is not None:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    async def ask(self, *messages: dict) -> list[dict]:
        base = {"token": self.token} if self.token else {}
        payload = "".join(json.dumps({**base, **m}) + "\n" for m in messages).encode()
        async with self._lock:
            for attempt in (1, 2):
                fresh = self._writer is None
                try:
                    if fresh:
                        self._reader, self._writer = await asyncio.wait_for(
                            asyncio.open_connection(self.host, self.port, limit=1 << 24),
                            self.timeout,
                        )
                    self._writer.write(payload)
                    await self._writer.drain()
                    answers = []
                    for _ in messages:
                        line = await asyncio.wait_for(self._reader.readline(), self.timeout)
                        if not line.endswith(b"\n"):
                            raise ConnectionResetError("the renderer closed the connection")
                        answer = json.loads(line)
                        if not isinstance(answer, dict) or "ok" not in answer:
                            raise ValueError
                        answers.append(answer)
                    return answers
                except TimeoutError:
                    await self.close()
                    raise UserError(
                        f"the renderer at {self.where} did not answer in {self.timeout:g} s"
                    ) from None
                except ValueError:
                    await self.close()
                    raise UserError(
                        f"{self.where} did not answer with the control protocol"
                    ) from None
                except (OSError, asyncio.IncompleteReadError) as exc:
                    await self.close()
                    if fresh or attempt == 2:  # a stale connection gets one more try
                        reason = getattr(exc, "strerror", None) or exc
                        raise UserError(
                            f"cannot reach the renderer at {self.where}: {reason}"
                        ) from None
        raise AssertionError("unreachable")


# -- one open page ---------------------------------------------------------------------
class _Page:
    """A connected WebSocket and the queue of messages going to it."""

    def __init__(self, ws: web.WebSocketResponse):
        self.ws = ws
        self.queue: asyncio.Queue[str] = asyncio.Queue(maxsize=256)
        self.task = asyncio.get_running_loop().create_task(self._pump())

    def post(self, message: dict | str, droppable: bool = False) -> None:
        text = message if isinstance(message, str) else _dumps(message)
        if droppable and self.queue.qsize() >= TICK_BACKLOG:
            return  # a slow page misses ticks, never a change
        try:
            self.queue.put_nowait(text)
        except asyncio.QueueFull:  # hopelessly behind: let it reconnect
            self.task.cancel()
            asyncio.get_running_loop().create_task(self.ws.close())

    async def _pump(self) -> None:
        with contextlib.suppress(ConnectionError, RuntimeError):
            while True:
                await self.ws.send_str(await self.queue.get())


# -- the console's state and actions ---------------------------------------------------
class Console:
    """The console's session state and what each page message does.

    Parameters
    ----------
    client : ControlClient
        The renderer's control port.
    save_dir : path
        Where ``save`` writes parameter files.
    """

    def __init__(self, client: ControlClient, save_dir="."):
        self.client = client
        self.save_dir = Path(save_dir)
        self.params: dict[str, float] = {}
        self.params_t = 0.0
        self.start: dict[str, float] = {}
        self.undo: list[dict[str, float]] = []
        self.ab: dict = {"A": None, "B": None, "active": None, "blind": False, "choice": None}
        self.participant = ""
        self.pages: set[_Page] = set()
        self.history: collections.deque = collections.deque(
            maxlen=int(HISTORY_S * LOG_ROWS_HZ / 10)
        )
        self.lost: str | None = None
        self._cursor: int | None = None
        self._ticks = 0
        self._health: dict = {}
        self._state: dict = {}
        self._actions = asyncio.Lock()
        self.actions_rate = RateLimit(ACTIONS_PER_S, ACTIONS_BURST)
        self.open_pages = 0  # sockets open (pages counts those that had their hello)
        self._curves: collections.OrderedDict = collections.OrderedDict()
        self._tasks: list[asyncio.Task] = []

    # -- start and stop -------------------------------------------------------------
    async def connect(self, wait: float | None = None) -> None:
        """Reach the renderer (trying for ``wait`` s) and take its set as the start."""
        wait = CONNECT_WAIT if wait is None else wait
        deadline = asyncio.get_running_loop().time() + wait
        while True:
            try:
                params, decl = await self.client.ask({"get": "params"}, {"get": "declaration"})
                break
            except UserError as exc:
                if asyncio.get_running_loop().time() >= deadline:
                    raise UserError(f"{_one_line(exc)} (tried for {wait:g} s)") from None
                await asyncio.sleep(0.2)
        for answer in (params, decl):
            if not answer.get("ok"):
                raise UserError(
                    f"the renderer at {self.client.where} refused: "
                    f"{answer.get('error', 'no reason given')}"
                )
        names = [row.get("name") for row in decl.get("declaration", [])]
        if names != list(PARAMS.names):
            raise UserError(
                f"the renderer at {self.client.where} declares other haptic parameters "
                "than this console (another evo-door version?)"
            )
        self.params = {k: float(v) for k, v in params["params"].items()}
        self.params_t = float(params.get("t", 0.0))
        self.start = dict(self.params)

    def start_polling(self) -> None:
        loop = asyncio.get_running_loop()
        self._tasks = [loop.create_task(self._tick_loop()), loop.create_task(self._params_loop())]

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        for page in list(self.pages):
            page.task.cancel()
            with contextlib.suppress(Exception):
                await page.ws.close()
        await self.client.close()

    # -- messages to pages ----------------------------------------------------------
    def broadcast(self, message: dict, droppable: bool = False) -> None:
        text = _dumps(message)
        for page in list(self.pages):
            page.post(text, droppable)

    def hello(self) -> dict:
        """A page's first message: the set in force, the session so far, and the loop's
        health and state as read when it opened (:meth:`read_health`)."""
        return {
            "type": "hello",
            "params": self.params,
            "t": self.params_t,
            "start": self.start,
            "participant": self.participant,
            "ab": self._ab_state(),
            "rows": list(self.history),
            "health": self._health,
            "state": self._tick_state(),
        }

    async def read_health(self) -> None:
        """Read the loop's health and state now, for a page that opens: it shows them
        from its hello, not from a tick that comes later (meanwhile a page that came
        back to a new renderer showed the old one's, a "running" with no data). Ticks
        poll only while a page is open, so what is kept may be old."""
        try:
            health, state = await self.client.ask({"get": "health"}, {"get": "state"})
        except UserError as exc:
            self._lost(exc)
            return
        if health.get("ok"):
            self._health = {k: v for k, v in health.items() if k != "ok"}
        if state.get("ok"):
            self._state = {k: state.get(k) for k in _STATE_KEYS if k != "status"}

    def _tick_state(self) -> dict:
        """The door's state for a page, with the loop's status (from its health)."""
        return {**self._state, "status": self._health.get("status")}

    def _ab_state(self) -> dict:
        return dict(self.ab)

    def _lost(self, exc: Exception) -> None:
        text = f"lost the renderer: {_one_line(exc)}"
        if self.lost != text:
            self.lost = text
            self.broadcast(_error(text))

    # -- background polling ---------------------------------------------------------
    async def _tick_loop(self) -> None:
        period = 1.0 / TICK_HZ
        loop = asyncio.get_running_loop()
        while True:
            started = loop.time()
            if not self.pages:
                self._cursor = None  # a page that opens later starts HISTORY_S back
            else:
                try:
                    await self._tick()
                    self.lost = None
                except UserError as exc:
                    self._lost(exc)
                    await asyncio.sleep(1.0)
            await asyncio.sleep(max(0.0, period - (loop.time() - started)))

    async def _tick(self) -> None:
        # one request a tick, two every HEALTH_EVERY: each costs the renderer's process
        # a little time next to its loop; the state is the newest row
        if self._cursor is None:
            (state,) = await self.client.ask({"get": "state"})
            t = float(state.get("t") or 0.0)
            self._cursor = max(0, int((t - HISTORY_S) * LOG_ROWS_HZ))
            self.history.clear()
        ask = [{"get": "rows", "since": self._cursor}]
        self._ticks += 1
        if self._ticks % HEALTH_EVERY == 1 or not self._health:
            ask.append({"get": "health"})
        answers = await self.client.ask(*ask)
        rows = answers[0]
        new = []
        if rows.get("ok"):
            new = rows.get("rows", [])
            self._cursor = int(rows.get("next", self._cursor))
            self.history.extend(new)
        if len(answers) > 1 and answers[1].get("ok"):
            self._health = {k: v for k, v in answers[1].items() if k != "ok"}
        if new:
            t, theta, dtheta, force = new[-1][:4]
            self._state = {"t": t, "theta": theta, "dtheta": dtheta, "force": force}
        elif not rows.get("ok"):  # a renderer without rows: its state
            (state,) = await self.client.ask({"get": "state"})
            if state.get("ok"):
                self._state = {k: state.get(k) for k in _STATE_KEYS if k != "status"}
        tick = {"type": "tick", "rows": new, "state": self._tick_state(), "health": self._health}
        self.broadcast(tick, droppable=True)

    async def _params_loop(self) -> None:
        while True:
            await asyncio.sleep(1.0 / PARAMS_HZ)
            try:
                async with self._actions:
                    await self._refresh()
            except UserError as exc:
                self._lost(exc)
                await asyncio.sleep(1.0)

    async def _refresh(self) -> dict[str, float]:
        """The set in force, read now; the pages hear of a change nobody here made."""
        (answer,) = await self.client.ask({"get": "params"})
        if not answer.get("ok"):
            raise UserError(f"the renderer refused: {answer.get('error', 'no reason given')}")
        now = {k: float(v) for k, v in answer["params"].items()}
        if now != self.params:
            self._push_undo(self.params)
            self.params, self.params_t = now, float(answer.get("t", 0.0))
            self.broadcast(
                {"type": "params", "params": self.params, "t": self.params_t, "source": "push"}
            )
        return now

    # -- changes ---------------------------------------------------------------------
    def _push_undo(self, values: dict) -> None:
        self.undo.append(dict(values))
        del self.undo[:-UNDO_DEPTH]

    async def _apply(self, values: dict, source: str, page: _Page, undoable=True) -> bool:
        """Send a change; on success it is the set in force and every page hears it."""
        if not values:
            return True
        (answer,) = await self.client.ask({"set": values})
        if not answer.get("ok"):
            page.post(_refused(answer.get("error", "no reason given"), values))
            return False
        if undoable:
            self._push_undo(self.params)
        new = dict(self.params)
        new.update({k: float(v) for k, v in answer.get("applied", values).items()})
        self.params, self.params_t = new, float(answer.get("t", self.params_t))
        self.broadcast(
            {"type": "params", "params": self.params, "t": self.params_t, "source": source}
        )
        return True

    async def _apply_set(self, target: dict, source: str, page: _Page, undoable=True) -> bool:
        """Make ``target`` (a whole set) the set in force: sends what differs from the
        set in force now."""
        now = await self._refresh()
        diff = {k: v for k, v in target.items() if now.get(k) != v}
        return await self._apply(diff, source, page, undoable)

    async def _event(self, kind: str, **fields) -> None:
        (answer,) = await self.client.ask({"event": {"kind": kind, **fields}})
        if not answer.get("ok"):
            self.broadcast(
                _error(
                    f"the renderer did not record the {kind} event: "
                    f"{answer.get('error', 'no reason given')}"
                )
            )

    # -- page messages ----------------------------------------------------------------
    async def handle(self, page: _Page, message, limits: ClientLimits | None = None) -> None:
        """Do what one page message asks; errors go back to that page on one line.
        ``limits``: the page's, for its rate per message type."""
        kind = message.get("type") if isinstance(message, dict) else None
        action = getattr(self, f"_on_{kind}", None) if kind in PAGE_KINDS else None
        if action is None:
            shown = kind if isinstance(kind, str) and len(kind) <= MAX_ID else "?"
            page.post(_error(f"unknown message type {shown!r}"))
            return
        reason = limits.check(kind) if limits is not None else None
        if reason is None and not self.actions_rate.take():
            reason = (
                f"more than {ACTIONS_PER_S:g} actions a second from all pages together: slow down"
            )
        if reason is not None:
            page.post(_refused(reason, message.get("values")) if kind == "set" else _error(reason))
            return
        try:
            async with self._actions:
                await action(page, message)
        except UserError as exc:
            page.post(_error(exc))
        except OSError as exc:  # the file system said no (save)
            where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
            page.post(_error(f"{where}{exc.strerror or exc}"))

    async def _on_set(self, page, message) -> None:
        source = message.get("source", "slider")
        if source not in SOURCES:
            source = "slider"
        try:
            values = check_values(message.get("values"))
        except UserError as exc:
            page.post(_refused(exc, message.get("values")))
            return
        await self._apply(values, source, page)

    async def _on_undo(self, page, message) -> None:
        if not self.undo:
            page.post(_error("nothing to undo"))
            return
        if await self._apply_set(self.undo[-1], "undo", page, undoable=False):
            self.undo.pop()
            await self._event("undo")

    async def _on_reset(self, page, message) -> None:
        if await self._apply_set(self.start, "reset", page):
            await self._event("reset")

    async def _on_save(self, page, message) -> None:
        from evo_door.files import check_folder
        from evo_door.params.sets import ParamSet

        stem = safe_stem(message.get("name") or self.participant or "console")
        folder = self.save_dir.resolve()
        check_folder(folder / "x.yaml")
        now = await self._refresh()
        note = "chosen in the evo-door console"
        if self.participant:
            note += f" by participant {self.participant}"
        ps = ParamSet.from_mapping(PARAMS, now, description=note)
        path = unused_path(folder, stem)
        try:
            ps.to_yaml(path)
        except BaseException:
            path.unlink(missing_ok=True)
            raise
        await self._event("save", path=str(path))
        self.broadcast({"type": "saved", "path": str(path)})

    async def _on_participant(self, page, message) -> None:
        ident = message.get("id")
        if not isinstance(ident, str) or not ident.strip() or len(ident) > MAX_ID:
            raise UserError(f"a participant id is a text of 1 to {MAX_ID} characters")
        ident = _one_line(ident)
        await self._event("participant", id=ident)
        self.participant = ident
        self.broadcast({"type": "participant", "id": ident})

    def _slot(self, message, stored: bool = False) -> str:
        slot = message.get("slot")
        if slot not in SLOTS:
            raise UserError(f"slot {slot!r}: expected 'A' or 'B'")
        if stored and self.ab[slot] is None:
            raise UserError(f"slot {slot} is empty: store a set in it first")
        return slot

    async def _on_ab_store(self, page, message) -> None:
        slot = self._slot(message)
        now = await self._refresh()
        await self._event("ab_store", slot=slot, params=now)
        self.ab[slot] = dict(now)
        self.broadcast({"type": "ab", **self._ab_state()})

    async def _on_ab_switch(self, page, message) -> None:
        slot = self._slot(message, stored=True)
        if await self._apply_set(self.ab[slot], "ab", page):
            self.ab["active"] = slot
            await self._event("ab_switch", slot=slot, blind=bool(self.ab["blind"]))
            self.broadcast({"type": "ab", **self._ab_state()})

    async def _on_ab_blind(self, page, message) -> None:
        blind = message.get("blind")
        if not isinstance(blind, bool):
            raise UserError('"blind" must be true or false')
        self.ab["blind"] = blind
        self.broadcast({"type": "ab", **self._ab_state()})

    async def _on_ab_choice(self, page, message) -> None:
        slot = self._slot(message, stored=True)
        await self._event("ab_choice", slot=slot, params=self.ab[slot])
        self.ab["choice"] = slot
        self.broadcast({"type": "ab", **self._ab_state()})

    async def _on_choose(self, page, message) -> None:
        now = await self._refresh()
        await self._event("chosen", params=now)
        self.broadcast({"type": "chosen", "params": now, "participant": self.participant})

    # -- the curve ---------------------------------------------------------------------
    async def curve(self) -> dict:
        """The force-angle curve of the set in force (cached per set)."""
        values, t = dict(self.params), self.params_t
        key = tuple(values[n] for n in PARAMS.names)
        if key not in self._curves:
            loop = asyncio.get_running_loop()
            self._curves[key] = await loop.run_in_executor(None, force_curve, values)
            while len(self._curves) > 16:
                self._curves.popitem(last=False)
        return {**self._curves[key], "params_t": t}


# -- the web application -------------------------------------------------------------
CONSOLE = web.AppKey("console", Console)
GUARD = web.AppKey("guard", dict)


def _host_port(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def _guard_for(host: str, port: int, token: str | None) -> dict:
    """What the security checks accept for a server on ``host``:``port``."""
    hosts = {_host_port(host, port)}
    loopback = is_loopback(host)
    if loopback:
        hosts |= {_host_port(h, port) for h in ("127.0.0.1", "localhost", "::1")}
    wildcard = host in ("0.0.0.0", "::", "")
    return {
        "hosts": hosts,
        "origins": {f"http://{h}" for h in hosts},
        "loopback": loopback,
        "wildcard": wildcard,
        "token": token,
        "cookie": f"evo_door_console_{port}",
        "csp": "default-src 'self'; connect-src 'self' "
        + " ".join(sorted(f"ws://{h}" for h in hosts if not h.startswith("[")))  # no IPv6
        + "; frame-ancestors 'none'",
    }


def _forbidden(why: str) -> web.HTTPForbidden:
    return web.HTTPForbidden(text=f"403 forbidden: {why}\n")


@web.middleware
async def _security(request: web.Request, handler):
    guard = request.app[GUARD]
    if guard["loopback"] and request.host not in guard["hosts"]:
        raise _forbidden("unexpected Host header")
    origin = request.headers.get("Origin")
    if origin is not None and (request.method not in ("GET", "HEAD") or request.path == "/ws"):
        allowed = origin in guard["origins"] or (
            guard["wildcard"] and origin == f"http://{request.host}"
        )
        if not allowed:
            raise _forbidden("cross-origin request")
    token = guard["token"]
    set_cookie = False
    if token is not None:
        given = request.query.get("token")
        by_query = isinstance(given, str) and hmac.compare_digest(given.encode(), token.encode())
        cookie = request.cookies.get(guard["cookie"], "")
        by_cookie = hmac.compare_digest(cookie.encode(), token.encode())
        if not (by_query or by_cookie):
            raise _forbidden("missing or wrong token (open the URL the console printed)")
        set_cookie = by_query and request.path == "/"
    response = await handler(request)
    if set_cookie:
        response.set_cookie(
            guard["cookie"], token, httponly=True, samesite="Strict", path="/", max_age=None
        )
    return response


async def _headers(request: web.Request, response: web.StreamResponse) -> None:
    guard = request.app[GUARD]
    response.headers["Content-Security-Policy"] = guard["csp"]
    response.headers["X-Frame-Options"] = "DENY"
    response.headers["X-Content-Type-Options"] = "nosniff"
    response.headers["Referrer-Policy"] = "no-referrer"
    response.headers["Cache-Control"] = "no-store"


async def _index(request: web.Request) -> web.StreamResponse:
    page = STATIC / "index.html"
    if page.is_file():
        return web.FileResponse(page)
    return web.Response(text="evo-door console: the page (static/index.html) is not installed\n")


async def _static(request: web.Request) -> web.StreamResponse:
    name = request.match_info["name"]
    path = STATIC / name
    if not _STATIC_NAME.match(name) or not path.is_file():
        raise web.HTTPNotFound()
    return web.FileResponse(path)


async def _declaration(request: web.Request) -> web.Response:
    return web.json_response(declaration())


async def _curve(request: web.Request) -> web.Response:
    body = await request.app[CONSOLE].curve()
    return web.Response(text=_dumps(body), content_type="application/json")


async def _ws(request: web.Request) -> web.WebSocketResponse:
    console = request.app[CONSOLE]
    ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=MAX_FRAME)
    await ws.prepare(request)
    if console.open_pages >= MAX_PAGES:
        why = f"the console serves at most {MAX_PAGES} pages at once: close one, then reload"
        await ws.send_str(_dumps(_error(why)))
        await ws.close(code=WSCloseCode.TRY_AGAIN_LATER, message=b"too many pages")
        return ws
    console.open_pages += 1  # counted before any await: two pages never both pass
    page = _Page(ws)
    try:
        await console.read_health()
        page.post(console.hello())
        console.pages.add(page)
        await _read_page(console, page)
    finally:
        console.open_pages -= 1
        console.pages.discard(page)
        page.task.cancel()
    return ws


async def _read_page(console: Console, page: _Page) -> None:
    """Read a page's messages within the limits and do what they ask."""
    limits = ClientLimits(
        PAGE_KINDS,
        PAGE_PER_S,
        PAGE_BURST,
        PAGE_KIND_PER_S,
        PAGE_KIND_BURST,
        what="messages",
        kind_what="messages of type",
    )
    async for msg in page.ws:
        if msg.type == WSMsgType.BINARY:
            page.post(_error("binary WebSocket messages are not read: send JSON text"))
            continue
        if msg.type != WSMsgType.TEXT:
            continue
        reason = limits.check_total()
        if reason is not None:
            page.post(_error(reason))
            await asyncio.sleep(limits.backoff())  # and read this page no sooner
            continue
        try:
            message = parse_message(msg.data)
        except BadMessage as exc:
            page.post(_error(exc))
            continue
        await console.handle(page, message, limits)


def make_app(console: Console, host: str, port: int, token: str | None) -> web.Application:
    """The aiohttp application of ``console`` served on ``host``:``port``."""
    app = web.Application(middlewares=[_security], client_max_size=MAX_PAGE_MESSAGE)
    app[CONSOLE] = console
    app[GUARD] = _guard_for(host, port, token)
    app.on_response_prepare.append(_headers)
    app.router.add_get("/", _index)
    app.router.add_get("/static/{name}", _static)
    app.router.add_get("/api/declaration", _declaration)
    app.router.add_get("/api/curve", _curve)
    app.router.add_get("/ws", _ws)
    app.router.add_get("/favicon.ico", _no_icon)
    return app


async def _no_icon(request: web.Request) -> web.Response:
    return web.Response(status=204)  # no icon, and no 404 in the browser's console


class ConsoleServer:
    """The console on ``host``:``port`` for the renderer at ``control`` (host, port).

    ``await start()`` reaches the renderer (trying for ``wait`` s), listens and
    returns the page's URL; ``await stop()`` ends it.
    """

    def __init__(
        self,
        control: tuple[str, int],
        token: str | None = None,
        host: str = "127.0.0.1",
        port: int = 8765,
        save_dir=".",
        wait: float | None = None,
    ):
        if not is_loopback(host) and not token:
            raise UserError(
                f"--host {host}: serving the console on a non-loopback address requires --token"
            )
        self.host, self.port, self.token = host, int(port), token or None
        self.wait = CONNECT_WAIT if wait is None else wait
        self.console = Console(ControlClient(*control, token=self.token), save_dir)
        self.runner: web.AppRunner | None = None
        self.url = ""

    async def start(self) -> str:
        await self.console.connect(self.wait)
        # the port is needed by the checks before the app exists: bind a socket first
        import socket

        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((self.host, self.port))
            sock.listen(128)
        except OSError as exc:
            sock.close()
            await self.console.client.close()
            raise UserError(
                f"--port {self.port}: cannot listen on {self.host}: {exc.strerror or exc}"
            ) from None
        sock.setblocking(False)
        self.port = sock.getsockname()[1]
        app = make_app(self.console, self.host, self.port, self.token)
        self.runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await self.runner.setup()
        await web.SockSite(self.runner, sock).start()
        self.console.start_polling()
        self.url = f"http://{_host_port(self.host, self.port)}/"
        if self.token:
            from urllib.parse import quote

            self.url += f"?token={quote(self.token, safe='')}"
        return self.url

    async def stop(self) -> None:
        await self.console.stop()
        if self.runner is not None:
            await self.runner.cleanup()
