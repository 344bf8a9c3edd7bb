"""The web console's server against a real renderer: API, WebSocket, security.

No browser: HTTP with urllib, the WebSocket with aiohttp's client. The renderer is a
ServoLoop on the simulated device in a thread with its control port, as in
tests/test_render_control.py; the console runs its event loop in another thread.
"""

from __future__ import annotations

import asyncio
import json
import math
import re
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

aiohttp = pytest.importorskip("aiohttp")

from evo_door.cli import build_parser, main  # noqa: E402
from evo_door.errors import UserError  # noqa: E402
from evo_door.models import get_model  # noqa: E402
from evo_door.models.haptic import PARAMS  # noqa: E402
from evo_door.render.console import app as console_app  # noqa: E402
from evo_door.render.console import server as console_server  # noqa: E402
from evo_door.render.console.saving import safe_stem  # noqa: E402
from evo_door.render.console.server import ConsoleServer  # noqa: E402
from evo_door.render.control import request  # noqa: E402
from evo_door.render.keys import key_map  # noqa: E402
from evo_door.render.loop import ServoLoop  # noqa: E402
from evo_door.sim.simulate import force_angle_curve  # noqa: E402
from tests.helpers import (  # noqa: E402
    LOADED_MACHINE_WATCHDOG,
    ServedConsole,
    assert_kept_time,
    console_url,
    serving,
    yielding_sim,
)

TOKEN = "s3cret-token"
SENSATIONS = [p.name for p in PARAMS if p.group == "sensation"]


@pytest.fixture
def renderer(seed_trial):
    """A renderer whose passivity check a sensation can fail: the model's tanh friction
    sampled explicitly on a device damped at 60 N s/m (seed_trial passes, a snap-zone
    damping of 50 N s/rad does not)."""
    build_parser()
    device = yielding_sim("open", radius=seed_trial["radius"], seed=3, damping=60.0)
    loop = ServoLoop(device, seed_trial, friction="tanh")
    with serving(loop, TOKEN, wait=10.0) as (loop, control, _end):
        yield loop, control


@pytest.fixture
def console(renderer, tmp_path):
    loop, control = renderer
    served = ServedConsole(ConsoleServer(control.address, TOKEN, "127.0.0.1", 0, tmp_path))
    yield served
    served.close()


def _get(url, headers=None):
    """(status, headers, body) of a GET."""
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, r.headers, r.read()
    except urllib.error.HTTPError as err:
        return err.code, err.headers, err.read()


def _api(console, path):
    status, _, body = _get(f"{console.base}{path}?token={TOKEN}")
    assert status == 200, body
    return json.loads(body)


