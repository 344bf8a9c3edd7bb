"""Adaptive procedures, participants and the logic of a JND session, without a device.

A JND session is a series of two-interval forced-choice (2IFC) trials on one
parameter of a feel: each trial renders the reference set and a comparison set (the
parameter changed by a relative step) in random order; the participant says which
interval felt stronger. Three pieces, each usable alone:

- a **procedure** chooses each trial's step from the answers so far:
  :class:`Staircase`, a transformed up-down staircase (Levitt 1971), or
  :class:`Quest`, a Bayesian placement at the posterior mean of the threshold
  (Watson and Pelli 1983; the mean, as King-Smith et al. 1994 advise);
- a **participant** answers a :class:`Stimulus` with the interval, 1 or 2, that felt
  stronger: :class:`SimParticipant` by a psychometric function, a person through the
  terminal or the console;
- :class:`JndSession` orders the trials (a seeded random order), records every answer
  with its time, and fits the psychometric function at the end
  (:func:`~evo_door.perception.psychometric.fit_psychometric`).

The device (rendering each interval) is the renderer's part: ``evo_door.render.jnd``.

>>> s = JndSession("viscous_damping", "N s/rad", 2.0, "staircase", trials=60, seed=1,
...                upper=100.0)
>>> p = SimParticipant(0.2, seed=2)
>>> while not s.done:
...     stim = s.next_trial()
...     _ = s.record(p.answer(stim), time=0.0)
>>> fit = s.fit()
>>> 0.1 < fit.weber < 0.4 and fit.covers(0.2)
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from evo_door.errors import UserError
from evo_door.perception.psychometric import Fit, Psychometric, fit_psychometric, p_correct

METHODS = ("staircase", "quest")
#: the smallest step a session presents (1: 0.1 %)
MIN_STEP = 1e-3
#: the word a question uses for "more", by the parameter's unit
WORDS = {"N": "stronger", "N s/rad": "more damped", "kg m": "heavier", "N/rad": "stiffer"}


def word_for(unit: str) -> str:
    """The comparative a participant is asked about, for a parameter of ``unit``.

    >>> word_for("kg m"), word_for("N s/rad"), word_for("1")
    ('heavier', 'more damped', 'stronger')
    """
    return WORDS.get(unit, "stronger")


@dataclass(frozen=True)
class Stimulus:
    """One trial as presented.

    ``step`` is the comparison's relative change (1), ``order`` the interval (1 or 2)
    that holds the comparison; ``values`` the parameter's value (its unit) in
    interval 1 and interval 2.
    """

    index: int
    step: float
    reference: float
    comparison: float
    order: int

    @property
    def values(self) -> tuple[float, float]:
        if self.order == 1:
            return (self.comparison, self.reference)
        return (self.reference, self.comparison)


class Staircase:
    """A transformed up-down staircase (Levitt 1971) on the log of the step.

    After ``down`` correct answers in a row the step shrinks by ``factor``, after
    one wrong answer it grows by it; the staircase then hovers where P(correct)^down
    = 1/2 (2-down: 70.7 %, 3-down: 79.4 %). The factor starts at ``factor`` and is
    square-rooted at each reversal until it reaches ``min_factor``: large steps find
    the region quickly, small ones sample it closely.
    """

    name = "staircase"

    def __init__(
        self,
        start: float = 0.5,
        down: int = 3,
        factor: float = 2.0,
        min_factor: float = 2.0**0.25,
        max_step: float = 1.0,
    ):
        if not (start > 0.0 and factor > 1.0 and min_factor > 1.0 and down >= 1):
            raise UserError("staircase: start > 0, factors > 1 and down >= 1 expected")
        self.step = min(start, max_step)
        self.down = int(down)
        self.factor = float(factor)
        self.min_factor = float(min_factor)
        self.max_step = float(max_step)
        self.run = 0  # correct answers in a row
        self.direction = 0  # -1 shrinking, +1 growing, 0 none yet
        self.reversals: list[int] = []
        self._trials = 0

    def next_step(self) -> float:
        return self.step

    def update(self, step: float, correct: bool) -> None:
        self._trials += 1
        move = 0
        if correct:
            self.run += 1
            if self.run >= self.down:
                move, self.run = -1, 0
        else:
            move, self.run = 1, 0
        if move == 0:
            return
        if self.direction and move != self.direction:
            self.reversals.append(self._trials - 1)
            self.factor = max(math.sqrt(self.factor), self.min_factor)
        self.direction = move
        new = self.step * self.factor**move
        self.step = float(min(max(new, MIN_STEP), self.max_step))

    def state(self) -> dict:
        return {"step": self.step, "factor": self.factor, "reversals": list(self.reversals)}


class Quest:
    """Bayesian placement (QUEST, Watson and Pelli 1983) on a grid of Weber fractions.

    The prior is a normal density of ln(weber) around ``guess`` with ``sd`` (natural
    log units); each answer multiplies the posterior by its likelihood under a
    psychometric function of assumed ``slope`` and ``lapse``; the next step is
    exp(posterior mean of ln weber), the step told apart 75 % of the time by the
    current belief.
    """

    name = "quest"

    def __init__(
        self,
        guess: float = 0.2,
        sd: float = 1.2,
        slope: float = 0.4,
        lapse: float = 0.02,
        max_step: float = 1.0,
        grid: int = 400,
    ):
        if not (guess > 0.0 and sd > 0.0):
            raise UserError("quest: a guess and a prior spread above 0 expected")
        self.max_step = float(max_step)
        self.slope = float(slope)
        self.lapse = float(lapse)
        self.log_weber = np.linspace(math.log(MIN_STEP), math.log(10.0), grid)
        self.log_post = -0.5 * ((self.log_weber - math.log(guess)) / sd) ** 2

    def _posterior(self) -> np.ndarray:
        w = np.exp(self.log_post - self.log_post.max())
        return w / w.sum()

    def next_step(self) -> float:
        mean = float(np.sum(self._posterior() * self.log_weber))
        return float(min(max(math.exp(mean), MIN_STEP), self.max_step))

    def update(self, step: float, correct: bool) -> None:
        p = p_correct(step, np.exp(self.log_weber), self.slope, self.lapse)
        p = np.clip(p, 1e-12, 1.0 - 1e-12)
        self.log_post = self.log_post + np.log(p if correct else 1.0 - p)

    def state(self) -> dict:
        post = self._posterior()
        mean = float(np.sum(post * self.log_weber))
        sd = float(np.sqrt(np.sum(post * (self.log_weber - mean) ** 2)))
        return {"step": self.next_step(), "log_weber_mean": mean, "log_weber_sd": sd}


def make_procedure(method: str, start: float, max_step: float, guess: float | None = None):
    """The procedure named ``method`` ("staircase" or "quest") starting at step
    ``start`` (staircase) or guessing ``guess`` (quest; default start / 2), never
    above ``max_step``."""
    if method == "staircase":
        return Staircase(start=start, max_step=max_step)
    if method == "quest":
        return Quest(guess=guess or start / 2.0, max_step=max_step)
    raise UserError(f"method {method!r}: expected one of {', '.join(METHODS)}")


class SimParticipant:
    """A simulated participant: answers by a 2IFC psychometric function.

    It compares the parameter's values in the two intervals: the relative difference
    is the step, and it names the stronger interval with the probability the function
    gives (a wrong answer names the other one). Seeded: the same answers every run.
    """

    kind = "simulated"

    def __init__(self, weber: float, slope: float = 0.4, lapse: float = 0.02, seed=None):
        self.function = Psychometric(weber, slope, lapse)
        self.rng = np.random.default_rng(seed)

    @classmethod
    def from_spec(cls, spec: str, seed=None) -> SimParticipant:
        """From ``sim:WEBER[,SLOPE[,LAPSE]]`` (``--participant``).

        >>> SimParticipant.from_spec("sim:0.1,0.3").function
        Psychometric(weber=0.1, slope=0.3, lapse=0.02)
        """
        kind, _, rest = spec.partition(":")
        if kind != "sim" or not rest:
            raise UserError(
                f"participant {spec!r}: expected sim:WEBER[,SLOPE[,LAPSE]] (sim:0.1), "
                "or none for a person"
            )
        try:
            numbers = [float(v) for v in rest.split(",")]
        except ValueError:
            raise UserError(f"participant {spec!r}: WEBER, SLOPE and LAPSE are numbers") from None
        if len(numbers) > 3:
            raise UserError(f"participant {spec!r}: at most WEBER,SLOPE,LAPSE")
        given = dict(zip(("weber", "slope", "lapse"), numbers))
        return cls(**given, seed=seed)

    def describe(self) -> str:
        f = self.function
        return f"sim:{f.weber:g},{f.slope:g},{f.lapse:g}"

    def answer(self, stimulus: Stimulus) -> int:
        """The interval (1 or 2) that felt stronger."""
        a, b = stimulus.values
        stronger = 1 if a > b else 2
        lo, hi = min(abs(a), abs(b)), max(abs(a), abs(b))
        step = (hi / lo - 1.0) if lo > 0 else math.inf
        if step <= 0.0:
            return int(self.rng.integers(1, 3))
        right = self.rng.random() < float(self.function.p_correct(step))
        return stronger if right else 3 - stronger


def max_step_for(reference: float, upper: float | None) -> float:
    """The largest step that keeps the comparison within the parameter's upper bound."""
    if upper is None or not math.isfinite(upper):
        return 1.0
    return min(1.0, upper / reference - 1.0)


