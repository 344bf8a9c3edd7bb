"""The servo loop: read the device, evaluate the haptic model, command the force.

Each cycle (:meth:`ServoLoop._cycle`; :meth:`ServoLoop.run` paces and repeats it):

1. a pending parameter change (:meth:`ServoLoop.request_change`, validated when asked)
   comes into force, whole: changes happen only between two cycles;
2. ``device.read()``: position, velocity, measured user force;
3. :func:`~evo_door.render.kernels.compute_command_implicit` (compiled, the default):
   the haptic model's device-space force (:func:`~evo_door.models.haptic.device_force`)
   without its dry friction, plus that friction rendered by the implicit Coulomb law
   for the device's mass and the loop period (stable at any level, holds still below
   it); or, with ``friction="tanh"``, :func:`~evo_door.render.kernels.compute_command`:
   the model's force as it is, tanh friction included (rings above 2 m v_s / T).
   Either made safe (:func:`~evo_door.render.safety.limit_force`: finite, within the
   device limit), and the door's state for the log (theta, dtheta, tangential user
   force);
4. ``device.command(force)``, ``device.step(T)`` (simulated devices only move here);
5. the log row, the watchdog.

A simulated device runs in simulated time, as fast as the machine allows, unless
``realtime``; a real device paces the loop on ``time.perf_counter``
(:mod:`evo_door.render.priority`: its thread's priority and the wait for each slot)
and the period statistics (:mod:`evo_door.render.timing`: mean period, p99 lateness,
missed cycles) say how well it kept time.

A mechanism (any model on a state vector) is rendered by a subclass,
:class:`~evo_door.render.mechanism.MechanismLoop`, through the hooks of "what the loop
renders" (the model's check, its declaration, its mass, its kernels, the time-0 event).

Size: under 775 lines, one class: its parameter changes, its statistics and
the cycle belong together (the cycle reads the set in force and feeds the statistics);
the kernels, pacing, timing and log are already modules of their own.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from evo_door.errors import UserError
from evo_door.models.haptic import FRICTION_CLOSING, FRICTION_OPENING, PARAMS
from evo_door.params import param_vector
from evo_door.render.columns import (
    COMMAND,
    DTHETA,
    FORCE,
    N_COLUMNS,
    POSITION,
    THETA,
    USER_FORCE,
    VELOCITY,
)
from evo_door.render.hands_off import HANDS_OFF_RANGE, check_hands_off
from evo_door.render.kernels import compute_command, compute_command_implicit
from evo_door.render.log import RenderLog
from evo_door.render.priority import Pacing
from evo_door.render.safety import IMPLICIT, NON_FINITE, Watchdog, check_passive
from evo_door.render.timing import LoopTiming

#: dry-friction laws of the loop: the implicit (set-valued) Coulomb law, the default,
#: or the haptic model's own explicit tanh (for comparison: rings above
#: :func:`~evo_door.render.friction.tanh_stability_limit`)
FRICTION_LAWS = ("implicit", "tanh")
#: the shortest gap between two commands that counts as a stall (s), whatever the
#: watchdog's budget in cycles: a Python process on a busy machine sees hiccups of
#: 5-15 ms (13 ms ended a console's render at the 4 ms of 10 cycles at 2500 Hz), and a
#: force held that long is what the supervisor tolerates too (its 20 ms budget)
STALL_FLOOR = 0.02
#: a paced loop's gaps (slots missed in a row) of at least :data:`STALL_FLOOR` that a
#: budget of more cycles let it survive are each logged, an event ``gap`` with its
#: span, up to this many (the statistics count them all): over a gap the device held
#: its last command, which the render check does not simulate across
#: (:mod:`evo_door.render.check`)
MAX_GAP_EVENTS = 1000

#: cycles run after which a paced loop checks passivity again with its measured period
_RECHECK_AFTER = 250

#: what a refusal of a change names as its source: the values the client sent, never
#: the file the running set came from (a preset's path on the server's installation)
CHANGE = "change"


def renderable(params):
    """``params`` if the loop may render it: every value finite and within its declared
    range, else a UserError naming the parameter. The loaders check this; a ParamSet
    built by hand (``ParamSet(table, vector)``) does not, and a NaN there reached the
    compiled force (a NaN radius, a simulated mass of NaN; a 0 a division by zero)."""
    for q, value in zip(PARAMS, param_vector(params, PARAMS), strict=True):
        q.check(value, "the set to render")
    return params


def _device_number(device, name: str, default: float, unit: str, positive=False) -> float:
    """A device's ``name`` (max_force, damping, mass): finite, >= 0 (> 0 if ``positive``),
    else a UserError: the kernel's passivity and force limit rest on it."""
    value = float(getattr(device, name, default))
    if not (math.isfinite(value) and (value > 0 if positive else value >= 0)):
        sign = ">" if positive else ">="
        raise UserError(f"the device's {name} is {value:g} {unit}: must be finite and {sign} 0")
    return value


