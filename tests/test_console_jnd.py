"""The console's JND session mode, server side, against a real renderer (no browser).

The renderer is a ServoLoop on the simulated device with its control port; the console
runs in a thread (the fixtures of tests/test_console_server.py). A simulated
participant answers each trial from the values the renderer actually had in force in
interval 1 and interval 2 (read from the loop, not from the page's messages).
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest

pytest.importorskip("aiohttp")

from evo_door.errors import UserError  # noqa: E402
from evo_door.perception.jnd_file import read_jnd_file  # noqa: E402
from evo_door.perception.procedures import SimParticipant  # noqa: E402
from evo_door.render.console.jnd_mode import parse_settings  # noqa: E402
from tests import test_console_server as base  # noqa: E402
from tests.helpers import ServedConsole  # noqa: E402
from tests.test_console_server import _next, _page, _session  # noqa: E402

# the renderer and the console of the server's tests
renderer = base.renderer
console = base.console

PARAM = "friction_closing"  # N; seed_trial: 1.5 N


class _Stimulus:
    def __init__(self, values):
        self.values = values


def _events(loop, prefix="jnd_"):
    return [e for e in loop.log.events if str(e.get("kind", "")).startswith(prefix)]


async def _until_phase(ws, phase, seen, timeout=10.0):
    """Read messages until a jnd_phase ``phase``; keep every message in ``seen``."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        assert left > 0, f"no phase {phase!r} within {timeout} s"
        try:
            msg = await ws.receive_json(timeout=left)
        except TimeoutError:
            shown = [m for m in seen if m["type"] != "tick"][-5:]
            raise AssertionError(f"no phase {phase!r} within {timeout} s; last: {shown}") from None
        seen.append(msg)
        if msg["type"] == "jnd_phase" and msg["phase"] == phase:
            return msg
        if msg["type"] == "jnd" and msg["status"] != "running":
            return msg


def test_settings_are_checked_with_one_line_reasons():
    now = {PARAM: 1.5, "viscous_damping": 0.2}
    s = parse_settings({"param": PARAM, "seed": 3}, now)
    assert (s.reference, s.unit, s.method, s.trials, s.blind) == (1.5, "N", "staircase", 40, True)
    assert (s.interval_s, s.pause_s) == (2.0, 1.0)
    assert parse_settings({"param": PARAM}, now).seed >= 0  # drawn, so the file records it
    bad = {
        "friction_closin": "did you mean friction_closing",
        "k_radial": "not a sensation parameter",
    }
    for param, reason in bad.items():
        with pytest.raises(UserError, match=reason):
            parse_settings({"param": param}, now)
    for extra, reason in (
        ({"method": "bisect"}, "staircase, quest"),
        ({"trials": 5}, "from 10 to 400"),
        ({"trials": 20.5}, "whole number"),
        ({"interval_s": 0.0}, "interval_s 0 s: must be from 0.05 to 30 s"),
        ({"pause_s": "1"}, "pause_s '1'"),
        ({"reference": 500.0}, "reference 500 N: must be from 0 to 100 N"),
        ({"seed": -1}, "seed -1"),
        ({"blind": "yes"}, "blind"),
    ):
        with pytest.raises(UserError, match=reason):
            parse_settings({"param": PARAM, **extra}, now)


@pytest.mark.slow
def test_a_session_plays_each_interval_on_the_renderer_and_records_every_answer(console, renderer):
    """10 trials of 50 ms intervals: each trial's two sets come into force on the
    renderer in the order the log's jnd_trial says, the answers (a simulated
    participant's, from what was in force) are events, the pages stay blind until the
    end, the fit and the JND file follow and the starting set comes back."""
    loop, _ = renderer
    start = loop.params.as_dict()
    participant = SimParticipant(0.15, seed=4)
    felt: list[tuple[float, float]] = []

    async def scenario(session):
        seen: list[dict] = []
        async with _page(console, session) as ws:
            await _next(ws, "hello")
            await ws.send_json({"type": "participant", "id": "P09"})
            await _next(ws, "participant")
            await ws.send_json(
                {"type": "jnd_start", "param": PARAM, "trials": 10, "seed": 7}
                | {"interval_s": 0.05, "pause_s": 0.05, "method": "quest"}
            )
            first = await _next(ws, "jnd")
            assert first["status"] == "running" and first["blind"] is True
            # an answer before the intervals are played is refused, and so is a set
            await ws.send_json({"type": "jnd_answer", "answer": 1})
            assert "no trial is waiting" in (await _next(ws, "error"))["error"]
            await ws.send_json({"type": "set", "values": {PARAM: 9.0}})
            assert "JND session is running" in (await _next(ws, "refused"))["error"]
            await ws.send_json({"type": "jnd_start", "param": PARAM})
            assert "stop it first" in (await _next(ws, "error"))["error"]
            while True:
                msg = await _until_phase(ws, "1", seen)
                if msg["type"] == "jnd":
                    break
                v1 = loop.params[PARAM]
                await _until_phase(ws, "2", seen)
                v2 = loop.params[PARAM]
                await _until_phase(ws, "answer", seen)
                felt.append((v1, v2))
                answer = participant.answer(_Stimulus((v1, v2)))
                if len(felt) == 1:
                    await ws.send_json({"type": "jnd_answer", "answer": 3})
                    assert "1 or 2" in (await _next(ws, "error"))["error"]
                await ws.send_json({"type": "jnd_answer", "answer": answer})
        return seen, msg

    seen, end = _session(scenario)

    assert end["status"] == "complete" and end["trial"] == 10
    # blind: no message told the page the step, the order, the correctness, or a value
    # of the parameter other than the reference, before the end
    for msg in seen:
        if msg["type"] == "jnd" and msg["status"] == "running":
            assert msg["fit"] is None and all(set(t) == {"answer"} for t in msg["track"])
        if msg["type"] == "params":  # the last one, the starting set back: 1.5 too
            assert msg["params"][PARAM] == 1.5, msg
        assert "step" not in msg and "order" not in msg
    assert len(end["track"]) == 10 and all("step" in t and "correct" in t for t in end["track"])
    fit = end["fit"]
    assert fit["ci95"][0] <= fit["weber"] <= fit["ci95"][1]
    assert fit["jnd"] == pytest.approx(fit["weber"] * 1.5)
    assert len(fit["curve"]["step"]) == len(fit["curve"]["p_correct"]) == 80
    # the set the session started from is back, on the renderer and on the pages
    assert loop.params.as_dict() == start
    # the log: start, each presentation with the values the renderer had, each answer
    events = _events(loop)
    kinds = [e["kind"] for e in events]
    assert kinds == ["jnd_start"] + ["jnd_trial", "jnd_answer"] * 10 + ["jnd_end", "jnd_save"]
    assert events[0]["param"] == PARAM and events[0]["blind"] is True
    trials = [e for e in events if e["kind"] == "jnd_trial"]
    answers = [e for e in events if e["kind"] == "jnd_answer"]
    for k, (trial, answer, values) in enumerate(zip(trials, answers, felt)):
        assert trial["trial"] == answer["trial"] == k
        assert tuple(trial["values"]) == pytest.approx(values)
        reference_at = 2 if trial["order"] == 1 else 1
        assert values[reference_at - 1] == 1.5
        assert values[trial["order"] - 1] == pytest.approx(1.5 * (1 + trial["step"]))
        assert answer["correct"] == (answer["answer"] == trial["order"])
        assert (answer["step"], answer["order"]) == (trial["step"], trial["order"])
    # the JND file, in the console's folder
    path = Path(end["path"])
    assert path.parent == Path(console.server.console.save_dir).resolve()
    assert path.name == "jnd-friction_closing-P09.h5"
    assert events[-1]["path"] == str(path)
    record = read_jnd_file(path)
    assert record.complete and record.participant == "P09" and record.method == "quest"
    assert record.fit.weber == pytest.approx(fit["weber"])
    assert record.trials["answer"].tolist() == [a["answer"] for a in answers]
    assert record.reference_params[PARAM] == 1.5
    assert record.attrs["seed"] == 7  # (the versions: evo-door console passes them)


