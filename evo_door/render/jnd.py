"""A JND session on a device: the two intervals of each trial rendered by the servo loop.

:class:`~evo_door.perception.procedures.JndSession` decides each trial (the step, which
interval holds the comparison) and records the answers; this module renders it. Each
trial is five phases, timed on the loop's clock (simulated time on an unpaced
simulated device, the wall clock otherwise), the same as in the console's JND mode:

1. **pause**: the participant lets go, for ``pause`` seconds;
2. **interval 1**: the set of interval 1 (the reference set or the comparison set),
   for ``interval`` seconds;
3. **pause**: the participant lets go again;
4. **interval 2**: the set of interval 2, for ``interval`` seconds;
5. **question**: until the participant answers which interval felt stronger (the word
   is the parameter's: :func:`~evo_door.perception.procedures.word_for`).

The **neutral pause** is, by default, one in which nobody holds the handle: the next
interval's set comes into force during it, so the participant never feels a switch
(a switch felt would itself be a cue). With a neutral set (``--neutral P``:
:func:`neutral_values`) the pauses and the question render that set instead, a
washout between the intervals, and each interval's set comes into force as the
interval starts.

Every switch goes through :meth:`ServoLoop.request_change
<evo_door.render.loop.ServoLoop.request_change>`, the loop's checked change (the
declaration's bounds, passivity at the loop period), as a **ramp**: ``ramp_steps``
changes spread over the first ``ramp`` seconds of its phase, each a linear blend of
the set before and the set after (the loop applies a change whole between two
cycles; the ramp keeps a large switch from being felt as a jolt, itself a cue). A
change the loop refuses ends the session (status ``refused``) with every answer so
far kept. The schedule runs in the loop's own thread (:attr:`ServoLoop.on_cycle`),
never blocking it: a participant is asked (:meth:`ask`) and then polled each cycle
(:meth:`poll`), and on a paced loop the changes are validated in a thread of their
own (a check takes 0.1 ms, a quarter of a 2500 Hz period; on an unpaced simulated
device they are made in the cycle, so a session's log is the same every run). The
watchdog, the force limit and a real device's supervisor work exactly as in
``evo-door render``.

Every switch and every answer is an event of the render log (kinds
:data:`EVENT_KINDS`), so a log kept with the session is its full record.

Participants: :class:`Immediate` puts any object with ``answer(stimulus) -> 1 | 2``
(:class:`~evo_door.perception.procedures.SimParticipant`) behind the polled
interface; :class:`TerminalPerson` asks a person at the terminal (keys 1 and 2, q
stops).
"""

from __future__ import annotations

import math
import os
import queue
import select
import sys
import threading
from dataclasses import dataclass

from evo_door.errors import UserError
from evo_door.models.haptic import PARAMS
from evo_door.render.device import UserScript, _min_jerk

#: the event kinds a JND session adds to the render log
EVENT_KINDS = ("jnd_start", "jnd_switch", "jnd_answer", "jnd_end")
#: what :meth:`poll` returns when the participant stops the session
STOP = "stop"
#: the parameter group a neutral set takes from the model's defaults (or --neutral)
NEUTRAL_GROUP = "sensation"


@dataclass(frozen=True)
class JndTiming:
    """The timing of a trial (s): each interval, the neutral pause between them, and
    the ramp of every switch (``ramp_steps`` checked changes over ``ramp`` s; a ramp
    of 0 switches in one change)."""

    interval: float = 2.0
    pause: float = 1.0
    ramp: float = 0.2
    ramp_steps: int = 8

    def __post_init__(self):
        if not (math.isfinite(self.interval) and 0.05 <= self.interval <= 60.0):
            raise UserError(f"--interval {self.interval:g}: must be in 0.05..60 s")
        if not (math.isfinite(self.pause) and 0.0 <= self.pause <= 60.0):
            raise UserError(f"--pause {self.pause:g}: must be in 0..60 s")
        if not (math.isfinite(self.ramp) and 0.0 <= self.ramp <= min(self.interval, 1.0) / 2):
            raise UserError(
                f"--ramp {self.ramp:g}: must be in 0..{min(self.interval, 1.0) / 2:g} s "
                "(half the interval, 0.5 s at most)"
            )
        if not 1 <= self.ramp_steps <= 100:
            raise UserError(f"ramp steps {self.ramp_steps}: must be in 1..100")

    @property
    def steps(self) -> int:
        return self.ramp_steps if self.ramp > 0.0 else 1