def _check_settings(rate, log_rate, ramp_time, friction) -> None:
    """A UserError for a loop setting out of its range (ServoLoop's arguments)."""
    if not (math.isfinite(rate) and 10.0 <= rate <= 20000.0):
        raise UserError(f"--rate {rate:g}: give a loop rate in 10..20000 Hz")
    if not (math.isfinite(log_rate) and 1.0 <= log_rate <= rate):
        raise UserError(f"--log-rate {log_rate:g}: give a log rate in 1..{rate:g} Hz (the loop's)")
    if not 0.0 < ramp_time <= 0.01:
        raise UserError(f"ramp time {ramp_time:g} s: must be in (0, 0.01] s")
    if friction not in FRICTION_LAWS:
        raise UserError(f"--friction {friction!r}: choose one of {', '.join(FRICTION_LAWS)}")


def _check_hands_off_speed(limit) -> None:
    """A UserError unless ``limit`` is None or a speed within :data:`HANDS_OFF_RANGE`."""
    if limit is None:
        return
    lo, hi = HANDS_OFF_RANGE
    if not (math.isfinite(limit) and lo <= limit <= hi):
        raise UserError(f"--hands-off-speed {limit:g}: give a speed in {lo:g}..{hi:g} rad/s")


class ServoLoop:
    """Renders a haptic parameter set on ``device``.

    Parameters
    ----------
    device : Device
        Any object with the :class:`~evo_door.render.device.Device` methods.
    params : ParamSet
        The haptic model's parameter set (checked for passivity at the loop period,
        and against ``hands_off_speed``).
    rate : float
        Loop rate (Hz), default the HapticMaster's 2500.
    log_rate : float
        Log rate (Hz).
    realtime : bool or None
        Pace on the wall clock; default: only for devices that are not simulated.
    clamp : bool
        Scale down a set that is not passive instead of refusing it (logged).
    watchdog_misses : int
        Consecutive late cycles that trip the watchdog.
    ramp_time : float
        Time (s) the tripped watchdog takes to ramp the force to zero (<= 10 ms).
    friction : str
        Dry-friction law: ``"implicit"`` (default) or the model's ``"tanh"``.
    supervisor : Supervisor or None
        The process that takes the force off a real device when the loop stops
        beating (:class:`~evo_door.render.supervisor.Supervisor`): armed before the
        first cycle, beaten every cycle, disarmed before the device is stopped.
    hands_off_speed : float or None
        Refuse a set (the first and every change) whose door, released from rest
        anywhere with no hand on it, moves faster than this (rad/s;
        :func:`~evo_door.render.hands_off.check_hands_off`); None: not checked.
        ``evo-door render`` passes its ``--hands-off-speed`` (default
        :data:`~evo_door.render.hands_off.HANDS_OFF_SPEED`).
    """

    def __init__(
        self,
        device,
        params,
        rate: float = 2500.0,
        *,
        log_rate: float = 1000.0,
        realtime: bool | None = None,
        clamp: bool = False,
        watchdog_misses: int = 10,
        ramp_time: float = 0.008,
        device_name: str = "",
        friction: str = "implicit",
        supervisor=None,
        hands_off_speed: float | None = None,
    ):
        _check_settings(rate, log_rate, ramp_time, friction)
        self._check_model(params)
        _check_hands_off_speed(hands_off_speed)
        self.hands_off_speed = None if hands_off_speed is None else float(hands_off_speed)
        self.friction = friction
        self.device = device
        self.device_name = device_name or type(device).__name__
        self.rate = float(rate)
        self.period = 1.0 / self.rate
        self.clamp = bool(clamp)
        self.limit = _device_number(device, "max_force", 200.0, "N", positive=True)
        self.damping = _device_number(device, "damping", 0.0, "N s/m")
        self.simulated = bool(getattr(device, "simulated", False))
        self.realtime = (not self.simulated) if realtime is None else bool(realtime)
        self.log = RenderLog(log_rate, self._table(params))
        self.pacing = Pacing(self.log)  # a paced loop's priority and wait for its slot
        self.watchdog = Watchdog(watchdog_misses, ramp_time)
        self.supervisor = supervisor
        self._lock = threading.Lock()  # guards _pending between the loop and the rest
        self._changing = threading.RLock()  # one change validated at a time
        self._pending = None
        self._check_period = self.period
        #: names the loop does not render by a sampled explicit law (solved over the
        #: step, or rendered by the device itself): out of the passivity check
        self.exclude = IMPLICIT if friction == "implicit" else frozenset()
        self._native: tuple[str, ...] = ()
        self.timing = LoopTiming(self.period)
        self.params, changes = self._passive(self._renderable(params))
        self._hands_off(self.params)
        self._clamp_note = changes
        self._set_vectors()
        self._mass = self._virtual_mass()
        self.faults = 0
        self.saturated = 0
        self.gaps = 0  # gaps of STALL_FLOOR or more a paced loop survived
        self.gap_longest = 0.0  # s
        self.statistics: dict = {}
        self.status = "new"
        #: perf_counter at the first cycle and when the loop ended (s; 0 until then)
        self.t0 = 0.0
        self.t_end = 0.0
        self._now = 0.0  # the loop time of the current cycle (s)
        self._k = 0  # cycles run
        self._sent = 0.0  # when the last command went (perf_counter, s; paced loops)
        self._stall_limit = 0.0  # a gap between two commands this long is a stall (s)
        #: called with the loop time (s) at the end of every cycle, in the loop's thread
        #: (a JND session's schedule: :mod:`evo_door.render.jnd`); it must not block
        self.on_cycle = None
        self._new_buffers()

    # -- parameter changes ---------------------------------------------------------
    def request_change(self, values: dict):
        """Validate ``values`` {name: SI value}; on success they apply between two cycles.

        All or nothing: a value outside its declaration, an unknown name, a set that
        is not passive at the loop period (unless the loop clamps) or whose door moves
        faster than ``hands_off_speed`` on its own raises a UserError with the reason,
        and the running set stays as it was. Returns the new set (after any clamp).
        """
        with self._changing:  # concurrent callers (control port, keys) queue here
            with self._lock:
                base = self._pending[0] if self._pending is not None else self.params
                before = dict(self._pending[1]) if self._pending is not None else {}
            try:
                new = base.replace(dict(values), source=CHANGE)
                new, changes = self._passive(self._renderable(new))
                self._hands_off(new)
            except UserError as exc:
                self.log.client_event(self._now, "refused", str(exc), values=dict(values))
                raise
            with self._lock:
                self._pending = (new, {**before, **values}, changes)
        return new

    @property
    def pending(self) -> bool:
        """A validated change waits for the next cycle."""
        return self._pending is not None

    def snapshot(self) -> dict:
        """The loop's state for a display, safe from any thread (the log's last row).

        ``t`` (s, loop time), ``status``, ``params`` (the ParamSet in force),
        ``pending`` (a change waits for the next cycle), the door state of the log's last
        row (1 kHz)
        ``theta`` (rad), ``dtheta`` (rad/s), ``force`` (N, the user's, on the
        tangent), ``position`` (m), ``velocity`` (m/s), ``user_force`` and
        ``command`` (N) in device axes (NaN before the first cycle), the counts
        ``faults`` and ``saturated``, ``watchdog`` (its reason), ``rate``, ``device``.
        """
        row = self.log.last()  # a copy of the last finished log row
        if row is None:
            row = np.full(N_COLUMNS, np.nan)
        return {
            "t": self._now,
            "status": self.status,
            "params": self.params,
            "pending": self.pending,
            "theta": float(row[THETA]),
            "dtheta": float(row[DTHETA]),
            "force": float(row[FORCE]),
            "position": row[POSITION : POSITION + 3].tolist(),
            "velocity": row[VELOCITY : VELOCITY + 3].tolist(),
            "user_force": row[USER_FORCE : USER_FORCE + 3].tolist(),
            "command": row[COMMAND : COMMAND + 3].tolist(),
            "faults": self.faults,
            "saturated": self.saturated,
            "watchdog": self.watchdog.reason,
            "rate": self.rate,
            "device": self.device_name,
        }

    def health(self) -> dict:
        """The loop's timing so far, for a display (any thread): the statistics of
        :meth:`run`'s end, computed now."""
        return self._stats(self._k)

    # -- what the loop renders: the haptic model (a subclass renders another) --------
    def _check_model(self, params) -> None:
        """A UserError unless ``params`` is a set of the model this loop renders."""
        if getattr(params, "model", None) != "haptic":
            raise UserError("the renderer takes a parameter set of the 'haptic' model")

    def _table(self, params):
        """The declaration of the sets the log records."""
        return PARAMS

    def _renderable(self, params):
        """``params`` if every value is finite and declared (:func:`renderable`)."""
        return renderable(params)

    def _virtual_mass(self) -> float:
        """The mass (kg) the device moves for the set in force: the haptic I / R."""
        return self.params["inertia"] / self.params["radius"]

    def _load_kernels(self) -> None:
        """Call the cycle's kernels once (numba's cache: milliseconds), not in the first
        slot."""
        T = self.period
        pos, vel, user, cmd, row = self._pos, self._vel, self._user, self._cmd, self._row
        compute_command(pos, vel, user, self._p, self.limit, cmd, row)
        compute_command_implicit(
            pos, vel, user, self._p, self._p_free, 1.0, T, 0.0, self.limit, cmd, row
        )

    def travel(self, first: float, last: float) -> str:
        """Where the handle went, for the summary: the door from ``first`` to ``last``
        (rad, the log's first and last theta)."""
        return f"door {math.degrees(first):.1f} -> {math.degrees(last):.1f} deg"

    def _log_law(self) -> None:
        """The event at time 0 that says how the set is rendered (its friction law)."""
        self.log.event(0.0, "friction", f"dry friction rendered by the {self.friction} law")

    def _passive(self, params):
        """Colgate-Schenkel at the period in force, without what is not sampled explicitly."""
        exclude = self.exclude | frozenset(self._native)
        return check_passive(params, self.damping, self._check_period, self.clamp, exclude)

    def _hands_off(self, params) -> None:
        """A UserError if the door of ``params`` moves too fast with no hand on it."""
        if self.hands_off_speed is not None:
            check_hands_off(params, self.hands_off_speed)

    def _apply_pending(self, t: float) -> None:
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is None:
            return
        new, values, changes = pending
        self.params = new
        self._set_native()
        self._set_vectors()
        self._set_mass()
        if not self.log.params(t, self._set_vector()):
            return  # past the log's cap of sets: in force, counted, not recorded
        self.log.event(t, "change", "parameters changed", values=values)
        if changes:
            self.log.event(t, "clamp", "clamped to be passive", changes=changes)

    def _set_native(self) -> None:
        """What the device renders itself (its own springs, dampers at its own rate)."""
        native = getattr(self.device, "render_natively", None)
        if native is not None:
            self._native = tuple(native(self.params))

    def _set_vector(self):
        """The set in force as a vector, for the log: the whole set, including what the
        device renders natively (``_p`` zeroes that, which is no change of the set)."""
        return param_vector(self.params, PARAMS)

    def _set_vectors(self) -> None:
        """Kernel vectors of the set in force: as it is, and without dry friction;
        both without what the device renders natively."""
        p = param_vector(self.params, PARAMS)
        for name in self._native:
            p[PARAMS.index(name)] = 0.0
        self._p = p
        self._p_free = self._p.copy()
        self._p_free[FRICTION_CLOSING] = 0.0
        self._p_free[FRICTION_OPENING] = 0.0

    def _set_mass(self) -> None:
        """The device renders the virtual mass I / R natively; the implicit friction
        needs the mass that moves, that one, or the device's own if it cannot be set."""
        virtual = self._virtual_mass()
        set_mass = getattr(self.device, "set_mass", None)
        if set_mass is not None:
            set_mass(virtual)
            self._mass = virtual
        else:
            self._mass = _device_number(self.device, "mass", virtual, "kg", positive=True)

    # -- the loop --------------------------------------------------------------------
    def run(self, duration: float | None = None, stop: threading.Event | None = None) -> dict:
        """Run for ``duration`` seconds (loop time) or until ``stop`` is set.

        Returns the statistics (also in ``self.statistics`` and the log); their
        ``status`` is ``done``, ``stopped`` (by ``stop``), ``watchdog`` or ``failed``
        (the loop raised). The device is stopped on the way out, whatever happened.
        """
        n_cycles = self._cycles(duration, stop)
        self._set_up()
        self.pacing.begin(self.realtime)
        k = 0
        try:
            self._start()
            while k < n_cycles and not (stop is not None and stop.is_set()):
                k, now, late = self._pace(k, n_cycles)
                if k >= n_cycles:
                    break  # the slots it missed reached the end
                if not self._cycle(k * self.period, now, late):
                    break  # the tripped watchdog's ramp reached zero force
                k += 1
                self._k = k
        except BaseException:
            self.status = "failed"
            raise
        finally:
            self._end(k, n_cycles, stop)
        return self.statistics

    def _cycles(self, duration: float | None, stop: threading.Event | None) -> float:
        """How many cycles ``run`` runs (inf: until ``stop``); a UserError for neither."""
        if duration is None and stop is None:
            raise UserError("give a duration or a stop event")
        if duration is not None and not (math.isfinite(duration) and duration > 0):
            raise UserError(f"--duration {duration:g}: must be > 0 s")
        return math.inf if duration is None else int(round(duration * self.rate))

    def _new_buffers(self) -> None:
        """The arrays a cycle reads into and writes to (the kernels allocate nothing)."""
        self._pos = np.zeros(3)  # m, device frame
        self._vel = np.zeros(3)  # m/s
        self._user = np.zeros(3)  # N, the measured user force
        self._cmd = np.zeros(3)  # N, the force to command
        self._last = np.zeros(3)  # N, the last force the device took (the ramp's start)
        self._row = np.zeros(N_COLUMNS)  # the cycle's log row

    def _set_up(self) -> None:
        """Before a run: fresh buffers and timing; the set in force and the friction law
        (and a clamp at start) logged at time 0."""
        self._new_buffers()
        self.timing = LoopTiming(self.period)
        self.log.params(0.0, self._set_vector())
        self._log_law()
        self._log_device()
        if self._clamp_note:
            self.log.event(0.0, "clamp", "clamped to be passive", changes=self._clamp_note)
        self.status = "running"
        self.t0 = self.t_end = 0.0

    def _log_device(self) -> None:
        """What the device puts on the handle besides the set, for a reader of the log
        (:mod:`evo_door.render.check`): its own damping (N s/m), its dry friction (N,
        where the device says), its force limit (N)."""
        friction = getattr(self.device, "coulomb", None)
        known = {} if friction is None else {"friction": float(friction)}
        said = "" if friction is None else f", dry friction {float(friction):g} N"
        self.log.event(
            0.0,
            "device",
            f"the device's own damping {self.damping:g} N s/m{said}, force limit "
            f"{self.limit:g} N: felt besides the set",
            damping=self.damping,
            max_force=self.limit,
            **known,
        )

    def _start(self) -> None:
        """Just before the first cycle: the kernels loaded, the device started and told
        what it renders, the clock's origin ``t0`` taken, the supervisor armed."""
        T = self.period
        self._load_kernels()
        self._cmd[:] = 0.0
        # a device over a link counts as stalled after the watchdog's budget without
        # an answer (the device applies its own floor): its read then fails, which
        # trips the watchdog, and the loop ends at the next command
        watch_stalls = getattr(self.device, "watch_stalls", None)
        if watch_stalls is not None:
            watch_stalls(self.watchdog.misses * T)
        self.device.start()
        self._set_native()
        self._set_vectors()
        self._set_mass()
        self.t0 = self._sent = time.perf_counter()
        self._stall_limit = max((self.watchdog.misses + 1) * T, STALL_FLOOR)
        if self.supervisor is not None:
            self.supervisor.arm()

    def _pace(self, k: int, n_cycles: float) -> tuple[int, float, float]:
        """Wait for cycle ``k``'s slot (paced loops); returns ``(k, now, late)``.

        ``now`` is the time (s after ``t0``) the cycle starts, ``late`` (s) how long
        after its slot. A paced loop that missed its slot counts the slots missed and
        skips ahead, keeping its schedule (``k`` grows; to ``n_cycles`` at most); a
        loop in simulated time starts each cycle at its slot, on time.
        """
        T = self.period
        t = k * T
        if not self.realtime:
            return k, t, 0.0
        now = self.pacing.wait_until(self.t0, t)
        late = now - t
        if late > T:  # missed its slot: count, skip ahead, keep the schedule
            skip = int(min(late / T, n_cycles - k))  # none past the end
            self.timing.missed += skip
            if late >= STALL_FLOOR:
                self._log_gap(k, k + skip, late)
            k += skip
            if k >= n_cycles:
                return k, now, late
        self.timing.start(now, late)
        return k, now, late

    def _log_gap(self, k: int, resumed: int, late: float) -> None:
        """A gap of the paced loop, ``late`` (s) after slot ``k``, resumed at slot
        ``resumed``: counted, and logged as an event ``gap`` (at the slot it resumed,
        ``from_t`` the last cycle's) while fewer than :data:`MAX_GAP_EVENTS` are."""
        self.gaps += 1
        self.gap_longest = max(self.gap_longest, late)
        if self.gaps <= MAX_GAP_EVENTS:
            T = self.period
            self.log.event(
                resumed * T,
                "gap",
                f"the loop missed {resumed - k} cycles ({late * 1e3:.0f} ms): the device "
                "held its last command",
                from_t=max(k - 1, 0) * T,
                count=resumed - k,
            )

    def _cycle(self, t: float, now: float, late: float) -> bool:
        """One servo cycle at loop time ``t`` (s), started at ``now`` (s after ``t0``),
        ``late`` (s) after its slot.

        1. a waiting parameter change comes into force, whole;
        2. the device is read (a failed read trips the watchdog);
        3. the stall rule (paced loops): too long since the last command trips the
           watchdog (:meth:`_check_stall`), checked before the read too
           (:meth:`_stalled_before`);
        4. the force: while the watchdog is tripped, the last force ramped down
           (:meth:`_ramp_down`); else the kernel's, commanded (:meth:`_command`);
        5. the supervisor's heartbeat, the device's step (a simulated device moves),
           the log row, the cycle's work timed, the watchdog fed, the ``on_cycle``
           hook called;
        6. once, after :data:`_RECHECK_AFTER` paced cycles: passivity with the period
           measured (:meth:`_recheck`).

        Returns False when the loop ends here: the ramp reached zero force.
        """
        tic = time.perf_counter()
        watchdog = self.watchdog
        self._now = t
        self._apply_pending(t)
        stalled = False
        if self.realtime and not watchdog.tripped:
            stalled = self._stalled_before(tic)
        self._read(t, now)
        if self.realtime and not watchdog.tripped:
            self._sent = self._check_stall(self._sent, self._stall_limit)
            stalled = watchdog.tripped
        if stalled:  # the ramp starts after the stall, not before
            now = self._sent - self.t0
        if watchdog.tripped:
            if not self._ramp_down(t, now):
                return False
        else:
            self._command(t, now)
        if self.supervisor is not None:
            self.supervisor.beat()
        self.device.step(self.period)
        self.log.add(t, self._row)
        self.timing.worked_for(time.perf_counter() - tic)
        watchdog.cycle(now, late > self.period)
        if watchdog.tripped and watchdog.tripped_at == now:
            self.log.event(t, "watchdog", watchdog.reason)
        if self.on_cycle is not None:
            self.on_cycle(t)
        # paced cycles run (not slots); not once tripped (a stall's gap is no period)
        if self.realtime and self.timing.starts == _RECHECK_AFTER and not watchdog.tripped:
            self._recheck(self.timing.period_mean(), t)
        return True

    def _read(self, t: float, now: float) -> None:
        """The device's position, velocity and measured force into the cycle's arrays;
        a read that fails (a dropped connection, a device error) trips the watchdog."""
        try:
            p_, v_, f_ = self.device.read()
            self._pos[:] = p_
            self._vel[:] = v_
            self._user[:] = f_
        except Exception as exc:
            self.watchdog.trip(now, f"device read failed: {exc}")
            self.log.event(t, "fault", f"device read failed: {exc}")

    def _command(self, t: float, now: float) -> None:
        """The kernel's force and log row for the state read, counted when it was not
        finite or was limited, then commanded; a command that fails trips the watchdog."""
        cmd = self._cmd
        if self.friction == "implicit":
            code = compute_command_implicit(
                self._pos,
                self._vel,
                self._user,
                self._p,
                self._p_free,
                self._mass,
                self._check_period,
                self.damping,
                self.limit,
                cmd,
                self._row,
            )
        else:
            code = compute_command(
                self._pos, self._vel, self._user, self._p, self.limit, cmd, self._row
            )
        self._send(t, now, code, cmd)

    def _send(self, t: float, now: float, code: int, cmd) -> None:
        """Count the kernel's ``code`` (not finite, limited), then command ``cmd``; a
        command that fails trips the watchdog."""
        if code == NON_FINITE:
            self.faults += 1
            if self.faults <= 100:
                self.log.event(t, "fault", "non-finite state or force: zero force")
        elif code:
            self.saturated += 1
        try:
            self.device.command(cmd)
            self._last[:] = cmd
        except Exception as exc:  # the connection dropped while sending
            self.watchdog.trip(now, f"device command failed: {exc}")
            self.log.event(t, "fault", f"device command failed: {exc}")

    def _ramp_down(self, t: float, now: float) -> bool:
        """The tripped watchdog's cycle: the last force the device took, scaled down by
        the ramp, commanded. At zero (or when the command fails: the connection is
        gone) the cycle's row is logged and False returned: the loop ends."""
        factor = self.watchdog.factor(now)
        cmd = self._cmd
        cmd[:] = self._last * factor
        self._row[COMMAND : COMMAND + 3] = cmd
        try:
            self.device.command(cmd)
        except Exception:  # the connection is gone: nothing more to send
            factor = 0.0
        if factor == 0.0:
            if self.watchdog.tripped_at == now:  # tripped and ended at once
                self.log.event(t, "watchdog", self.watchdog.reason)
            self.log.add(t, self._row)
            return False
        return True

    def _end(self, k: int, n_cycles: float, stop: threading.Event | None) -> None:
        """After the last cycle (``k`` run), also when the loop raised: the thread's
        scheduling put back, the supervisor disarmed, the device stopped, the status
        and the statistics."""
        self.pacing.end()
        self.t_end = time.perf_counter()
        if self.supervisor is not None:  # first: a normal end is no stall
            self._disarm_supervisor()
        try:
            self.device.stop()
        finally:
            if self.status != "failed":
                stopped = stop is not None and stop.is_set() and k < n_cycles
                self.status = self._end_status(stopped)
            # also when the loop raised: an interrupted log keeps its statistics
            self.statistics = self._stats(k)

    def _check_stall(self, sent: float, limit: float) -> float:
        """Trip the watchdog when the loop stalled (paced loops, before each command).

        A paced loop that was kept from running (SIGSTOP, a blocked read, the machine
        busy) skips the slots it missed, so a stall of seconds counted as one late
        cycle and the loop went on from a stale state. Now a gap since the last
        command longer than ``limit`` (the watchdog's misses plus one periods) ends
        the render, as does the supervisor having taken the force off. It trips at
        the time of the check (s after ``t0``): a stall inside the cycle (a read held
        up) must not use up the ramp. Returns the time of this command
        (perf_counter), the next call's ``sent``.
        """
        tic = time.perf_counter()
        gap = tic - sent
        if gap > limit:
            self.watchdog.trip(tic - self.t0, f"stalled {gap * 1e3:.0f} ms")
        elif self.supervisor is not None and self.supervisor.latched:
            self.watchdog.trip(tic - self.t0, "stalled: the supervisor took the force off")
        return tic

    def _stalled_before(self, tic: float) -> bool:
        """The stall rule at a cycle's start (``tic``), before the device is read: a
        loop kept from running between two cycles (SIGSTOP) ends as stalled. Read
        first, the device's answer to a command sent before the stall could end it
        instead ("no effect named ...": the supervisor had removed it meanwhile), which
        hid the stall and its length from the log and the summary. True when it trips."""
        if tic - self._sent <= self._stall_limit:
            return False
        self._sent = self._check_stall(self._sent, self._stall_limit)
        return True

    def _disarm_supervisor(self) -> None:
        """The loop ends: disarm the supervisor; log what it did, if it did anything."""
        self.supervisor.disarm()
        note = self.supervisor.report()
        if note:
            self.log.event(self._now, "supervisor", note)

    def _end_status(self, stopped: bool) -> str:
        """How a loop that did not raise ended: ``watchdog`` (tripped), ``stopped``
        (its stop event came before its duration, if it had one) or ``done``."""
        if self.watchdog.tripped:
            return "watchdog"
        return "stopped" if stopped else "done"

    def _recheck(self, measured: float, t: float) -> None:
        """Passivity again with the measured period (over TCP, the round trip)."""
        self._check_period = max(self.period, measured)
        if self._check_period <= self.period * 1.05:
            return
        with self._changing:
            with self._lock:  # a change waiting is checked too, on top of the set
                base, values = (self.params, {}) if self._pending is None else self._pending[:2]
            try:
                new, changes = self._passive(base)
            except UserError as exc:
                self.watchdog.trip(t, f"measured period {measured * 1e3:.3g} ms: {exc}")
                self.log.event(t, "watchdog", self.watchdog.reason)
                return
            if changes or values:
                with self._lock:
                    self._pending = (new, values, changes)

    def _stats(self, cycles) -> dict:
        tm = self.timing
        stats = {
            "cycles": int(cycles),
            "cycles_run": tm.worked,
            "rate_hz": self.rate,
            "friction": self.friction,
            "realtime": self.realtime,
            "compute_mean_s": tm.work_sum / tm.worked if tm.worked else 0.0,
            "compute_p99_s": tm.percentile("work", 99),
            "faults": self.faults,
            "saturated_cycles": self.saturated,
            "gaps": self.gaps,
            "gap_longest_s": self.gap_longest,
            "status": self.status,
            "watchdog": self.watchdog.reason,
            # wall-clock time the cycles took (s): the loop time of a paced loop, less
            # for a simulated device run as fast as it goes
            "wall_s": ((self.t_end or time.perf_counter()) - self.t0) if self.t0 else 0.0,
        }
        stats.update(tm.schedule(cycles, self.realtime))
        rtt = getattr(self.device, "round_trips", None)  # a networked device's
        if rtt is not None and len(rtt):
            stats.update(
                round_trip_mean_s=float(np.mean(rtt)),
                round_trip_p99_s=float(np.percentile(rtt, 99)),
            )
        return stats

    def write_log(self, path) -> None:
        self.log.write(
            path, loop_rate=self.rate, device=self.device_name, statistics=self.statistics
        )
