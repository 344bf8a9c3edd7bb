"""The console as a process of its own, started by ``evo-door render --console``: spawned
below the servo loop's priority, its URL relayed, its errors shown, and ended with
the render. The console reaches the renderer only through the control port, so the
servo loop carries none of its work.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterable

from evo_door.errors import UserError

#: where the token is read from when --token is not given (``render --console`` passes
#: it this way: the command line of a process is visible to every local user)
TOKEN_ENV = "EVO_DOOR_CONSOLE_TOKEN"

#: niceness added to the console's process (spawned before the servo loop starts, so it
#: keeps normal scheduling while the loop's thread runs real-time or at niceness -20)
CONSOLE_NICENESS = 10

#: how long ``render --console`` waits for the console to print its URL (s)
CONSOLE_START = 30.0


def start_console(address, token, console_host: str, console_port: int, model=None):
    """Spawn ``evo-door console`` for the control port at ``address``; print its URL.
    ``model``: the rendered model's name as the user gave it (a mechanism file made
    absolute), passed as ``--model``; None for the haptic model."""
    command = _command(address, console_host, console_port)
    if model:
        command += ["--model", str(model)]
    child = _spawn(command, _environment(token))
    # spawned with pipes: stdout and stderr are never None (the `or` is for the types)
    first, errors = _relay(child.stdout or (), child.stderr or ())
    if not first.startswith("console "):
        stop_console(child)
        time.sleep(0.1)  # its last words
        why = next((e for e in reversed(errors) if e), "") or "it printed no URL"
        raise UserError(
            f"--console: the console did not start: {why.removeprefix('evo-door: error: ')}"
        )
    print(first, flush=True)
    return child


def _command(address, console_host: str, console_port: int) -> list[str]:
    """The console's command line, for the control port at ``address``."""
    host, port = address
    if host in ("0.0.0.0", "::"):
        host = "127.0.0.1"
    return [
        sys.executable,
        "-m",
        "evo_door",
        "console",
        "--control",
        f"[{host}]:{port}" if ":" in host else f"{host}:{port}",
        "--host",
        console_host,
        "--port",
        str(console_port),
        "--with-parent",
    ]


def _environment(token) -> dict[str, str]:
    """This process's environment, with the token in :data:`TOKEN_ENV` (if any)."""
    env = dict(os.environ)
    env.pop(TOKEN_ENV, None)
    if token:
        env[TOKEN_ENV] = token  # not on the command line, which every local user can read
    return env


def _spawn(command: list[str], env: dict[str, str]) -> subprocess.Popen:
    # its own session: Ctrl-C reaches the renderer, which then stops the console
    return subprocess.Popen(
        command,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        text=True,
        start_new_session=True,
        # below the servo loop: the page's curves and messages can wait, its cycles not
        preexec_fn=(lambda: os.nice(CONSOLE_NICENESS)) if hasattr(os, "nice") else None,
    )


def _relay(out: Iterable[str], err: Iterable[str]) -> tuple[str, list[str]]:
    """Relay the console's output (``out``, ``err``) from threads of their own: its
    first line (the URL, waited for up to :data:`CONSOLE_START` s; "" if none) and its
    error lines kept until it runs, which it then writes through. Returns the first
    line and the errors kept (the list goes on filling)."""
    url: list[str] = []
    errors: list[str] = []
    started = threading.Event()

    def relay_out() -> None:
        for line in out:
            if not started.is_set():
                url.append(line.strip())
                started.set()
            else:
                sys.stdout.write(line)
        started.set()  # closed: the console ended

    def relay_err() -> None:  # its errors: kept until it runs, then shown
        for line in err:
            if started.is_set() and url and url[0].startswith("console "):
                sys.stderr.write(line)
            else:
                errors.append(line.strip())

    for target in (relay_out, relay_err):
        threading.Thread(target=target, name="evo-door-console-io", daemon=True).start()
    started.wait(CONSOLE_START)
    return (url[0] if url else ""), errors


def stop_console(child) -> None:
    """End the console process and wait for it."""
    if child.poll() is None:
        child.terminate()
        try:
            child.wait(5.0)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