class JndSession:
    """The trials of one JND session, their answers and the fit (no device).

    ``param`` (of ``unit``) is compared at ``reference`` (> 0) against
    ``reference * (1 + step)``; ``method`` chooses the steps, ``trials`` ends the
    session, ``seed`` fixes the interval order. ``upper`` (the parameter's upper
    bound) caps the step.
    """

    def __init__(
        self,
        param: str,
        unit: str,
        reference: float,
        method: str = "staircase",
        trials: int = 80,
        seed=None,
        upper: float | None = None,
        start: float = 0.5,
    ):
        if not (math.isfinite(reference) and reference > 0.0):
            raise UserError(
                f"{param} reference {reference!r} {unit}: a Weber fraction needs a value "
                "above 0 (set --reference)"
            )
        if int(trials) < 10:
            raise UserError(f"trials {trials}: at least 10 for a psychometric fit")
        max_step = max_step_for(reference, upper)
        if max_step < 0.05:
            raise UserError(
                f"{param} reference {reference:g} {unit}: within 5 % of its upper bound "
                f"{upper:g} {unit}; no room for a comparison above it"
            )
        self.param, self.unit, self.reference = param, unit, float(reference)
        self.method, self.trials = method, int(trials)
        self.procedure = make_procedure(method, start, max_step)
        self.max_step = max_step
        self.rng = np.random.default_rng(seed)
        self.stimuli: list[Stimulus] = []
        self.answers: list[int] = []
        self.times: list[float] = []
        self._pending: Stimulus | None = None

    @property
    def done(self) -> bool:
        return len(self.answers) >= self.trials

    @property
    def word(self) -> str:
        return word_for(self.unit)

    def next_trial(self) -> Stimulus:
        """The next trial to present (the same one again until it is answered)."""
        if self.done:
            raise UserError("the session is complete: no more trials")
        if self._pending is None:
            step = float(self.procedure.next_step())
            order = int(self.rng.integers(1, 3))
            self._pending = Stimulus(
                len(self.answers), step, self.reference, self.reference * (1.0 + step), order
            )
        return self._pending

    def record(self, answer: int, time: float) -> bool:
        """The answer (1 or 2) to the pending trial, at ``time`` (s); True if correct."""
        if self._pending is None:
            raise UserError("no trial is waiting for an answer")
        if answer not in (1, 2):
            raise UserError(f"answer {answer!r}: 1 or 2 (the interval that felt {self.word})")
        stim, self._pending = self._pending, None
        correct = answer == stim.order
        self.stimuli.append(stim)
        self.answers.append(int(answer))
        self.times.append(float(time))
        self.procedure.update(stim.step, correct)
        return correct

    def table(self) -> dict[str, np.ndarray]:
        """Every answered trial as columns: step (1), comparison (unit), order,
        answer, correct, time (s)."""
        return {
            "step": np.array([s.step for s in self.stimuli], dtype=float),
            "comparison": np.array([s.comparison for s in self.stimuli], dtype=float),
            "order": np.array([s.order for s in self.stimuli], dtype=np.int8),
            "answer": np.array(self.answers, dtype=np.int8),
            "correct": np.array(
                [a == s.order for a, s in zip(self.answers, self.stimuli)], dtype=bool
            ),
            "time": np.array(self.times, dtype=float),
        }

    def fit(self) -> Fit:
        t = self.table()
        return fit_psychometric(t["step"], t["correct"])


def run_simulated(session: JndSession, participant) -> Fit:
    """Every trial of ``session`` answered by ``participant`` with no device (the
    planning benchmark and tests); returns the fit."""
    while not session.done:
        session.record(participant.answer(session.next_trial()), time=float(len(session.answers)))
    return session.fit()
