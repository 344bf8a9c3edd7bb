"""An emulated MOOG HapticMaster: its TCP string protocol backed by a simulated device.

The emulator listens on 127.0.0.1 (by default), takes frames in the framing of
:mod:`evo_door.render.hm_protocol` in any pieces and batches, and answers every
command: device states (``init``, ``force``, ``stop`` ...), effects created by name
(``biasforce``; ``spring`` with ``stiffness``, ``dampfactor``, ``pos``, ``direction``,
``deadband``, ``maxforce``; ``damper`` with ``dampcoef``, alias ``dampcoeff``) with
their settings, the model's position, velocity and acceleration, the measured force,
and ``--- ERROR`` answers for anything else, as the device does. A setting outside a
physical range (:data:`LIMITS`: not finite, a negative mass, a stiffness of 1e24 N/m)
is refused likewise. Its memory is bounded however long it runs: it counts the
commands and frames it answered and keeps only the last :data:`RECENT` of each
(:attr:`received`, :attr:`frames`, cut short), at most :data:`MAX_EFFECTS` effects and
:data:`MAX_CLIENTS` connections. Every connection shares one device: a second one (a
probe) reads the state and effects the first set (``get state``, ``get NAME force``,
``get NAME enabled``), and effects outlive the connection that made them, as on the
HapticMaster. ``evo-door emulate hapticmaster --port 0`` runs it as a process of its
own (its first line names the port), which a test can stop with SIGSTOP.

Its physics, a point mass with damping, Coulomb friction and the enabled effects, is
in :mod:`evo_door.render.emulator_physics`. Simulated time advances, before each frame
is answered, either by the wall time elapsed since the last frame (``clock="wall"``,
the default: the device does not wait for the host) or by ``steps_per_query`` steps
(``clock="query"``: reproducible, for tests); on the wall clock, a silence longer
than :data:`MAX_ADVANCE` is skipped, since it cannot be told from the emulator's own
stall. The user force is evaluated once per advance and held over its steps; the
scripted hand's clock starts each time the device enters the ``force`` state, so that
no other client's frames (a supervisor's keep-alive) and no wait of the host's move
the script. The mass only moves in the ``force`` state; otherwise it is held where it
is.

Size: a little over 600 lines: the protocol's commands (states, effects and their
settings, queries) are one table of small handlers; the physics and the framing are
modules of their own.
"""

from __future__ import annotations

import math
import os
import socket
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from evo_door.errors import UserError
from evo_door.render.emulator_physics import DEVICE_RATE, advance_effects, compile_kernel
from evo_door.render.hm_protocol import (
    ERROR_PREFIX,
    FrameReader,
    HapticMasterError,
    encode,
    format_vector,
    parse_vector,
)

#: The longest stretch of wall time one advance simulates (s): a stalled emulator
#: must not make the mass jump.
MAX_ADVANCE = 0.05
_STATES = ("init", "off", "force", "position", "home", "stop")
_EFFECTS = ("biasforce", "spring", "damper")
#: Other spellings of effect settings: ``dampcoeff`` for the device's ``dampcoef``.
_ALIASES = {"dampcoeff": "dampcoef"}

#: Physical ranges (SI) of what the protocol sets: ``(low, high)``, both included,
#: per number (per component for a vector); anything outside, or NaN, is refused
#: with an error answer. Wide around a HapticMaster (a few kg of rendered mass, about
#: 250 N, springs to some 5e4 N/m, a workspace of some 0.4 m) so that every haptic set
#: evo-door renders fits (a virtual mass I / R of 0.05 to 400 kg, springs to 1e5 N/m).
LIMITS = {
    "inertia": (0.01, 1000.0),  # kg
    "coulombfriction": (0.0, 1000.0),  # N
    "force": (-1000.0, 1000.0),  # N, a bias force's components
    "stiffness": (0.0, 1e6),  # N/m
    "dampfactor": (0.0, 1e5),  # N s/m
    "dampcoef": (0.0, 1e5),  # N s/m per axis: a negative one would feed energy in
    "deadband": (0.0, 10.0),  # m
    "pos": (-10.0, 10.0),  # m
    "direction": (-1e6, 1e6),  # any scale: it is made a unit vector
    "maxforce": (1e-9, math.inf),  # N; inf: no cap
}
#: At most this many effects at a time (the renderer uses three).
MAX_EFFECTS = 32
#: Longest effect name (characters).
MAX_NAME = 64
#: At most this many open connections; more are closed at once.
MAX_CLIENTS = 8
#: How many of the last commands and frames are kept (:attr:`received`,
#: :attr:`frames`), each cut to :data:`KEPT_CHARS` characters: at most about 1.3 MB.
RECENT = 4096
RECENT_FRAMES = 256
KEPT_CHARS = 256


