"""A participant's session in the render log: events over the control port, the
session record, `evo-door show` of it, and the chosen set as a parameter set and as
the target of the case study's specification stage."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from evo_door.cli import main
from evo_door.errors import UserError
from evo_door.models import get_model
from evo_door.render.columns import THETA
from evo_door.render.control import ControlServer, request
from evo_door.render.device import SimDevice
from evo_door.render.loop import ServoLoop
from evo_door.render.session import read_session, session_params
from tests.helpers import yielding_sim


def _session(seed_trial, path, choose=True):
    """A scripted session over the control port while the loop runs in its thread."""
    loop = ServoLoop(yielding_sim("hold", seed=1), seed_trial)
    stop = threading.Event()
    thread = threading.Thread(target=loop.run, kwargs={"stop": stop}, daemon=True)
    with ControlServer(loop, "127.0.0.1", 0) as server:
        host, port = server.address
        thread.start()

        def ask(message):
            answer = request(host, port, message)
            time.sleep(0.02)
            return answer

        assert ask({"event": {"kind": "participant", "id": "P07"}})["ok"]
        a = {"friction_closing": 4.0}
        assert ask({"set": a})["ok"]
        assert ask({"event": {"kind": "ab_store", "slot": "A", "params": a}})["ok"]
        assert ask({"set": {"friction_closing": 6.0, "open_force": 15.0}})["ok"]
        assert ask({"event": {"kind": "ab_choice", "slot": "B"}})["ok"]
        if choose:
            assert ask({"event": {"kind": "chosen", "params": {"viscous_damping": 0.5}}})["ok"]
        refused = request(host, port, {"event": {"kind": "chosen", "params": {"inertia": 99.0}}})
        assert not refused["ok"] and "outside" in refused["error"]
        assert not request(host, port, {"event": {"kind": "party"}})["ok"]
        stop.set()
        thread.join(10.0)
    loop.write_log(path)
    return loop


def test_the_session_record_holds_the_participant_choices_and_chosen_set(seed_trial, tmp_path):
    log = tmp_path / "s.h5"
    loop = _session(seed_trial, log)
    s = read_session(log)
    assert s["participant"] == "P07"
    assert [c["slot"] for c in s["choices"]] == ["B"]
    # the chosen set: the set in force when chosen, with the value the event gave
    expected = {**loop.params.as_dict(), "viscous_damping": 0.5}
    assert s["chosen"] == pytest.approx(expected)
    choice = next(e for e in s["events"] if e["kind"] == "ab_choice")
    assert 0.0 < choice["t"] < s["chosen_t"] < s["duration_s"] + 0.01
    # every set in force, time-stamped at a cycle
    times = [t for t, _ in s["sets"]]
    assert len(times) == 3 and np.allclose(np.array(times) * 2500, np.round(np.array(times) * 2500))
    # the parameter-set loader takes the log: the chosen set
    ps = get_model("haptic").load_params(str(log))
    assert ps["viscous_damping"] == 0.5 and ps["open_force"] == 15.0
    assert "chosen of participant P07" in session_params(log)[1]


def test_without_a_choice_the_log_stands_for_its_last_set(seed_trial, tmp_path, capsys):
    log = tmp_path / "n.h5"
    _session(seed_trial, log, choose=False)
    ps = get_model("haptic").load_params(str(log))
    assert ps["friction_closing"] == 6.0 and ps["viscous_damping"] == seed_trial["viscous_damping"]
    assert main(["show", str(log)]) == 0
    out = capsys.readouterr().out
    assert "participant P07" in out and "prefers B" in out and "no final choice" in out
    assert "friction_closing" in out and "open_force" in out


def test_show_summarises_a_session_and_refuses_results_options(seed_trial, tmp_path, capsys):
    log = tmp_path / "s.h5"
    _session(seed_trial, log)
    assert main(["show", str(log)]) == 0
    out = capsys.readouterr().out
    assert "chosen at" in out and "viscous_damping" in out
    assert main(["show", str(log), "--stage", "x"]) == 2
    with pytest.raises(UserError, match="not one of 'door'"):
        get_model("door").load_params(str(log))


def test_rows_and_health_over_the_control_port(seed_trial):
    loop = ServoLoop(SimDevice("open", seed=1), seed_trial)
    loop.run(0.5)  # 500 log rows
    with ControlServer(loop, "127.0.0.1", 0) as server:
        host, port = server.address
        first = request(host, port, {"get": "rows", "since": 0})
        assert len(first["rows"]) == 50 and first["next"] == 500
        a = loop.log.array()
        np.testing.assert_allclose(np.array(first["rows"])[:, 1], a[::10, THETA])
        again = request(host, port, {"get": "rows", "since": first["next"]})
        assert again["rows"] == [] and again["next"] == 500
        # off the 10-row grid: from the next row on it
        assert request(host, port, {"get": "rows", "since": 3})["rows"][0][0] == 0.01
        assert not request(host, port, {"get": "rows", "since": -1})["ok"]
        health = request(host, port, {"get": "health"})
        assert health["ok"] and health["cycles_run"] == 1250 and health["status"] == "done"


def test_a_session_is_the_target_of_the_specification_stage(seed_trial, tmp_path):
    """The case study's stage 3 with the participant's chosen set as the feel."""
    log = tmp_path / "session.h5"
    _session(seed_trial, log)
    exp = tmp_path / "spec.yaml"
    exp.write_text(
        "name: from-session\nmodel: door\nparams: default\n"
        "target:\n  model: haptic\n  params: session.h5\n"
        "  inputs: {model: door, params: default, users: 1, trials: 3, seed: 3}\n"
        "free: {K: [200.0, 800.0], F_load: [40.0, 160.0], unlock_force: [10.0, 80.0]}\n"
        "objective: {kind: ise, derivative: 1}\n"
        "algorithm: {population: 8, generations: 2, seed: 1}\n"
    )
    out = tmp_path / "run.h5"
    assert main(["run", str(exp), "--out", str(out), "--quiet"]) == 0
    assert main(["show", str(out)]) == 0


def test_rows_come_in_bounded_answers(seed_trial):
    from evo_door.render.control import MAX_ROWS, ROWS_EVERY

    loop = ServoLoop(SimDevice("hold", seed=1), seed_trial)
    loop.run(3.0)  # 3000 log rows: 300 at 100 Hz
    with ControlServer(loop, "127.0.0.1", 0) as server:
        host, port = server.address
        first = request(host, port, {"get": "rows", "since": 0})
        assert len(first["rows"]) == MAX_ROWS and first["next"] == MAX_ROWS * ROWS_EVERY
        got, since = list(first["rows"]), first["next"]
        while since < 3000:  # ask again from "next" until the end: every row once
            more = request(host, port, {"get": "rows", "since": since})
            assert 0 < len(more["rows"]) <= MAX_ROWS
            got += more["rows"]
            since = more["next"]
        assert len(got) == 300 and since == 3000
        np.testing.assert_allclose([r[0] for r in got], np.arange(300) * ROWS_EVERY / 1000.0)
