"""Sensations that cannot hurt: the balance's declared bounds and the hands-off check.

A haptic set describes a door that may move by itself; released with no hand on it,
the device swings the handle as that door would. The declaration bounds the balance
at what a door's weight and springs can give (:data:`BALANCE_LIMIT`), and the renderer
refuses a set whose door, released from rest anywhere, moves faster than
``--hands-off-speed`` (:mod:`evo_door.render.hands_off`): at its start, on a push, from
the console. The speeds are checked against Newton and energy, not against the code.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from evo_door.cli import build_parser, main
from evo_door.errors import UserError
from evo_door.models.haptic import MODEL as HAPTIC
from evo_door.models.haptic import PARAMS
from evo_door.models.haptic_params import BALANCE_LIMIT
from evo_door.params import ParamSet
from evo_door.render.control import ControlServer, request
from evo_door.render.hands_off import (
    HANDS_OFF_RANGE,
    HANDS_OFF_SPEED,
    check_hands_off,
    hands_off_duration,
    hands_off_motion,
)
from evo_door.render.loop import ServoLoop
from tests.helpers import LOADED_MACHINE_WATCHDOG, yielding_sim

ROOT = Path(__file__).resolve().parents[1]
BALANCES = [f"balance_{k}" for k in range(1, 10)]
TOKEN = "s3cret"


def _balanced(value, **others) -> dict:
    """Every balance at ``value`` (N), with ``others`` on top."""
    return {**{name: value for name in BALANCES}, **others}


def _write(path: Path, values: dict) -> Path:
    path.write_text(yaml.safe_dump({"model": "haptic", "values": values}))
    return path


def _one_line(err: str) -> str:
    assert err.count("\n") == 1 and err.startswith("evo-door: error:"), err
    return err


#: a door with nothing but its balance and inertia: no friction, no latch, no spring
FREE = {
    "friction_closing": 0.0,
    "friction_opening": 0.0,
    "viscous_damping": 0.0,
    "return_stiffness": 0.0,
    "open_force": 0.0,
    "close_force": 0.0,
    "seat_force": 0.0,
    "gasket_stiffness": 0.0,
    "transition_damping": 0.0,
    "c_energy": 0.0,
}


# -- the declaration ---------------------------------------------------------------------
def test_the_balance_is_declared_within_what_a_door_can_push():
    for name in BALANCES:
        assert (PARAMS[name].lower, PARAMS[name].upper) == (-BALANCE_LIMIT, BALANCE_LIMIT)
    # half the weight of a heavy 10 kg door, its whole push at the handle
    assert 10.0 * 9.81 / 2.0 <= BALANCE_LIMIT <= 50.0


def test_a_balance_of_100_n_is_refused_in_one_line(capsys, tmp_path):
    assert main(["params", "haptic", "--set", "balance_1=100"]) == 2
    err = _one_line(capsys.readouterr().err)
    assert "balance_1" in err and "[-50, 50] N" in err
    with pytest.raises(UserError, match="balance_5.*outside its declared range"):
        HAPTIC.load_params(None, {"balance_5": -100.0})
    path = _write(tmp_path / "b.yaml", _balanced(100.0))
    with pytest.raises(UserError, match="balance_1.*outside its declared range"):
        HAPTIC.load_params(str(path))


def test_every_shipped_set_and_search_range_keeps_the_balance_within_bounds():
    """Presets, experiments, examples and test files that set a balance."""
    found = 0
    for folder in ("evo_door/params/presets", "experiments", "examples", "tests"):
        for path in sorted((ROOT / folder).rglob("*.y*ml")):
            text = path.read_text(errors="replace")
            if "balance_" not in text:
                continue
            for line in text.splitlines():
                key, _, rest = line.strip().partition(":")
                if not key.startswith("balance_"):
                    continue
                numbers = [float(x) for x in rest.strip(" []").split(",") if x.strip()]
                found += 1
                assert all(abs(x) <= BALANCE_LIMIT for x in numbers), (path, line)
    assert found >= 9  # the case study's search ranges at least: the scan is not vacuous


# -- the check, against Newton and energy ---------------------------------------------
def test_a_constant_balance_gives_b_t_over_i():
    """No friction, a constant balance B (N) on an inertia I (kg m): theta'' = B / I, so
    after the check's duration T the speed is B T / I wherever the door has room."""
    b, inertia, duration = 1.0, 10.0, 1.0
    ps = HAPTIC.load_params(None, _balanced(b, inertia=inertia, **FREE))
    out = hands_off_motion(ps, limit=3.0, duration=duration)
    assert out["speed"] == pytest.approx(b * duration / inertia, rel=1e-9)
    assert out["ok"] and out["duration"] == duration
    assert math.degrees(out["start"]) < 87.0  # a start with room: 0.05 rad of travel
    # toward opening: the same speed, from a start above the travel's 2.9 deg
    ps = HAPTIC.load_params(None, _balanced(-b, inertia=inertia, **FREE))
    out = hands_off_motion(ps, limit=3.0, duration=duration)
    assert out["speed"] == pytest.approx(b * duration / inertia, rel=1e-9)
    assert math.degrees(out["start"]) > 2.9


