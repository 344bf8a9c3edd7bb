"""The HapticMaster emulator is bounded: physical settings only, prompt answers at any
accepted stiffness, physics that stays finite, memory that does not grow with use."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from evo_door.render.emulator import (
    KEPT_CHARS,
    LIMITS,
    MAX_CLIENTS,
    MAX_EFFECTS,
    RECENT,
    RECENT_FRAMES,
    HapticMasterEmulator,
)
from evo_door.render.emulator_physics import MAX_SUBSTEPS, advance_effects
from evo_door.render.hapticmaster import HapticMasterDevice
from evo_door.render.hm_protocol import HapticMasterError, encode

EFFECTS = "create spring sp;create biasforce bf;create damper dm"


def _state(emu: HapticMasterEmulator):
    """What a setting could change: mass, friction, every effect's settings."""
    effects = {
        name: {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in e.items()}
        for name, e in emu.effects.items()
    }
    return emu.inertia, emu.coulomb_friction, effects


@pytest.mark.parametrize(
    "command",
    [
        "set inertia inf",
        "set inertia nan",
        "set inertia -1",
        "set inertia 0",
        "set inertia 1e9",
        "set coulombfriction -1",
        "set coulombfriction inf",
        "set sp stiffness 1e24",
        "set sp stiffness -5",
        "set sp stiffness nan",
        "set sp dampfactor inf",
        "set sp deadband -0.1",
        "set sp maxforce 0",
        "set sp maxforce nan",
        "set sp pos [0,0,1e30]",
        "set sp direction [inf,0,0]",
        "set bf force [0,1e9,0]",
        "set bf force [nan,0,0]",
        "set dm dampcoef [-5,0,0]",
    ],
)
def test_settings_out_of_a_physical_range_are_refused(emulator, command):
    emulator.answer_frame(EFFECTS)
    before = _state(emulator)
    answer = emulator.answer_frame(command)
    assert answer.startswith("--- ERROR") and "outside" in answer, answer
    assert _state(emulator) == before


def test_the_client_reads_a_refusal_as_one_line(emulator):
    from tests.helpers import started

    device = started(emulator)
    with pytest.raises(HapticMasterError, match="device refused 'set inertia inf'") as info:
        device.request("set inertia inf")
    assert "\n" not in str(info.value) and "outside 0.01 to 1000 kg" in str(info.value)
    device.stop()


def test_stiffest_accepted_springs_answer_promptly_and_stay_finite():
    """Every spring at the stiffness limit on the lightest mass: substepped within
    MAX_SUBSTEPS, answered in milliseconds, the mass settling between the springs."""
    low_mass, k_max = LIMITS["inertia"][0], LIMITS["stiffness"][1]
    with HapticMasterEmulator(clock="query", steps_per_query=125, inertia=low_mass) as emu:
        emu.answer_frame("set state init;set state force")
        for i in range(MAX_EFFECTS):
            name = f"s{i}"
            x = 0.01 * (i % 5)
            answer = emu.answer_frame(
                f"create spring {name};set {name} stiffness {k_max:g};"
                f"set {name} pos [{x},0,0];set {name} dampfactor 20;set {name} enable"
            )
            assert "ERROR" not in answer, answer
        assert emu.answer_frame("create spring one_too_many").startswith("--- ERROR")
        t0 = time.perf_counter()
        for _ in range(10):  # 10 x 0.05 s of device time
            pos = emu.answer_frame("get modelpos")
        elapsed = time.perf_counter() - t0
    assert elapsed < 2.0, elapsed  # about 10 ms on a quiet machine; 1e24 hung for ever
    x = [float(c) for c in pos.strip("[]").split(",")]
    assert np.all(np.isfinite(x)) and 0.0 <= x[0] <= 0.04 and emu.faults == 0


def test_the_kernel_is_bounded_whatever_it_is_given():
    """Past the limits (the protocol refuses them) an advance still ends at once:
    at most MAX_SUBSTEPS substeps per step, however stiff; the emulator then undoes a
    step that left the mass non-finite rather than answer NaN positions."""
    pos, vel = np.zeros(3), np.zeros(3)
    k, at = np.array([1e24]), np.array([[0.1, 0.0, 0.0]])
    t0 = time.perf_counter()
    advance_effects(
        pos, vel, 125, 4e-4, 4.0, np.zeros(3), 0.0, np.zeros(3), k, at,
        np.zeros(1), np.zeros((1, 3)), np.zeros(1), np.full(1, np.inf),
    )  # fmt: skip
    assert time.perf_counter() - t0 < 1.0  # 125 x MAX_SUBSTEPS substeps, not 1e9 each
    assert MAX_SUBSTEPS <= 256
    with HapticMasterEmulator(clock="query", steps_per_query=125) as emu:
        emu.answer_frame("set state init;set state force;create spring sp;set sp enable")
        emu.effects["sp"]["stiffness"] = 1e24  # what the protocol would refuse
        emu.effects["sp"]["pos"] = np.array([0.1, 0.0, 0.0])
        emu._layout = None
        t0 = time.perf_counter()
        answer = emu.answer_frame("get modelpos;get modelvel")
        assert time.perf_counter() - t0 < 1.0
    position, velocity = answer.split(";")
    assert "nan" not in answer.lower() and "inf" not in answer.lower(), answer
    assert emu.faults >= 1


