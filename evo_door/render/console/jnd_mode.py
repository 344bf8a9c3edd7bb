"""The console's JND session mode: two-interval forced-choice trials on one sensation
parameter, played on the renderer through the console's checked changes and answered
on the page.

The operator starts a session from the page (``jnd_start``: parameter, reference,
method, trials, seed, interval and pause durations, blind). For each trial of a
:class:`~evo_door.perception.procedures.JndSession` the console plays::

    pause  (let go)   the set of interval 1 comes into force while nobody holds the door
    1                 held for the interval's duration
    pause  (let go)   the set of interval 2 comes into force
    2                 held for the interval's duration
    answer            the page asks "Which felt {word}?"; 1 or 2 (button or key)

The **neutral pause** is a pause in which the participant lets go of the handle; the
set does not go back to a third, neutral one: the next interval's set is switched in
at its start, so every change of set happens while the door is not held, and the
participant never feels a switch (a step of force under the hand would tell the
intervals apart by itself). Every switch is a control-port ``set``, checked by the
renderer (bounds, passivity) like any other change; a refused one ends the session.

Blind (the default): while the session runs, the pages are never told which interval
holds the comparison, its step, nor whether an answer was right, and the parameter's
value in force is shown to them as the reference (:meth:`JndRun.visible`); the
operator may turn it off at the start. At the end the console fits the psychometric
function, sends the track and the fit to the pages, writes the JND file in its save
folder (``jnd-PARAM-PARTICIPANT.h5``, never over another file) and puts the set the
session started from back in force.

Sessions are the haptic model's (a declaration with a ``sensation`` group): a console
rendering a mechanism refuses ``jnd_start`` in one line.

Render-log events: ``jnd_start`` (the settings), ``jnd_trial`` (each presentation:
trial, step, order, the values of interval 1 and 2), ``jnd_answer`` (trial, answer,
correct, step, order, time), ``jnd_end`` (status and fit) and ``jnd_save`` (the file).
"""

from __future__ import annotations

import asyncio
import contextlib
import difflib
import math
import secrets
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING

from evo_door.errors import UserError
from evo_door.perception.jnd_file import curve_points, write_jnd_file
from evo_door.perception.procedures import METHODS, JndSession
from evo_door.perception.psychometric import Fit
from evo_door.render.console.client import cancel_and_wait
from evo_door.render.console.page import error
from evo_door.render.console.saving import safe_stem, unused_path
from evo_door.render.console.sensations import Tunable

if TYPE_CHECKING:
    from evo_door.render.console.page import Page
    from evo_door.render.console.session import Console

#: default durations of an interval and of a pause (s)
INTERVAL_S = 2.0
PAUSE_S = 1.0
#: the durations a page may ask for (s)
DURATION_RANGE = (0.05, 30.0)
#: the trials a session may have
TRIALS_RANGE = (10, 400)
#: points of the fitted function sent to the pages
CURVE_POINTS = 80
#: the page messages refused while a session runs: they would change the set in force
#: (or record it) under the participant's hand
BLOCKED = ("set", "undo", "reset", "ab_store", "ab_switch", "choose")


@dataclass(frozen=True)
class JndSettings:
    """A session's settings, checked (:func:`parse_settings`); SI units."""

    param: str
    unit: str
    reference: float
    method: str
    trials: int
    seed: int
    interval_s: float
    pause_s: float
    blind: bool


def _number(message: dict, key: str, default, lo: float, hi: float, unit: str) -> float:
    value = message.get(key, default)
    if value is None:
        value = default
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise UserError(f"{key} {value!r}: a number from {lo:g} to {hi:g} {unit}".rstrip())
    if not lo <= value <= hi:
        raise UserError(f"{key} {value:g} {unit}: must be from {lo:g} to {hi:g} {unit}")
    return float(value)


