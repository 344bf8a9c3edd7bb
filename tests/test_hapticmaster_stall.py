"""Stalls of the device or of the link: the renderer ends at once and leaves no force.

The HapticMaster keeps rendering its effects (the bias force through which the
renderer adds its force) after a connection closes, and has no timeout of its own.
These tests stall a real emulator process (SIGSTOP, SIGCONT) under a real client over
TCP on 127.0.0.1 and read what the device holds afterwards through a connection of
their own (:func:`probe`), independent of the renderer's.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from evo_door.cli import main
from evo_door.models.haptic import on_path
from evo_door.render.hapticmaster import FAILSAFE_WAIT, STALL_FLOOR, HapticMasterDevice
from evo_door.render.hm_protocol import (
    BIAS_NAME,
    FrameReader,
    HapticMasterConnectionLost,
    encode,
    failsafe_commands,
)
from evo_door.render.loop import ServoLoop
from tests.helpers import LOADED_MACHINE_WATCHDOG, freeze

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGSTOP"), reason="needs SIGSTOP")


@contextlib.contextmanager
def emulator_process(*options: str):
    """``evo-door emulate hapticmaster --port 0`` in a process of its own: (process, port)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "evo_door", "emulate", "hapticmaster", "--port", "0"]
        + ["--seconds", "300", *options],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        line = proc.stdout.readline()  # its first line names the port, flushed
        assert "127.0.0.1:" in line, line
        yield proc, int(line.split("127.0.0.1:")[1].split()[0])
    finally:
        proc.send_signal(signal.SIGCONT)  # a stopped process would not see the SIGTERM
        proc.terminate()
        proc.wait(10)


def probe(port: int, *commands: str) -> list[str]:
    """The device's answers to ``commands`` over a connection of the test's own."""
    with socket.create_connection(("127.0.0.1", port), timeout=5.0) as sock:
        sock.sendall(encode(";".join(commands)))
        reader = FrameReader()
        while True:
            data = sock.recv(4096)
            assert data, "the device closed the probe's connection"
            texts = reader.feed(data)
            if texts:
                return texts[0].split(";")


def bias_newtons(port: int) -> float:
    """The bias force the device holds (N); 0 when it has none."""
    (answer,) = probe(port, f"get {BIAS_NAME} force")
    if answer.startswith("--- ERROR"):  # no such effect
        return 0.0
    return float(np.linalg.norm([float(c) for c in answer.strip("[]").split(",")]))


def wait_for(condition, seconds: float, every: float = 0.02) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(every)
    return condition()


def assert_holds_no_force(port: int) -> None:
    """After the fail-safe: the device stopped, no bias force, no effect left."""
    assert wait_for(lambda: probe(port, "get state") == ["stop"], 10.0), probe(port, "get state")
    state, bias, plane = probe(
        port, "get state", f"get {BIAS_NAME} enabled", "get evoDoorPlane enabled"
    )
    assert state == "stop"
    assert bias.startswith("--- ERROR") and plane.startswith("--- ERROR"), (bias, plane)


# -- the client against a stalled device ----------------------------------------------


@pytest.mark.slow
def test_a_stalled_device_is_noticed_in_milliseconds_and_resumes_without_force():
    """SIGSTOP the device while it holds 40 N: the read fails within the stall
    timeout (the socket timeout took 1 s), stop() returns at once, and the device,
    resumed, reads the fail-safe from the connection: stopped, no effect."""
    with emulator_process() as (emu, port):
        device = HapticMasterDevice("127.0.0.1", port, init_wait=0.0, timeout=5.0)
        device.start()
        assert device.stall_timeout == STALL_FLOOR
        device.command([0.0, 40.0, 0.0])
        device.read()
        assert probe(port, f"get {BIAS_NAME} force", "get state") == ["[0,40,0]", "force"]
        freeze(emu.pid)
        try:
            t0 = time.monotonic()
            with pytest.raises(HapticMasterConnectionLost, match="no answer within 50 ms"):
                device.command([0.0, 40.0, 0.0])  # lands in the kernel's buffers
                device.read()
            noticed = time.monotonic() - t0
            device.stop()
            stopped = time.monotonic() - t0
        finally:
            os.kill(emu.pid, signal.SIGCONT)
        # generous for a loaded machine, far below the old 1 s
        assert noticed < STALL_FLOOR + 0.25, noticed
        assert stopped < noticed + FAILSAFE_WAIT + 0.25, stopped
        assert device.failsafe == "unacknowledged" and not device.connected
        assert "may still hold a force" in device.failsafe_warning
        assert "\n" not in device.failsafe_warning
        assert_holds_no_force(port)