def test_stop_ends_a_session_and_puts_the_starting_set_back(console, renderer, tmp_path):
    loop, _ = renderer
    start = loop.params.as_dict()

    async def scenario(session):
        async with _page(console, session) as ws:
            await ws.send_json({"type": "jnd_stop"})
            nothing = await _next(ws, "error")
            await ws.send_json({"type": "jnd_answer", "answer": 1})
            no_session = await _next(ws, "error")
            await ws.send_json(
                {"type": "jnd_start", "param": "viscous_damping", "trials": 10, "blind": False}
                | {"interval_s": 0.3, "pause_s": 0.05, "reference": 2.0}
            )
            await _next(ws, "jnd")
            phase = await _next(ws, "jnd_phase")
            while phase["phase"] != "1":
                phase = await _next(ws, "jnd_phase")
            during = loop.params["viscous_damping"]
            await ws.send_json({"type": "jnd_stop"})
            end = await _next(ws, "jnd")
            while end["status"] == "running":
                end = await _next(ws, "jnd")
            await asyncio.sleep(0.1)
            return nothing, no_session, during, end

    nothing, no_session, during, end = _session(scenario)
    assert "no JND session is running" in nothing["error"]
    assert "start one first" in no_session["error"]
    assert during in (2.0, 2.0 * 1.5)  # the staircase's first step: 50 %
    assert end["status"] == "stopped" and end["track"] == [] and end["path"] == ""
    assert loop.params.as_dict() == start
    kinds = [e["kind"] for e in _events(loop)]
    assert kinds == ["jnd_start", "jnd_trial", "jnd_end"]  # no answer: no file
    assert _events(loop, "jnd_end")[0]["status"] == "stopped"
    assert not list(tmp_path.glob("*.h5"))


def test_a_console_shut_down_mid_session_writes_what_was_answered(renderer, tmp_path):
    """Closing the console while a session runs (its process told to stop) loses no
    answer: the session ends "stopped", its file holds every answer so far, and the
    starting set is back in force on the renderer."""
    from evo_door.render.console.server import ConsoleServer

    loop, control = renderer
    start = loop.params.as_dict()
    served = ServedConsole(ConsoleServer(control.address, base.TOKEN, "127.0.0.1", 0, tmp_path))
    closed = False
    try:

        async def scenario(session):
            seen: list[dict] = []
            async with _page(served, session) as ws:
                await ws.send_json(
                    {"type": "jnd_start", "param": PARAM, "trials": 20, "seed": 2}
                    | {"interval_s": 0.05, "pause_s": 0.05, "blind": False}
                )
                for _ in range(3):
                    await _until_phase(ws, "answer", seen)
                    await ws.send_json({"type": "jnd_answer", "answer": 1})
                await _until_phase(ws, "1", seen)  # the fourth trial is playing

        _session(scenario)
        served.close()
        closed = True
    finally:
        if not closed:
            served.close()
    (path,) = tmp_path.glob("jnd-*.h5")
    record = read_jnd_file(path)
    assert record.status == "stopped" and record.trials["answer"].tolist() == [1, 1, 1]
    assert record.fit is None  # 3 answers: too few to fit, kept all the same
    assert _events(loop, "jnd_end")[-1]["status"] == "stopped"
    assert loop.params.as_dict() == start
