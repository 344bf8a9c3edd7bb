"""The operator's console on a rendered mechanism (docs/renderer.md, "The operator's
console", "Rendering a mechanism"): the soft-close drawer of examples/blocks rendered
on the simulated device (its stop softened to 5000 N/m for the explicit loop) in a
thread with its control port, the console in another, no browser.

- ``/api/declaration`` lists the drawer's parameters outside its geometry, each with
  its unit, bounds, step and keys, and the handle's unit (m) and stroke;
- a change from a page is the renderer's to check: one within the loop's reach comes
  into force, a stop too stiff for the loop is refused with the renderer's reason, a
  geometry parameter by the console itself, and nothing changes;
- ``/api/curve`` is the drawer's own force-position curve of the set in force, in m;
- Save writes a parameter file of the drawer that ``render DRAWER --params`` renders;
- a JND session is refused in one line; a console that is not told the mechanism's
  file says how to give it;
- the terminal's keys of ``render DRAWER`` step what the console changes;
- ``render DRAWER --console`` end to end (slow).
"""

from __future__ import annotations

import asyncio
import json
import time
import urllib.request
from pathlib import Path

import pytest

aiohttp = pytest.importorskip("aiohttp")

from evo_door.cli import build_parser, main  # noqa: E402
from evo_door.errors import UserError  # noqa: E402
from evo_door.models import get_model  # noqa: E402
from evo_door.models.blocks import CACHE_ENV  # noqa: E402
from evo_door.render.console.server import ConsoleServer  # noqa: E402
from evo_door.render.keys import KEY_PAIRS, nice_step  # noqa: E402
from evo_door.render.mechanism import MechanismLoop, Stroke  # noqa: E402
from evo_door.sim.simulate import force_angle_curve  # noqa: E402
from tests.helpers import LOADED_MACHINE_WATCHDOG, ServedConsole, console_url, serving, yielding_sim  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DRAWER = str(ROOT / "examples" / "blocks" / "soft_close_drawer.yaml")
TOKEN = "drawer-token"


@pytest.fixture(scope="module")
def drawer(tmp_path_factory):
    """The drawer's model, generated in a tmp folder (not the user's cache)."""
    mp = pytest.MonkeyPatch()
    mp.setenv(CACHE_ENV, str(tmp_path_factory.getbasetemp() / "mechanisms"))
    yield get_model(DRAWER)
    mp.undo()


@pytest.fixture
def renderer(drawer):
    """The drawer rendered on the simulated device, held, with its control port."""
    build_parser()
    params = drawer.load_params(None, {"stop.k": 5000.0})
    device = yielding_sim("hold", path=Stroke(*drawer.theta_range), seed=3)
    loop = MechanismLoop(device, drawer, params)
    with serving(loop, TOKEN, wait=30.0) as (loop, control, _end):
        yield loop, control


@pytest.fixture
def console(renderer, drawer, tmp_path):
    _, control = renderer
    served = ServedConsole(
        ConsoleServer(control.address, TOKEN, "127.0.0.1", 0, tmp_path, model=drawer)
    )
    yield served
    served.close()


def _api(console, path):
    with urllib.request.urlopen(f"{console.base}{path}?token={TOKEN}", timeout=60) as r:
        assert r.status == 200
        return json.loads(r.read())


def _page_run(console, scenario):
    """Run ``scenario(ws)`` on a page's WebSocket, its hello taken."""

    async def run():
        async with aiohttp.ClientSession() as session:
            url = f"{console.base}ws?token={TOKEN}"
            origin = {"Origin": f"http://127.0.0.1:{console.server.port}"}
            async with session.ws_connect(url, headers=origin) as ws:
                await _next(ws, "hello")
                return await scenario(ws)

    return asyncio.run(run())


