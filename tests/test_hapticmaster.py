"""The HapticMaster string protocol: framing, the client Device, the emulator, the CLI.

Everything network-facing runs over real TCP on 127.0.0.1 with an ephemeral port.
"""

from __future__ import annotations

import math
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from evo_door.errors import UserError
from evo_door.render.emulator import HapticMasterEmulator
from evo_door.render.emulator_physics import advance
from evo_door.render.hapticmaster import HapticMasterDevice
from evo_door.render.hm_protocol import (
    BIAS_NAME,
    CYCLE_QUERY,
    FrameReader,
    HapticMasterConnectionLost,
    HapticMasterError,
    encode,
    failsafe_commands,
    parse_address,
    parse_vector,
    split_answers,
)
from tests.helpers import started


def exchange(sock: socket.socket, reader: FrameReader, n: int) -> list[str]:
    """Read ``n`` whole answer frames from a raw socket."""
    texts: list[str] = []
    sock.settimeout(2.0)
    while len(texts) < n:
        data = sock.recv(4096)
        assert data, "emulator closed the connection"
        texts.extend(reader.feed(data))
    return texts


# -- framing --------------------------------------------------------------------------


def test_header_carries_length_in_fourth_byte():
    frame = encode("get modelpos")
    assert len(frame) == 8 + 12
    assert frame[3] == 12 and frame[:3] == b"\0\0\0" and frame[4:8] == b"\0\0\0\0"
    assert frame[8:] == b"get modelpos"


@pytest.mark.parametrize("text", ["get state", "", "x" * 255, "y" * 256, "a;b;" * 700])
def test_frame_round_trip(text):
    assert FrameReader().feed(encode(text)) == [text.strip()]


def test_reader_reassembles_byte_by_byte_and_splits_batches():
    texts = ["get modelpos", "set f force [1,2,3]", "x" * 300]
    stream = b"".join(encode(t) for t in texts)
    reader = FrameReader()
    got = []
    for i in range(len(stream)):
        got.extend(reader.feed(stream[i : i + 1]))
        # a frame only once its last byte arrived, never early
        complete = sum(len(encode(t)) for t in texts[: len(got)])
        assert complete <= i + 1
    assert got == texts and reader.pending == 0
    # several frames and a half in one piece: the half waits for the rest
    reader = FrameReader()
    assert reader.feed(stream[:-5]) == texts[:2]
    assert reader.feed(stream[-5:]) == texts[2:]


def test_reader_refuses_corrupt_length():
    with pytest.raises(HapticMasterError, match="corrupt frame header"):
        FrameReader().feed(b"\xff\xff\xff\xff\0\0\0\0abc")


def test_answer_parsing_errors_are_one_line():
    assert parse_vector(" [1, -2.5,3e-3] ").tolist() == [1.0, -2.5, 0.003]
    for bad in ["[1,2]", "1,2,3", "[1,2,x]", "", "[1,2,3,4]", "--- ERROR: no"]:
        with pytest.raises(HapticMasterError) as info:
            parse_vector(bad, "get modelpos")
        assert "\n" not in str(info.value) and "get modelpos" in str(info.value)
    with pytest.raises(HapticMasterError, match="3 commands .* 2 answers"):
        split_answers("[0,0,0];[0,0,0]", CYCLE_QUERY.split(";"))
    with pytest.raises(HapticMasterError, match="device refused 'get nothing'"):
        split_answers("--- ERROR: unknown", ["get nothing"])
    assert isinstance(HapticMasterError("x"), UserError)


def test_parse_address():
    assert parse_address("hapticmaster://10.0.0.5:7654") == ("10.0.0.5", 7654)
    for bad in ["hapticmaster://host", "hapticmaster://:12", "host:0", "host:99999"]:
        with pytest.raises(UserError, match="HOST:PORT"):
            parse_address(bad)


# -- the emulator over TCP ------------------------------------------------------------


def test_emulator_accepts_partial_and_batched_frames(emulator):
    with socket.create_connection(("127.0.0.1", emulator.port)) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        reader = FrameReader()
        for byte in encode("get state"):  # one byte per send
            sock.sendall(bytes([byte]))
            time.sleep(0.0005)
        assert exchange(sock, reader, 1) == ["off"]
        # three frames in one send, the second a batch of two commands
        sock.sendall(encode("get inertia") + encode("get state;bogus cmd") + encode("remove all"))
        first, second, third = exchange(sock, reader, 3)
    assert float(first) == pytest.approx(4.0)
    state, error = second.split(";")
    assert state == "off" and error.startswith("--- ERROR")
    assert third == "All effects removed"
    assert emulator.received == ["get state", "get inertia", "get state", "bogus cmd", "remove all"]


