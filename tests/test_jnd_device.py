"""`evo-door jnd` on the simulated device: the estimate, the file, show and report, the
render log, and the ways a session ends (a refused change, Ctrl-C, the participant)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from evo_door.cli import main
from evo_door.files import open_h5, read_attrs
from evo_door.perception.jnd_file import read_jnd_file
from evo_door.perception.procedures import JndSession, SimParticipant, run_simulated
from evo_door.render.jnd import STOP, JndTiming, TerminalPerson
from tests.helpers import LOADED_MACHINE_LIMITS, LOADED_MACHINE_WATCHDOG

ROOT = Path(__file__).resolve().parents[1]
#: short intervals in simulated time: a session of 80 trials is 38 s on the loop's clock
FAST = ["--interval", "0.2", "--pause", "0.05", "--ramp", "0.02", "--rate", "1000"]


def jnd(tmp_path, *extra, out="j.h5"):
    return main(["jnd", *FAST, "--out", str(tmp_path / out), *extra])


@pytest.mark.slow
@pytest.mark.parametrize(  # not "numerics": the answers do not depend on the device's
    ("param", "weber", "method", "seed"),
    [("friction_closing", 0.10, "staircase", 1), ("viscous_damping", 0.25, "quest", 1)],
)
def test_estimate_on_the_sim_device(tmp_path, capsys, param, weber, method, seed):
    """The issue's first Done-when: a simulated participant of a known Weber fraction,
    estimated within 30 % with an interval that covers it, for a force and a damping."""
    args = ["--param", param, "--participant", f"sim:{weber}", "--method", method]
    code = jnd(tmp_path, *args, "--seed", str(seed), "--json")
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    assert {"param", "reference", "weber", "ci95", "trials"} <= set(doc)
    assert doc["param"] == param and doc["trials"] == 80 and doc["status"] == "complete"
    assert abs(doc["weber"] / weber - 1.0) < 0.3
    lo, hi = doc["ci95"]
    assert lo <= weber <= hi
    assert doc["setting"] == {"friction_closing": "force", "viscous_damping": "viscosity"}[param]
    # the device changes nothing in the logic: the same answers as without one
    record = read_jnd_file(tmp_path / "j.h5")
    unit = "N" if param == "friction_closing" else "N s/rad"
    plain = JndSession(param, unit, record.reference, method, 80, seed=[seed, 0], upper=100.0)
    run_simulated(plain, SimParticipant(weber, seed=[seed, 1]))
    np.testing.assert_array_equal(record.trials["step"], plain.table()["step"])
    np.testing.assert_array_equal(record.trials["answer"], plain.table()["answer"])


@pytest.mark.slow
def test_file_show_report_and_log(tmp_path, capsys):
    log = tmp_path / "log.h5"
    code = jnd(
        tmp_path,
        *["--param", "open_force", "--participant", "sim:0.15", "--trials", "12"],
        *["--reference", "25", "--log", str(log), "--neutral", "defaults"],
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "open_force at 25 N" in text and "Weber fraction" in text and "force" in text
    record = read_jnd_file(tmp_path / "j.h5")
    assert record.reference == 25.0 and record.reference_params["open_force"] == 25.0
    assert record.status == "complete" and len(record.trials["step"]) == 12
    # show, as text and JSON, says what the file holds
    assert main(["show", str(tmp_path / "j.h5"), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown == record.summary()
    assert main(["show", str(tmp_path / "j.h5")]) == 0
    assert (
        "sets the JND setting force (a Weber fraction) where it is used" in capsys.readouterr().out
    )
    # the render log holds the session: its start, every switch and answer, its end
    with open_h5(log) as f:
        events = read_attrs(f["render"])["events"]
    kinds = [e["kind"] for e in events]
    assert kinds.count("jnd_answer") == 12 and kinds.count("jnd_start") == 1
    assert kinds.count("jnd_switch") == 5 * 12  # pause, interval 1, pause, interval 2, question
    answers = [e for e in events if e["kind"] == "jnd_answer"]
    assert [e["answer"] for e in answers] == record.trials["answer"].tolist()
    assert events[kinds.index("jnd_end")]["status"] == "complete"
    # each interval holds the set it should: the parameter's value in force there
    switches = [e for e in events if e["kind"] == "jnd_switch" and "value" in e]
    assert all(e["value"] in (25.0, *record.trials["comparison"].tolist()) for e in switches)
    # every switch is a ramp of checked changes: neutral (open_force's default, 20 N)
    # to the reference (25 N) passes 20 + 5 k / 8 N
    with open_h5(log) as f:
        names = list(read_attrs(f["render/params"])["names"])
        logged = f["render/params/values"][()][:, names.index("open_force")]
    for k in range(1, 9):
        assert np.any(np.isclose(logged, 20.0 + 5.0 * k / 8)), k
    # report: the page and its two figures
    assert main(["report", str(tmp_path / "j.h5"), "--out", str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "JND session: open_force" in page
    for name in ("track", "psychometric"):
        assert (tmp_path / "rep" / f"{name}.png").stat().st_size > 1000


def test_out_exists_refused(tmp_path, capsys):
    out = tmp_path / "j.h5"
    out.write_bytes(b"a participant's session")
    code = jnd(tmp_path, "--param", "open_force", "--participant", "sim:0.1")
    assert code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--force" in err
    assert out.read_bytes() == b"a participant's session"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--param", "friction_closin"], "did you mean 'friction_closing'"),
        (["--param", "balance_1"], "reference above 0"),  # its default is 0
        (["--param", "open_force", "--reference", "0"], "--reference 0: must be > 0"),
        (["--param", "open_force", "--reference", "500"], "open_force"),  # above its bound
        (["--param", "open_force", "--participant", "robot"], "--participant 'robot'"),
        (["--param", "open_force", "--trials", "5"], "--trials 5"),
        (["--param", "open_force", "--supervisor-budget", "50"], "hapticmaster:// device"),
        (["--param", "open_force", "--watchdog-misses", "0"], "--watchdog-misses 0"),
    ],
)
def test_bad_input_is_one_line(tmp_path, capsys, args, message):
    assert jnd(tmp_path, *args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err
    assert not (tmp_path / "j.h5").exists()


@pytest.mark.parametrize("paced", [False, True])
def test_refused_change_ends_the_session_with_the_file(tmp_path, capsys, paced):
    """c_energy is negative damping: the comparison above the device's damping margin
    is refused by the loop's passivity check (in the cycle, or in the checking thread
    of a paced loop); the file keeps what was answered."""
    extra = ["--realtime", *LOADED_MACHINE_WATCHDOG] if paced else []
    code = jnd(
        tmp_path, "--param", "c_energy", "--reference", "0.8", "--participant", "sim:0.1", *extra
    )
    assert code == 2
    err = capsys.readouterr().err
    assert "refused" in err and "not passive" in err
    record = read_jnd_file(tmp_path / "j.h5")
    assert record.status == "refused" and record.fit is None
    assert "not passive" in record.attrs["configuration"]["outcome"]


@pytest.mark.slow
def test_ctrl_c_keeps_the_answered_trials(tmp_path):
    """A session paced on the wall clock, Ctrl-C after a few answers: the file holds
    them, its status 'stopped', exit 0."""
    out = tmp_path / "j.h5"
    # a loaded machine misses deadlines of the paced loop: its watchdog would end the
    # session before the Ctrl-C this tests (exit 1, status "watchdog")
    cmd = [sys.executable, "-m", "evo_door", "jnd", *FAST, "--realtime", *LOADED_MACHINE_WATCHDOG]
    cmd += ["--param", "open_force", "--participant", "sim:0.1", "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
    seen = 0
    deadline = time.monotonic() + 60
    while seen < 3 and time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        seen += line.startswith("trial ")
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stdout + stderr
    record = read_jnd_file(out)
    assert record.status == "stopped"
    assert 3 <= len(record.trials["step"]) < 80
    assert "stopped" in stdout


def test_terminal_person_answers_only_when_asked():
    read, write = os.pipe()
    with os.fdopen(read) as stream, open(os.devnull, "w") as out:
        person = TerminalPerson("P07", stream=stream, out=out)
        try:
            os.write(write, b"2")  # during the intervals: no answer
            time.sleep(0.3)
            assert person.poll() is None
            person.ask(None, "heavier")
            os.write(write, b"x1")
            for _ in range(50):
                reply = person.poll()
                if reply is not None:
                    break
                time.sleep(0.02)
            assert reply == 1
            os.write(write, b"q")
            time.sleep(0.3)
            assert person.poll() == STOP
            assert person.describe() == "person P07"
        finally:
            person.close()
            os.close(write)


def test_neutral_set_keeps_the_device_parameters():
    from evo_door.models import get_model
    from evo_door.render.jnd import neutral_values

    model = get_model("haptic")
    reference = model.load_params(None, {"open_force": 40.0, "radius": 0.4})
    neutral = neutral_values(reference)
    assert neutral["open_force"] == 20.0  # a sensation: the model's default
    assert neutral["radius"] == 0.4  # the device's: the reference's
    other = model.load_params(None, {"open_force": 30.0})
    assert neutral_values(reference, other)["open_force"] == 30.0


def test_timing_checked():
    with pytest.raises(Exception, match="--ramp"):
        JndTiming(interval=0.2, ramp=0.5)
    assert JndTiming(ramp=0.0).steps == 1


@pytest.mark.slow
def test_a_person_at_a_terminal_answers_and_stops(tmp_path):
    """A person on a terminal (a pty): blind cues and questions on stderr, keys 2 to
    answer, q to stop; the two answers are kept, status 'stopped'."""
    out = tmp_path / "j.h5"
    master, slave = os.openpty()
    cmd = [sys.executable, "-m", "evo_door", "jnd", *FAST, "--trials", "10"]
    cmd += ["--param", "open_force", "--participant", "person:P01", "--out", str(out)]
    cmd += LOADED_MACHINE_WATCHDOG  # a person's session is paced: a stalled machine ended it
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        cmd, stdin=slave, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )
    asked, shown = 0, []
    for line in proc.stderr:
        shown.append(line)
        if line.startswith("Which interval felt stronger: 1 or 2?"):
            asked += 1
            os.write(master, b"2" if asked <= 2 else b"q")
    printed = proc.stdout.read()
    proc.wait(timeout=60)
    os.close(master)
    os.close(slave)
    assert proc.returncode == 0, "".join(shown) + printed
    record = read_jnd_file(out)
    assert record.status == "stopped" and record.participant == "person P01"
    assert record.trials["answer"].tolist() == [2, 2]
    # blind: nothing on the screen says where the comparison was or whether it was right
    text = "".join(shown)
    assert "trial 2/10 answered" in text and "right" not in text and "step" not in text


@pytest.mark.slow
def test_let_go_pauses_switch_only_while_nobody_holds_the_handle(tmp_path):
    """Without --neutral the pauses are let-go pauses: the next interval's set comes in
    during the pause, so each interval renders its set from its first cycle, and no
    change lands within an interval or the question."""
    log = tmp_path / "log.h5"
    args = ["--param", "viscous_damping", "--participant", "sim:0.2", "--trials", "10"]
    assert jnd(tmp_path, *args, "--log", str(log)) == 0
    with open_h5(log) as f:
        events = read_attrs(f["render"])["events"]
        names = list(read_attrs(f["render/params"])["names"])
        change_t = f["render/params/t"][()]
        values = f["render/params/values"][()][:, names.index("viscous_damping")]
    phases = [e for e in events if e["kind"] == "jnd_switch"]
    assert [e["phase"] for e in phases[:5]] == [
        "pause",
        "interval 1",
        "pause",
        "interval 2",
        "question",
    ]
    for e in phases:
        if e["phase"].startswith("interval"):
            in_force = values[np.searchsorted(change_t, e["t"], side="right") - 1]
            assert in_force == pytest.approx(e["value"]), e
    # every change after the start lies within a pause
    pauses = [(e["t"], e["t"] + 0.05) for e in phases if e["phase"] == "pause"]
    for t in change_t[1:]:
        assert any(a - 1e-9 <= t <= b + 1e-9 for a, b in pauses), t


@pytest.mark.slow
def test_a_session_over_the_emulated_hapticmaster(tmp_path):
    """The same session over real TCP to the HapticMaster's protocol emulator, paced on
    the wall clock with the supervisor watching: complete, every answer in the file
    and the log, the same steps as without a device."""
    emulator = subprocess.Popen(
        [sys.executable, "-m", "evo_door", "emulate", "hapticmaster", "--port", "0"]
        + ["--user", "swing", "--damping", "2", "--seconds", "60"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        port = int(emulator.stdout.readline().split("127.0.0.1:")[1].split()[0])
        log = tmp_path / "log.h5"
        args = ["jnd", "--param", "viscous_damping", "--participant", "sim:0.2"]
        args += ["--trials", "10", "--interval", "0.15", "--pause", "0.1", "--ramp", "0.05"]
        args += ["--device", f"hapticmaster://127.0.0.1:{port}", "--device-damping", "2"]
        args += ["--rate", "1000", *LOADED_MACHINE_LIMITS]
        args += ["--out", str(tmp_path / "j.h5"), "--log", str(log), "--json"]
        code = main(args)
    finally:
        emulator.terminate()
        emulator.wait(10)
    assert code == 0
    record = read_jnd_file(tmp_path / "j.h5")
    assert record.status == "complete" and record.device.startswith("hapticmaster://")
    with open_h5(log) as f:
        events = read_attrs(f["render"])["events"]
    assert sum(e["kind"] == "jnd_answer" for e in events) == 10
    plain = JndSession(
        "viscous_damping", "N s/rad", record.reference, "staircase", 10, seed=[0, 0], upper=100.0
    )
    run_simulated(plain, SimParticipant(0.2, seed=[0, 1]))
    np.testing.assert_array_equal(record.trials["step"], plain.table()["step"])


def test_a_binary_parameter_file_is_one_line(tmp_path, capsys):
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(bytes(range(256)) * 2)
    assert jnd(tmp_path, "--param", "open_force", "--params", str(binary)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not a parameter file" in err
    assert not (tmp_path / "j.h5").exists()
