"""The renderer's control port, `evo-door push` and the key map of the terminal UI."""

from __future__ import annotations

import json
import socket
import threading
import time

import pytest

from evo_door.cli import main
from evo_door.errors import UserError
from evo_door.models.haptic import PARAMS
from evo_door.render.columns import DTHETA, THETA
from evo_door.render.control import ControlServer, parse_control, request
from evo_door.render.device import SimDevice
from evo_door.render.keys import KEY_PAIRS, key_change, key_map, nice_step
from evo_door.render.loop import ServoLoop
from evo_door.render.session import format_session, read_session, session_params
from tests.helpers import answer_lines, served_loop, yielding_sim


@pytest.fixture
def running(seed_trial):
    """A ServoLoop on the simulated device in its own thread, with its control server."""
    with served_loop(seed_trial, "s3cret") as (loop, server, _end):
        yield loop, server


def _ask(server, message, token="s3cret"):
    host, port = server.address
    return request(host, port, {"token": token, **message} if token else message)


def test_pushed_change_is_applied_between_cycles_and_logged(running, seed_trial):
    loop, server = running
    old = seed_trial["friction_closing"]
    answer = _ask(server, {"set": {"friction_closing": 7.5, "viscous_damping": 0.4}})
    assert answer["ok"], answer
    assert answer["applied"] == {"friction_closing": 7.5, "viscous_damping": 0.4}
    assert answer["in_force"]
    assert loop.params["friction_closing"] == 7.5
    assert _ask(server, {"get": "params"})["params"]["viscous_damping"] == 0.4
    # the log's parameter history: the first set, then the change, at a cycle boundary
    times, sets = loop.log.param_times, loop.log.param_sets
    assert len(times) == 2 and times[0] == 0.0
    i = PARAMS.index("friction_closing")
    assert sets[0][i] == old and sets[1][i] == 7.5
    cycles = times[1] / loop.period
    assert cycles == pytest.approx(round(cycles), abs=1e-6) and cycles >= 1
    assert any(e["kind"] == "change" and e["t"] == times[1] for e in loop.log.events)
    state = _ask(server, {"get": "state"})
    assert state["ok"] and state["status"] == "running"
    assert 0.0 <= state["theta"] <= 1.6 and len(state["command"]) == 3


@pytest.mark.parametrize(
    "change, reason",
    [
        ({"friction_closing": 500.0}, "outside its declared range"),
        ({"k_radial": 100000.0}, "not passive"),
        ({"friction_closing": 9.0, "k_radial": 100000.0}, "not passive"),
        ({"no_such_thing": 1.0}, "no_such_thing"),
        ({"friction_closing": "a lot"}, "not a number"),
    ],
)
def test_refused_change_leaves_the_set_and_says_why(running, change, reason):
    loop, server = running
    before = loop.params.as_dict()
    answer = _ask(server, {"set": change})
    assert not answer["ok"]
    assert reason in answer["error"] and "\n" not in answer["error"]
    time.sleep(0.02)  # cycles run: nothing pending comes into force
    assert loop.params.as_dict() == before
    assert loop._pending is None
    assert len(loop.log.param_times) == 1


def test_wrong_or_missing_token_is_refused(running):
    loop, server = running
    before = loop.params.as_dict()
    for token in ("guess", None):
        answer = _ask(server, {"set": {"friction_closing": 8.0}}, token=token)
        assert answer == {"ok": False, "error": "missing or wrong token"}
        assert not _ask(server, {"get": "params"}, token=token)["ok"]
    assert loop.params.as_dict() == before


def test_garbage_and_batched_lines_on_one_connection(running):
    """Bad lines get a one-line error and the connection goes on; answers keep order."""
    _, server = running
    with socket.create_connection(server.address, timeout=5) as sock:
        sock.sendall(b'not json\n{"token": "s3cret", "get": "params"}\n{"token": "s3cret"}\n')
        data = b""
        while data.count(b"\n") < 3:
            data += sock.recv(65536)
    first, second, third = (json.loads(x) for x in data.splitlines())
    assert not first["ok"] and "JSON" in first["error"]
    assert second["ok"] and "friction_closing" in second["params"]
    assert not third["ok"] and "expected" in third["error"]


def test_non_loopback_bind_requires_a_token(seed_trial):
    loop = ServoLoop(SimDevice("hold"), seed_trial)
    with pytest.raises(UserError, match="requires --token"):
        ControlServer(loop, "0.0.0.0", 0)
    server = ControlServer(loop, "127.0.0.1", 0)  # loopback: no token needed
    assert server.address[0] == "127.0.0.1"
    server.close()