def test_emulator_enforces_device_rules(emulator):
    answer = emulator.answer_frame
    assert answer("set state force").startswith("--- ERROR")  # no init yet
    assert answer("set state init") == "state set to 'init'"
    assert answer("set state force") == "state set to 'force'"
    assert answer("create biasforce bf") == "Effect biasforce with name bf created"
    assert answer("create biasforce bf").startswith("--- ERROR")  # name in use
    assert answer("set bf force [1,2]").startswith("--- ERROR")
    assert answer("set bf force [1,nan,2]").startswith("--- ERROR")
    assert answer("set nobody force [1,2,3]").startswith("--- ERROR")
    assert answer("set bf force [1,2,3];get bf force") == "Effect bf force set;[1,2,3]"
    assert emulator.bias_force().tolist() == [0.0, 0.0, 0.0]  # not enabled yet
    answer("set bf enable")
    assert emulator.bias_force().tolist() == [1.0, 2.0, 3.0]
    assert answer("remove all") == "All effects removed"
    assert emulator.bias_force().tolist() == [0.0, 0.0, 0.0]


def test_emulator_kernel_matches_damped_mass_and_sticks():
    m, b, dt, n = 4.0, 40.0, 1 / 2500, 250
    damping = np.full(3, b)
    none_k, none_at = np.zeros(0), np.zeros((0, 3))
    pos, vel = np.zeros(3), np.zeros(3)
    advance(pos, vel, n, dt, m, damping, 0.0, np.array([0.0, 10.0, 0.0]), none_k, none_at, none_k)
    # implicit Euler of m dv/dt = F - b v, closed form; and the exact solution within 1 %
    assert vel[1] == pytest.approx(10 / b * (1 - (1 + dt * b / m) ** -n), rel=1e-12)
    assert vel[1] == pytest.approx(10 / b * (1 - math.exp(-b * n * dt / m)), rel=1e-2)
    assert vel[0] == 0.0 and vel[2] == 0.0
    # Coulomb friction 20 N: a 10 N push does not move the mass, 30 N slides at (F - Fc)/b
    for push, speed in [(10.0, 0.0), (30.0, 10.0 / b)]:
        pos, vel = np.zeros(3), np.zeros(3)
        f = np.array([push, 0.0, 0.0])
        advance(pos, vel, 5000, dt, m, damping, 20.0, f, none_k, none_at, none_k)
        assert vel[0] == pytest.approx(speed, abs=1e-9)
    # a spring at 0.1 m with light damping settles there, stably
    pos, vel = np.zeros(3), np.zeros(3)
    at = np.array([[0.0, 0.0, 0.1]])
    advance(pos, vel, 20000, dt, m, damping, 0.0, np.zeros(3), np.array([5000.0]), at, np.zeros(1))
    assert pos[2] == pytest.approx(0.1, abs=1e-6)


# -- the client -----------------------------------------------------------------------


def test_start_up_and_shut_down_sequences(emulator):
    device = started(emulator)
    assert emulator.received == [
        "remove all",
        "get position_calibrated",
        "get force_calibrated",
        "set state init",
        "set state force",
        f"create biasforce {BIAS_NAME}",
        f"set {BIAS_NAME} force [0,0,0]",
        f"set {BIAS_NAME} enable",
    ]
    assert emulator.state == "force"
    device.command([0.0, 3.0, 0.0])
    device.read()
    assert emulator.bias_force().tolist() == [0.0, 3.0, 0.0]
    n = len(emulator.received)
    device.stop()
    # one frame: the bias force to zero, every effect removed, the device stopped
    assert emulator.received[n:] == failsafe_commands()
    assert emulator.frames[-1] == ";".join(failsafe_commands())
    assert device.failsafe == "acknowledged" and device.failsafe_warning == ""
    assert emulator.state == "stop" and emulator.bias_force().tolist() == [0.0, 0.0, 0.0]
    assert not emulator.effects
    assert not device.connected
    device.stop()  # idempotent
    assert len(emulator.received) == n + 3


def test_start_refuses_uncalibrated_device_and_leaves_it_stopped():
    with HapticMasterEmulator(clock="query", calibrated=False) as emu:
        device = HapticMasterDevice("127.0.0.1", emu.port, init_wait=0.0)
        with pytest.raises(HapticMasterError, match="not calibrated"):
            device.start()
        assert "set state init" not in emu.received
        assert emu.received[-2:] == ["remove all", "set state stop"]
        assert not device.connected


def test_batched_query_answered_and_split(emulator):
    emulator.position[:] = [0.01, -0.02, 0.03]
    emulator.velocity[:] = [0.0, 0.0, 0.0]
    emulator.user_force = lambda t, p, v: [1.5, -2.0, 0.25]
    device = started(emulator)
    n = len(emulator.received)
    pos, vel, force = device.read()
    assert emulator.received[n:] == CYCLE_QUERY.split(";")
    assert pos.tolist() == [0.01, -0.02, 0.03]
    assert vel.tolist() == [0.0, 0.0, 0.0]
    assert force.tolist() == [1.5, -2.0, 0.25]
    assert device.last_round_trip > 0 and device.round_trips.size == 1
    device.stop()