@pytest.mark.slow
def test_render_over_a_stalled_emulator_ends_within_half_a_second():
    """A render holds tens of newtons, the emulator stops for 3 s;
    the render ends within 0.5 s of the stall's start, non-zero, with the reason in
    one line; the emulator, resumed, holds no force."""
    with emulator_process("--user", "hold", "--damping", "10") as (emu, port):
        render = _render(port)
        try:
            # the radial spring (its circle 4 cm inside the hand's) pulls on the handle
            assert wait_for(lambda: bias_newtons(port) > 20.0, 90.0), render.poll()
            freeze(emu.pid)
            t0 = time.monotonic()
            try:
                code = render.wait(timeout=2.5)
                ended = time.monotonic() - t0
                time.sleep(max(3.0 - (time.monotonic() - t0), 0.0))
            finally:
                os.kill(emu.pid, signal.SIGCONT)
            out, err = render.communicate(timeout=10)
        finally:
            _end(render)
        assert ended < 0.5, (ended, out, err)
        assert code == 1, (out, err)
        assert "watchdog: device read failed:" in out and "no answer within 50 ms" in out, out
        # one line of the renderer's on stderr: the force may still be on until the device
        # resumes (the supervisor, a process of its own, says in its own line that it
        # saw the loop stop beating and sent the removal too)
        own = [ln for ln in err.splitlines() if not ln.startswith("evo-door: supervisor:")]
        assert len(own) == 1 and own[0].startswith("evo-door: warning:"), err
        assert "may still hold a force" in own[0]
        assert_holds_no_force(port)


@pytest.mark.slow
def test_sigterm_ends_a_render_with_the_force_taken_off():
    """SIGTERM (a service manager, kill): the render ends as on Ctrl-C, the device
    left stopped, without effects (the default action ended the process at once)."""
    with emulator_process("--user", "hold", "--damping", "10") as (_, port):
        render = _render(port)
        try:
            assert wait_for(lambda: bias_newtons(port) > 20.0, 90.0), render.poll()
            render.send_signal(signal.SIGTERM)
            out, err = render.communicate(timeout=10)
        finally:
            _end(render)
        assert render.returncode == 0 and "stopped by the operator" in out, (out, err)
        assert err == ""  # acknowledged: nothing to warn of
        assert_holds_no_force(port)


