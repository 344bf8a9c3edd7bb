"""Rendering a mechanism (docs/renderer.md, "Rendering a mechanism"): a state-vector
model's handle on the device, its force from the compiled rhs, its other states
integrated in the loop.

- the force the loop commands at a set device state is the mechanism's force on the
  hand, written again here, and points the right way along the device's axis or the
  circle's tangent (a linear drawer, a rotary door with a weight);
- a render on the simulated device with a virtual hand: the other states (a second
  body, a soft-close's fluid) follow an independent scipy integration of the same
  equations, written again here, with the handle's logged trajectory imposed;
- a too-stiff stop, a mechanism that moves on its own, a model with no state vector:
  refused in one line, the number named;
- the command end to end: summary, log, the commanded force against the law, on the
  simulated device and on the emulated HapticMaster over TCP.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from evo_door.cli import main
from evo_door.errors import UserError
from evo_door.files import open_h5, read_attrs
from evo_door.models import get_model
from evo_door.models.blocks import CACHE_ENV
from evo_door.models.haptic import on_path
from evo_door.params import param_vector
from evo_door.render.device import SimDevice
from evo_door.render.mechanism import (
    C_ACROSS,
    K_ACROSS,
    RADIUS,
    MechanismLoop,
    Stroke,
)
from tests.helpers import LOADED_MACHINE_LIMITS, LOADED_MACHINE_WATCHDOG

DRAWER = str(Path(__file__).resolve().parents[1] / "examples" / "blocks" / "soft_close_drawer.yaml")
#: the drawer's stop made soft enough for the default loop: K T / 2 = 1 N s/m below
#: the simulated device's 2 N s/m at 2500 Hz (its own 1e5 N/m is refused, as it must be)
SOFT_STOP = {"stop.k": 5000.0}


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    """Generated mechanisms in a tmp folder of the session (not the user's cache)."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path_factory.getbasetemp() / "mechanisms"))


class FixedDevice:
    """A device held at one state: it reads ``pos``, ``vel``, ``user`` and keeps what it
    is commanded."""

    simulated = True
    max_force = 200.0
    damping = 2.0

    def __init__(self, pos, vel, user=(0.0, 0.0, 0.0)):
        self.pos, self.vel, self.user = (np.array(v, dtype=float) for v in (pos, vel, user))
        self.commands: list[np.ndarray] = []
        self.mass = None

    def start(self):
        pass

    def read(self):
        return self.pos.copy(), self.vel.copy(), self.user.copy()

    def command(self, force):
        self.commands.append(np.array(force, dtype=float))

    def step(self, dt):
        pass

    def stop(self):
        pass

    def set_mass(self, mass):
        self.mass = float(mass)


def one_cycle(model, params, pos, vel):
    """The force the loop commands in its first cycle with the device at ``pos``,
    ``vel``; and the device."""
    device = FixedDevice(pos, vel)
    loop = MechanismLoop(device, model, params, 2500.0, hands_off_speed=None)
    loop.run(1.0 / 2500.0)
    return device.commands[0], device


def write(tmp_path, name: str, text: str) -> str:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return str(path)


# -- (a) the force at a set device state ------------------------------------------------
def test_the_drawer_s_force_is_its_law_along_the_device_y_axis():
    model = get_model(DRAWER)
    params = model.load_params(None, SOFT_STOP)
    v = params.as_dict()
    lo, hi = model.theta_range
    for q, dq in ((0.40, 0.3), (0.40, -0.2), (0.20, 0.5), (0.452, 0.1)):
        y = q - 0.5 * (lo + hi)  # the stroke's middle at y = 0
        cmd, device = one_cycle(model, params, (0.0, y, 0.0), (0.0, dq, 0.0))
        # the law written again: runners (sign), grease, soft-close past engage, stop
        f = -v["runners.level"] * math.copysign(1.0, dq) - v["grease.c"] * dq
        if q > v["softie.engage"]:
            f += v["softie.pull"] - v["softie.c_fluid"] * dq
        if q > v["stop.at"]:
            f += min(-v["stop.k"] * (q - v["stop.at"]) - v["stop.c"] * dq, 0.0)
        # and the model's own rhs: mass times the handle's acceleration with no hand
        x = model.plant.initial_state(param_vector(params), q, dq)
        dx = np.empty_like(x)
        model.rhs(x, 0.0, param_vector(params), dx)
        assert cmd[1] == pytest.approx(v["box.mass"] * dx[1], rel=1e-12, abs=1e-12)
        assert cmd[1] == pytest.approx(f, rel=1e-12)
        assert cmd[0] == 0.0 and cmd[2] == 0.0  # on the axis, at rest across it
        assert np.sign(cmd[1]) == np.sign(f) != 0.0  # toward open (-y) when it brakes
        assert device.mass == pytest.approx(v["box.mass"], rel=1e-12)  # the handle's mass
    # off the axis the springs pull back toward it
    cmd, _ = one_cycle(model, params, (0.01, 0.0, -0.02), (0.0, 0.1, 0.0))
    assert cmd[0] < 0.0 and cmd[2] == pytest.approx(K_ACROSS * 0.02, rel=1e-12)


DOOR = """\
    mechanism:
      name: heavy-flap
      title: a flap whose weight pulls it open, on a damped hinge
      handle: flap
      bodies:
        flap: {kind: rotary, inertia: 0.4, mass: 2.0, arm: 0.1, hand_lever: 0.5,
               range: [0.0, 1.5]}
      elements:
        hinge: {kind: damper, on: flap, c: 0.8}
"""


def test_a_rotary_handle_s_moment_over_its_lever_acts_along_the_circle(tmp_path):
    model = get_model(write(tmp_path, "flap.yaml", DOOR))
    params = model.load_params()
    for theta, omega in ((0.3, 0.5), (1.2, -1.0)):
        pos = on_path(theta, RADIUS)
        vel = (0.0, RADIUS * omega * math.cos(theta), -RADIUS * omega * math.sin(theta))
        cmd, device = one_cycle(model, params, pos, vel)
        moment = -2.0 * 9.80665 * 0.1 * math.cos(theta) - 0.8 * omega
        f_t = moment / 0.5  # on the hand, N toward closed
        e_t = np.array([0.0, math.cos(theta), -math.sin(theta)])
        # on the circle, no radial speed: the constraint adds nothing
        np.testing.assert_allclose(cmd, f_t * e_t, rtol=1e-12, atol=1e-12)
        assert np.sign(cmd @ e_t) == np.sign(f_t) != 0.0  # the weight pulls it open, the
        # hinge damper against the motion (at 1.2 rad opening, it wins)
        assert device.mass == pytest.approx(0.4 / (0.5 * RADIUS), rel=1e-12)
    # off the circle (outside it) the radial spring pulls in
    theta = 0.7
    out = np.array(on_path(theta, RADIUS + 0.01))
    cmd, _ = one_cycle(model, params, out, (0.0, 0.0, 0.0))
    e_r = np.array([0.0, math.sin(theta), math.cos(theta)])
    assert cmd @ e_r == pytest.approx(-K_ACROSS * 0.01, rel=1e-9)
    assert C_ACROSS > 0.0


# -- (b) the other states integrated in the loop ----------------------------------------
COUPLED = """\
    mechanism:
      name: towed-cart
      title: a cart towing another through a spring and damper, with a soft-close fluid
      handle: a
      bodies:
        a: {kind: linear, mass: 2.0, range: [0.0, 0.4]}
        b: {kind: linear, mass: 1.5}
      elements:
        tow: {kind: spring, between: [a, b], k: 300.0, at: -0.1}
        tow_damping: {kind: damper, between: [a, b], c: 4.0}
        drag_b: {kind: damper, on: b, c: 3.0}
        grease: {kind: damper, on: a, c: 2.0}
        softie: {kind: soft_close, on: a, engage: 0.2, c_fluid: 40.0, tau: 0.02}
"""


def coupled_others(t, y, q, dq, v):
    """The towed cart and the fluid written again: ``y = (b, b_speed, fluid)``, the
    handle a at ``q + dq t`` moving at ``dq``."""
    b, vb, fluid = y
    a = q + dq * t
    tension = v["tow.preload"] + v["tow.k"] * (b - a - v["tow.at"])
    fb = -tension - v["tow_damping.c"] * (vb - dq) - v["drag_b.c"] * vb
    if a > v["softie.engage"]:
        dfluid = (-v["softie.c_fluid"] * dq - fluid) / v["softie.tau"]
    else:
        dfluid = -fluid / v["softie.tau"]
    return [vb, fb / v["b.mass"], dfluid]


def test_the_other_states_follow_scipy_with_the_logged_handle_imposed(tmp_path):
    model = get_model(write(tmp_path, "towed.yaml", COUPLED))
    params = model.load_params()
    v = params.as_dict()
    rate = 2500.0
    device = SimDevice("swing", path=Stroke(*model.theta_range), seed=3)
    loop = MechanismLoop(device, model, params, rate, log_rate=rate, hands_off_speed=3.0)
    names = model.plant.state_names
    others = [names.index(n) for n in ("b", "b_speed", "softie_fluid")]
    states = []
    loop.on_cycle = lambda t: states.append(loop.state[others])
    loop.run(1.6)
    rows = loop.log.rows()
    assert loop.faults == 0 and rows.shape[0] == len(states) == 4000
    from evo_door.render.columns import DTHETA, FORCE, THETA

    q, dq = rows[:, THETA], rows[:, DTHETA]
    assert np.ptp(q) > 0.1 and q.max() > v["softie.engage"] > q.min()  # it crossed engage
    assert np.all(np.isfinite(rows[:, FORCE]))
    # the start: the loop's first cycle puts the others at rest with the handle held
    # (the swing starts still): the tow slack, b where the spring has its rest length
    # (tension = preload + k (b - a - at) = 0), the fluid settled before engage (0)
    assert dq[0] == 0.0 and q[0] < v["softie.engage"]
    y = np.array([q[0] + v["tow.at"] - v["tow.preload"] / v["tow.k"], 0.0, 0.0])
    T = 1.0 / rate
    ref = np.empty((len(states), 3))
    for k in range(len(states)):
        sol = solve_ivp(
            coupled_others, (0.0, T), y, args=(q[k], dq[k], v), rtol=1e-11, atol=1e-13,
            method="DOP853",
        )  # fmt: skip
        y = sol.y[:, -1]
        ref[k] = y
    got = np.array(states)
    # b and its speed are smooth: RK4 at |h lambda| <= 1 is exact to far below 1e-6
    scale_b = np.ptp(ref[:, 0]) + np.ptp(ref[:, 1])
    assert np.max(np.abs(got[:, :2] - ref[:, :2])) < 1e-6 * scale_b
    # the fluid's rate jumps where a crosses engage: a Runge-Kutta step across the jump
    # misplaces at most the jump (c_fluid |dq| / tau) times the step, once a crossing,
    # and the fluid forgets it with tau: the bound is the largest such jump times T
    assert np.ptp(ref[:, 2]) > 1.0  # the fluid did work
    jump = v["softie.c_fluid"] * np.max(np.abs(dq)) / v["softie.tau"]
    assert np.max(np.abs(got[:, 2] - ref[:, 2])) < jump * T
    event = next(e for e in loop.log.events if e["kind"] == "model")
    assert event["model"] == "towed-cart" and event["handle"] == "a"


# -- (c) refusals -------------------------------------------------------------------------
def test_a_stop_too_stiff_for_the_rate_is_refused_in_one_line_naming_it(capsys):
    args = ["render", DRAWER, "--user", "swing", "--duration", "0.1"]
    assert main([*args, "--set", "stop.k=1e9"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert "not passive" in err and "K = 1e+09 N/m" in err and "(stop.k)" in err, err
    assert "box = 0.45" in err, err  # where the stiffness begins
    # the example's own 1e5 N/m too: 20 N s/m needed, the device has 2 (the line of
    # docs/renderer.md, "Rendering a mechanism")
    assert main(args) == 2
    assert capsys.readouterr().err.strip() == (
        "evo-door: error: mechanism refused: not passive at a 0.4 ms loop period: the "
        "handle's stiffness reaches K = 1e+05 N/m at box = 0.45 m (stop.k), negative damping "
        "|B| = 0 N s/m, and the device damping b = 2 N s/m is not above K T / 2 + |B| = 20 "
        "N s/m (lower it with --set NAME=VALUE, raise --rate, or state the device's damping "
        "with --device-damping)"
    )


def test_a_mechanism_that_moves_on_its_own_is_refused_hands_off(tmp_path):
    text = """\
        mechanism:
          name: sprung-drawer
          title: a light drawer pulled shut hard by its soft-close
          handle: box
          bodies:
            box: {kind: linear, mass: 0.5, range: [0.0, 0.45]}
          elements:
            softie: {kind: soft_close, on: box, engage: 0.3, c_fluid: 0.0, pull: 200.0}
            stop: {kind: end_stop, on: box, at: 0.45, k: 2000.0, c: 10.0}
    """
    model = get_model(write(tmp_path, "sprung.yaml", text))
    device = SimDevice("hold", path=Stroke(*model.theta_range))
    with pytest.raises(UserError) as err:
        MechanismLoop(device, model, model.load_params(), hands_off_speed=3.0)
    message = str(err.value)
    assert "\n" not in message and "with no hand on it" in message
    assert "above the hands-off limit of 1.8 m/s" in message, message


def test_a_model_without_a_state_vector_is_refused(capsys):
    assert main(["render", "door", "--user", "swing", "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "takes a model on a state vector" in err, err
    assert main(["render", DRAWER, "--clamp", "--control", "0"]) == 2
    assert "--clamp goes with the haptic model" in capsys.readouterr().err


# -- the command end to end ---------------------------------------------------------------
def test_render_a_mechanism_file_on_the_simulated_device(tmp_path, capsys):
    log = tmp_path / "drawer.h5"
    args = ["render", DRAWER, "--set", "stop.k=5000", "--user", "close", "--duration", "2.5"]
    assert main([*args, "--log-rate", "2500", "--log", str(log)]) == 0
    out = capsys.readouterr().out
    assert "model 'soft-close-drawer', handle box 0.1003 ->" in out, out
    with open_h5(log) as f:
        attrs = read_attrs(f["render"])
        theta = f["trials/render/theta"][:].astype(float)
        dtheta = f["trials/render/dtheta"][:].astype(float)
        command = f["render/command"][:].astype(float)
    assert attrs["statistics"]["model"] == "soft-close-drawer"
    assert any(e["kind"] == "model" for e in attrs["events"])
    # the logged command is the drawer's law at the logged state (float32 storage)
    model = get_model(DRAWER)
    v = model.load_params(None, SOFT_STOP).as_dict()
    f = -v["runners.level"] * np.sign(dtheta) - v["grease.c"] * dtheta
    engaged = theta > v["softie.engage"]
    f += np.where(engaged, v["softie.pull"] - v["softie.c_fluid"] * dtheta, 0.0)
    inside = theta - v["stop.at"]
    f += np.where(inside > 0.0, np.minimum(-v["stop.k"] * inside - v["stop.c"] * dtheta, 0.0), 0.0)
    # float32 can put a row either side of an edge
    near = (np.abs(theta - v["softie.engage"]) < 1e-5) | (np.abs(inside) < 1e-5)
    keep = ~near & (np.abs(dtheta) > 1e-4)
    assert keep.sum() > 3000 and theta.max() > v["stop.at"]  # into the stop, through engage
    np.testing.assert_allclose(command[keep, 1], f[keep], rtol=1e-4, atol=1e-3)


FLAP = """\
    mechanism:
      name: heavy-flap
      title: a flap whose weight pulls it open, on a damped hinge, stopped at open
      handle: flap
      bodies:
        flap: {kind: rotary, inertia: 0.4, mass: 2.0, arm: 0.1, hand_lever: 0.3,
               range: [0.0, 1.5]}
      elements:
        hinge: {kind: damper, on: flap, c: 2.0}
        open_stop: {kind: end_stop, on: flap, at: 0.0, side: below, k: 300.0, c: 5.0}
"""


def test_render_a_rotary_mechanism_on_the_emulated_hapticmaster_over_tcp(tmp_path, capsys):
    """The device layer is the haptic path's: the emulator in its own process, its hand
    swinging along the circle, the flap rendered at 1 kHz over real TCP."""
    import subprocess
    import sys

    flap = write(tmp_path, "flap.yaml", FLAP)
    emulator = subprocess.Popen(
        [sys.executable, "-m", "evo_door", "emulate", "hapticmaster", "--port", "0"]
        + ["--user", "swing", "--damping", "2", "--noise", "0.05", "--seconds", "60"],
        stdout=subprocess.PIPE,
        text=True,
    )
    log = tmp_path / "flap.h5"
    try:
        line = emulator.stdout.readline()
        port = int(line.split("127.0.0.1:")[1].split()[0])
        device = ["--device", f"hapticmaster://127.0.0.1:{port}", "--device-damping", "2"]
        args = ["render", flap, *device, "--rate", "1000", "--log-rate", "1000"]
        args += LOADED_MACHINE_LIMITS
        assert main([*args, "--duration", "3", "--log", str(log)]) == 0
    finally:
        emulator.terminate()
        emulator.wait(10)
    assert "model 'heavy-flap', handle flap 0.35 ->" in capsys.readouterr().out
    with open_h5(log) as f:
        theta = f["trials/render/theta"][:].astype(float)
        omega = f["trials/render/dtheta"][:].astype(float)
        command = f["render/command"][:].astype(float)
    assert theta.max() > 1.0  # the hand swung it
    # along the circle's tangent, the flap's moment over its lever (float32 storage;
    # a missed slot's rows are interpolated across, hence the loose largest error)
    f_t = (-2.0 * 9.80665 * 0.1 * np.cos(theta) - 2.0 * omega) / 0.3
    along = command[:, 1] * np.cos(theta) - command[:, 2] * np.sin(theta)
    err = np.abs(along - f_t)
    assert np.percentile(err, 99) < 1e-3 and err.max() < 0.5, (np.percentile(err, 99), err.max())


def test_other_states_too_stiff_for_the_cycle_are_refused_and_steps_follow_their_rate(
    tmp_path,
):
    """A light body on a stiff spring behind a soft tow: the handle feels 400 N/m (fine),
    the towed body rings at sqrt(k / m); the loop takes ceil(rho T) Runge-Kutta steps,
    at most 64."""
    text = """\
        mechanism:
          name: ringing-tow
          title: a cart towing a light body held by a stiff spring
          handle: a
          bodies:
            a: {kind: linear, mass: 2.0, range: [0.0, 0.4]}
            b: {kind: linear, mass: 1.0e-3}
          elements:
            tow: {kind: spring, between: [a, b], k: 400.0}
            anchor: {kind: spring, on: b, k: 1.0e7}
            drag: {kind: damper, on: b, c: 1.0}
    """
    model = get_model(write(tmp_path, "ringing.yaml", text))
    device = SimDevice("hold", path=Stroke(*model.theta_range))
    loop = MechanismLoop(device, model, model.load_params(), 2500.0, hands_off_speed=None)
    rho = math.sqrt((1.0e7 + 400.0) / 1.0e-3)  # |lambda| of the damped body, just over 1e5
    assert loop.substeps == math.ceil(rho / 2500.0) == 41
    with pytest.raises(UserError) as err:  # 1e6 1/s: 400 steps a cycle
        MechanismLoop(device, model, model.load_params(None, {"b.mass": 1.0e-5}), 2500.0)
    message = str(err.value)
    assert "\n" not in message and "too stiff for the loop" in message, message
    assert "fastest rate 1e+06 1/s" in message, message


def test_push_changes_a_rendered_mechanism_through_its_control_port(tmp_path, capsys):
    """``render DRAWER --control`` in a process of its own; ``push --set`` of the
    drawer's own names: applied and logged; a stop too stiff for the rate, an unknown
    name: refused in one line, the running set kept."""
    import os
    import subprocess
    import sys
    import time

    from evo_door.render.control import request

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root)}
    # paced at 1 kHz with a watchdog of 1 s: a loaded machine (CI) does not stall it
    cmd = [sys.executable, "-m", "evo_door", "render", DRAWER, "--set", "stop.k=1000",
           "--user", "hold", "--duration", "60", "--realtime", "--control", "0",
           "--rate", "1000", *LOADED_MACHINE_WATCHDOG,
           "--log", str(tmp_path / "drawer.h5")]  # fmt: skip
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    try:
        line = proc.stdout.readline()
        assert line.startswith("control port 127.0.0.1:"), (line, proc.stderr.read())
        to = line.split()[2]
        host, port = to.rsplit(":", 1)
        deadline = time.monotonic() + 60.0
        while request(host, int(port), {"get": "state"}).get("t", 0.0) <= 0.0:
            assert time.monotonic() < deadline and proc.poll() is None, proc.stderr.read()
            time.sleep(0.05)  # the loop's checks done, its cycles running
        assert main(["push", "--set", "grease.c=5.5", "--to", to, "--timeout", "60"]) == 0
        out = capsys.readouterr().out
        assert "grease.c = 5.5 N s/m" in out and "1 value(s)" in out
        assert main(["push", "--set", "stop.k=1e6", "--to", to, "--timeout", "60"]) == 2
        err = capsys.readouterr().err.strip()
        assert "not passive" in err and "(stop.k)" in err and "\n" not in err
        assert main(["push", "--set", "grease.cc=1", "--to", to, "--timeout", "60"]) == 2
        err = capsys.readouterr().err.strip()
        assert "has no parameter 'grease.cc' (did you mean 'grease.c'?)" in err
        assert main(["push", "--set", "grease.c=5.5", "--to", to, "--timeout", "60"]) == 0
        assert "nothing to push" in capsys.readouterr().out
    finally:
        proc.terminate()
        proc.wait(30)


_CYCLE_COMPILES = """
import sys
import numpy as np
from numba.core import event

compiled = []


class Count(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)

    def on_end(self, ev):
        pass


from evo_door.models import get_model
from evo_door.params import param_vector

model = get_model(sys.argv[1])  # generated and compiled, or loaded, before the count
p = param_vector(model.load_params(), model.params)
event.register("numba:compile", Count())
from evo_door.render.mechanism_kernels import hand_force

x = np.array(model.x0, dtype=float)
force = hand_force(model.rhs, x, p, model.handle[1], 1.0, np.empty(x.size))
print(len(compiled), force)
print(" ".join(compiled))
"""


def test_a_mechanisms_cycle_compiles_nothing_for_the_mechanisms_rendered_before(tmp_path):
    """The cycle's kernels take a mechanism's ``rhs`` as a typed first-class function:
    once compiled, a process rendering a mechanism compiles nothing, whatever others
    were rendered before it. (Typed by each mechanism's own function, numba's cache of
    them named every mechanism rendered before, and a process reading it compiled
    each of those again: tens of seconds of start-up after a few dozen.)"""
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root), CACHE_ENV: str(tmp_path / "mechanisms")}
    examples = root / "examples" / "blocks"
    runs = []
    for name in ("soft_close_drawer", "knob", "two_carts", "soft_close_drawer"):
        done = subprocess.run(
            [sys.executable, "-c", _CYCLE_COMPILES, str(examples / f"{name}.yaml")],
            env=env, capture_output=True, text=True, timeout=600,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-2000:]
        count, force = done.stdout.split("\n")[0].split()
        runs.append((int(count), done.stdout.split("\n")[1]))
        assert math.isfinite(float(force))
    assert runs[-1] == (0, ""), runs


def test_the_cycle_given_the_rhs_looked_up_once_is_the_cycle_given_the_function():
    """The loop hands its kernels the mechanism's ``rhs`` with its entry point looked up
    once (``RenderedModel.cycle_rhs``): 200 cycles of the drawer, moving, give the same
    states, commands and log rows to the bit as with the compiled function itself."""
    from evo_door.render.mechanism import RenderedModel
    from evo_door.render.mechanism_kernels import N_GEOMETRY, N_WORK, mechanism_command

    model = get_model(DRAWER)
    p = param_vector(model.load_params(), model.params)
    ih, iv = model.handle
    found = []
    for rhs in (model.rhs, RenderedModel(model).cycle_rhs):
        x = np.linspace(0.01, 0.2, len(model.x0))
        pos, vel, user = (
            np.array([0.0, 0.1, 0.0]),
            np.array([0.0, 0.3, 0.0]),
            np.array([0.0, 2.0, 0.0]),
        )
        geo = np.zeros(N_GEOMETRY)
        geo[:8] = (1.0, 0.0, 0.0, 2000.0, 5.0, 2000.0, 5.0, 0.5)
        hs, work, out, row = np.zeros(5), np.zeros((N_WORK, x.size)), np.zeros(3), np.zeros(40)
        rows = []
        for _ in range(200):
            pos[1] += 1e-4
            code = mechanism_command(rhs, pos, vel, user, x, p, geo, ih, iv, 1e-3, 4, 40.0, hs,
                                     work, out, row)  # fmt: skip
            rows.append((code, *x, *out, *row))
        found.append(np.array(rows))
    assert np.isfinite(found[0]).all() and np.ptp(found[0][:, 1]) > 0.0  # the drawer moved
    np.testing.assert_array_equal(found[1], found[0])