def test_a_balance_that_reverses_swings_the_door_at_the_speed_energy_gives():
    """A balance falling linearly from +B at open to -B at closed is a spring about
    45 deg, of stiffness k = 2 B / (pi/2) N/rad: released at an end (amplitude pi/4) the
    door passes 45 deg at omega pi/4, omega = sqrt(k / I), the fastest of any start."""
    b, inertia = 5.0, 1.2
    values = {name: b - 2.0 * b * j / 8.0 for j, name in enumerate(BALANCES)}
    ps = HAPTIC.load_params(None, {**values, **FREE, "inertia": inertia, "loose_angle": 0.0})
    out = hands_off_motion(ps, limit=3.0)
    omega = math.sqrt(2.0 * b / (math.pi / 2.0) / inertia)
    assert out["duration"] > math.pi / (2.0 * omega)  # it reaches 45 deg within the check
    assert out["speed"] == pytest.approx(omega * math.pi / 4.0, rel=1e-5)
    assert out["start"] in (0.0, pytest.approx(math.pi / 2.0))


def test_the_presets_pass_and_a_strong_balance_is_refused():
    for spec in (None, "seed_trial"):  # None: the declared defaults, the "default" set
        ps = HAPTIC.load_params(spec)
        assert check_hands_off(ps) is ps
        assert hands_off_motion(ps)["speed"] < 0.5  # the door settling onto its catch
    for sign in (1.0, -1.0):
        ps = HAPTIC.load_params(None, _balanced(sign * BALANCE_LIMIT))
        out = hands_off_motion(ps)
        assert not out["ok"] and out["speed"] > HANDS_OFF_SPEED
        with pytest.raises(UserError) as err:
            check_hands_off(ps)
        text = str(err.value)
        assert "\n" not in text
        deg = f"{math.degrees(out['start']):.4g} deg"
        for part in (deg, f"{out['speed']:.3g} rad/s", "3 rad/s", "--hands-off-speed"):
            assert part in text, (part, text)
        # a raised limit lets it through
        assert check_hands_off(ps, limit=HANDS_OFF_RANGE[1]) is ps


def test_the_check_is_fast_enough_for_every_start_and_push():
    ps = HAPTIC.load_params("seed_trial")
    hands_off_motion(ps)  # compiled (or loaded from numba's cache)
    t = time.perf_counter()
    hands_off_motion(ps)
    assert time.perf_counter() - t < 0.5
    assert hands_off_duration(HANDS_OFF_SPEED) == pytest.approx(1.25 * math.pi / 3.0)