def parse_settings(
    message: dict, params: dict[str, float], tunable: Tunable | None = None
) -> JndSettings:
    """The settings of a ``jnd_start`` message, checked against the declaration of
    ``tunable`` (default: the haptic model's); ``params`` is the set in force (the
    default reference)."""
    if tunable is None:
        from evo_door.models import get_model

        tunable = Tunable(get_model("haptic"))
    names = tunable.names
    param = message.get("param")
    if not isinstance(param, str) or param not in names:
        shown = param if isinstance(param, str) and len(param) <= 64 else "?"
        close = difflib.get_close_matches(shown, names, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise UserError(f"param {shown!r}: not a sensation parameter of the declaration{hint}")
    p = tunable.table[param]
    reference = message.get("reference")
    if reference is None:
        reference = params.get(param, p.default)
    reference = _number({"reference": reference}, "reference", None, p.lower, p.upper, p.unit)
    method = message.get("method", "staircase")
    if method not in METHODS:
        raise UserError(f"method {method!r}: expected one of {', '.join(METHODS)}")
    lo, hi = TRIALS_RANGE
    trials = message.get("trials", 40)
    if isinstance(trials, bool) or not isinstance(trials, int) or not lo <= trials <= hi:
        raise UserError(f"trials {trials!r}: a whole number from {lo} to {hi}")
    seed = message.get("seed")
    if seed is None:
        seed = secrets.randbelow(2**31)  # drawn here so that the file records it
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise UserError(f"seed {seed!r}: a whole number from 0, or none for a random one")
    blind = message.get("blind", True)
    if not isinstance(blind, bool):
        raise UserError('"blind" must be true or false')
    return JndSettings(
        param=param,
        unit=p.unit,
        reference=reference,
        method=str(method),
        trials=int(trials),
        seed=int(seed),
        interval_s=_number(message, "interval_s", INTERVAL_S, *DURATION_RANGE, "s"),
        pause_s=_number(message, "pause_s", PAUSE_S, *DURATION_RANGE, "s"),
        blind=blind,
    )


class JndRun:
    """One JND session in the console: its trials (:class:`JndSession`), the phase
    being played, the task that plays it, and what the pages may see of it."""

    def __init__(self, console: Console, settings: JndSettings, page: Page):
        self.console = console
        self.settings = settings
        self.page = page  # the operator's: told of refusals
        s = settings
        self.session = JndSession(
            s.param,
            s.unit,
            s.reference,
            s.method,
            trials=s.trials,
            seed=s.seed,
            upper=console.tunable.table[s.param].upper,
        )
        self.base = dict(console.params)  # put back in force at the end
        self.participant = console.participant
        self.phase = "pause"
        self.status = "running"
        self.fit: Fit | None = None
        self.path = ""
        self.started = time.monotonic()
        self.created = datetime.now(UTC).isoformat(timespec="seconds")
        self.task: asyncio.Task | None = None
        self._answered: asyncio.Event = asyncio.Event()

    # -- what the pages see ------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self.status == "running"

    @property
    def hidden(self) -> bool:
        """Whether the pages are kept blind now (a blind session still running)."""
        return self.settings.blind and self.running

    def visible(self, params: dict[str, float]) -> dict[str, float]:
        """``params`` as the pages may see them: blind, the parameter at its reference."""
        if not self.hidden:
            return params
        return {**params, self.settings.param: self.settings.reference}

    def track(self) -> list[dict]:
        """The answered trials; blind and running, the answers only."""
        t = self.session
        if self.hidden:
            return [{"answer": a} for a in t.answers]
        return [
            {"step": s.step, "order": s.order, "answer": a, "correct": a == s.order}
            for s, a in zip(t.stimuli, t.answers)
        ]

    def state(self) -> dict:
        """A ``jnd`` message: the session as the pages may see it."""
        s = self.settings
        out = {
            "type": "jnd",
            "status": self.status,
            "phase": self.phase,
            "trial": len(self.session.answers),
            **asdict(s),
            "word": self.session.word,
            "participant": self.participant,
            "track": self.track(),
            "fit": None,
            "path": self.path,
        }
        if self.fit is not None and not self.hidden:
            f = self.fit
            x, p = curve_points([st.step for st in self.session.stimuli], f, CURVE_POINTS)
            out["fit"] = {
                **f.as_dict(),
                "jnd": f.weber * s.reference,
                "curve": {"step": x.tolist(), "p_correct": p.tolist()},
            }
        return out

    def _tell(self) -> None:
        self.console.broadcast(self.state())

    def _enter(self, phase: str) -> None:
        self.phase = phase
        self.console.broadcast(
            {"type": "jnd_phase", "phase": phase, "trial": len(self.session.answers)}
        )

    # -- playing ------------------------------------------------------------------------
    def start(self) -> None:
        self.task = asyncio.get_running_loop().create_task(self._play())
        self.task.add_done_callback(self._ended)

    def _ended(self, task: asyncio.Task) -> None:
        """A task that failed says why on the pages (a bug: nothing else would)."""
        if not task.cancelled() and task.exception() is not None:
            exc = task.exception()
            self.status, self.phase = "aborted", "aborted"
            self.console.broadcast(error(f"JND session failed: {type(exc).__name__}: {exc}"))
            self._tell()

    async def _switch(self, value: float) -> None:
        """The reference set with the parameter at ``value`` into force (checked)."""
        target = {**self.base, self.settings.param: value}
        async with self.console.action_lock:
            ok = await self.console.apply_set(target, "jnd", self.page, undoable=False)
        if not ok:
            raise UserError(
                f"the renderer refused {self.settings.param} = {value:g} {self.settings.unit}"
            )

    async def _play(self) -> None:
        s = self.settings
        try:
            while not self.session.done:
                stim = self.session.next_trial()
                await self.console.event(
                    "jnd_trial",
                    trial=stim.index,
                    step=stim.step,
                    order=stim.order,
                    values=list(stim.values),
                    unit=s.unit,
                )
                for interval, value in enumerate(stim.values, start=1):
                    self._enter("pause")
                    await self._switch(value)
                    await asyncio.sleep(s.pause_s)
                    self._enter(str(interval))
                    await asyncio.sleep(s.interval_s)
                self._answered.clear()
                self._enter("answer")
                await self._answered.wait()
            self._enter("fitting")
            loop = asyncio.get_running_loop()
            self.fit = await loop.run_in_executor(None, self.session.fit)
            async with self.console.action_lock:
                await self.finish("complete")
        except (UserError, OSError) as exc:
            self.console.broadcast(error(f"JND session ended: {exc}"))
            async with self.console.action_lock:
                await self.finish("aborted")

    async def answer(self, answer) -> bool:
        """The participant's answer (1 or 2) to the trial waiting for one; True if right."""
        if not self.running or self.phase != "answer":
            raise UserError(
                f"no trial is waiting for an answer: answer after interval 2 (now: {self.phase})"
            )
        if isinstance(answer, bool) or answer not in (1, 2):
            raise UserError(
                f"answer {answer!r}: 1 or 2 (the interval that felt {self.session.word})"
            )
        stim = self.session.next_trial()
        t = time.monotonic() - self.started
        correct = self.session.record(int(answer), time=t)
        await self.console.event(
            "jnd_answer",
            trial=stim.index,
            answer=int(answer),
            correct=bool(correct),
            step=stim.step,
            order=stim.order,
            time_s=t,
        )
        self.phase = "answered"
        self._answered.set()
        self._tell()
        return correct

    async def finish(self, status: str) -> None:
        """End the session (the caller holds the console's action lock): the fit
        (``complete``; a stopped session's when it has enough answers), the end event,
        the file, and the starting set back in force."""
        if not self.running:
            return
        self.status = status
        self.phase = {"complete": "done"}.get(status, status)
        if self.fit is None and len(self.session.answers) >= TRIALS_RANGE[0]:
            loop = asyncio.get_running_loop()
            self.fit = await loop.run_in_executor(None, self.session.fit)
        f = self.fit
        with contextlib.suppress(UserError, OSError):  # a renderer gone: the file still
            await self.console.event(
                "jnd_end",
                status=status,
                param=self.settings.param,
                answers=len(self.session.answers),
                weber=f.weber if f else None,
                ci95=list(f.ci95) if f else None,
                slope=f.slope if f else None,
                lapse=f.lapse if f else None,
            )
        try:
            if self.session.answers:
                await self._save()
        except (UserError, OSError) as exc:  # the session stays on the page and in the log
            filename = getattr(exc, "filename", None)
            where = f"{filename}: " if filename else ""
            text = getattr(exc, "strerror", None) or exc
            self.console.broadcast(error(f"the JND file was not written: {where}{text}"))
        try:
            await self.console.apply_set(self.base, "jnd", self.page, undoable=False)
        finally:
            self._tell()

    async def _save(self) -> None:
        """The session as a JND file in the console's save folder (a name of its own)."""
        from evo_door.files import check_folder

        console, s = self.console, self.settings
        folder = console.save_dir.resolve()
        check_folder(folder / "x.h5")
        stem = safe_stem(f"jnd-{s.param}-{self.participant or 'anonymous'}")
        path = unused_path(folder, stem, ".h5")
        reference_params = {**self.base, s.param: s.reference}

        def write() -> None:
            write_jnd_file(
                path,
                self.session,
                self.fit,
                status=self.status,
                participant=self.participant or "anonymous",
                device=f"renderer at {console.client.where} (evo-door console)",
                model=console.tunable.table.model,
                reference_params=reference_params,
                settings={**asdict(s), "neutral": "pause: let go, next set switched in"},
                seed=s.seed,
                created=self.created,
                wall_s=time.monotonic() - self.started,
                versions=console.versions,
            )

        try:
            await asyncio.get_running_loop().run_in_executor(None, write)
        except BaseException:
            path.unlink(missing_ok=True)
            raise
        self.path = str(path)
        with contextlib.suppress(UserError, OSError):  # written: the event is a record
            await console.event("jnd_save", path=self.path)

    async def stop(self) -> None:
        """The operator's stop (the caller holds the action lock)."""
        if self.task is not None:
            await cancel_and_wait(self.task)
        await self.finish("stopped")


# -- page messages ---------------------------------------------------------------------
async def on_jnd_start(console: Console, page: Page, message: dict) -> None:
    if console.jnd is not None and console.jnd.running:
        raise UserError("a JND session is running: stop it first")
    if not console.tunable.sensations:
        raise UserError(
            f"JND sessions compare the haptic model's sensations; the renderer renders "
            f"{console.tunable.table.model!r}: compare its sets with A/B instead"
        )
    settings = parse_settings(message, await console.refresh(), console.tunable)
    run = JndRun(console, settings, page)
    console.jnd = run
    await console.event(
        "jnd_start",
        **asdict(settings),
        word=run.session.word,
        participant=run.participant,
        neutral="pause: the participant lets go; the next set comes into force",
    )
    run._tell()
    run.start()


async def on_jnd_answer(console: Console, page: Page, message: dict) -> None:
    if console.jnd is None:
        raise UserError("no JND session: start one first")
    await console.jnd.answer(message.get("answer"))


async def on_jnd_stop(console: Console, page: Page, message: dict) -> None:
    if console.jnd is None or not console.jnd.running:
        raise UserError("no JND session is running")
    await console.jnd.stop()