def test_bias_force_moves_the_emulated_mass_its_way(emulator):
    device = started(emulator)
    device.command([0.0, 0.0, -10.0])
    device.read()  # the set is acknowledged; no time has passed
    emulator.steps_per_query = 250  # 0.1 s of device time per frame from now on
    pos, vel, _ = device.read()
    m, b, dt = emulator.inertia, emulator.damping[2], emulator.dt
    assert vel[2] == pytest.approx(-10 / b * (1 - (1 + dt * b / m) ** -250), rel=1e-6)
    assert pos[2] < -1e-3 and pos[0] == 0.0 and pos[1] == 0.0
    device.command([0.0, 0.0, 10.0])
    for _ in range(10):
        pos2, vel2, _ = device.read()
    assert vel2[2] > 0.2  # reversed, toward 10 / 40 = 0.25 m/s
    device.stop()


def test_command_guards_non_finite_and_excessive_forces(emulator):
    device = started(emulator, max_force=50.0)
    device.command([math.nan, 1.0, 0.0])
    device.read()
    assert emulator.bias_force().tolist() == [0.0, 0.0, 0.0]
    device.command([300.0, 400.0, 0.0])
    device.read()
    assert emulator.bias_force() == pytest.approx([30.0, 40.0, 0.0], rel=1e-8)
    device.command([5.0, 0.0, 0.0])  # its acknowledgement still due when stop() comes
    device.stop()
    assert emulator.received[-4:] == [f"set {BIAS_NAME} force [5,0,0]", *failsafe_commands()]
    assert device.failsafe == "acknowledged"
    assert emulator.state == "stop" and emulator.bias_force().tolist() == [0.0, 0.0, 0.0]


def test_device_refusal_is_a_one_line_error(emulator):
    device = started(emulator)
    with pytest.raises(HapticMasterError, match="device refused 'set inertia -1'") as info:
        device.request("set inertia -1")
    assert "\n" not in str(info.value)
    emulator.answer_frame = lambda text: "[1,2];[0,0,0];[0,0,0]"
    with pytest.raises(HapticMasterError, match="get modelpos: expected a vector"):
        device.read()
    del emulator.answer_frame
    device.stop()


def test_dropped_connection_raises_clearly_and_stop_still_works(emulator):
    device = started(emulator)
    device.read()
    emulator.drop_clients()
    with pytest.raises(HapticMasterConnectionLost, match="lost") as info:
        for _ in range(3):  # the first send may still land in a kernel buffer
            device.command([1.0, 0.0, 0.0])
            device.read()
    assert isinstance(info.value, ConnectionError) and "\n" not in str(info.value)
    assert not device.connected
    device.stop()  # safe after the error: says the force may still be on
    assert device.failsafe == "undelivered"
    assert "may still hold a force" in device.failsafe_warning
    assert "\n" not in device.failsafe_warning


def test_silent_device_times_out():
    server = socket.create_server(("127.0.0.1", 0))
    accepted = []
    thread = threading.Thread(target=lambda: accepted.append(server.accept()), daemon=True)
    thread.start()
    try:
        device = HapticMasterDevice("127.0.0.1", server.getsockname()[1], timeout=0.2)
        t0 = time.perf_counter()
        with pytest.raises(HapticMasterConnectionLost, match="no answer within 200 ms"):
            device.start()
        assert time.perf_counter() - t0 < 1.5  # the timeout, and stop()'s own
        # the fail-safe went out but nobody answered: it waits in the connection
        assert device.failsafe == "unacknowledged"
        assert "may still hold a force" in device.failsafe_warning
    finally:
        thread.join(1.0)
        for conn, _ in accepted:
            conn.close()
        server.close()


def test_unreachable_device():
    probe = socket.create_server(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    with pytest.raises(HapticMasterConnectionLost, match="cannot connect"):
        HapticMasterDevice("127.0.0.1", port).start()


# -- the command line -----------------------------------------------------------------


def test_emulate_command_serves_a_client():
    proc = subprocess.Popen(
        [sys.executable, "-m", "evo_door", "emulate", "hapticmaster", "--port", "0"]
        + ["--seconds", "20", "--user", "hold"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        assert "127.0.0.1:" in line, line
        port = int(line.split("127.0.0.1:")[1].split()[0])
        device = HapticMasterDevice("127.0.0.1", port, init_wait=0.0, timeout=5.0)
        device.start()
        time.sleep(0.05)
        _, _, force = device.read()
        device.stop()
        assert np.all(np.isfinite(force))
    finally:
        proc.terminate()
        proc.wait(10)


def test_emulate_command_rejects_bad_options():
    from evo_door.cli import main

    assert main(["emulate", "hapticmaster", "--port", "70000"]) == 2
    assert main(["emulate", "hapticmaster", "--port", "0", "--inertia", "0"]) == 2