async def _next(ws, *kinds, timeout=30.0):
    """The next message of one of ``kinds`` (ticks and others skipped)."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError(f"no {kinds} message within {timeout} s")
        msg = await ws.receive_json(timeout=left)
        if msg["type"] in kinds:
            return msg


def test_declaration_lists_the_drawers_parameters_but_its_geometry(console, drawer):
    body = _api(console, "api/declaration")
    rows = body["params"]
    expected = [p for p in drawer.params if p.group in ("specification", "numerics")]
    assert [r["name"] for r in rows] == [p.name for p in expected]
    assert {"box.mass", "runners.level", "grease.c", "stop.k", "softie.c_fluid"} <= {
        r["name"] for r in rows
    }
    assert not {"stop.at", "softie.engage"} & {r["name"] for r in rows}
    for row, p in zip(rows, expected, strict=True):
        assert (row["unit"], row["lower"], row["upper"]) == (p.unit, p.lower, p.upper)
        lo, hi = row["range"]  # the slider's: inside the declared range
        assert row["meaning"] == p.meaning and p.lower <= lo < hi <= p.upper
        assert row["step"] == nice_step(hi - lo)
    by_name = {r["name"]: r for r in rows}
    units = {name: r["unit"] for name, r in by_name.items()}
    assert units["box.mass"] == "kg" and units["stop.k"] == "N/m" and units["grease.c"] == "N s/m"
    # four times the value the render started with: a step a hand can feel
    assert by_name["box.mass"]["range"] == [1e-6, 12.0] and by_name["box.mass"]["step"] == 0.5
    assert by_name["stop.k"]["range"] == [1.0, 20000.0] and by_name["stop.k"]["step"] == 500.0
    keys = [k for r in rows for k in r["keys"] if k]
    assert len(keys) == len(set(keys)) == 2 * min(len(rows), len(KEY_PAIRS))
    assert rows[0]["keys"] == list(KEY_PAIRS[0])
    model = body["model"]
    assert model["name"] == "soft-close-drawer" and model["unit"] == "m"
    assert model["range"] == [0.0, 0.45] and not model["door"] and not model["jnd"]


def test_a_change_is_the_renderers_to_check(console, renderer):
    loop, _ = renderer

    async def scenario(ws):
        await ws.send_json({"type": "set", "values": {"grease.c": 5.5}, "source": "key"})
        applied = await _next(ws, "params", "refused")
        await ws.send_json({"type": "set", "values": {"stop.k": 1.0e6}})
        stiff = await _next(ws, "params", "refused")
        await ws.send_json({"type": "set", "values": {"stop.at": 0.4}})
        geometry = await _next(ws, "params", "refused")
        return applied, stiff, geometry

    applied, stiff, geometry = _page_run(console, scenario)
    assert applied["type"] == "params" and applied["params"]["grease.c"] == 5.5
    assert loop.params["grease.c"] == 5.5
    # the renderer's reason, on one line, and the set in force kept
    assert stiff["type"] == "refused" and "\n" not in stiff["error"]
    assert "not passive" in stiff["error"] and "(stop.k)" in stiff["error"], stiff
    assert loop.params["stop.k"] == 5000.0
    assert geometry["type"] == "refused" and "stop.at" in geometry["error"]
    assert "the console changes" in geometry["error"] and loop.params["stop.at"] == 0.45


def test_curve_is_the_drawers_own_in_metres(console, renderer, drawer):
    loop, _ = renderer
    body = _api(console, "api/curve")
    ref = force_angle_curve(drawer, loop.params)
    assert body["unit"] == "m" and "theta_deg" not in body
    assert body["theta"] == pytest.approx(ref["theta"].tolist(), rel=1e-12)
    assert body["opening"] == pytest.approx(ref["opening"].tolist(), rel=1e-12, abs=1e-12)
    assert body["closing"] == pytest.approx(ref["closing"].tolist(), rel=1e-12, abs=1e-12)
    assert body["theta"][0] == 0.0 and body["theta"][-1] == 0.45
    # the runners' dry friction: the opening and closing curves 2 x 1.2 N apart mid-stroke
    mid = min(range(len(body["theta"])), key=lambda k: abs(body["theta"][k] - 0.2))
    assert body["closing"][mid] - body["opening"][mid] == pytest.approx(2.4, rel=1e-6)


def test_save_writes_a_file_render_params_takes(console, renderer, drawer, tmp_path, capsys):
    loop, _ = renderer

    async def scenario(ws):
        await ws.send_json({"type": "set", "values": {"runners.level": 2.0}})
        await _next(ws, "params")
        await ws.send_json({"type": "save", "name": "P07 drawer"})
        saved = await _next(ws, "saved", "error")
        await ws.send_json({"type": "jnd_start", "param": "runners.level"})
        return saved, await _next(ws, "error", "jnd")

    saved, jnd = _page_run(console, scenario)
    path = Path(saved["path"])
    assert path == tmp_path.resolve() / "P07_drawer.yaml"
    assert path.read_text().startswith("model: soft-close-drawer\n")
    assert drawer.load_params(path).as_dict() == loop.params.as_dict()
    assert drawer.load_params(path)["runners.level"] == 2.0
    assert jnd["type"] == "error" and "\n" not in jnd["error"]
    assert "JND sessions compare the haptic model's sensations" in jnd["error"]
    args = ["render", DRAWER, "--params", str(path), "--user", "close", "--duration", "0.3"]
    assert main(args) == 0, capsys.readouterr().err
    assert "soft-close-drawer" in capsys.readouterr().out


def test_a_console_not_told_the_mechanisms_file_says_how(renderer, drawer, tmp_path):
    _, control = renderer
    server = ConsoleServer(control.address, TOKEN, "127.0.0.1", 0, tmp_path, wait=1.0)
    with pytest.raises(UserError) as err:
        asyncio.run(server.start())
    assert "renders model 'soft-close-drawer': give its file with --model" in str(err.value)
    other = get_model("haptic")
    server = ConsoleServer(control.address, TOKEN, "127.0.0.1", 0, tmp_path, model=other)
    with pytest.raises(UserError) as err:
        asyncio.run(server.start())
    assert "--model: model 'haptic', but the renderer" in str(err.value)


def test_the_terminal_keys_of_a_mechanism_are_the_consoles(drawer):
    """``render DRAWER`` on a terminal: the keys step what the console changes, by its
    steps; the haptic model's keys are as they were."""
    from evo_door.models.haptic import PARAMS
    from evo_door.render.console.sensations import tunable_keys
    from evo_door.render.keys import key_change, key_map, screen

    params = drawer.load_params(None, {"stop.k": 5000.0})
    keys = tunable_keys(drawer.params, params.as_dict())
    assert keys["a"] == ("box.mass", -0.5) and keys["A"] == ("box.mass", 0.5)
    assert ("stop.k", 500.0) in keys.values()
    assert not {"stop.at", "softie.engage"} & {name for name, _ in keys.values()}
    assert key_change("A", params.as_dict(), keys, drawer.params) == {"box.mass": 3.5}
    assert tunable_keys(PARAMS) == key_map()
    device = yielding_sim("hold", path=Stroke(*drawer.theta_range))
    text = screen(MechanismLoop(device, drawer, params), keys, "", drawer.params, "m")
    assert "box.mass" in text and " kg" in text and "stop.k" in text and " N/m" in text