def neutral_values(reference, neutral=None) -> dict[str, float]:
    """The neutral set of the pauses, as ``{name: value}`` over the whole model.

    The reference set (a haptic ParamSet) with every parameter of the
    :data:`NEUTRAL_GROUP` group ("sensation") taken from ``neutral`` (another
    ParamSet: ``--neutral P``) or, without it, the model's declared defaults. The
    device, specification and numerics parameters stay the reference's: the handle's
    circle and the end stops do not move between intervals.
    """
    values = reference.as_dict()
    source = neutral.as_dict() if neutral is not None else PARAMS.as_dict(PARAMS.defaults)
    for p in PARAMS:
        if p.group == NEUTRAL_GROUP:
            values[p.name] = float(source[p.name])
    return values


@dataclass(frozen=True)
class SwingUser(UserScript):
    """The simulated device's user in a JND session: swings the door from
    ``theta_start`` to ``theta_end`` and back every ``period`` s, for as long as the
    session lasts (a scripted :class:`~evo_door.render.device.UserScript` ends)."""

    period: float = 2.0

    def target(self, t: float, grab: tuple | None = None) -> float:
        s = (max(t - self.t_begin, 0.0) % self.period) / self.period
        a, b = self.theta_start, self.theta_end
        return _min_jerk(a, b, 2.0 * s) if s < 0.5 else _min_jerk(b, a, 2.0 * s - 1.0)


def swing_user(interval: float) -> SwingUser:
    """A user swinging 20 -> 69 deg and back once per ``interval`` s (0.5 s at least)."""
    return SwingUser("jnd-swing", 0.35, 1.2, t_begin=0.0, period=max(float(interval), 0.5))


class Immediate:
    """A participant that answers at once (``answer(stimulus) -> 1 | 2``, such as
    :class:`~evo_door.perception.procedures.SimParticipant`), polled like a person."""

    blind = False  # a simulated participant sees nothing: the progress may say all

    def __init__(self, participant):
        self.participant = participant
        self._reply = None

    def ask(self, stimulus, word: str) -> None:
        self._reply = self.participant.answer(stimulus)

    def poll(self):
        reply, self._reply = self._reply, None
        return reply

    def cue(self, text: str) -> None:
        """A simulated participant needs no cue."""

    def describe(self) -> str:
        return self.participant.describe()

    def close(self) -> None:
        """Nothing to release."""


