"""The MOOG HapticMaster's TCP/IP string protocol: its frames, answers and commands.

The device takes ASCII commands (``set state force``, ``get modelpos``,
``create biasforce NAME``, ``set NAME force [x,y,z]`` ...) in frames of an 8-byte
header followed by the text. Public clients put the text length in the header's 4th
byte and leave the rest zero; here bytes 0-3 are read as one big-endian unsigned
length, which is the same bytes for every text under 256 characters and still frames
longer ones. Several commands go in one frame separated by ``;`` and the device
answers them in one frame, its answers separated by ``;`` in the same order. Replies
use the same framing. An answer starting with ``--- ERROR`` is the device refusing.

TCP is a byte stream: one ``recv`` may hold half a frame or three frames. The
:class:`FrameReader` keeps a buffer and hands out whole frames only, so neither the
client nor the emulator (:mod:`evo_door.render.emulator`) ever parses a partial reply.

Here: the framing (:func:`encode`, :class:`FrameReader`), the answers' parsing
(:func:`parse_vector`, :func:`split_answers`), the commands the renderer sends (the
effects the device renders natively, the fail-safe frame) and the device's address.
The client Device is :mod:`evo_door.render.hapticmaster`; the supervisor
(:mod:`evo_door.render.supervisor`) keeps a copy of the framing of its own, which a
test checks against this one.
"""

from __future__ import annotations

import re
import string

import numpy as np

from evo_door.errors import UserError
from evo_door.models.haptic import C_PLANE, K_PLANE, PARAMS
from evo_door.params import param_vector

#: Bytes of the frame header; the text length is in bytes 0-3 (big-endian).
HEADER_SIZE = 8
#: The longest frame text accepted (a larger length means a corrupt stream).
MAX_TEXT = 1 << 16
#: What the device's error answers start with.
ERROR_PREFIX = "--- ERROR"
#: Name of the bias force through which the host adds its force.
BIAS_NAME = "evoDoorForce"
#: The batched per-cycle query; answers come back in this order.
CYCLE_QUERY = "get modelpos;get modelvel;get measforce"
#: Names of the device's own effects that render the haptic model's plane constraint.
PLANE_SPRING = "evoDoorPlane"
PLANE_DAMPER = "evoDoorPlaneDamper"
#: The haptic parameters the device renders itself once
#: :meth:`~evo_door.render.hapticmaster.HapticMasterDevice.render_natively` ran.
NATIVE_PARAMS = ("k_plane", "c_plane")

_PRINTABLE = set(string.printable) - set("\t\n\r\x0b\x0c")
_VECTOR = re.compile(r"^\[([^\[\]]*)\]$")


class HapticMasterError(UserError):
    """The device refused a command or answered something this client cannot read."""


class HapticMasterConnectionLost(HapticMasterError, ConnectionError):
    """The connection to the device dropped or timed out (the watchdog's cue)."""


# -- framing ------------------------------------------------------------------------


def encode(text: str) -> bytes:
    """One frame: the 8-byte header then ``text`` as ASCII.

    >>> encode("get state")[:8]
    b'\\x00\\x00\\x00\\t\\x00\\x00\\x00\\x00'
    """
    try:
        body = text.encode("ascii")
    except UnicodeEncodeError:
        raise HapticMasterError(f"command {text!r} is not ASCII") from None
    if len(body) > MAX_TEXT:
        raise HapticMasterError(f"command of {len(body)} bytes exceeds {MAX_TEXT} bytes")
    return len(body).to_bytes(4, "big") + b"\x00\x00\x00\x00" + body


def clean_text(body: bytes) -> str:
    """A frame's text as the device means it: printable ASCII, quotes and edges removed."""
    text = body.decode("ascii", errors="replace")
    text = "".join(c for c in text if c in _PRINTABLE)
    return text.replace('"', "").strip()