def test_the_loop_refuses_a_first_set_and_a_change_that_move_too_fast(seed_trial):
    fast = seed_trial.replace(_balanced(-40.0))
    with pytest.raises(UserError, match="hands-off limit of 3 rad/s"):
        ServoLoop(yielding_sim("hold"), fast, hands_off_speed=3.0)
    ServoLoop(yielding_sim("hold"), fast)  # None: not checked (a library caller's choice)
    with pytest.raises(UserError, match="--hands-off-speed 0.1"):
        ServoLoop(yielding_sim("hold"), seed_trial, hands_off_speed=0.1)
    loop = ServoLoop(yielding_sim("hold"), seed_trial, hands_off_speed=3.0)
    with pytest.raises(UserError, match="hands-off"):
        loop.request_change(_balanced(-40.0))
    assert not loop.pending and loop.params is seed_trial
    assert [e for e in loop.log.events if e["kind"] == "refused"]
    loop.request_change({"balance_1": -1.0})  # a gentle one goes through
    assert loop.pending


# -- evo-door render -----------------------------------------------------------------------
RENDER = ["render", "--device", "sim", "--user", "hold", "--duration", "0.5"]


def _render(*args) -> subprocess.CompletedProcess:
    """``evo-door render`` in a fresh process (its exit status and stderr as a user sees)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    return subprocess.run(
        [sys.executable, "-m", "evo_door", *args],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
        cwd=ROOT,
    )


def test_render_refuses_a_set_pushing_100_n_in_one_line(tmp_path):
    path = _write(tmp_path / "b100.yaml", _balanced(100.0))
    done = _render(*RENDER, "--params", str(path))
    assert done.returncode == 2
    _one_line(done.stderr)
    assert "balance_1" in done.stderr and "outside its declared range" in done.stderr
    assert done.stdout == ""


def test_render_refuses_a_set_too_fast_hands_off_unless_the_limit_is_raised(capsys, tmp_path):
    path = _write(tmp_path / "b40.yaml", _balanced(40.0))
    assert main([*RENDER, "--params", str(path)]) == 2
    captured = capsys.readouterr()
    err = _one_line(captured.err)
    assert "hands-off limit of 3 rad/s" in err and "--hands-off-speed" in err
    assert captured.out == ""  # refused before the loop started
    assert main([*RENDER, "--params", str(path), "--hands-off-speed", "15"]) == 0
    assert "rendered" in capsys.readouterr().out
    for bad in ("0.2", "25", "nan", "fast"):
        assert main([*RENDER, "--params", str(path), "--hands-off-speed", bad]) == 2
        assert "--hands-off-speed" in _one_line(capsys.readouterr().err)


# -- evo-door push to a running renderer ---------------------------------------------------
@pytest.fixture
def render_process(tmp_path):
    """``evo-door render --control 0`` in its own process, paced, until stopped; yields
    ``(process, "HOST:PORT")``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    args = ["render", "--params", "seed_trial", "--device", "sim", "--user", "hold"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "evo_door", *args, "--duration", "60", "--realtime",
         "--control", "0", "--token", TOKEN, *LOADED_MACHINE_WATCHDOG],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
    )  # fmt: skip
    try:
        line = proc.stdout.readline()
        assert line.startswith("control port "), (line, proc.stderr.read() if line == "" else "")
        yield proc, line.split()[2]
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


def test_push_of_a_set_too_fast_hands_off_is_refused_and_the_set_kept(
    render_process, capsys, tmp_path
):
    proc, to = render_process
    host, port = to.rsplit(":", 1)

    def running() -> dict:
        answer = request(host, int(port), {"token": TOKEN, "get": "params"}, timeout=10)
        assert answer["ok"]
        return answer["params"]

    before = running()
    path = _write(tmp_path / "fast.yaml", {**before, **_balanced(-40.0)})
    assert main(["push", str(path), "--to", to, "--token", TOKEN, "--timeout", "20"]) == 2
    err = _one_line(capsys.readouterr().err)
    assert "the renderer refused" in err and "hands-off limit of 3 rad/s" in err
    assert running() == before
    # a gentle push still goes through
    args = ["push", "--set", "balance_2=-1", "--to", to, "--token", TOKEN, "--timeout", "20"]
    assert main(args) == 0
    assert running()["balance_2"] == -1.0
    assert proc.poll() is None  # the renderer went on