class TerminalPerson:
    """A person answering at the terminal: keys ``1`` and ``2`` (the interval that
    felt stronger), ``q`` stops the session.

    A reader thread takes the keys from ``stream`` (stdin by default; one key at a
    time on a terminal, in cbreak mode) as they come; ``1`` or ``2`` counts only
    while a question is open (a key pressed during the intervals is no answer),
    ``q`` at any time. The cues (which interval is playing) and the question go to
    ``out`` (stderr), never whether an answer was right: blind.
    """

    blind = True

    def __init__(self, who: str = "", stream=None, out=None):
        self.who = who
        self.stream = stream if stream is not None else sys.stdin
        self.out = out if out is not None else sys.stderr
        self._question = threading.Event()
        self._reply: int | str | None = None
        self._closed = threading.Event()
        self._saved = None
        self._fd = self.stream.fileno()
        if os.isatty(self._fd):
            import termios
            import tty

            self._saved = termios.tcgetattr(self._fd)
            tty.setcbreak(self._fd)
        self._thread = threading.Thread(target=self._read, name="evo-door-jnd-keys", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._closed.is_set():
            ready, _, _ = select.select([self._fd], [], [], 0.1)
            if not ready:
                continue
            key = os.read(self._fd, 1).decode(errors="replace")
            if key == "":  # end of input: nobody left to answer
                self._reply = STOP
                return
            if key.lower() == "q":
                self._reply = STOP
            elif key in "12" and self._question.is_set():
                self._question.clear()
                self._reply = int(key)

    def ask(self, stimulus, word: str) -> None:
        self.cue(f"Which interval felt {word}: 1 or 2? (q stops)")
        self._question.set()

    def poll(self):
        reply = self._reply
        if reply is not None:
            self._reply = None
        return reply

    def cue(self, text: str) -> None:
        print(text, file=self.out, flush=True)

    def describe(self) -> str:
        return f"person {self.who}".strip() if self.who else "a person at the terminal"

    def close(self) -> None:
        self._closed.set()
        self._thread.join(timeout=1.0)
        if self._saved is not None:
            import termios

            termios.tcsetattr(self._fd, termios.TCSADRAIN, self._saved)
            self._saved = None


@dataclass
class Outcome:
    """How a session on a device ended: ``status`` complete, stopped (Ctrl-C, q),
    refused (a change the loop refused: ``message`` says why), watchdog or failed
    (the loop's own ending), and the loop's statistics."""

    status: str
    message: str
    statistics: dict


class JndSchedule:
    """The phases of a session's trials, run from the loop's ``on_cycle`` hook.

    ``reference`` is ``{name: value}`` over the model, and ``neutral`` too or None
    (the pauses are let-go pauses: see the module docstring); the comparison set is
    the reference with ``session.param`` at the stimulus's value. ``progress(text)``
    is told each answered trial (without the step and whether it was right for a
    blind participant).
    """

    #: the phases of a trial, in order
    PHASES = ("pause", "interval 1", "pause", "interval 2", "question")

    def __init__(self, loop, session, participant, reference, neutral, timing, stop, progress):
        self.loop = loop
        self.session = session
        self.participant = participant
        self.reference = dict(reference)
        self.neutral = None if neutral is None else dict(neutral)
        self.timing = timing
        self.stop = stop
        self.progress = progress
        self.status = ""
        self.message = ""
        self._names = [p.name for p in PARAMS]
        # the set the last change asked for: the loop starts in the neutral set, or
        # (let-go pauses) in the reference set
        self._current = dict(self.neutral if self.neutral is not None else self.reference)
        self._phase = -1  # index in PHASES
        self._phase_end = -math.inf  # loop time the phase ends (question: its ramp ends)
        self._ramp: tuple = ()  # (t0, from, to, changes done)
        self._stimulus = None
        self._refused = ""  # a change the worker's check refused (paced loops)
        self._queue: queue.SimpleQueue | None = None
        self._worker: threading.Thread | None = None
        if self.neutral is None and timing.ramp > timing.pause:
            raise UserError(
                f"--pause {timing.pause:g}: the next interval's set comes in during the "
                f"pause, which must last its ramp ({timing.ramp:g} s) at least"
            )
        if loop.realtime:
            self._queue = queue.SimpleQueue()
            self._worker = threading.Thread(
                target=self._validate, name="evo-door-jnd-changes", daemon=True
            )
            self._worker.start()

    def _validate(self) -> None:
        """The worker of a paced loop: each change checked by the loop, in order."""
        assert self._queue is not None
        while (values := self._queue.get()) is not None:
            if self._refused:
                continue  # the session is ending: nothing more to change
            try:
                self.loop.request_change(values)
            except UserError as exc:
                self._refused = str(exc)

    def close(self) -> None:
        """Stop the worker (after the loop ended)."""
        if self._queue is not None and self._worker is not None:
            self._queue.put(None)
            self._worker.join(timeout=5.0)

    def _request(self, values: dict) -> None:
        if self._queue is None:
            self.loop.request_change(values)
        else:
            self._queue.put(values)

    # -- the hook ---------------------------------------------------------------------
    def tick(self, t: float) -> None:
        """One cycle at loop time ``t`` (s): the ramp's next change, the next phase."""
        if self.status:
            return
        if self._refused:
            self._finish(t, "refused", self._refused)
            return
        try:
            self._step_ramp(t)
            if t < self._phase_end:
                return
            if self._phase == len(self.PHASES) - 1 and not self._answered(t):
                return
            if self.status:
                return
            self._next_phase(t)
        except UserError as exc:  # a change refused: the session ends, answers kept
            self._finish(t, "refused", str(exc))

    def _answered(self, t: float) -> bool:
        reply = self.participant.poll()
        if reply is None:
            return False
        if reply == STOP:
            self._finish(t, "stopped", "stopped by the participant")
            return True
        stim = self._stimulus
        correct = self.session.record(reply, t)
        n = len(self.session.answers)
        self.loop.log.event(
            t,
            "jnd_answer",
            f"trial {n}: interval {reply} felt {self.session.word}",
            trial=n,
            answer=int(reply),
            order=stim.order,
            step=stim.step,
            comparison=stim.comparison,
            correct=bool(correct),
        )
        if self.participant.blind:
            self.progress(f"trial {n}/{self.session.trials} answered")
        else:
            mark = "right" if correct else "wrong"
            self.progress(f"trial {n}/{self.session.trials}: step {100 * stim.step:.3g} %, {mark}")
        if self.session.done:
            self._finish(t, "complete", f"{n} trials answered")
        return True

    def _interval_set(self, interval: int) -> dict:
        """The set of interval 1 or 2 of the current trial."""
        value = self._stimulus.values[interval - 1]
        return {**self.reference, self.session.param: value}

    def _next_phase(self, t: float) -> None:
        """Start the next phase at loop time ``t``: its switch (if any), its event, its
        end; a new trial's stimulus at the first pause, the question at the last."""
        timing = self.timing
        self._phase = (self._phase + 1) % len(self.PHASES)
        phase = self.PHASES[self._phase]
        if self._phase == 0:
            self._stimulus = self.session.next_trial()
        stim = self._stimulus
        trial = len(self.session.answers) + 1
        details: dict = {}
        if phase == "pause":
            if self.neutral is not None:
                self._switch(t, self.neutral)
            else:  # let go: the next interval's set comes in now
                self._switch(t, self._interval_set(1 if self._phase == 0 else 2))
            self._phase_end = t + timing.pause
            text = f"trial {trial}: pause" + (" (neutral set)" if self.neutral else " (let go)")
        elif phase == "question":
            if self.neutral is not None:
                self._switch(t, self.neutral)
            self._phase_end = t + (timing.ramp if self.neutral is not None else 0.0)
            self.participant.ask(stim, self.session.word)
            text = f"trial {trial}: question"
        else:
            interval = 1 if phase == "interval 1" else 2
            target = self._interval_set(interval)
            if self.neutral is not None:
                self._switch(t, target)
            holds = "comparison" if interval == stim.order else "reference"
            details = {"holds": holds, "value": target[self.session.param]}
            self.participant.cue(f"trial {trial}: interval {interval}")
            self._phase_end = t + timing.interval
            text = f"trial {trial}: interval {interval} ({holds})"
        self.loop.log.event(t, "jnd_switch", text, trial=trial, phase=phase, **details)

    # -- switches ---------------------------------------------------------------------
    def _switch(self, t: float, target: dict) -> None:
        """Start the ramp from the set in force to ``target``; its first change now."""
        self._ramp = (t, dict(self._current), dict(target), 0)
        self._step_ramp(t)

    def _step_ramp(self, t: float) -> None:
        """The ramp's changes due by ``t``: change k of n at t0 + k ramp / n, the blend
        (k + 1) / n of the way (the last one is the target itself)."""
        if not self._ramp:
            return
        t0, start, end, done = self._ramp
        n = self.timing.steps
        while done < n and t >= t0 + done * self.timing.ramp / n:
            w = (done + 1) / n
            values = {
                k: end[k] if done + 1 == n else start[k] + w * (end[k] - start[k])
                for k in self._names
                if end[k] != start[k]
            }
            changed = {k: v for k, v in values.items() if v != self._current[k]}
            if changed:
                self._request(changed)
                self._current.update(changed)
            done += 1
        self._ramp = (t0, start, end, done) if done < n else ()

    def _finish(self, t: float, status: str, message: str) -> None:
        self.status, self.message = status, message
        self.loop.log.event(
            t,
            "jnd_end",
            f"JND session {status}: {message}",
            status=status,
            param=self.session.param,
            answers=len(self.session.answers),
        )
        self.stop.set()


def run_session(
    loop, session, participant, reference: dict, neutral: dict, timing: JndTiming, stop, progress
) -> Outcome:
    """Render ``session`` on ``loop``'s device until it is complete, the participant
    stops it, a change is refused or ``stop`` is set (Ctrl-C); every answer so far
    stays in ``session``. The loop starts from the set it holds (the neutral one)."""
    schedule = JndSchedule(loop, session, participant, reference, neutral, timing, stop, progress)
    loop.log.event(
        0.0,
        "jnd_start",
        f"JND session: {session.param} at {session.reference:g} {session.unit}, "
        f"{session.method}, {session.trials} trials, {participant.describe()}",
        param=session.param,
        unit=session.unit,
        reference=session.reference,
        method=session.method,
        trials=session.trials,
        participant=participant.describe(),
        interval_s=timing.interval,
        pause_s=timing.pause,
        ramp_s=timing.ramp,
    )
    loop.on_cycle = schedule.tick
    try:
        stats = loop.run(stop=stop)
    finally:
        loop.on_cycle = None
        schedule.close()
    status, message = schedule.status, schedule.message
    if not status:  # the loop ended on its own: Ctrl-C, or the watchdog
        status = "stopped" if stats.get("status") == "stopped" else stats.get("status", "failed")
        message = "stopped by the operator" if status == "stopped" else stats.get("watchdog", "")
        loop.log.event(
            loop.snapshot()["t"],
            "jnd_end",
            f"JND session {status}: {message}",
            status=status,
            param=session.param,
            answers=len(session.answers),
        )
    return Outcome(status, message, stats)