def test_render_cli_refuses_open_control_port_without_token(capsys):
    args = ["render", "--params", "seed_trial", "--user", "open", "--duration", "0.01"]
    assert main([*args, "--control", "0.0.0.0:0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("evo-door: error:") and "--token" in err and "\n" not in err


def test_render_cli_serves_the_control_port(capsys, tmp_path):
    args = ["render", "--params", "seed_trial", "--user", "hold", "--duration", "0.05"]
    assert main([*args, "--control", "0", "--log", str(tmp_path / "l.h5")]) == 0
    assert "control port 127.0.0.1:" in capsys.readouterr().out


def test_parse_control():
    assert parse_control("7700") == ("127.0.0.1", 7700)
    assert parse_control("0.0.0.0:81") == ("0.0.0.0", 81)
    assert parse_control("[::1]:81") == ("::1", 81)
    with pytest.raises(UserError):
        parse_control("host:port")
    with pytest.raises(UserError):
        parse_control("70000")


# -- evo-door push ---------------------------------------------------------------------
def test_push_cli_sends_only_what_differs(running, capsys, tmp_path, seed_trial):
    loop, server = running
    to = "{}:{}".format(*server.address)
    path = tmp_path / "p.yaml"
    seed_trial.replace({"open_force": 25.0}).to_yaml(path)
    assert main(["push", str(path), "--to", to, "--token", "s3cret"]) == 0
    out = capsys.readouterr().out
    assert "1 value(s) in force" in out and "open_force = 25 N" in out
    assert loop.params["open_force"] == 25.0
    assert main(["push", str(path), "--to", to, "--token", "s3cret"]) == 0
    assert "nothing to push" in capsys.readouterr().out
    assert main(["push", "--set", "loose_angle=0.01", "--to", to, "--token", "s3cret"]) == 0
    assert "loose_angle = 0.01 rad (0.573 deg)" in capsys.readouterr().out


def test_push_logs_only_the_changes_it_made(seed_trial, tmp_path, capsys):
    """The device renders k_plane and c_plane itself, so the loop zeroes them in the
    force it computes; the log took that vector for the set in force, and every push
    showed them dropping to zero (and a log used as a set lost them). It holds the
    set in force, whole."""
    loop = ServoLoop(yielding_sim("open", radius=seed_trial["radius"], seed=3), seed_trial)
    assert seed_trial["k_plane"] > 0 and seed_trial["c_plane"] > 0  # or this tests nothing
    stop = threading.Event()
    thread = threading.Thread(target=loop.run, kwargs={"stop": stop}, daemon=True)
    pushed = tmp_path / "p.yaml"
    seed_trial.replace({"open_force": 25.0}).to_yaml(pushed)  # the whole set, one value new
    with ControlServer(loop, "127.0.0.1", 0) as server:
        thread.start()
        deadline = time.monotonic() + 10.0
        while loop.log.n < 10 and time.monotonic() < deadline:
            time.sleep(0.001)
        assert main(["push", str(pushed), "--to", "{}:{}".format(*server.address)]) == 0
        stop.set()
        thread.join(10.0)
    assert "1 value(s) in force" in capsys.readouterr().out
    log = tmp_path / "l.h5"
    loop.write_log(log)
    s = read_session(log)
    (_, start), (_, after) = s["sets"]
    assert start == seed_trial.as_dict()
    assert [n for n in start if after[n] != start[n]] == ["open_force"]
    assert [c["values"] for c in s["changes"]] == [{"open_force": 25.0}]
    summary = format_session(s)
    assert "differs from the starting set in 1 parameters" in summary, summary
    assert "k_plane" not in summary and "c_plane" not in summary
    assert session_params(log)[0] == seed_trial.replace({"open_force": 25.0}).as_dict()


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("evo-door: error:")
    return err


def test_push_cli_one_line_errors(running, capsys, tmp_path):
    loop, server = running
    to = "{}:{}".format(*server.address)
    before = loop.params.as_dict()
    # refused by the renderer, with its reason
    assert main(["push", "--set", "k_radial=100000", "--to", to, "--token", "s3cret"]) == 2
    err = _one_line_error(capsys)
    assert "the renderer refused" in err and "not passive" in err
    assert main(["push", "--set", "open_force=20", "--to", to, "--token", "nope"]) == 2
    assert "wrong token" in _one_line_error(capsys)
    # checked before sending
    assert main(["push", "--set", "open_force=900", "--to", to]) == 2
    assert "declared range" in _one_line_error(capsys)
    assert main(["push", str(tmp_path / "missing.yaml"), "--to", to]) == 2
    _one_line_error(capsys)
    bad = tmp_path / "bad.yaml"
    bad.write_text("model: haptic\nvalues: [1, 2\n")
    assert main(["push", str(bad), "--to", to]) == 2
    _one_line_error(capsys)
    assert main(["push", "--to", to]) == 2
    _one_line_error(capsys)
    assert loop.params.as_dict() == before
    # unreachable: a port nobody listens on
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        free = s.getsockname()[1]
    assert main(["push", "--set", "open_force=20", "--to", f"127.0.0.1:{free}"]) == 2
    assert "cannot reach the renderer" in _one_line_error(capsys)


# -- the key map -----------------------------------------------------------------------
def test_key_map_covers_every_sensation_with_two_keys():
    keys = key_map()
    sensations = [p.name for p in PARAMS if p.group == "sensation"]
    assert len(keys) == 2 * len(sensations)
    assert "q" not in keys and "Q" not in keys
    for (down_key, up_key), name in zip(KEY_PAIRS, sensations):
        (n_down, down), (n_up, up) = keys[down_key], keys[up_key]
        assert n_down == n_up == name and down == -up
        span = PARAMS[name].upper - PARAMS[name].lower
        assert span / 50 <= up <= span / 20 * (1 + 1e-12)  # 2 % .. 5 % of the range
    assert {n for n, _ in keys.values()} == set(sensations)


def test_key_change_steps_and_stops_on_the_bounds(seed_trial):
    values = seed_trial.as_dict()
    keys = key_map()
    assert key_change("B", values, keys) == {"friction_closing": values["friction_closing"] + 5}
    assert key_change("b", values, keys) == {
        "friction_closing": max(values["friction_closing"] - 5, 0)
    }
    assert key_change("q", values, keys) is None and key_change("?", values, keys) is None
    top = dict(values, inertia=PARAMS["inertia"].upper)
    assert key_change("A", top, keys) is None
    low = dict(values, inertia=PARAMS["inertia"].lower + 0.1)
    assert key_change("a", low, keys) == {"inertia": PARAMS["inertia"].lower}
    # every key's change passes the declaration
    for key in keys:
        change = key_change(key, values, keys)
        if change is not None:
            seed_trial.replace(change)


def test_key_change_goes_through_the_loop(seed_trial):
    loop = ServoLoop(SimDevice("hold"), seed_trial)
    change = key_change("P", loop.params.as_dict())  # P: the 15th sensation, up
    name = next(iter(change))
    new = loop.request_change(change)
    assert new[name] == change[name]


def test_nice_step():
    assert nice_step(100.0) == 5.0 and nice_step(1000.0) == 50.0
    assert nice_step(0.2) == 0.01 and nice_step(19.95) == 0.5 and nice_step(0.1) == 0.005
    assert nice_step(0.0) == 0.0


# -- the loop's public view and concurrent changes ----------------------------------
def test_concurrent_changes_from_two_operators_are_all_kept(seed_trial):
    """The control port and the keys change different parameters at the same time,
    while a change already waits for the next cycle: each is validated on top of the
    others, none is lost (validation made slow to open the window wide)."""
    loop = ServoLoop(SimDevice("hold"), seed_trial)
    validate = loop._passive

    def slow(params):
        time.sleep(0.05)
        return validate(params)

    loop._passive = slow
    threads = [
        threading.Thread(target=loop.request_change, args=({name: value},))
        for name, value in (("friction_closing", 2.5), ("viscous_damping", 0.7))
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10.0)
    assert loop.pending
    loop.run(0.001)  # the cycles apply what waits
    assert not loop.pending
    assert loop.params["friction_closing"] == 2.5
    assert loop.params["viscous_damping"] == 0.7
    change = next(e for e in loop.log.events if e["kind"] == "change")
    assert change["values"] == {"friction_closing": 2.5, "viscous_damping": 0.7}


def test_snapshot_is_the_last_cycle_and_nan_before_the_first(seed_trial):
    loop = ServoLoop(SimDevice("open", seed=1), seed_trial)
    before = loop.snapshot()
    assert before["status"] == "new" and before["theta"] != before["theta"]  # NaN
    loop.run(0.5)
    snap = loop.snapshot()
    last = loop.log.array()[-1]
    assert snap["status"] == "done" and snap["params"] is loop.params
    # the log's last row: within its last 10 ms whatever its source
    assert (
        abs(snap["theta"] - last[THETA]) < 10e-3 * abs(loop.log.array()[-10:, DTHETA]).max() + 1e-9
    )
    assert snap["t"] == pytest.approx(0.5 - loop.period)


def test_a_paced_loop_leaves_the_control_port_served(seed_trial):
    """At 2500 Hz the paced loop spins between cycles; it must give the interpreter to
    the control port's thread there, or a console's requests wait for seconds."""
    loop = ServoLoop(SimDevice("hold", seed=1), seed_trial, realtime=True, watchdog_misses=10**6)
    stop = threading.Event()
    thread = threading.Thread(target=loop.run, kwargs={"stop": stop}, daemon=True)
    waits = []
    with ControlServer(loop, "127.0.0.1", 0) as server:
        thread.start()
        time.sleep(0.3)
        with socket.create_connection(server.address, timeout=10.0) as sock:
            stream = sock.makefile("rwb")
            for _ in range(40):
                tic = time.perf_counter()
                stream.write(b'{"get": "health"}\n')
                stream.flush()
                assert json.loads(stream.readline())["ok"]
                waits.append(time.perf_counter() - tic)
                time.sleep(0.01)
        stop.set()
        thread.join(10.0)
    waits = sorted(waits)
    # starved, the slowest answers take seconds (1-10 s measured); served, a few ms
    # (loaded machines: tens of ms)
    assert waits[len(waits) // 2] < 0.1  # s: the median answer
    assert waits[-3] < 0.5  # s: all but the two slowest


# -- bounded input (the control port's limits) ------------------------------------------
PARAMS_REQUEST = b'{"token": "s3cret", "get": "params"}\n'


def _garbage() -> bytes:
    """Binary garbage on one line: every byte but the newline, invalid UTF-8 included."""
    return bytes(b for b in range(256) if b != 10) * 3


@pytest.mark.parametrize(
    "line, reason",
    [
        (b'{"token": "s3cret", "get": "rows", "since": ' + b"7" * 400 + b"}", "400 digits"),
        (b'{"token": "s3cret", "set": {"open_force": ' + b"7" * 400 + b"}}", "400 digits"),
        (b'{"token": "s3cret", "set": {"friction_closing": 1e400}}', "beyond a 64-bit float"),
        (b'{"token": "s3cret", "set": {"friction_closing": NaN}}', "NaN is not a number"),
        (b'{"token": "s3cret", "set": {"friction_closing": Infinity}}', "Infinity is not"),
        (b'{"token": "s3cret", "set": {"friction_closing": -Infinity}}', "Infinity is not"),
        (b"[" * 30_000 + b"]" * 30_000, "arrays and objects"),
        (b'{"token": "s3cret", "get": [' + b"0," * 5000 + b"0]}", "at most 256 values"),
        (b'{"token": "s3cret", "note": "' + b"x" * 10 * 2**20 + b'"}', "at most 65536 bytes"),
        (_garbage(), ""),
    ],
    ids=["int400", "int400-set", "1e400", "nan", "inf", "-inf", "deep", "values", "10MB", "binary"],
)
def test_absurd_input_is_answered_and_the_connection_goes_on(running, line, reason):
    """A 400-digit integer, 1e400, NaN and Infinity, nesting 30,000 deep, a 10 MB line
    and binary garbage each ended in a traceback (the integer's float() overflowed, the
    nesting a RecursionError) or a closed connection (the long line): each is now one
    answer with ok false and the reason, and the same connection then answers."""
    from evo_door.render.messages import RateLimit

    loop, server = running
    server.reading = RateLimit(1e9, 1e9)  # the 10 MB line at once, past the byte budget
    before = loop.params.as_dict()
    with socket.create_connection(server.address, timeout=30) as sock:
        sock.sendall(line + b"\n" + PARAMS_REQUEST)
        refused, answered = answer_lines(sock, 2)
    assert refused["ok"] is False and reason in refused["error"], refused
    assert "\n" not in refused["error"] and len(refused["error"]) < 200
    assert answered["ok"] and answered["params"] == before
    assert loop.params.as_dict() == before and loop.status == "running"


def test_a_long_line_is_answered_at_once_and_the_stream_resynchronised(running):
    """The refusal of a line too long comes as soon as it is seen (the client may wait
    for it before it sends the newline); what follows the newline is served."""
    loop, server = running
    with socket.create_connection(server.address, timeout=30) as sock:
        sock.sendall(b"{" + b" " * 200_000)
        (refused,) = answer_lines(sock, 1)
        assert not refused["ok"] and "at most 65536 bytes" in refused["error"]
        sock.sendall(b'"still": "the same line"}\n' + PARAMS_REQUEST)  # the newline
        (answered,) = answer_lines(sock, 1)
    assert answered["ok"] and "friction_closing" in answered["params"]


def test_parse_message_takes_what_the_protocol_needs():
    from evo_door.render.messages import BadMessage, parse_message

    whole = {"event": {"kind": "chosen", "params": {p.name: p.default for p in PARAMS}}}
    assert parse_message(json.dumps(whole).encode()) == whole
    assert parse_message('{"since": -12345678901234567890, "x": 1.5e300}') == {
        "since": -12345678901234567890,
        "x": 1.5e300,
    }
    with pytest.raises(BadMessage, match="21 digits"):
        parse_message('{"since": 123456789012345678901}')
    with pytest.raises(BadMessage, match="not a JSON object"):
        parse_message("[1, 2]")


def test_a_connection_over_the_cap_is_told_why_and_closed(running):
    from evo_door.render.control import MAX_CLIENTS

    loop, server = running
    held = []
    try:
        for _ in range(MAX_CLIENTS):
            sock = socket.create_connection(server.address, timeout=30)
            held.append(sock)
            sock.sendall(PARAMS_REQUEST)
            assert answer_lines(sock, 1)[0]["ok"]  # served: counted
        with socket.create_connection(server.address, timeout=30) as extra:
            extra.sendall(PARAMS_REQUEST)  # sent before the refusal: still told why
            answers = answer_lines(extra, 2)
            assert extra.recv(1) == b""  # then closed
        (refused,) = answers
        assert refused == {
            "ok": False,
            "error": f"the control port serves at most {MAX_CLIENTS} connections at once: "
            "try again when one has closed",
        }
        held[0].sendall(PARAMS_REQUEST)  # the ones served go on
        assert answer_lines(held[0], 1)[0]["ok"]
        held.pop().close()  # one leaves: a new one is served
        deadline = time.monotonic() + 10.0
        while True:
            with socket.create_connection(server.address, timeout=30) as again:
                again.sendall(PARAMS_REQUEST)
                answer = answer_lines(again, 1)[0]
            if answer["ok"] or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        assert answer["ok"], answer
    finally:
        for sock in held:
            sock.close()
    assert server.clients <= MAX_CLIENTS


def test_requests_past_the_rate_are_refused_and_the_connection_slowed(running):
    from evo_door.render.messages import REQUESTS_BURST, REQUESTS_PER_S, RateLimit

    loop, server = running
    server.budget = RateLimit(1e6, 1e6)  # the connection's own limit, not all of them
    n = REQUESTS_BURST + 150
    with socket.create_connection(server.address, timeout=30) as sock:
        sock.sendall(b'{"token": "s3cret", "get": "health"}\n' * n)
        answers = answer_lines(sock, n)
        refused = [a for a in answers if not a["ok"]]
        assert len(answers) == n and all(a["ok"] for a in answers[:REQUESTS_BURST])
        assert refused, "a burst of 350 requests at once was all served"
        assert refused[0]["error"] == (
            f"more than {REQUESTS_PER_S:g} requests a second on this connection "
            f"(bursts of {REQUESTS_BURST}): slow down"
        )
        time.sleep(0.5)
        sock.sendall(PARAMS_REQUEST)
        assert answer_lines(sock, 1)[0]["ok"]  # the same connection, later


def _note(i) -> bytes:
    return json.dumps({"token": "s3cret", "event": {"kind": "note", "text": f"n{i}"}}).encode()


def test_events_past_the_rate_of_their_kind_are_refused_and_not_logged(running):
    from evo_door.render.messages import EVENTS_BURST, EVENTS_PER_S, RateLimit

    loop, server = running
    server.budget = RateLimit(1e6, 1e6)  # the kind's own limit, not all connections'
    n = EVENTS_BURST + 30
    with socket.create_connection(server.address, timeout=30) as sock:
        sock.sendall(b"\n".join(_note(i) for i in range(n)) + b"\n")
        answers = answer_lines(sock, n)
        # another kind has its own budget
        other = {"token": "s3cret", "event": {"kind": "participant", "id": "P1"}}
        sock.sendall(json.dumps(other).encode() + b"\n")
        (participant,) = answer_lines(sock, 1)
    ok = [a for a in answers if a["ok"]]
    refused = [a for a in answers if not a["ok"]]
    assert EVENTS_BURST <= len(ok) < n and refused
    assert refused[0]["error"] == (
        f"more than {EVENTS_PER_S:g} events of kind 'note' a second "
        f"(bursts of {EVENTS_BURST}): slow down"
    )
    notes = [e["text"] for e in loop.log.events if e["kind"] == "note"]
    assert len(notes) == len(ok)  # what was refused is not in the log
    assert participant["ok"]


def test_the_log_keeps_client_events_up_to_its_cap_and_counts_the_rest(running, monkeypatch):
    """5,000 session events of 16 kB grew the renderer by 118 MB and its log to 164 MB:
    past the cap an event is answered ok false, the connection goes on, and the log
    says once how many it dropped."""
    from evo_door.render import log as render_log

    loop, server = running
    monkeypatch.setattr(render_log, "MAX_CLIENT_EVENTS", 5)
    with socket.create_connection(server.address, timeout=30) as sock:
        sock.sendall(b"\n".join(_note(i) for i in range(8)) + b"\n" + PARAMS_REQUEST)
        answers = answer_lines(sock, 9)
    assert [a["ok"] for a in answers] == [True] * 5 + [False] * 3 + [True]
    assert "cap of session events (5 events or 4 MiB)" in answers[5]["error"]
    assert [e["text"] for e in loop.log.events if e["kind"] == "note"] == [
        f"n{i}" for i in range(5)
    ]
    (dropped,) = [e for e in loop.log.events if e["kind"] == "dropped"]
    assert dropped["count"] == 3 and "not kept" in dropped["message"]
    # refused changes are client events too
    with pytest.raises(UserError):
        loop.request_change({"friction_closing": 1e9})
    assert dropped["count"] == 4 and not any(e["kind"] == "refused" for e in loop.log.events)
    # the participant's choice is what the session is for: the flood does not cost it
    with socket.create_connection(server.address, timeout=30) as sock:
        sock.sendall(json.dumps({"token": "s3cret", "event": {"kind": "chosen"}}).encode() + b"\n")
        (answer,) = answer_lines(sock, 1)
    assert answer["ok"], answer
    assert [e["kind"] for e in loop.log.events].count("chosen") == 1


def test_a_flood_of_large_events_leaves_memory_and_the_log_bounded(seed_trial, tmp_path):
    """The tester's flood, 5,000 events of 16 kB, against the log itself: what is kept
    stays within the cap in count and bytes, and so does the written log."""
    from evo_door.render.log import MAX_CLIENT_BYTES, MAX_CLIENT_EVENTS

    loop = ServoLoop(SimDevice("hold", seed=1), seed_trial)
    loop.run(0.05)
    text = "x" * 16_000
    kept = sum(loop.log.client_event(0.01, "note", "session: note", text=text) for _ in range(5000))
    assert kept * 16_000 <= MAX_CLIENT_BYTES < (kept + 1) * 16_100 and kept < MAX_CLIENT_EVENTS
    assert loop.log.client_bytes <= MAX_CLIENT_BYTES and loop.log.dropped == 5000 - kept
    assert len(loop.log.events) < kept + 10  # the loop's own few, one "dropped"
    path = tmp_path / "flood.h5"
    loop.write_log(path)
    # the events are stored twice (/render and /session): the log stays near twice the cap
    assert path.stat().st_size < 2 * MAX_CLIENT_BYTES + 2**20
    assert len(read_session(path)["events"]) == kept


def test_all_connections_together_wait_their_turn(running):
    """A flood of cheap requests from 16 clients (1,500 answers a second) cost a loaded
    machine's loop 12 % of its cycles: past the server-wide budget a request waits (the
    connection is not read meanwhile), whoever sends it. A small budget here: 120
    requests from three connections at 50 a second, 10 at once, take over 2 s."""
    from evo_door.render.messages import RateLimit

    loop, server = running
    server.budget = RateLimit(50.0, 10)
    socks = [socket.create_connection(server.address, timeout=30) for _ in range(3)]
    try:
        tic = time.monotonic()
        for sock in socks:
            sock.sendall(b'{"token": "s3cret", "get": "health"}\n' * 40)
        answers = [a for sock in socks for a in answer_lines(sock, 40)]
        elapsed = time.monotonic() - tic
    finally:
        for sock in socks:
            sock.close()
    assert len(answers) == 120 and all(a["ok"] for a in answers)  # waited, not refused
    assert elapsed > (120 - 10) / 50.0 * 0.95
