"""The console's session: its state, the loop state it polls, and the changes it sends.

A :class:`Console` keeps what the pages share: the set in force and the one the
session started from, the undo stack (the whole sets in force before each accepted
change), the A/B slots, the participant, the JND session
(:mod:`~evo_door.render.console.jnd_mode`), the open pages. Background tasks poll the
renderer (:meth:`Console.start_polling`): the new log rows, the state and the loop's
health about 30 times a second while a page is open, sent to every page as a
``tick``; the set in force 4 times a second, the pages told when it changed
(``source`` ``"push"`` when no page caused it). What each page message does is in
:mod:`~evo_door.render.console.actions`.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
from pathlib import Path

from evo_door.errors import UserError
from evo_door.render.console.actions import ACTIONS, PAGE_KINDS
from evo_door.render.console.client import ControlClient, cancel_and_wait
from evo_door.render.console.jnd_mode import BLOCKED, JndRun
from evo_door.render.console.page import Page, dumps, error, one_line, refused
from evo_door.render.console.saving import MAX_ID
from evo_door.render.console.sensations import Tunable
from evo_door.render.messages import ClientLimits, RateLimit

#: ticks (rows, state, health) a second while a page is open
TICK_HZ = 30.0
#: ticks per reading of the loop's health (10 a second)
HEALTH_EVERY = 3
#: reads of the set in force a second (changes made by evo-door push)
PARAMS_HZ = 4.0
#: how long the console tries to reach the renderer at start (s)
CONNECT_WAIT = 10.0
#: sets kept for undo
UNDO_DEPTH = 1000
#: seconds of rows a page gets in its hello
HISTORY_S = 10.0
#: s a shutdown waits for a running JND session to write what was answered
STOP_JND_S = 10.0
#: log rows per second the control port counts in (its ``since``)
LOG_ROWS_HZ = 1000.0
#: actions a second of all pages together, and at once: each is one to three requests
#: to the control port, which takes 200 a second from the console (it polls about 45)
ACTIONS_PER_S = 30.0
ACTIONS_BURST = 60
_STATE_KEYS = ("t", "status", "theta", "dtheta", "force")


class Console:
    """The console's session: its state, the polling of the renderer, the changes it
    sends, and the dispatch of each page message to its action.

    Parameters
    ----------
    client : ControlClient
        The renderer's control port.
    save_dir : path
        Where ``save`` writes parameter files (and a JND session its JND file).
    versions : dict, optional
        The software's versions, recorded in JND files (the command passes them).
    model : Model, optional
        The rendered model (``evo-door console --model``; ``render --console`` passes
        its own). By default the model the renderer names, if it is installed (the
        haptic model); a mechanism file must be given.
    """

    def __init__(
        self, client: ControlClient, save_dir=".", versions: dict | None = None, model=None
    ):
        self.client = client
        self.model = model
        self._tunable: Tunable | None = None  # what a page may change: known at connect
        self.save_dir = Path(save_dir)
        self.versions = dict(versions or {})  # the software's, for the JND files
        self.jnd: JndRun | None = None  # the JND session, running or last ended
        self.params: dict[str, float] = {}
        self.params_t = 0.0
        self.start: dict[str, float] = {}
        self.undo: list[dict[str, float]] = []
        self.ab: dict = {"A": None, "B": None, "active": None, "blind": False, "choice": None}
        self.participant = ""
        self.pages: set[Page] = set()
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
                    raise UserError(f"{one_line(exc)} (tried for {wait:g} s)") from None
                await asyncio.sleep(0.2)
        for answer in (params, decl):
            if not answer.get("ok"):
                raise UserError(
                    f"the renderer at {self.client.where} refused: "
                    f"{answer.get('error', 'no reason given')}"
                )
        model = self._rendered_model(params.get("model", "haptic"))
        names = [row.get("name") for row in decl.get("declaration", [])]
        if names != list(model.params.names):
            raise UserError(
                f"the renderer at {self.client.where} declares other "
                f"{model.params.model} parameters than this console (another evo-door "
                "version, or another file of that name?)"
            )
        self.params = {k: float(v) for k, v in params["params"].items()}
        self._tunable = Tunable(model, self.params)
        self.params_t = float(params.get("t", 0.0))
        self.start = dict(self.params)

    @property
    def tunable(self) -> Tunable:
        """The rendered model as the pages see it (:meth:`connect` learns it)."""
        if self._tunable is None:
            raise UserError("the console has not reached the renderer yet")
        return self._tunable

    def _rendered_model(self, name):
        """The model the renderer renders (its declaration's ``name``): the one given,
        which must be it, or an installed model of that name; else a UserError."""
        from evo_door.models import available_models, get_model

        where = self.client.where
        if not isinstance(name, str) or not name:
            raise UserError(f"the renderer at {where} does not name its model")
        if self.model is not None:
            if self.model.params.model != name:
                raise UserError(
                    f"--model: model {self.model.params.model!r}, but the renderer at "
                    f"{where} renders {name!r}"
                )
            return self.model
        if name not in available_models():
            raise UserError(
                f"the renderer at {where} renders model {name!r}: give its file with "
                "--model (a mechanism file, path/file.py:MODEL)"
            )
        return get_model(name)

    def start_polling(self) -> None:
        loop = asyncio.get_running_loop()
        self._tasks = [loop.create_task(self._tick_loop()), loop.create_task(self._params_loop())]

    @property
    def action_lock(self) -> asyncio.Lock:
        """Held by each page action, and by a JND session while it changes the set."""
        return self._actions

    async def _stop_jnd(self) -> None:
        assert self.jnd is not None
        async with self.action_lock:
            await self.jnd.stop()

    def visible(self, params: dict[str, float]) -> dict[str, float]:
        """``params`` as the pages may see them (a blind JND session hides its step)."""
        return self.jnd.visible(params) if self.jnd is not None else params

    async def stop(self) -> None:
        if self.jnd is not None and self.jnd.running:
            # the console shuts down mid-session: the answers so far are written (a
            # stopped session's file), the starting set put back, within a bound
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._stop_jnd(), timeout=STOP_JND_S)
        if self.jnd is not None and self.jnd.task is not None:
            await cancel_and_wait(self.jnd.task)
        for task in self._tasks:
            await cancel_and_wait(task)
        for page in list(self.pages):
            page.task.cancel()
            with contextlib.suppress(Exception):
                await page.ws.close()
        await self.client.close()

    # -- messages to pages ----------------------------------------------------------
    def broadcast(self, message: dict, droppable: bool = False) -> None:
        text = dumps(message)
        for page in list(self.pages):
            page.post(text, droppable)

    def hello(self) -> dict:
        """A page's first message: the set in force, the session so far, and the loop's
        health and state as read when it opened (:meth:`read_health`)."""
        return {
            "type": "hello",
            "params": self.visible(self.params),
            "t": self.params_t,
            "start": self.start,
            "participant": self.participant,
            "ab": self.ab_state(),
            "jnd": self.jnd.state() if self.jnd is not None else None,
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

    def ab_state(self) -> dict:
        return dict(self.ab)

    def _lost(self, exc: Exception) -> None:
        text = f"lost the renderer: {one_line(exc)}"
        if self.lost != text:
            self.lost = text
            self.broadcast(error(text))

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
                    await self.refresh()
            except UserError as exc:
                self._lost(exc)
                await asyncio.sleep(1.0)

    async def refresh(self) -> dict[str, float]:
        """The set in force, read now; the pages hear of a change nobody here made."""
        (answer,) = await self.client.ask({"get": "params"})
        if not answer.get("ok"):
            raise UserError(f"the renderer refused: {answer.get('error', 'no reason given')}")
        now = {k: float(v) for k, v in answer["params"].items()}
        if now != self.params:
            self._push_undo(self.params)
            self.params, self.params_t = now, float(answer.get("t", 0.0))
            shown = self.visible(self.params)
            self.broadcast(
                {"type": "params", "params": shown, "t": self.params_t, "source": "push"}
            )
        return now

    # -- changes ---------------------------------------------------------------------
    def _push_undo(self, values: dict) -> None:
        self.undo.append(dict(values))
        del self.undo[:-UNDO_DEPTH]

    async def apply(self, values: dict, source: str, page: Page, undoable=True) -> bool:
        """Send a change; on success it is the set in force and every page hears it."""
        if not values:
            return True
        (answer,) = await self.client.ask({"set": values})
        if not answer.get("ok"):
            page.post(refused(answer.get("error", "no reason given"), values))
            return False
        if undoable:
            self._push_undo(self.params)
        new = dict(self.params)
        new.update({k: float(v) for k, v in answer.get("applied", values).items()})
        self.params, self.params_t = new, float(answer.get("t", self.params_t))
        shown = self.visible(self.params)
        self.broadcast({"type": "params", "params": shown, "t": self.params_t, "source": source})
        return True

    async def apply_set(self, target: dict, source: str, page: Page, undoable=True) -> bool:
        """Make ``target`` (a whole set) the set in force: sends what differs from the
        set in force now."""
        now = await self.refresh()
        diff = {k: v for k, v in target.items() if now.get(k) != v}
        return await self.apply(diff, source, page, undoable)

    async def event(self, kind: str, **fields) -> None:
        (answer,) = await self.client.ask({"event": {"kind": kind, **fields}})
        if not answer.get("ok"):
            self.broadcast(
                error(
                    f"the renderer did not record the {kind} event: "
                    f"{answer.get('error', 'no reason given')}"
                )
            )

    # -- page messages ----------------------------------------------------------------
    async def handle(self, page: Page, message, limits: ClientLimits | None = None) -> None:
        """Do what one page message asks; errors go back to that page on one line.
        ``limits``: the page's, for its rate per message type."""
        kind = message.get("type") if isinstance(message, dict) else None
        # a tuple's ``in``: a kind that is a list or an object is refused, not a TypeError
        action = ACTIONS[kind] if kind in PAGE_KINDS else None
        if action is None:
            shown = kind if isinstance(kind, str) and len(kind) <= MAX_ID else "?"
            page.post(error(f"unknown message type {shown!r}"))
            return
        reason = limits.check(kind) if limits is not None else None
        if reason is None and not self.actions_rate.take():
            reason = (
                f"more than {ACTIONS_PER_S:g} actions a second from all pages together: slow down"
            )
        if reason is None and kind in BLOCKED and self.jnd is not None and self.jnd.running:
            reason = f"a JND session is running: {kind} waits until it ends (or stop it)"
        if reason is not None:
            page.post(refused(reason, message.get("values")) if kind == "set" else error(reason))
            return
        try:
            async with self._actions:
                await action(self, page, message)
        except UserError as exc:
            page.post(error(exc))
        except OSError as exc:  # the file system said no (save)
            where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
            page.post(error(f"{where}{exc.strerror or exc}"))

    # -- the curve ---------------------------------------------------------------------
    async def curve(self) -> dict:
        """The force-angle curve of the set in force (cached per set)."""
        values, t = self.visible(dict(self.params)), self.params_t
        key = tuple(values[n] for n in self.tunable.table.names)
        if key not in self._curves:
            loop = asyncio.get_running_loop()
            self._curves[key] = await loop.run_in_executor(None, self.tunable.curve, values)
            while len(self._curves) > 16:
                self._curves.popitem(last=False)
        return {**self._curves[key], "params_t": t}