def _render(port: int) -> subprocess.Popen:
    """``evo-door render`` on the emulator at ``port``, with a pull of tens of newtons:
    the handle held (emulator's --user hold) on a circle of 0.3 m, the rendered door's
    radius 0.26 m, so its radial spring pulls 4 cm in. At 1 kHz with 50 misses allowed
    (a loaded machine), the watchdog's budget is the stall floor, 50 ms; the device's
    damping (emulator and render alike) 10 N s/m keeps the set passive at the period a
    loaded machine keeps."""
    return subprocess.Popen(
        [sys.executable, "-m", "evo_door", "render", "--params", "seed_trial"]
        + ["--set", "radius=0.26", "--device", f"hapticmaster://127.0.0.1:{port}"]
        + ["--device-damping", "10", "--rate", "1000", "--watchdog-misses", "50"]
        + ["--duration", "60"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _end(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.communicate(timeout=10)


# -- the fail-safe on every way out ---------------------------------------------------


def test_failsafe_frame_ends_a_normal_render_and_one_that_raised(seed_trial):
    """The loop's end and an exception inside it both send the fail-safe frame, whole,
    before the connection closes, and the device acknowledges it. The loop gives the
    device its watchdog's budget as the stall timeout."""
    from evo_door.render.emulator import HapticMasterEmulator

    with HapticMasterEmulator(position=on_path(1.2, 0.31)) as emu:
        for failing in (False, True):
            dev = HapticMasterDevice("127.0.0.1", emu.port, damping=2.0, init_wait=0.0)
            loop = ServoLoop(dev, seed_trial, rate=2000.0, watchdog_misses=1000)
            held = []
            add = loop.log.add

            def add_then_fail(t, row, add=add, failing=failing, held=held):
                add(t, row)
                held.append(float(np.linalg.norm(emu.bias_force())))
                if failing and len(held) == 200:
                    raise RuntimeError("a bug in the loop")

            loop.log.add = add_then_fail
            if failing:
                with pytest.raises(RuntimeError, match="a bug"):
                    loop.run(0.5)
                assert loop.status == "failed"
            else:
                loop.run(0.1)
                assert loop.status == "done"
            assert max(held) > 1.0  # it held a force while rendering
            assert dev.stall_timeout == pytest.approx(1000 / 2000.0)  # misses x period
            assert emu.frames[-1] == ";".join(failsafe_commands())
            assert dev.failsafe == "acknowledged" and dev.failsafe_warning == ""
            assert emu.state == "stop" and not emu.effects


def test_render_says_in_one_line_when_the_device_may_still_hold_a_force(capsys):
    """The device closes the connection while the render holds a force: the fail-safe
    cannot reach it (the emulator keeps its effects, as the HapticMaster does), and
    the render says so in one line and exits non-zero."""
    from evo_door.render.emulator import HapticMasterEmulator

    with HapticMasterEmulator(position=on_path(1.2, 0.31)) as emu:

        def drop_once_rendering() -> None:
            if wait_for(lambda: np.linalg.norm(emu.bias_force()) > 1.0, 60.0):
                time.sleep(0.05)
                emu.drop_clients()

        dropper = threading.Thread(target=drop_once_rendering, daemon=True)
        dropper.start()
        code = main(
            ["render", "--params", "seed_trial", "--device"]
            + [f"hapticmaster://127.0.0.1:{emu.port}", "--device-damping", "2"]
            + ["--rate", "1000", *LOADED_MACHINE_WATCHDOG, "--duration", "20"]
        )
        dropper.join(5.0)
        out, err = capsys.readouterr()
        assert code == 1, (out, err)
        assert "closed by the device" in out
        assert err.count("\n") == 1 and err.startswith("evo-door: warning:"), err
        assert "could not be delivered" in err and "may still hold a force" in err
        # and it is true: the device still renders the bias force
        assert emu.effects[BIAS_NAME]["enabled"] and emu.state == "force"


def test_answers_ending_with_a_semicolon_are_read():
    from evo_door.render.hm_protocol import split_answers

    assert split_answers("stop;", ["get state"]) == ["stop"]
    assert split_answers("true;false;", ["a", "b"]) == ["true", "false"]


def test_stall_timeout_has_a_floor_and_can_be_fixed():
    device = HapticMasterDevice("127.0.0.1", 1)
    assert device.watch_stalls(0.004) == STALL_FLOOR  # 10 misses at 2500 Hz
    assert device.watch_stalls(0.2) == pytest.approx(0.2)
    fixed = HapticMasterDevice("127.0.0.1", 1, stall_timeout=0.3)
    assert fixed.watch_stalls(0.004) == pytest.approx(0.3)
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(Exception, match="stall timeout"):
            HapticMasterDevice("127.0.0.1", 1, stall_timeout=bad)


def test_close_takes_the_force_off_too(emulator):
    """close() is stop(): no way to close the connection without the fail-safe first."""
    from tests.helpers import started

    device = started(emulator)
    device.command([0.0, 30.0, 0.0])
    device.read()
    assert emulator.bias_force().tolist() == [0.0, 30.0, 0.0]
    device.close()
    assert emulator.frames[-1] == ";".join(failsafe_commands())
    assert device.failsafe == "acknowledged" and not device.connected
    assert emulator.state == "stop" and not emulator.effects
