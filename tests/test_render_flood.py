"""A flood of valid parameter changes: the log keeps a bounded record of them.

A client at the control port's allowed rate (400 requests a second) changed the set
24,001 times in a minute: the log grew by 30 MiB and the loop missed 428 cycles. Past
:data:`~evo_door.render.log.MAX_PARAM_SETS` a change still comes into force, and the
log (and its side file) counts it and keeps the set in force at each choice and at the
end.
"""

from __future__ import annotations

import json
import socket
import time

import numpy as np
import pytest

from evo_door.files import open_h5, read_attrs
from evo_door.models.haptic import PARAMS
from evo_door.render import log as render_log
from evo_door.render.check import render_agreement
from evo_door.render.columns import N_COLUMNS
from evo_door.render.log import MAX_PARAM_SETS, RenderLog, recover
from evo_door.render.session import format_session, read_session, session_params
from evo_door.render.spill import SPILL_ROWS, read_partial
from tests.helpers import answer_lines, served_loop

TOKEN = "s3cret"


@pytest.fixture
def served(seed_trial):
    """A ServoLoop on the simulated device in its own thread, its control server, and
    the stop that ends it."""
    with served_loop(seed_trial, TOKEN) as running:
        yield running


def _request(message: dict) -> bytes:
    return (json.dumps({"token": TOKEN, **message}) + "\n").encode()


def test_a_flood_of_valid_changes_keeps_the_cap_and_the_sets_that_matter(
    served, monkeypatch, tmp_path
):
    """80 valid changes past a cap of 20 sets: every one comes into force and is answered
    ok; the log keeps 20 sets, the one in force at the participant's choice and the one
    at the end, and says how many it did not keep."""
    monkeypatch.setattr(render_log, "MAX_PARAM_SETS", 20)
    loop, server, end = served
    values = [6.0 + 0.02 * i for i in range(80)]
    sets = [_request({"set": {"friction_closing": v}}) for v in values]
    chosen = _request({"event": {"kind": "chosen"}})
    with socket.create_connection(server.address, timeout=30) as sock:
        sock.sendall(b"".join(sets[:50]) + chosen + b"".join(sets[50:]))
        answers = answer_lines(sock, 81)
    assert len(answers) == 81 and all(a["ok"] for a in answers), answers[-1]
    assert all(a["in_force"] for a in answers[:50] + answers[51:])
    assert loop.params["friction_closing"] == values[-1]  # the tuning goes on
    end()
    log = loop.log
    assert len(log.param_sets) == 20 + 1  # the cap, and the set the choice was made on
    path = tmp_path / "flood.h5"
    loop.write_log(path)  # the set in force at the end is kept
    s = read_session(path)
    i = PARAMS.index("friction_closing")
    kept = [v[i] for v in log.param_sets]
    assert kept[1:20] == values[:19] and kept[20:] == [values[49], values[79]]
    assert [v["friction_closing"] for _, v in s["sets"]] == kept
    assert len(s["changes"]) == 19 and s["changes_not_kept"] == 61
    assert s["chosen"]["friction_closing"] == values[49]
    assert session_params(path)[0]["friction_closing"] == values[49]
    with open_h5(path) as f:
        events = read_attrs(f["render"])["events"]
    (dropped,) = [e for e in events if e["kind"] == "changes_dropped"]
    assert dropped["count"] == 61 and dropped["t"] < dropped["last_t"]
    assert s["not_kept_span"] == [dropped["t"], dropped["last_t"]]
    text = format_session(s, path)
    assert "80 parameter changes" in text
    assert "61 of the changes not kept in the log (past its cap of sets)" in text
    # render-check leaves out the span where the log does not know the set in force
    a = render_agreement(path)
    gap = (a.t >= dropped["t"] + 1e-9) & (a.t < dropped["last_t"] - 1e-9)
    assert gap.any() and np.isnan(a.theta_sim[gap]).all()
    assert np.isfinite(a.theta_sim[a.t < dropped["t"] - 1e-9]).any()
    assert "did not keep the sets in force" in a.model


def _changes(log: RenderLog, vectors: np.ndarray, t0: float = 0.0) -> None:
    """The loop's record of each change: its set, and its change event when kept."""
    for k, v in enumerate(vectors):
        t = t0 + 0.001 * k
        if log.params(t, v):
            log.event(t, "change", "parameters changed", values={"friction_closing": v[0]})


