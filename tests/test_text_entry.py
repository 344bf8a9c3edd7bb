"""Text that a file cannot hold is refused where it enters, in one line, and never
reaches a writer: a lone surrogate (JSON's ``\\ud800``) or a NUL in a control-port
event, a console message, a token or a participant's id.

Before, a participant id of ``"\\ud800"`` was answered ok, and at the end ``render``
exited 1 with UnicodeEncodeError and wrote no log: a whole session lost to one message.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from evo_door.cli import main
from evo_door.errors import UserError, plain_text
from evo_door.render.control import request
from evo_door.render.messages import BadMessage, parse_message
from tests.helpers import LOADED_MACHINE_WATCHDOG

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "s3cret"
SURROGATE = '"\\ud800"'  # JSON text whose string is a lone surrogate


def _one_line(err: str) -> str:
    assert err.count("\n") == 1 and err.startswith("evo-door: error:"), err
    return err


@pytest.mark.parametrize(
    "message",
    [
        '{"event": {"kind": "participant", "id": ' + SURROGATE + "}}",  # control port
        '{"type": "participant", "id": ' + SURROGATE + "}",  # the console's WebSocket
        '{"token": ' + SURROGATE + ', "get": "params"}',
        '{"event": {"kind": "note", "text": "a\\u0000b"}}',
        '{"event": {"kind": "note", ' + SURROGATE + ": 1}}",  # a key too
        '{"event": {"kind": "note", "list": [1, [' + SURROGATE + "]]}}",  # at any depth
    ],
)
def test_a_message_with_text_a_file_cannot_hold_is_refused_in_one_line(message):
    with pytest.raises(BadMessage, match="refused") as got:
        parse_message(message)
    assert "\n" not in str(got.value)
    with pytest.raises(BadMessage, match="refused"):
        parse_message(message.encode())


def test_plain_text_keeps_every_unicode_text_a_file_can_hold():
    for text in ("Ana", "Zoë 🙂", "参加者 7", "", "tab\there"):
        assert plain_text(text, "id") == text
    with pytest.raises(UserError, match="U\\+DC80"):
        plain_text("x\udc80", "--token")


def test_a_surrogate_token_or_participant_on_the_command_line_is_one_line(capsys, tmp_path):
    args = ["push", "--set", "friction_opening=3", "--to", "127.0.0.1:9", "--token", "\ud800"]
    assert main(args) == 2
    assert "--token: not Unicode text" in _one_line(capsys.readouterr().err)
    out = tmp_path / "j.h5"
    args = ["jnd", "--param", "friction_closing", "--params", "seed_trial", "--device", "sim",
            "--participant", "person:\ud800", "--trials", "10", "--out", str(out)]  # fmt: skip
    assert main(args) == 2
    assert "--participant person:ID: not Unicode text" in _one_line(capsys.readouterr().err)


def test_a_surrogate_event_and_token_leave_the_session_and_its_log_whole(tmp_path):
    """Over real TCP to a running ``render --control``: the participant-id surrogate is
    refused with the reason, so is the token surrogate (the server thread lives on and
    answers the next request), and the render log is written at the end (exit 0)."""
    log = tmp_path / "session.h5"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    args = ["render", "--params", "seed_trial", "--device", "sim", "--user", "hold",
            "--duration", "60", "--realtime", "--control", "0", "--token", TOKEN,
            "--log", str(log), *LOADED_MACHINE_WATCHDOG]  # fmt: skip
    proc = subprocess.Popen(
        [sys.executable, "-m", "evo_door", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )
    try:
        line = proc.stdout.readline()
        assert line.startswith("control port "), (line, proc.stderr.read() if not line else "")
        port = int(line.split()[2].rpartition(":")[2])
        for _ in range(200):  # until the loop has run its first cycles
            if "theta" in request("127.0.0.1", port, {"token": TOKEN, "get": "state"}):
                break
            time.sleep(0.05)
        # (json.dumps writes a lone surrogate as the escape \ud800, as a client would)
        bad = {"token": TOKEN, "event": {"kind": "participant", "id": "\ud800"}}
        answer = request("127.0.0.1", port, bad)
        assert answer["ok"] is False and "not Unicode text" in answer["error"]
        answer = request("127.0.0.1", port, {"token": "\ud800", "get": "params"})
        assert answer["ok"] is False and "not Unicode text" in answer["error"]
        good = {"token": TOKEN, "event": {"kind": "participant", "id": "Zoë"}}
        assert request("127.0.0.1", port, good)["ok"] is True  # the server still answers
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            out, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
    assert proc.returncode == 0, err
    assert log.is_file() and log.stat().st_size > 0, (out, err, list(tmp_path.iterdir()))
    shown = subprocess.run(
        [sys.executable, "-m", "evo_door", "show", str(log)],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
    )
    assert shown.returncode == 0, shown.stderr
    assert "Zoë" in shown.stdout
