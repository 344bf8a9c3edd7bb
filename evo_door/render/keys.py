"""The terminal UI of interactive rendering: step each sensation up or down with a key.

Every parameter of the haptic declaration's ``sensation`` group gets two keys, a
letter and its capital: the letter steps it down, the capital up (``q`` is kept to
quit, so the letters run ``a`` .. ``z`` without ``q``, in declaration order); past the
letters, a digit steps down and its shifted sign on a US keyboard up (``1`` / ``!``
.. ``0`` / ``)``). A step
is 1/20 of the declared range (upper - lower), rounded down to 1, 2 or 5 times a power
of ten so the values stay readable; a step that would leave the declared range stops
on its bound. Each change goes to :meth:`ServoLoop.request_change`, so the loop checks
it (declaration, passivity) and applies it between two cycles, or refuses it and the
screen shows why.

A mechanism (``render MECHANISM.yaml`` on a terminal) gets keys for the parameters the
web console changes, with its steps
(:func:`~evo_door.render.console.sensations.tunable_keys`: its specification and
numerics, a step a twentieth of four times the value it started with), and its
handle's coordinate in its own unit.

:func:`key_change` (key -> change) is the whole of the key handling and needs no
terminal; :func:`run_terminal` adds raw mode, ``select`` on stdin and the screen.
"""

from __future__ import annotations

import math
import sys
import time

from evo_door.errors import UserError
from evo_door.models.haptic import PARAMS

#: the group whose parameters the keys step
GROUP = "sensation"
#: the letters handed out in declaration order (q quits)
LETTERS = "abcdefghijklmnoprstuvwxyz"
#: every (down, up) pair of keys, in the order they are handed out: the letters and
#: their capitals, then the digits and their shifted signs (US layout)
KEY_PAIRS = [(c, c.upper()) for c in LETTERS] + list(zip("1234567890", "!@#$%^&*()"))
#: fraction of the declared range a step is at most
STEP_FRACTION = 1.0 / 20.0

_DEG = 180.0 / math.pi


def nice_step(span: float) -> float:
    """``span * STEP_FRACTION`` rounded down to 1, 2 or 5 times a power of ten.

    >>> nice_step(100.0), nice_step(0.2), nice_step(19.95)
    (5.0, 0.01, 0.5)
    """
    raw = span * STEP_FRACTION
    if not raw > 0:
        return 0.0
    exp = math.floor(math.log10(raw))
    for mant in (5.0, 2.0, 1.0):
        step = mant * 10.0**exp
        if step <= raw * (1 + 1e-9):
            return float(f"{step:.12g}")
    return float(f"{10.0 ** (exp - 1) * 5:.12g}")


def key_map(table=PARAMS, group: str = GROUP) -> dict[str, tuple[str, float]]:
    """key -> (parameter name, signed step in SI units) for ``group`` of ``table``."""
    names = [p for p in table if p.group == group]
    if len(names) > len(KEY_PAIRS):
        raise UserError(f"{len(names)} parameters in group {group!r}: more than the keys")
    return keys_for(names)


def keys_for(params, steps: dict | None = None) -> dict[str, tuple[str, float]]:
    """key -> (parameter name, signed step) for the declared ``params`` (:class:`Param`),
    handed out in their order; past the :data:`KEY_PAIRS`, a parameter has no keys.
    A parameter's step is ``steps[name]`` where given, else :func:`nice_step` of its
    declared range."""
    keys: dict[str, tuple[str, float]] = {}
    steps = steps or {}
    stepped = [(p, steps.get(p.name, nice_step(p.upper - p.lower))) for p in params]
    for (down, up), (p, step) in zip(KEY_PAIRS, [(p, s) for p, s in stepped if s > 0]):
        keys[down] = (p.name, -step)
        keys[up] = (p.name, step)
    return keys