@pytest.mark.slow
def test_render_console_serves_a_mechanism(tmp_path_factory, tmp_path):
    """``render DRAWER --console``: the console process is told the drawer's file, its
    page declares the drawer's parameters and draws its curve, and it ends with the
    render."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env[CACHE_ENV] = str(tmp_path_factory.getbasetemp() / "mechanisms")
    cmd = [sys.executable, "-m", "evo_door", "render", DRAWER, "--set", "stop.k=5000"]
    cmd += ["--user", "hold", "--duration", "8", "--console", "--console-port", "0"]
    cmd += LOADED_MACHINE_WATCHDOG  # paced beside the suite's workers: a 53 ms stall ended one
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=subprocess.PIPE, text=True)
    try:
        url = console_url(proc.stdout)
        assert url.startswith("http://127.0.0.1:") and "?token=" in url
        base, query = url.split("?")
        with urllib.request.urlopen(f"{base}api/declaration?{query}", timeout=60) as r:
            body = json.loads(r.read())
        assert body["model"]["name"] == "soft-close-drawer"
        assert "stop.k" in [row["name"] for row in body["params"]]
        with urllib.request.urlopen(f"{base}api/curve?{query}", timeout=60) as r:
            assert json.loads(r.read())["unit"] == "m"
        rest = proc.stdout.read()
        assert proc.wait(60) == 0, rest
        assert "soft-close-drawer" in rest
    finally:
        proc.kill()
        proc.wait(30)
    with pytest.raises(OSError):
        urllib.request.urlopen(f"{base}api/declaration?{query}", timeout=2)
