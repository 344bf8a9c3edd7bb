"""The renderer's control port, `evo-door push` and the key map of the terminal UI."""

from __future__ import annotations

import json
import socket
import threading
import time

import pytest

from evo_door.cli import build_parser, main
from evo_door.errors import UserError
from evo_door.models.haptic import PARAMS
from evo_door.render.control import ControlServer, parse_control, request
from evo_door.render.device import SimDevice
from evo_door.render.keys import LETTERS, key_change, key_map, nice_step
from evo_door.render.log import format_session, read_session, session_params
from evo_door.render.loop import ServoLoop
from tests.conftest import yielding_sim


@pytest.fixture
def running(seed_trial):
    """A ServoLoop on the simulated device in its own thread, with its control server."""
    build_parser()  # import every command before the loop competes for the GIL
    loop = ServoLoop(yielding_sim("open", radius=seed_trial["radius"], seed=3), seed_trial)
    stop = threading.Event()
    thread = threading.Thread(target=loop.run, kwargs={"stop": stop}, daemon=True)
    server = ControlServer(loop, "127.0.0.1", 0, token="s3cret").start()
    thread.start()
    deadline = time.monotonic() + 10.0
    while loop.log.n < 10 and time.monotonic() < deadline:  # some cycles have run
        time.sleep(0.001)
    yield loop, server
    stop.set()
    thread.join(10.0)
    server.close()


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
    for letter, name in zip(LETTERS, sensations):
        (n_down, down), (n_up, up) = keys[letter], keys[letter.upper()]
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
    assert abs(snap["theta"] - last[12]) < 10e-3 * abs(loop.log.array()[-10:, 13]).max() + 1e-9
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