def key_change(key: str, values: dict, keys: dict | None = None, table=PARAMS) -> dict | None:
    """The change {name: new value} that ``key`` asks of the set ``values``, or None.

    None for a key without a parameter, or when the value already sits on the bound
    the step goes toward.
    """
    keys = key_map(table) if keys is None else keys
    if key not in keys:
        return None
    name, step = keys[key]
    p = table[name]
    old = float(values[name])
    new = min(max(old + step, p.lower), p.upper)
    new = float(f"{new:.12g}")  # no 0.30000000000000004 on the screen
    new = min(max(new, p.lower), p.upper)
    if new == old:
        return None
    return {name: new}


def shown(value: float, unit: str) -> str:
    """A value with its unit for people: angles in degrees, labelled."""
    if unit == "rad":
        return f"{value * _DEG:9.4g} deg"
    return f"{value:9.4g} {unit}" if unit != "1" else f"{value:9.4g}"


def screen(loop, keys: dict, message: str = "", table=PARAMS, unit: str = "rad") -> str:
    """The text of one screen: the state, then a line per parameter of ``table`` with its
    keys; ``unit``: the handle's (an angle in rad is shown in degrees)."""
    snap = loop.snapshot()
    params = snap["params"]
    lines = [f"evo-door render: {snap['device']} at {snap['rate']:g} Hz, {snap['status']}"]
    if math.isfinite(snap["theta"]) and unit == "rad":
        lines.append(
            f"t {snap['t']:8.2f} s   theta {snap['theta'] * _DEG:7.2f} deg   "
            f"dtheta {snap['dtheta'] * _DEG:8.2f} deg/s   user force {snap['force']:7.2f} N"
        )
    elif math.isfinite(snap["theta"]):
        lines.append(
            f"t {snap['t']:8.2f} s   position {snap['theta']:8.4f} {unit}   "
            f"speed {snap['dtheta']:8.4f} {unit}/s   user force {snap['force']:7.2f} N"
        )
    lines.append("key down/up  parameter                  value         step")
    by_name: dict[str, list] = {}
    for key, (name, step) in keys.items():
        by_name.setdefault(name, []).append((key, step))
    for name, pair in by_name.items():
        down = next(k for k, s in pair if s < 0)
        up = next(k for k, s in pair if s > 0)
        p_unit = table[name].unit
        step = abs(pair[0][1])
        lines.append(
            f"  {down}/{up}       {name:24s} {shown(params[name], p_unit)}  "
            f"{shown(step, p_unit).strip()}"
        )
    lines.append("q quits" + (f"   | {message}" if message else ""))
    return "\r\n".join(lines)


def run_terminal(
    loop, stop, refresh: float = 0.1, keys=None, table=PARAMS, unit: str = "rad"
) -> None:
    """Raw-mode key loop on stdin until ``q`` or ``stop`` (the loop's own end) is set;
    ``keys`` (default :func:`key_map`) step the parameters of ``table``, the handle's
    coordinate shown in ``unit``."""
    import select
    import termios
    import tty

    keys = key_map() if keys is None else keys
    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    message = ""
    out = sys.stdout
    try:
        tty.setcbreak(fd)
        out.write("\x1b[?25l")  # hide the cursor
        while not stop.is_set():
            out.write("\x1b[H\x1b[2J" + screen(loop, keys, message, table, unit) + "\r\n")
            out.flush()
            ready, _, _ = select.select([sys.stdin], [], [], refresh)
            if not ready:
                continue
            key = sys.stdin.read(1)
            if key == "q":
                stop.set()
                break
            change = key_change(key, loop.params.as_dict(), keys, table)
            if change is None:
                continue
            try:
                new = loop.request_change(change)
                name = next(iter(change))
                message = f"{name} -> {shown(new[name], table[name].unit).strip()}"
            except UserError as exc:
                message = f"refused: {' '.join(str(exc).split())}"
            time.sleep(0.005)
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)
        out.write("\x1b[?25h\n")
        out.flush()