async def _next(ws, kind, timeout=5.0):
    """The next message of type ``kind`` (ticks and others skipped)."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError(f"no {kind!r} message within {timeout} s")
        msg = await ws.receive_json(timeout=left)
        if msg["type"] == kind:
            return msg


def _page(console, session, origin=None, token=TOKEN):
    origin = f"http://127.0.0.1:{console.server.port}" if origin is None else origin
    query = f"?token={token}" if token else ""
    return session.ws_connect(f"{console.base}ws{query}", headers={"Origin": origin})


def _session(scenario):
    async def run():
        async with aiohttp.ClientSession() as session:
            return await scenario(session)

    return asyncio.run(run())


def _events(loop, kind):
    return [e for e in loop.log.events if e["kind"] == kind]


# -- the API ----------------------------------------------------------------------------
def test_declaration_lists_the_sensations_with_bounds_steps_and_two_keys(console):
    body = _api(console, "api/declaration")
    rows = body["params"]
    assert [r["name"] for r in rows] == SENSATIONS
    assert body["display"] == {"rad": "deg"}
    keys = key_map()
    seen = set()
    for row in rows:
        p = PARAMS[row["name"]]
        assert (row["lower"], row["upper"], row["unit"]) == (p.lower, p.upper, p.unit)
        span = p.upper - p.lower
        assert span / 50 <= row["step"] <= span / 20 * (1 + 1e-12)
        down, up = row["keys"]
        assert keys[down] == (p.name, -row["step"]) and keys[up] == (p.name, row["step"])
        seen |= {down, up}
    assert len(seen) == 2 * len(rows)


def test_curve_is_the_force_angle_curve_of_the_set_in_force(console, renderer):
    loop, control = renderer
    haptic = get_model("haptic")

    def check():
        body = _api(console, "api/curve")
        ref = force_angle_curve(haptic, loop.params)
        assert body["theta_deg"] == pytest.approx(ref["theta"] * 180 / math.pi, rel=1e-12)
        assert body["opening"] == pytest.approx(ref["opening"], rel=1e-12, abs=1e-12)
        assert body["closing"] == pytest.approx(ref["closing"], rel=1e-12, abs=1e-12)
        return body

    first = check()
    old = loop.params["close_force"]

    async def scenario(session):
        async with _page(console, session) as ws:
            await ws.send_json({"type": "set", "values": {"close_force": 30.0}})
            return await _next(ws, "params")

    _session(scenario)
    second = check()  # a new set, a new curve
    # the latch's peak rises with the declared close force
    rise = max(second["closing"]) - max(first["closing"])
    assert rise == pytest.approx(30.0 - old, rel=1e-3)
    assert second["params_t"] > first["params_t"]


# -- the loop's health on the page ---------------------------------------------------------
def test_every_health_field_the_page_reads_comes_in_its_hello_and_each_tick(console, renderer):
    """The servo panel showed a red "running (no data)" on a healthy loop: the hello
    carried no health, so a page that came back (a new renderer on the same port) kept
    the last one's status and tick time until a tick came; and the page read fields
    the server never sends. The hello now carries the health read as the page opens."""
    script = (console_app.STATIC / "console.js").read_text()
    read = set(re.findall(r"\bhl\.([a-z_0-9]+)", script))
    assert {"status", "on_time_fraction", "missed_cycles", "watchdog"} <= read, read

    async def open_page(session):
        async with _page(console, session) as ws:
            return await _next(ws, "hello"), await _next(ws, "tick")

    first_hello, first_tick = _session(open_page)
    time.sleep(0.3)  # no page open: the console polls nothing meanwhile
    hello, tick = _session(open_page)
    for message in (first_hello, first_tick, hello, tick):
        health = message["health"]
        assert read <= set(health), f"the page reads {sorted(read - set(health))}, not sent"
        assert health["status"] == "running" == message["state"]["status"]
        assert health["watchdog"] == "" and health["cycles"] > 0
    # read when the page opened, not kept from the last page's ticks
    assert hello["health"]["t"] > first_tick["health"]["t"]


# -- changes over the WebSocket ----------------------------------------------------------
def test_set_changes_the_renderer_between_cycles_and_every_page_hears(console, renderer):
    loop, _ = renderer

    async def scenario(session):
        async with _page(console, session) as one, _page(console, session) as two:
            hello = await _next(one, "hello")
            assert hello["params"] == loop.params.as_dict() == hello["start"]
            assert hello["ab"] == {
                "A": None,
                "B": None,
                "active": None,
                "blind": False,
                "choice": None,
            }
            tick = await _next(one, "tick")
            assert tick["state"]["status"] == "running" and "on_time_fraction" in tick["health"]
            await one.send_json(
                {"type": "set", "values": {"friction_closing": 7.5}, "source": "key"}
            )
            mine, theirs = await _next(one, "params"), await _next(two, "params")
        # closed and opened again: the new page starts from the set in force
        async with _page(console, session) as three:
            again = await _next(three, "hello")
        return mine, theirs, again

    mine, theirs, again = _session(scenario)
    assert mine == theirs and mine["source"] == "key"
    assert mine["params"]["friction_closing"] == 7.5 == loop.params["friction_closing"]
    assert again["params"]["friction_closing"] == 7.5
    change = _events(loop, "change")[-1]
    assert change["values"] == {"friction_closing": 7.5}
    cycles = change["t"] / loop.period
    assert cycles == pytest.approx(round(cycles), abs=1e-6) and cycles >= 1
    assert loop.log.param_times[-1] == change["t"]


def test_ticks_carry_the_log_rows_at_100_hz(console, renderer):
    loop, _ = renderer

    async def scenario(session):
        async with _page(console, session) as ws:
            return [await _next(ws, "tick") for _ in range(4)]

    ticks = _session(scenario)
    rows = [r for tick in ticks for r in tick["rows"]]
    assert len(rows) >= 2
    t = [r[0] for r in rows]
    assert all(b - a == pytest.approx(0.01, abs=1e-9) for a, b in zip(t, t[1:]))
    log = loop.log.array()
    k = round(t[-1] * loop.log.rate)
    assert rows[-1][1] == pytest.approx(log[k, 12], abs=1e-12)  # theta of that log row


@pytest.mark.parametrize(
    "values, reason",
    [
        ({"friction_closing": 500.0}, "outside its declared range"),
        ({"friction_closing": None}, "not a number"),
        ({"friction_closing": True}, "not a number"),
        ({"k_radial": 10.0}, "not a sensation parameter"),
        ({"no_such_thing": 1.0}, "not a sensation parameter"),
        ({"transition_damping": 50.0}, "not passive"),  # the renderer's refusal
        ({"friction_closing": 9.0, "transition_damping": 50.0}, "not passive"),
    ],
)
def test_refused_values_change_nothing_and_say_why(console, renderer, values, reason):
    loop, _ = renderer
    before = loop.params.as_dict()
    n_sets = len(loop.log.param_times)

    async def scenario(session):
        async with _page(console, session) as ws:
            await ws.send_str(json.dumps({"type": "set", "values": values}))
            return await _next(ws, "refused")

    refused = _session(scenario)
    assert reason in refused["error"] and "\n" not in refused["error"]
    time.sleep(0.02)
    assert loop.params.as_dict() == before and len(loop.log.param_times) == n_sets
    assert console.server.console.undo == []


def test_a_push_from_elsewhere_reaches_the_pages(console, renderer):
    loop, control = renderer

    async def scenario(session):
        async with _page(console, session) as ws:
            await _next(ws, "hello")
            answer = await asyncio.to_thread(
                request, *control.address, {"token": TOKEN, "set": {"open_force": 25.0}}
            )
            assert answer["ok"]
            return await _next(ws, "params")

    msg = _session(scenario)
    assert msg["source"] == "push" and msg["params"]["open_force"] == 25.0


def test_undo_and_reset_restore_the_sets(console, renderer, seed_trial):
    loop, _ = renderer

    async def scenario(session):
        async with _page(console, session) as ws:
            for values in ({"friction_closing": 7.5}, {"viscous_damping": 0.4}):
                await ws.send_json({"type": "set", "values": values})
                await _next(ws, "params")
            await ws.send_json({"type": "undo"})
            undone = await _next(ws, "params")
            assert undone["source"] == "undo"
            assert loop.params["viscous_damping"] == seed_trial["viscous_damping"]
            assert loop.params["friction_closing"] == 7.5
            await ws.send_json({"type": "reset"})
            reset = await _next(ws, "params")
            assert reset["source"] == "reset"
            assert loop.params.as_dict() == seed_trial.as_dict() == reset["params"]
            await ws.send_json({"type": "undo"})  # the reset itself can be undone
            await _next(ws, "params")
            assert loop.params["friction_closing"] == 7.5
            await ws.send_json({"type": "undo"})
            await _next(ws, "params")
            await ws.send_json({"type": "undo"})
            return await _next(ws, "error")

    empty = _session(scenario)
    assert empty["error"] == "nothing to undo"
    assert loop.params.as_dict() == seed_trial.as_dict()
    assert len(_events(loop, "undo")) == 3 and len(_events(loop, "reset")) == 1


def test_save_writes_a_parameter_file_inside_save_dir_never_over_another(
    console, renderer, tmp_path
):
    loop, _ = renderer
    kept = tmp_path / "keep.yaml"
    kept.write_text("not mine\n")

    async def scenario(session):
        async with _page(console, session) as ws:
            await ws.send_json({"type": "set", "values": {"open_force": 31.0}})
            await _next(ws, "params")
            paths = []
            for name in ("../x", "../x", "keep", "/etc/passwd"):
                await ws.send_json({"type": "save", "name": name})
                paths.append(Path((await _next(ws, "saved"))["path"]))
            return paths

    paths = _session(scenario)
    assert [p.name for p in paths] == ["x.yaml", "x-2.yaml", "keep-2.yaml", "etc_passwd.yaml"]
    assert all(p.parent == tmp_path.resolve() for p in paths)
    assert kept.read_text() == "not mine\n"
    haptic = get_model("haptic")
    for path in paths:
        assert haptic.load_params(path).as_dict() == loop.params.as_dict()
    assert haptic.load_params(paths[0])["open_force"] == 31.0
    assert [e["path"] for e in _events(loop, "save")] == [str(p) for p in paths]
    assert safe_stem("..") == "console" and safe_stem("a b") == "a_b"


def test_ab_participant_and_choice_reach_the_log(console, renderer):
    loop, _ = renderer

    async def scenario(session):
        async with _page(console, session) as ws:
            await ws.send_json({"type": "participant", "id": "P07"})
            assert (await _next(ws, "participant"))["id"] == "P07"
            for slot, value in (("A", 7.5), ("B", 12.0)):
                await ws.send_json({"type": "set", "values": {"friction_closing": value}})
                await _next(ws, "params")
                await ws.send_json({"type": "ab_store", "slot": slot})
                await _next(ws, "ab")
            await ws.send_json({"type": "ab_blind", "blind": True})
            assert (await _next(ws, "ab"))["blind"] is True
            await ws.send_json({"type": "ab_switch", "slot": "A"})
            switched = await _next(ws, "params")
            assert switched["source"] == "ab" and loop.params["friction_closing"] == 7.5
            ab = await _next(ws, "ab")
            assert ab["active"] == "A" and ab["A"]["friction_closing"] == 7.5
            await ws.send_json({"type": "ab_choice", "slot": "A"})
            assert (await _next(ws, "ab"))["choice"] == "A"
            await ws.send_json({"type": "choose"})
            await _next(ws, "chosen")
            await ws.send_json({"type": "ab_switch", "slot": "C"})
            return await _next(ws, "error")

    bad_slot = _session(scenario)
    assert "slot" in bad_slot["error"]
    assert [e["id"] for e in _events(loop, "participant")] == ["P07"]
    stores = _events(loop, "ab_store")
    assert [(e["slot"], e["params"]["friction_closing"]) for e in stores] == [
        ("A", 7.5),
        ("B", 12.0),
    ]
    (switch,) = _events(loop, "ab_switch")
    assert switch["slot"] == "A" and switch["blind"] is True
    (choice,) = _events(loop, "ab_choice")
    assert choice["slot"] == "A" and choice["params"]["friction_closing"] == 7.5
    (chosen,) = _events(loop, "chosen")
    assert chosen["params"] == loop.params.as_dict()
    times = [e["t"] for e in stores + [switch, choice, chosen]]
    assert times == sorted(times)


# -- security ----------------------------------------------------------------------------
def test_foreign_origin_and_missing_token_get_403(console):
    port = console.server.port

    async def handshake(session, **kw):
        try:
            async with _page(console, session, **kw) as ws:
                await _next(ws, "hello")
                return 101
        except aiohttp.WSServerHandshakeError as err:
            return err.status

    async def scenario(session):
        return (
            await handshake(session),
            await handshake(session, origin="http://evil.example"),
            await handshake(session, origin=f"http://127.0.0.1:{port + 1}"),
            await handshake(session, token=None),
            await handshake(session, token="guess"),
        )

    assert _session(scenario) == (101, 403, 403, 403, 403)
    assert _get(f"{console.base}api/declaration")[0] == 403
    assert _get(f"{console.base}api/declaration?token=guess")[0] == 403
    # the first visit sets the cookie; the cookie alone then opens everything
    status, headers, _ = _get(f"{console.base}?token={TOKEN}")
    assert status == 200
    cookie = headers["Set-Cookie"]
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    pair = cookie.split(";")[0]
    status, headers, _ = _get(f"{console.base}api/declaration", {"Cookie": pair})
    assert status == 200
    assert headers["X-Frame-Options"] == "DENY"
    csp = headers["Content-Security-Policy"]
    assert "default-src 'self'" in csp and f"ws://127.0.0.1:{port}" in csp
    assert "Access-Control-Allow-Origin" not in headers
    # DNS rebinding: a name that is not the server's
    spoofed = {"Cookie": pair, "Host": f"evil.example:{port}"}
    assert _get(f"{console.base}api/declaration", spoofed)[0] == 403


def test_non_loopback_bind_requires_a_token(capsys):
    with pytest.raises(UserError, match="requires --token"):
        ConsoleServer(("127.0.0.1", 1), None, "0.0.0.0", 0)
    assert main(["console", "--control", "127.0.0.1:1", "--host", "0.0.0.0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "requires --token" in err


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_console_cli_one_line_errors(capsys, monkeypatch, renderer, tmp_path):
    monkeypatch.setattr(console_server, "CONNECT_WAIT", 0.3)
    started = time.monotonic()
    assert main(["console", "--control", f"127.0.0.1:{_free_port()}"]) == 2
    assert time.monotonic() - started < 5.0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("evo-door: error: cannot reach the renderer")
    assert main(["console", "--control", "nowhere"]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    _, control = renderer
    to = "{}:{}".format(*control.address)
    assert main(["console", "--control", to, "--token", "guess", "--port", "0"]) == 2
    assert "wrong token" in capsys.readouterr().err
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["console", "--control", to, "--token", TOKEN, "--port", str(port)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot listen" in err
    args = ["console", "--control", to, "--save-dir", str(tmp_path / "no")]
    assert main(args) == 2 and "--save-dir" in capsys.readouterr().err


@pytest.mark.slow
def test_render_console_spawns_the_console_and_stops_it(tmp_path):
    """render --console prints the page's URL, the page answers while the render
    runs, and the console process is gone when the render ends. A console keeps the
    loop on the wall clock without --realtime (unpaced, a 4 s render ended in about
    one and the page with it, its summary giving a period the loop never kept)."""
    cmd = [sys.executable, "-m", "evo_door", "render", "--params", "seed_trial"]
    cmd += ["--user", "hold", "--duration", "4", "--console", "--console-port", "0"]
    cmd += LOADED_MACHINE_WATCHDOG  # a 37 ms stall beside the suite's workers ended one
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, text=True)
    try:
        url = console_url(proc.stdout)
        assert url.startswith("http://127.0.0.1:") and "?token=" in url
        printed = time.monotonic()  # the loop starts after the console is up
        base, query = url.split("?")
        status, _, body = _get(f"{base}api/declaration?{query}")
        assert status == 200 and json.loads(body)["params"][0]["name"] == SENSATIONS[0]
        assert _get(f"{base}api/declaration")[0] == 403
        rest = proc.stdout.read()
        assert proc.wait(30) == 0, rest
        assert time.monotonic() - printed > 3.5  # the 4 s on the wall clock; unpaced about 1 s
        assert_kept_time(rest, 0.4)
    finally:
        proc.kill()
    with pytest.raises(OSError):
        urllib.request.urlopen(f"{base}api/declaration?{query}", timeout=2)


# -- bounded input (the control port's rules on the WebSocket) ----------------------------
async def _answer_then_usable(ws, send):
    """Send something absurd, take its error, then check the same socket still works."""
    await _next(ws, "hello")
    await send(ws)
    error = await _next(ws, "error", timeout=30.0)
    await ws.send_json({"type": "participant", "id": "P42"})
    return error, await _next(ws, "participant", timeout=30.0)


ABSURD = {
    "int400": ('{"type": "set", "values": {"open_force": ' + "7" * 400 + "}}", "400 digits"),
    "1e400": ('{"type": "set", "values": {"open_force": 1e400}}', "beyond a 64-bit float"),
    "nan": ('{"type": "set", "values": {"open_force": NaN}}', "NaN is not a number"),
    "inf": ('{"type": "set", "values": {"open_force": Infinity}}', "Infinity is not"),
    "deep": ("[" * 30_000 + "]" * 30_000, "arrays and objects"),
    "values": ('{"type": "x", "v": [' + "0," * 5000 + "0]}", "at most 256 values"),
    "10MB": ('{"type": "note", "text": "' + "x" * 10 * 2**20 + '"}', "at most 65536 bytes"),
    "binary": (bytes(range(256)) * 4, "binary WebSocket messages are not read"),
    "not-json": ("{'type': 'set'}", "not a JSON object"),
}


@pytest.mark.parametrize("name", list(ABSURD))
def test_absurd_page_messages_are_answered_and_the_socket_goes_on(console, renderer, name):
    """The console parses a page's messages with the control port's function and
    bounds (a 400-digit integer ended in an OverflowError, 30,000 deep in a
    RecursionError, 64 KiB in a socket closed by aiohttp): each is an error with ok
    false and the reason, and the same socket then does what a page asks."""
    loop, _ = renderer
    before = loop.params.as_dict()
    data, reason = ABSURD[name]

    async def send(ws):
        if isinstance(data, bytes):
            await ws.send_bytes(data)
        else:
            await ws.send_str(data)

    async def scenario(session):
        async with _page(console, session) as ws:
            return await _answer_then_usable(ws, send)

    error, participant = _session(scenario)
    assert error["ok"] is False and reason in error["error"], error
    assert participant["id"] == "P42"
    assert loop.params.as_dict() == before


def test_pages_over_the_cap_are_told_why_and_closed(console):
    cap = console_app.MAX_PAGES

    async def scenario(session):
        pages = []
        try:
            for _ in range(cap):
                ws = await _page(console, session)
                pages.append(ws)
                await _next(ws, "hello")
            extra = await _page(console, session)
            error = await extra.receive_json(timeout=10)
            closed = await extra.receive(timeout=10)
            await extra.close()
            await pages.pop().close()  # one leaves: a new page is served
            await asyncio.sleep(0.2)
            async with _page(console, session) as again:
                hello = await _next(again, "hello")
            return error, closed, extra.close_code, hello
        finally:
            for ws in pages:
                await ws.close()

    error, closed, code, hello = _session(scenario)
    assert error == {
        "type": "error",
        "ok": False,
        "error": f"the console serves at most {cap} pages at once: close one, then reload",
    }
    assert closed.type == aiohttp.WSMsgType.CLOSE and code == 1013  # try again later
    assert hello["type"] == "hello"


def test_page_messages_past_their_rate_are_refused(console, renderer):
    """A page that floods one message type gets refusals with the reason, other types
    still go through, and a flood of sets reaches the renderer only within the rate."""
    loop, _ = renderer
    burst = console_app.PAGE_KIND_BURST
    n = burst + 20

    async def scenario(session):
        async with _page(console, session) as ws:
            await _next(ws, "hello")
            for i in range(n):  # no renderer request: only the console's limits
                await ws.send_json({"type": "ab_blind", "blind": bool(i % 2)})
            replies = []
            while len(replies) < n:
                msg = await ws.receive_json(timeout=10)
                if msg["type"] in ("ab", "error"):
                    replies.append(msg)
            await ws.send_json({"type": "participant", "id": "P9"})
            return replies, await _next(ws, "participant")

    replies, participant = _session(scenario)
    errors = [r for r in replies if r["type"] == "error"]
    assert errors and len(replies) - len(errors) >= burst
    assert errors[0] == {
        "type": "error",
        "ok": False,
        "error": f"more than {console_app.PAGE_KIND_PER_S:g} messages of type 'ab_blind' "
        f"a second (bursts of {burst}): slow down",
    }
    assert participant["id"] == "P9"


def test_a_set_refused_for_its_rate_is_a_refused_message(console, renderer):
    """The page resets its sliders on ``refused``: a set over the rate must say so as
    one, with the values it asked for."""
    loop, _ = renderer
    n = console_app.PAGE_KIND_BURST + 10

    async def scenario(session):
        async with _page(console, session) as ws:
            await _next(ws, "hello")
            for i in range(n):
                await ws.send_json({"type": "set", "values": {"open_force": 20.0 + i % 2}})
            return await _next(ws, "refused", timeout=30.0)

    refused = _session(scenario)
    assert refused["ok"] is False and "messages of type 'set'" in refused["error"]
    assert refused["values"]["open_force"] in (20.0, 21.0)


def test_a_task_that_swallows_a_cancellation_is_still_stopped():
    """Python 3.11's asyncio.wait_for can swallow a cancellation that arrives with the
    answer (the console's polling loops await it): one cancel then left the loop
    running and the console's stop hung. cancel_and_wait cancels until it ends."""
    from evo_door.render.console.client import cancel_and_wait

    async def stubborn(swallow: int):
        while True:
            try:
                await asyncio.sleep(0.01)
            except asyncio.CancelledError:
                if swallow == 0:
                    raise
                swallow -= 1  # as wait_for does when the answer came first

    async def scenario():
        once = asyncio.get_running_loop().create_task(stubborn(1))
        await asyncio.sleep(0.02)
        once.cancel()  # the old way: one cancel, then wait
        done, _ = await asyncio.wait({once}, timeout=0.2)
        assert not done  # still running: a stop awaiting it would hang
        await asyncio.wait_for(cancel_and_wait(once), 2.0)
        twice = asyncio.get_running_loop().create_task(stubborn(3))
        await asyncio.sleep(0.02)
        await asyncio.wait_for(cancel_and_wait(twice, every=0.01), 2.0)
        return once.cancelled() and twice.cancelled()

    assert asyncio.run(scenario())