class FrameReader:
    """Reassembles frames from the pieces a stream delivers.

    ``feed`` takes any bytes received (a part of a frame, several frames) and returns
    the texts of the frames it completed, in order; the rest waits in the buffer.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()

    @property
    def pending(self) -> int:
        """Bytes received that do not yet make a whole frame."""
        return len(self._buffer)

    def feed(self, data: bytes) -> list[str]:
        self._buffer += data
        texts = []
        while len(self._buffer) >= HEADER_SIZE:
            size = int.from_bytes(self._buffer[:4], "big")
            if size > MAX_TEXT:
                head = bytes(self._buffer[:HEADER_SIZE]).hex()
                self._buffer.clear()
                raise HapticMasterError(
                    f"corrupt frame header {head}: length {size} bytes exceeds {MAX_TEXT}"
                )
            end = HEADER_SIZE + size
            if len(self._buffer) < end:
                break
            texts.append(clean_text(bytes(self._buffer[HEADER_SIZE:end])))
            del self._buffer[:end]
        return texts


# -- answers ------------------------------------------------------------------------


def parse_vector(answer: str, what: str = "answer") -> np.ndarray:
    """``[x,y,z]`` (spaces allowed) as a float64 3-vector; anything else is an error.

    >>> parse_vector("[0.1, -2, 3e-3]")
    array([ 0.1  , -2.   ,  0.003])
    """
    match = _VECTOR.match(answer.strip())
    parts = match.group(1).split(",") if match else []
    if len(parts) != 3:
        raise HapticMasterError(f"{what}: expected a vector [x,y,z], got {answer!r}")
    try:
        return np.array([float(p) for p in parts], dtype=np.float64)
    except ValueError:
        raise HapticMasterError(f"{what}: expected a vector [x,y,z], got {answer!r}") from None


def split_answers(text: str, commands: list[str]) -> list[str]:
    """The answers of a batched frame, one per command; device errors raised."""
    answers = [a.strip() for a in text.split(";")]
    if len(answers) == len(commands) + 1 and answers[-1] == "":
        answers.pop()  # the older API ends its answers with ';'
    if len(answers) != len(commands):
        raise HapticMasterError(
            f"{len(commands)} commands ({'; '.join(commands)}) got {len(answers)} answers: {text!r}"
        )
    for command, answer in zip(commands, answers, strict=True):
        if answer.startswith(ERROR_PREFIX):
            raise HapticMasterError(f"device refused {command!r}: {answer}")
    return answers


def format_vector(v) -> str:
    """A 3-vector as the device reads it: ``[x,y,z]`` without spaces."""
    return "[" + ",".join(f"{float(c):.9g}" for c in v) + "]"


# -- native effects -----------------------------------------------------------------


def native_commands(params, max_force: float | None = None) -> list[str]:
    """The commands that set the device's own effects to the haptic set ``params``.

    What of the haptic model the HapticMaster renders itself at 2.5 kHz: the plane
    constraint ``F_x = -k_plane x - c_plane v_x`` (eq. 4.21), exactly a spring of
    stiffness ``k_plane`` (N/m) along ``[1,0,0]`` about ``[0,0,0]`` (it pulls only on
    the x component of the displacement) plus a damper ``[c_plane,0,0]`` (N s/m).
    Every setting is sent, so the commands configure the effects whatever state they
    were in; the effects must exist (:meth:`HapticMasterDevice.render_natively`
    creates them). ``max_force`` (N) caps the spring's force as the host's is capped.

    The rest stays on the host: the door's viscous damping, dry friction and latch
    depend on the door angle and the direction of motion, and the radial spring
    holds the handle on a circle about the hinge, not at a point; none of them is a
    spring, damper or bias force of the device. The virtual mass I / R is native too,
    through ``set inertia`` (:meth:`HapticMasterDevice.set_mass`).

    ``params`` is a haptic ParamSet or kernel vector.

    >>> from evo_door.models.haptic import MODEL
    >>> for command in native_commands(MODEL.load_params("seed_trial")):
    ...     print(command)  # doctest: +ELLIPSIS
    set evoDoorPlane stiffness ...
    set evoDoorPlane dampfactor 0
    set evoDoorPlane direction [1,0,0]
    set evoDoorPlane pos [0,0,0]
    set evoDoorPlane deadband 0
    set evoDoorPlaneDamper dampcoef [...,0,0]
    """
    p = param_vector(params, PARAMS)
    commands = [
        f"set {PLANE_SPRING} stiffness {float(p[K_PLANE]):.9g}",
        f"set {PLANE_SPRING} dampfactor 0",
        f"set {PLANE_SPRING} direction [1,0,0]",
        f"set {PLANE_SPRING} pos [0,0,0]",
        f"set {PLANE_SPRING} deadband 0",
    ]
    if max_force is not None:
        commands.append(f"set {PLANE_SPRING} maxforce {float(max_force):.9g}")
    commands.append(f"set {PLANE_DAMPER} dampcoef {format_vector((p[C_PLANE], 0.0, 0.0))}")
    return commands


def failsafe_commands(bias: bool = True) -> list[str]:
    """The commands that take the force off the handle, sent in one frame.

    The bias force to zero first (``bias``: it exists), so that the force is gone even
    if the device stopped at the next command; then every effect removed and the
    device stopped: the HapticMaster keeps rendering its effects after a connection
    closes, and has no timeout of its own (docs/renderer.md, "Stalls").

    >>> failsafe_commands()
    ['set evoDoorForce force [0,0,0]', 'remove all', 'set state stop']
    """
    return ([f"set {BIAS_NAME} force [0,0,0]"] if bias else []) + ["remove all", "set state stop"]


def parse_address(text: str) -> tuple[str, int]:
    """``hapticmaster://HOST:PORT`` (or ``HOST:PORT``) as ``(host, port)``.

    >>> parse_address("hapticmaster://127.0.0.1:7654")
    ('127.0.0.1', 7654)
    """
    rest = text.removeprefix("hapticmaster://")
    host, sep, port = rest.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise UserError(f"device {text!r}: expected hapticmaster://HOST:PORT")
    return host.strip("[]"), int(port)