#: The real-time priority (SCHED_FIFO) of a ``realtime`` emulator's threads: below the
#: render loop's (10), so that on one machine the loop comes first.
RT_PRIORITY = 5


def _real_time() -> str:
    """Raise this thread's scheduling as far as permitted; what it got."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
        return f"real-time priority {RT_PRIORITY}"
    except (OSError, AttributeError):
        pass
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), -10)
        return "niceness -10"
    except (OSError, AttributeError):
        return "normal priority"


def _unit(v: np.ndarray) -> np.ndarray:
    """``v`` scaled to unit length; the zero vector stays zero (an isotropic spring)."""
    norm = math.sqrt(float(v @ v))
    return v / norm if norm > 0.0 else np.zeros(3)


def _zero_user(t: float, position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    return np.zeros(3)


#: The unit of each setting in :data:`LIMITS`, for the error answers.
_UNITS = {
    "force": "N",
    "pos": "m",
    "dampcoef": "N s/m",
    "direction": "",
    "stiffness": "N/m",
    "dampfactor": "N s/m",
    "deadband": "m",
    "maxforce": "N",
}


def in_range(name: str, value: float) -> bool:
    """``value`` lies within :data:`LIMITS` of the setting ``name`` (NaN never does)."""
    low, high = LIMITS[name]
    return low <= value <= high


def _out_of_range(what: str, value, unit: str) -> str:
    low, high = LIMITS[what.lower().replace(" ", "")]
    span = f"{low:g} to {high:g} {unit}".rstrip()
    return f"{ERROR_PREFIX}: {what} {_shown(str(value))!r} is outside {span}"


def _shown(text: str, most: int = 80) -> str:
    """``text`` cut to ``most`` characters for an error answer (a frame may be 64 kB)."""
    return text if len(text) <= most else text[: most - 3] + "..."


def _check_settings(clock: str, inertia: float, damping: float, coulomb_friction: float) -> None:
    """An emulator's settings, checked as the protocol checks them (a UserError)."""
    if clock not in ("wall", "query"):
        raise UserError(f"clock {clock!r}: expected 'wall' or 'query'")
    for name, value, unit in (
        ("inertia", inertia, "kg"),
        ("coulombfriction", coulomb_friction, "N"),
        ("dampcoef", damping, "N s/m"),
    ):
        if not in_range(name, value):
            low, high = LIMITS[name]
            raise UserError(f"{name} {value!r} {unit}: expected {low:g} to {high:g} {unit}")


def _listen(host: str, port: int) -> socket.socket:
    """The emulator's listening socket, polled every 50 ms (so that close() is seen)."""
    try:
        server = socket.create_server((host, int(port)))
    except OSError as exc:
        raise UserError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    server.settimeout(0.05)
    return server