def test_memory_stays_bounded_over_many_commands(emulator):
    """5e4 commands (500 frames of 100, 12 times what it keeps) through answer_frame:
    counted, only the last kept; every container the emulator holds stays within its
    bound (it kept every command, and every connection's thread, before)."""
    emulator.answer_frame("set state init;set state force;create biasforce bf;set bf enable")
    frame = ";".join(["set bf force [1,2,3]", "get modelpos", "get bf force", "bogus"] * 25)
    for _ in range(500):
        emulator.answer_frame(frame)
    assert emulator.commands == 4 + 50_000
    assert emulator.frames_answered == 501 and emulator.refused == 12_500
    assert len(emulator.received) == RECENT and emulator.received[-1] == "bogus"
    assert len(emulator.frames) == RECENT_FRAMES
    # a command or frame of 64 kB is kept cut short
    emulator.answer_frame("x" * 60_000 + ";get state")
    assert max(len(c) for c in emulator.received) <= KEPT_CHARS
    assert max(len(f) for f in emulator.frames) <= 4 * KEPT_CHARS
    for name, value in vars(emulator).items():  # any list, dict or deque it keeps
        if hasattr(value, "__len__") and not isinstance(value, (str, bytes, np.ndarray)):
            assert len(value) <= RECENT, name


def test_connections_are_bounded_and_forgotten_when_they_end(emulator):
    socks = [socket.create_connection(("127.0.0.1", emulator.port)) for _ in range(MAX_CLIENTS + 2)]
    try:
        for sock in socks[:MAX_CLIENTS]:  # served
            sock.sendall(encode("get state"))
            sock.settimeout(5.0)
            assert sock.recv(64)
        for sock in socks[MAX_CLIENTS:]:  # refused: closed at once
            sock.settimeout(5.0)
            assert sock.recv(64) == b""
    finally:
        for sock in socks:
            sock.close()
    end = time.monotonic() + 5.0
    while (emulator._clients or emulator._threads) and time.monotonic() < end:
        time.sleep(0.01)
    assert not emulator._clients and not emulator._threads
    # and a new client is served again
    device = HapticMasterDevice("127.0.0.1", emulator.port, init_wait=0.0, timeout=2.0)
    device.start()
    device.stop()
    assert emulator.state == "stop"


def test_the_scripted_hand_starts_when_the_device_renders_whoever_else_asks():
    """The hand's script runs from the moment the device enters the force state, each
    time it does, whatever other clients ask meanwhile. Its clock was the emulator's
    own, which skips any silence longer than MAX_ADVANCE (a stall): while a host waited
    for the device to home, a second connection asking 100 times a second (a
    supervisor's keep-alive) carried the script 0.3 s on, against 0.05 s without it,
    and a render began at another point of its script (the viscous damping estimated
    from a swing log moved from 0.85 to 0.95 N s/rad with a 10 Hz keep-alive)."""
    seen = []

    def hand(t, position, velocity):
        seen.append(t)
        return np.zeros(3)

    for asking in (False, True):
        with HapticMasterEmulator(user_force=hand) as emu:
            emu.answer_frame("set state init")
            for _ in range(30):  # the host waits 0.3 s; another client asks, or not
                time.sleep(0.01)
                if asking:
                    emu.answer_frame("get state")
            for _ in range(2):  # a render, stopped, and another
                emu.answer_frame("set state force")
                seen.clear()
                emu.answer_frame("get modelpos")
                assert seen == [0.0], (asking, seen)  # at the start of its script
                time.sleep(0.02)
                emu.answer_frame("get modelpos")  # an advance takes the hand at its start
                emu.answer_frame("get modelpos")
                assert 0.019 < seen[-1] <= 0.05 + 1e-9  # then on the wall clock
                emu.answer_frame("set state stop")