def _flooded_log(path, n_sets: int) -> RenderLog:
    log = RenderLog(1000.0, PARAMS)
    for k in range(3000):
        log.add(k * 0.0004, np.full(N_COLUMNS, float(k)))
    _changes(log, np.random.default_rng(5).uniform(1.0, 2.0, (n_sets, len(PARAMS))))
    log.write(path, loop_rate=2500.0, device="sim", statistics={})
    return log


def test_the_written_log_stays_bounded_past_the_cap(tmp_path):
    """Three times the cap of sets (random values: nothing to compress) writes a log the
    size of one with the cap's; the last set in force is its last."""
    capped, flooded = tmp_path / "capped.h5", tmp_path / "flooded.h5"
    _flooded_log(capped, MAX_PARAM_SETS)
    log = _flooded_log(flooded, 3 * MAX_PARAM_SETS)
    assert log.changes_dropped == 2 * MAX_PARAM_SETS
    assert flooded.stat().st_size < capped.stat().st_size + 16 * 2**10
    with open_h5(flooded) as f:
        values = f["render/params/values"][()]
    assert values.shape == (MAX_PARAM_SETS + 1, len(PARAMS))
    np.testing.assert_array_equal(values[-1], log.param_sets[-1])
    last = np.random.default_rng(5).uniform(1.0, 2.0, (3 * MAX_PARAM_SETS, len(PARAMS)))[-1]
    np.testing.assert_array_equal(values[-1], last)
    s = read_session(flooded)
    assert s["changes_not_kept"] == 2 * MAX_PARAM_SETS
    assert session_params(flooded)[0] == dict(zip(PARAMS.names, last.tolist(), strict=True))


def test_the_side_file_keeps_the_same_record_and_recovers_it(tmp_path, monkeypatch):
    """The side file holds the capped sets, the counts as they are last (not as they
    were when their event was first written) and the set held back: a crash recovers the
    sets and counts a clean stop writes."""
    monkeypatch.setattr(render_log, "MAX_PARAM_SETS", 30)
    monkeypatch.setattr(render_log, "MAX_CLIENT_EVENTS", 3)
    out = tmp_path / "l.h5"
    log = RenderLog(1000.0, PARAMS)
    vectors = np.random.default_rng(2).uniform(1.0, 2.0, (100, len(PARAMS)))
    log.params(0.0, vectors[0])
    side = log.spill_to(out, loop_rate=2500.0, device="sim")
    k = 0

    def cycles(m):
        nonlocal k
        for _ in range(m):
            log.add(k * 0.0004, np.full(N_COLUMNS, float(k)))
            k += 1

    for i in range(1, 100):
        cycles(300)  # 120 rows: the side file takes them every 8 or 9 changes
        t = k * 0.0004
        log.params(t, vectors[i])
        if i == 60:
            assert log.client_event(t, "chosen", "session: chosen", params={})
        if i % 10 == 0:
            log.client_event(t, "note", "session: note", text=str(i))
    cycles(int(2.5 * SPILL_ROWS * 2.5))  # the side file catches up
    deadline = time.monotonic() + 10.0
    while log._spill.written < log._spill.rows:  # until the writer has caught up
        assert time.monotonic() < deadline
        time.sleep(0.01)
    # not closed: as a crash leaves it
    _, _, events, times, sets = read_partial(side)
    assert len(times) == 30 + 2  # the cap, the set chosen, the set held back at the end
    np.testing.assert_array_equal(sets, vectors[[*range(30), 60, 99]])
    counted = {e["kind"]: e["count"] for e in events if "count" in e}
    assert counted == {"changes_dropped": 70, "dropped": 6}
    recovered = recover(side, tmp_path / "r.h5")
    log.write(out, loop_rate=2500.0, device="sim", statistics={})
    both = []
    for path in (recovered, out):
        with open_h5(path) as f:
            kept = [e for e in read_attrs(f["render"])["events"] if e["kind"] != "recovered"]
            both.append((f["render/params/t"][()], f["render/params/values"][()], kept))
    (t_r, v_r, e_r), (t_w, v_w, e_w) = both
    np.testing.assert_array_equal(t_r, t_w)
    np.testing.assert_array_equal(v_r, v_w)
    assert e_r == e_w