class HapticMasterEmulator:
    """A TCP server on ``host:port`` that behaves as a HapticMaster (``port=0``: any).

    Parameters
    ----------
    inertia
        The device's mass (kg); the protocol's ``set inertia`` changes it.
    damping
        Its viscous damping (N s/m), its physical damping in the passivity check.
    coulomb_friction
        Its Coulomb friction (N), ``set coulombfriction``.
    user_force
        ``f(t, position, velocity) -> [fx, fy, fz]``: the force (N) the simulated hand
        applies at time t (s, simulated, since the device last entered the ``force``
        state; 0 before it first does) with the device's position (m) and velocity
        (m/s); ``measforce`` reports it plus ``sensor_noise`` (N, standard deviation).
    clock, steps_per_query
        How simulated time advances (module docstring).
    calibrated
        What the calibration queries answer.
    realtime
        Serve under real-time scheduling (SCHED_FIFO, priority :data:`RT_PRIORITY`)
        where permitted, else at niceness -10 where permitted
        (:attr:`scheduling` says what it got): the HapticMaster's controller is a
        real-time system, and an emulator at normal priority on a loaded machine
        waits for a core for tens of milliseconds, at times seconds, which a renderer
        rightly takes for a stalled device. Its threads only answer frames, each in
        well under a millisecond, and the kernel keeps 5 % of each second from
        real-time threads. For ``evo-door emulate``, a process of its own.
    """

    def __init__(
        self,
        port: int = 0,
        host: str = "127.0.0.1",
        *,
        inertia: float = 4.0,
        damping: float = 2.0,
        coulomb_friction: float = 0.0,
        user_force: Callable[[float, np.ndarray, np.ndarray], object] | None = None,
        sensor_noise: float = 0.0,
        clock: str = "wall",
        steps_per_query: int = 1,
        calibrated: bool = True,
        position: tuple[float, float, float] = (0.0, 0.0, 0.0),
        seed: int = 0,
        realtime: bool = False,
    ) -> None:
        _check_settings(clock, inertia, damping, coulomb_friction)
        self.host = host
        self.inertia = float(inertia)
        self.damping = np.full(3, float(damping))
        self.coulomb_friction = float(coulomb_friction)
        self.user_force = user_force or _zero_user
        self.sensor_noise = float(sensor_noise)
        self.clock = clock
        self.steps_per_query = int(steps_per_query)
        self.calibrated = bool(calibrated)
        self.dt = 1.0 / DEVICE_RATE
        #: the last :data:`RECENT` commands and frames received, oldest first
        self._recent: deque[str] = deque(maxlen=RECENT)
        self.frames: deque[str] = deque(maxlen=RECENT_FRAMES)
        #: how many commands (``;``-separated) and frames it answered, and refused
        self.commands = 0
        self.frames_answered = 0
        self.refused = 0
        #: simulated steps whose result was not finite, undone (none within LIMITS)
        self.faults = 0
        self.state = "off"
        self.initialised = False
        self.effects: dict[str, dict] = {}
        self._layout: tuple | None = None  # the springs and dampers, as arrays
        self.time = 0.0
        #: the simulated time (s) at which the device last entered the force state: the
        #: scripted hand's time zero (None: not yet)
        self._hand_from: float | None = None
        self.position = np.array(position, dtype=np.float64)
        self.velocity = np.zeros(3)
        self.acceleration = np.zeros(3)
        self._user = np.zeros(3)
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self._wall: float | None = None
        self._steps = 0
        self._clients: set[socket.socket] = set()  # open connections only
        self._threads: set[threading.Thread] = set()
        self._clients_lock = threading.Lock()
        self._closed = threading.Event()
        compile_kernel()  # before any client waits on an answer
        self._server = _listen(host, port)
        self.port = self._server.getsockname()[1]
        #: the scheduling of the threads that answer (``realtime``)
        self.scheduling = "normal priority"
        self._accept_thread = self._start_accepting(realtime)

    # -- server ---------------------------------------------------------------------

    def _start_accepting(self, realtime: bool) -> threading.Thread:
        """The thread that accepts connections, started; it has its scheduling
        (``realtime``) when this returns, or after 5 s at the most."""
        scheduled = threading.Event()
        thread = threading.Thread(
            target=self._accept,
            args=(realtime, scheduled),
            name="hapticmaster-emulator",
            daemon=True,
        )
        thread.start()
        scheduled.wait(5.0)
        return thread

    @property
    def address(self) -> str:
        return f"hapticmaster://{self.host}:{self.port}"

    @property
    def received(self) -> list[str]:
        """The last :data:`RECENT` commands received, oldest first (:attr:`commands`
        counts them all)."""
        return list(self._recent)

    def _accept(self, realtime: bool, scheduled: threading.Event) -> None:
        if realtime:  # the connections' threads inherit it from this one
            self.scheduling = _real_time()
        scheduled.set()
        while not self._closed.is_set():
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue  # a poll, so that close() is seen
            except OSError:
                return
            with self._clients_lock:
                if len(self._clients) >= MAX_CLIENTS:  # bounded: refuse, do not queue
                    conn.close()
                    continue
                conn.settimeout(None)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                thread = threading.Thread(target=self._serve, args=(conn,), daemon=True)
                self._clients.add(conn)
                self._threads.add(thread)
            thread.start()

    def _serve(self, conn: socket.socket) -> None:
        try:
            with conn:
                self._serve_frames(conn)
        finally:  # forget the connection: none is kept after it ends
            with self._clients_lock:
                self._clients.discard(conn)
                self._threads.discard(threading.current_thread())

    def _serve_frames(self, conn: socket.socket) -> None:
        """Answer each frame, in order, until the host closes. When the host can no
        longer take answers (it closed or reset), the frames it sent before still
        count: the device processes what it received, in order, answered or not (the
        client's fail-safe frame arrives last, after a host's stall)."""
        reader = FrameReader()
        answering = True
        while not self._closed.is_set():
            try:
                data = conn.recv(65536)
            except OSError:
                return
            if not data:
                return
            try:
                texts = reader.feed(data)
            except HapticMasterError:
                return  # a corrupt stream: the device drops the connection
            replies = [encode(self._safe_answer(text)) for text in texts]
            if replies and answering:
                try:
                    conn.sendall(b"".join(replies))
                except OSError:
                    answering = False

    def _safe_answer(self, text: str) -> str:
        try:
            return self.answer_frame(text)
        except Exception as exc:  # the emulator keeps answering, as the device would
            return f"{ERROR_PREFIX}: internal error {type(exc).__name__}: {exc}"

    def drop_clients(self) -> None:
        """Cut every open connection (what a pulled cable looks like to the host)."""
        with self._clients_lock:
            clients = list(self._clients)
        for conn in clients:
            try:
                conn.shutdown(socket.SHUT_RDWR)
                conn.close()
            except OSError:
                pass

    def close(self) -> None:
        self._closed.set()
        try:
            self._server.close()
        except OSError:
            pass
        self.drop_clients()
        self._accept_thread.join(timeout=1.0)
        with self._clients_lock:
            threads = list(self._threads)
        for thread in threads:
            thread.join(timeout=1.0)

    def __enter__(self) -> HapticMasterEmulator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def serve_forever(self, seconds: float = math.inf) -> None:
        """Block until :meth:`close`, ``seconds`` pass, or Ctrl-C in the caller."""
        end = time.monotonic() + seconds
        while not self._closed.wait(min(0.2, max(end - time.monotonic(), 0.0))):
            if time.monotonic() >= end:
                return

    # -- physics ----------------------------------------------------------------------

    def _advance(self) -> None:
        if self.clock == "query":
            n = self.steps_per_query
        else:
            # whole device steps since the first frame, on the wall clock
            now = time.perf_counter()
            if self._wall is None:
                self._wall, self._steps = now, 0
            n = int((now - self._wall) / self.dt) - self._steps
            cap = int(MAX_ADVANCE / self.dt)
            if n > cap:  # a stall: skip the lost time rather than jump
                self._steps += n - cap
                n = cap
            self._steps += n
        t = 0.0 if self._hand_from is None else self.time - self._hand_from
        user = self.user_force(t, self.position.copy(), self.velocity.copy())
        self._user = np.asarray(user, dtype=np.float64).reshape(3)
        if n <= 0:
            return
        if self.state != "force":
            self.velocity[:] = 0.0
            self.time += n * self.dt
            return
        force = self._user.copy()
        for e in self.effects.values():
            if e["type"] == "biasforce" and e["enabled"]:
                force += e["force"]
        if self._layout is None:  # the springs and dampers changed since the last frame
            self._layout = self._effects_layout()
        k, at, b, direction, deadband, maxforce, damping = self._layout
        before = self.position.copy(), self.velocity.copy()
        self.acceleration = advance_effects(
            self.position,
            self.velocity,
            n,
            self.dt,
            self.inertia,
            damping,
            self.coulomb_friction,
            force,
            k,
            at,
            b,
            direction,
            deadband,
            maxforce,
        )
        if not (np.all(np.isfinite(self.position)) and np.all(np.isfinite(self.velocity))):
            # never within LIMITS; should it happen, the mass stops where it was
            # rather than answer NaN positions for ever
            self.position[:], self.velocity[:] = before[0], 0.0
            self.acceleration[:] = 0.0
            self.faults += 1
        self.time += n * self.dt

    def _effects_layout(self) -> tuple:
        """The enabled springs as the kernel's arrays, and the total damping per axis."""
        springs = [e for e in self.effects.values() if e["type"] == "spring" and e["enabled"]]
        ns = len(springs)
        k = np.array([e["stiffness"] for e in springs], dtype=np.float64)
        b = np.array([e["dampfactor"] for e in springs], dtype=np.float64)
        at = np.array([e["pos"] for e in springs], dtype=np.float64).reshape(ns, 3)
        direction = np.array([_unit(e["direction"]) for e in springs]).reshape(ns, 3)
        deadband = np.array([e["deadband"] for e in springs], dtype=np.float64)
        maxforce = np.array([e["maxforce"] for e in springs], dtype=np.float64)
        damping = self.damping.copy()
        for e in self.effects.values():
            if e["type"] == "damper" and e["enabled"]:
                damping += e["dampcoef"]
        return k, at, b, direction, deadband, maxforce, damping

    def bias_force(self) -> np.ndarray:
        """The sum of the enabled bias forces (N)."""
        with self._lock:
            total = np.zeros(3)
            for e in self.effects.values():
                if e["type"] == "biasforce" and e["enabled"]:
                    total += e["force"]
            return total

    # -- protocol ---------------------------------------------------------------------

    def answer_frame(self, text: str) -> str:
        """The answer frame's text for one received frame (commands split on ``;``)."""
        with self._lock:
            self._advance()
            commands = [c.strip() for c in text.split(";")]
            if len(commands) > 1 and commands[-1] == "":
                commands.pop()  # a trailing ';' as some clients send
            # counted, and only the last kept: memory bounded over millions of commands
            self.frames.append(_shown(text, 4 * KEPT_CHARS))
            self._recent.extend(_shown(c, KEPT_CHARS) for c in commands)
            self.frames_answered += 1
            self.commands += len(commands)
            answers = [self._answer(c) for c in commands]
            self.refused += sum(a.startswith(ERROR_PREFIX) for a in answers)
            return ";".join(answers)

    def _answer(self, command: str) -> str:
        try:
            return self._dispatch(command.split())
        except (ValueError, IndexError, HapticMasterError):
            return f"{ERROR_PREFIX}: cannot execute {_shown(command)!r}"

    def _dispatch(self, words: list[str]) -> str:
        if not words:
            return f"{ERROR_PREFIX}: empty command"
        verb, args = words[0].lower(), words[1:]
        if verb == "get":
            return self._get(args)
        if not (verb == "set" and len(args) > 1 and args[1].lower() == "force"):
            self._layout = None  # anything but a bias force may change springs, dampers
        if verb == "set":
            return self._set(args[0], args[1:])
        if verb == "create" and len(args) == 2 and args[0].lower() in _EFFECTS:
            kind, name = args[0].lower(), args[1]
            if name in self.effects or name.lower() in ("state", "inertia", "all"):
                return f"{ERROR_PREFIX}: name {name!r} is already in use"
            if len(self.effects) >= MAX_EFFECTS or len(name) > MAX_NAME:
                return (
                    f"{ERROR_PREFIX}: at most {MAX_EFFECTS} effects of names up to "
                    f"{MAX_NAME} characters"
                )
            self.effects[name] = {
                "type": kind,
                "enabled": False,
                "force": np.zeros(3),
                "stiffness": 0.0,
                "pos": np.zeros(3),
                "dampfactor": 0.0,
                "direction": np.zeros(3),
                "deadband": 0.0,
                "maxforce": math.inf,
                "dampcoef": np.zeros(3),
            }
            return f"Effect {kind} with name {name} created"
        if verb == "remove" and len(args) == 1:
            if args[0] == "all":
                self.effects.clear()
                return "All effects removed"
            if self.effects.pop(args[0], None) is None:
                return f"{ERROR_PREFIX}: no effect named {args[0]!r}"
            return f"Effect {args[0]} removed"
        return f"{ERROR_PREFIX}: unknown command {_shown(' '.join(words))!r}"

    def _get(self, args: list[str]) -> str:
        what, rest = args[0], args[1:]
        values = {
            "state": lambda: self.state,
            "modelpos": lambda: format_vector(self.position),
            "measpos": lambda: format_vector(self.position),
            "modelvel": lambda: format_vector(self.velocity),
            "modelacc": lambda: format_vector(self.acceleration),
            "measforce": lambda: format_vector(
                self._user + self.sensor_noise * self._rng.standard_normal(3)
            ),
            "inertia": lambda: f"{self.inertia:.9g}",
            "coulombfriction": lambda: f"{self.coulomb_friction:.9g}",
            "position_calibrated": lambda: "true" if self.calibrated else "false",
            "force_calibrated": lambda: "true" if self.calibrated else "false",
        }
        if what.lower() in values and not rest:
            return values[what.lower()]()
        effect = self.effects.get(what)
        if effect is not None and len(rest) == 1:
            value = effect[_ALIASES.get(rest[0].lower(), rest[0].lower())]
            if isinstance(value, np.ndarray):
                return format_vector(value)
            return str(value).lower()
        return f"{ERROR_PREFIX}: cannot get {_shown(' '.join([what, *rest]))!r}"

    def _set(self, name: str, rest: list[str]) -> str:
        value = " ".join(rest)
        if name == "state":
            state = value.lower()
            if state not in _STATES:
                return f"{ERROR_PREFIX}: unknown state {value!r}"
            if state in ("force", "position") and not self.initialised:
                return f"{ERROR_PREFIX}: set state init before set state {state}"
            self.initialised = self.initialised or state == "init"
            if state == "force" and self.state != "force":  # the hand's script starts
                self._hand_from = self.time
            self.state = state
            if state != "force":
                self.velocity[:] = 0.0
            return f"state set to '{state}'"
        if name == "inertia":
            inertia = float(value)
            if not in_range("inertia", inertia):
                return _out_of_range("inertia", value, "kg")
            self.inertia = inertia
            return "Inertia set"
        if name == "coulombfriction":
            friction = float(value)
            if not in_range("coulombfriction", friction):
                return _out_of_range("Coulomb friction", value, "N")
            self.coulomb_friction = friction
            return "Coulomb friction set"
        return self._set_effect(name, rest)

    def _set_effect(self, name: str, rest: list[str]) -> str:
        """``set NAME FIELD VALUE`` of an effect (``enable``, a vector, a number)."""
        effect = self.effects.get(name)
        if effect is None or not rest:
            return f"{ERROR_PREFIX}: no effect named {name!r}"
        field = _ALIASES.get(rest[0].lower(), rest[0].lower())
        arg = " ".join(rest[1:])
        if field in ("enable", "disable") and len(rest) == 1:
            effect["enabled"] = field == "enable"
            return f"Effect {name} {field}d"
        if field == "enabled":
            effect["enabled"] = arg.strip().lower() in ("1", "true")
            return f"Effect {name} {'enabled' if effect['enabled'] else 'disabled'}"
        if field in ("force", "pos", "dampcoef", "direction"):
            vector = parse_vector(arg, field)
            if not all(in_range(field, float(c)) for c in vector):
                return _out_of_range(field, arg, _UNITS[field])
            effect[field] = vector
            return f"Effect {name} {field} set"
        if field in ("stiffness", "dampfactor", "deadband", "maxforce"):
            number = float(arg)
            if not in_range(field, number):  # maxforce inf: no cap
                return _out_of_range(field, arg, _UNITS[field])
            effect[field] = number
            return f"Effect {name} {field} set"
        return f"{ERROR_PREFIX}: effect {name!r} has no setting {field!r}"