# -- the operator's console -----------------------------------------------------------------
def test_the_console_hears_a_hands_off_refusal_as_any_other(seed_trial, tmp_path):
    """The console changes sets through the control port: the renderer's hands-off
    refusal reaches the page as a ``refused`` message, and nothing changes."""
    aiohttp = pytest.importorskip("aiohttp")
    from evo_door.render.console.server import ConsoleServer

    build_parser()
    loop = ServoLoop(
        yielding_sim("hold", radius=seed_trial["radius"], seed=3), seed_trial, hands_off_speed=3.0
    )
    stop = threading.Event()
    thread = threading.Thread(target=loop.run, kwargs={"stop": stop}, daemon=True)
    control = ControlServer(loop, "127.0.0.1", 0, token=TOKEN).start()
    thread.start()
    events = asyncio.new_event_loop()
    events_thread = threading.Thread(target=events.run_forever, daemon=True)
    events_thread.start()
    console = ConsoleServer(control.address, TOKEN, "127.0.0.1", 0, tmp_path)

    def call(coro):
        return asyncio.run_coroutine_threadsafe(coro, events).result(30)

    try:
        call(console.start())
        base = f"http://127.0.0.1:{console.port}/"
        before = loop.params.as_dict()
        values = _balanced(-40.0)

        async def scenario():
            async with aiohttp.ClientSession() as session:
                origin = {"Origin": f"http://127.0.0.1:{console.port}"}
                async with session.ws_connect(f"{base}ws?token={TOKEN}", headers=origin) as ws:
                    await ws.send_str(json.dumps({"type": "set", "values": values}))
                    deadline = time.monotonic() + 30.0
                    while time.monotonic() < deadline:
                        msg = await ws.receive_json(timeout=deadline - time.monotonic())
                        if msg["type"] == "refused":
                            return msg
                    raise AssertionError("no refused message")

        refused = asyncio.run(scenario())
        assert "hands-off limit of 3 rad/s" in refused["error"] and "\n" not in refused["error"]
        assert refused["values"] == values
        time.sleep(0.02)
        assert loop.params.as_dict() == before
    finally:
        call(console.stop())
        events.call_soon_threadsafe(events.stop)
        events_thread.join(5.0)
        events.close()
        stop.set()
        thread.join(10.0)
        control.close()


def test_a_set_that_round_trips_keeps_its_balance(tmp_path):
    """A set at the new bound is written and read back (the loader takes it)."""
    ps = HAPTIC.load_params(None, _balanced(BALANCE_LIMIT))
    ps.to_yaml(tmp_path / "p.yaml")
    back = HAPTIC.load_params(str(tmp_path / "p.yaml"))
    assert isinstance(back, ParamSet) and back["balance_9"] == BALANCE_LIMIT


def test_a_jnd_session_whose_comparison_would_move_too_fast_is_refused(capsys, tmp_path):
    """A JND session renders its reference and comparisons up to the reference times
    (1 + the largest step): each is checked before the device is touched. A balance of
    20 N at 45 deg is safe (2.3 rad/s); the session's comparison at 40 N would not be
    (3.4 rad/s), so the session is refused in one line and no file is written."""
    out = tmp_path / "j.h5"
    args = ["jnd", "--param", "balance_5", "--params", "seed_trial", "--set", "balance_5=20",
            "--device", "sim", "--participant", "sim:0.2", "--trials", "10", "--out", str(out)]  # fmt: skip
    assert main(args) == 2
    err = _one_line(capsys.readouterr().err)
    assert "hands-off limit of 3 rad/s" in err and "35 deg" in err
    assert "a JND session keeps the default limit" in err
    assert not out.exists()
