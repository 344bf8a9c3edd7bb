"""Force-feedback devices behind one small interface, and a simulated one.

Every device speaks :class:`Device`: ``start``, ``read`` (position m, velocity m/s,
measured user force N, device frame), ``command`` (the force the host adds this cycle,
N), ``step`` (simulated devices advance their physics; real ones do nothing) and
``stop`` (idempotent, safe after errors). Duck typing is enough: a device need not
inherit from :class:`Device`.

:class:`SimDevice` is an admittance device like the MOOG HapticMaster: a point mass
(the haptic model's virtual mass I / R, rendered natively) with its own viscous and
Coulomb friction, a force sensor with seeded Gaussian noise, and saturation of the
host's command at ``max_force``. A scripted virtual user (:func:`user_script`) drives
it: a hand, a spring-damper, pulling the handle along the door's circle toward a
target angle that moves with time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from evo_door.errors import UserError
from evo_door.models.haptic import (
    C_PLANE,
    CLOSED,
    DEVICE_OFFSET_Y,
    DEVICE_OFFSET_Z,
    K_PLANE,
    PARAMS,
    on_path,
)
from evo_door.params import param_vector

#: Default saturation of a device's force (N): the HapticMaster's 200 N.
MAX_FORCE = 200.0


class Device:
    """The interface every device implements (see the module docstring)."""

    #: N, the device's saturation
    max_force: float = MAX_FORCE
    #: True for devices whose time is simulated (the loop then runs as fast as it can)
    simulated: bool = False
    #: N s/m, the device's own physical damping (for the passivity check)
    damping: float = 0.0

    def start(self) -> None:
        """Start-up sequence."""

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (m), velocity (m/s), measured user force (N): device-frame 3-vectors."""
        raise NotImplementedError

    def command(self, force: np.ndarray) -> None:
        """The force (N, 3-vector) the host adds this cycle."""
        raise NotImplementedError

    def step(self, dt: float) -> None:
        """Simulated devices advance their physics by ``dt`` (s); real ones do nothing."""

    def stop(self) -> None:
        """Shut-down: zero the host's force; idempotent, safe to call after errors."""


# ---------------------------------------------------------------------------------
# Virtual users
# ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class UserScript:
    """A hand on the handle pulling toward a target angle that moves with time.

    The target goes from ``theta_start`` to ``theta_end`` (rad) along a smooth
    (minimum-jerk) profile between ``t_begin`` and ``t_begin + t_move`` (s); or, when
    ``waypoints`` ``((t s, theta rad), ...)`` are given, from each waypoint to the
    next in the same way (held before the first and after the last). The hand is a
    spring ``stiffness`` (N/m) and damper ``damping`` (N s/m) toward the target's
    point on the circle, its force limited to ``max_force`` (N).

    ``let_go`` ``((t_release s, t_grab s), ...)``: the hand lets go of the handle at
    ``t_release`` (no force: the door goes on by itself) and takes it again at
    ``t_grab`` where it finds it, its target going from there to the next waypoint
    (held there without one; :class:`Hand` keeps where that was).
    """

    name: str
    theta_start: float
    theta_end: float
    t_begin: float = 0.2
    t_move: float = 2.0
    stiffness: float = 800.0
    damping: float = 40.0
    max_force: float = 80.0
    waypoints: tuple = ()
    let_go: tuple = ()

    def target(self, t: float, grab: tuple | None = None) -> float:
        """The target angle (rad) at ``t`` (s); after a ``grab`` ``(t s, theta rad)``
        (the hand took the handle again), from there to the next waypoint."""
        if grab is not None and t >= grab[0]:
            later = tuple(w for w in self.waypoints if w[0] > grab[0])
            return _through_waypoints((grab, *later), t)
        if self.waypoints:
            return _through_waypoints(self.waypoints, t)
        return _min_jerk(self.theta_start, self.theta_end, (t - self.t_begin) / self.t_move)

    def holding(self, t: float) -> bool:
        """Whether the hand holds the handle at ``t`` (s): not while it has let go."""
        return not any(a <= t < b for a, b in self.let_go)


class Circle:
    """The handle's path of the haptic model: the circle of ``radius`` (m) about the
    model frame's origin; a script's angle is the door's angle on it."""

    def __init__(self, radius: float):
        self.radius = float(radius)

    def point(self, angle: float) -> tuple[float, float, float]:
        """Device coordinates (m) of the handle at the script's ``angle`` (rad)."""
        return on_path(angle, self.radius)

    def angle(self, pos) -> float:
        """The script's angle (rad) of the handle at ``pos`` (m, device frame)."""
        return math.atan2(pos[1] + DEVICE_OFFSET_Y, pos[2] + DEVICE_OFFSET_Z)


class Hand:
    """A :class:`UserScript`'s hand on the handle, for a device to ask its force.

    :meth:`force` is the spring-damper toward the script's target (:func:`hand_force`)
    while the hand holds the handle, zero while it has let go; when it takes the
    handle again it remembers the angle there, so that its target starts from it.
    Time going back (a new render) starts the script afresh. ``radius`` (m): the
    handle's circle; ``path``: another path of the handle (an object with the methods
    ``point(angle)`` and ``angle(pos)`` of :class:`Circle`: a mechanism's straight
    stroke, :mod:`evo_door.render.mechanism`), the script's angles read on it.
    """

    def __init__(self, script: UserScript, radius: float, path=None):
        self.script = script
        self.radius = float(radius)
        self.path = Circle(radius) if path is None else path
        self._grab: tuple | None = None  # (t s, theta rad) where it took the handle again
        self._held = True
        self._last = -math.inf
        self._target = np.zeros(3)

    def force(self, t: float, pos, vel, out) -> None:
        """The hand's force (N, device frame) at ``t`` (s) on a handle at ``pos`` (m)
        moving at ``vel`` (m/s), into ``out``."""
        s = self.script
        if t < self._last:  # a new render: the script from its start
            self._grab, self._held = None, True
        self._last = t
        if not s.holding(t):
            self._held = False
            out[:] = 0.0
            return
        if not self._held:  # takes the handle again, where it is
            self._grab, self._held = (t, self.path.angle(pos)), True
        self._target[:] = self.path.point(s.target(t, self._grab))
        hand_force(pos, vel, self._target, s.stiffness, s.damping, s.max_force, out)


def _min_jerk(a: float, b: float, s: float) -> float:
    """From ``a`` to ``b`` along the minimum-jerk profile, ``s`` in [0, 1] (clipped)."""
    s = min(max(s, 0.0), 1.0)
    return a + (b - a) * s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


def _through_waypoints(points, t: float) -> float:
    if t <= points[0][0]:
        return points[0][1]
    for (t0, a), (t1, b) in zip(points[:-1], points[1:], strict=True):
        if t < t1:
            return _min_jerk(a, b, (t - t0) / (t1 - t0))
    return points[-1][1]


def _back_and_forth(t0: float, a: float, b: float, half_period: float, n: int) -> tuple:
    """Waypoints from ``a`` to ``b`` and back, ``n`` legs of ``half_period`` s each."""
    return tuple((t0 + i * half_period, a if i % 2 == 0 else b) for i in range(n + 1))


@dataclass(frozen=True)
class ForceScript:
    """A hand that pushes the handle along the door's tangent with a set force.

    ``segments`` are ``((force N, duration s), ...)``, force + toward closing,
    applied one after the other from t = 0 (zero after the last); the handle starts
    at rest at ``theta_start`` (rad). The force follows the tangent at the handle's
    current position; it does not depend on the motion (a pure force source).
    """

    name: str
    theta_start: float
    segments: tuple = ()

    def force(self, t: float) -> float:
        end = 0.0
        for value, duration in self.segments:
            end += duration
            if t < end:
                return float(value)
        return 0.0


#: the latched door rests at about closed minus the free play (0.5 deg)
_LATCHED = CLOSED - 0.5 * math.pi / 180.0

#: past the latch's bands, where the door is free (8 deg from closed)
_PAST_LATCH = CLOSED - 8.0 * math.pi / 180.0

#: the virtual users of ``--user`` (angles in rad, times in s)
SCRIPTS = {
    # from latched through the latch to 20 deg open, in 2 s
    "open": UserScript("open", _LATCHED, 0.35),
    # from 20 deg open to shut, pushing 1.1 deg past closed, in 2 s
    "close": UserScript("close", 0.35, CLOSED + 0.02),
    # through the latch only, slowly (1.5 s), then held past it
    "unlock": UserScript("unlock", _LATCHED, _PAST_LATCH, t_move=1.5),
    # from past the latch to shut, slowly (1.5 s), the hand aiming 3.4 deg beyond
    "lock": UserScript("lock", _PAST_LATCH, CLOSED + 0.06, t_move=1.5),
    # full swings between 20 and 69 deg, 1.5 s each way, three times
    "swing": UserScript("swing", 0.35, 0.35, waypoints=_back_and_forth(0.2, 0.35, 1.2, 1.5, 6)),
    # small fast shakes (+-1.7 deg at 3 Hz) about 46 deg, 3 s
    "shake": UserScript(
        "shake", 0.8, 0.8, waypoints=_back_and_forth(0.2, 0.77, 0.83, 1.0 / 6.0, 18)
    ),
    # held at 46 deg
    "hold": UserScript("hold", 0.8, 0.8),
    # from latched through the latch toward 46 deg, let go at 0.9 s while the door
    # still moves (it coasts to rest), taken again at 2 s and pushed shut through the
    # latch by 3.2 s, the hand aiming 1.7 deg beyond closed
    "open-shut": UserScript(
        "open-shut",
        _LATCHED,
        CLOSED + 0.03,
        waypoints=((0.2, _LATCHED), (1.2, 0.8), (2.0, 0.8), (3.2, CLOSED + 0.03)),
        let_go=((0.9, 2.0),),
    ),
}


def user_script(name: str) -> UserScript:
    """The virtual user script ``name``, one of :data:`SCRIPTS`."""
    try:
        return SCRIPTS[name]
    except KeyError:
        raise UserError(
            f"--user {name!r}: unknown script; choose one of {', '.join(SCRIPTS)}"
        ) from None


@njit(cache=True)
def hand_force(pos, vel, target, stiffness, damping, limit, out):
    """Spring-damper hand toward ``target`` (device frame, m), norm limited (N)."""
    n2 = 0.0
    for i in range(3):
        out[i] = stiffness * (target[i] - pos[i]) - damping * vel[i]
        n2 += out[i] * out[i]
    if n2 > limit * limit:
        scale = limit / math.sqrt(n2)
        for i in range(3):
            out[i] *= scale


@njit(cache=True)
def sim_step(
    pos, vel, f_user, f_cmd, mass, damping, coulomb, v_stick, dt, substeps, k_plane, c_plane
):
    """Advance the device's point mass by ``dt`` (s), semi-implicit Euler in substeps.

    Force = user + host command - damping v - Coulomb friction, plus on x alone the
    device's native plane constraint ``-k_plane x - c_plane v_x`` (N/m, N s/m; zero
    unless :meth:`SimDevice.render_natively` set them); the friction is a tanh of the
    speed with velocity scale ``v_stick`` (m/s), stable at the substep as long as
    coulomb < 2 mass v_stick / h (:class:`SimDevice` picks the substeps).
    """
    h = dt / substeps
    for _ in range(substeps):
        speed = math.sqrt(vel[0] * vel[0] + vel[1] * vel[1] + vel[2] * vel[2])
        for i in range(3):
            friction = 0.0
            if speed > 0.0 and coulomb > 0.0:
                friction = coulomb * math.tanh(speed / v_stick) * vel[i] / speed
            f = f_user[i] + f_cmd[i] - damping * vel[i] - friction
            if i == 0:
                f -= k_plane * pos[0] + c_plane * vel[0]
            vel[i] += h * (f / mass)
            pos[i] += h * vel[i]


class SimDevice(Device):
    """A simulated admittance device driven by a scripted virtual user.

    Parameters
    ----------
    script : UserScript, ForceScript or str
        The virtual user: a hand toward a moving target, or a set tangential force.
    radius : float
        Radius of the handle's circle (m), to place the hand's target.
    mass : float
        Moving mass (kg); the loop sets it to the haptic model's I / R.
    damping : float
        The device's own viscous damping (N s/m): what lets a sampled loop render
        stiff springs passively (Colgate-Schenkel).
    coulomb, v_stick : float
        The device's own dry friction (N) and its velocity scale (m/s).
    noise : float
        Standard deviation of the force sensor's noise (N), per axis.
    max_force : float
        Saturation of the host's command (N).
    seed : int
        Seed of the sensor noise.
    path : object or None
        The handle's path, on which a :class:`UserScript` reads its angles and the
        device starts (:class:`Hand`); None: the haptic model's circle of ``radius``.
    """

    simulated = True

    def __init__(
        self,
        script: UserScript | ForceScript | str = "hold",
        radius: float = 0.3,
        mass: float = 4.0,
        damping: float = 2.0,
        coulomb: float = 0.3,
        v_stick: float = 0.002,
        noise: float = 0.05,
        max_force: float = MAX_FORCE,
        seed: int = 0,
        substeps: int = 4,
        path=None,
    ):
        self.script = user_script(script) if isinstance(script, str) else script
        self.radius = float(radius)
        self.mass = float(mass)
        self.damping = float(damping)
        self.coulomb = float(coulomb)
        self.v_stick = float(v_stick)
        self.noise = float(noise)
        self.max_force = float(max_force)
        self.substeps = int(substeps)
        self._rng = np.random.default_rng(seed)
        self.t = 0.0
        self.path = Circle(self.radius) if path is None else path
        self.pos = np.array(self.path.point(self.script.theta_start), dtype=np.float64)
        self.vel = np.zeros(3)
        self._user = np.zeros(3)
        self._cmd = np.zeros(3)
        script = self.script
        self._hand = (
            Hand(script, self.radius, self.path) if isinstance(script, UserScript) else None
        )
        self.stopped = False
        #: the plane constraint rendered natively (N/m, N s/m); 0 until asked
        self.k_plane = 0.0
        self.c_plane = 0.0
        # load the kernel (numba's cache) now, not in a paced loop's first cycle
        z = np.zeros(3)
        sim_step(z, z.copy(), z, z, 1.0, 0.0, 0.0, 1.0, 0.0, 1, 0.0, 0.0)

    def set_mass(self, mass: float) -> None:
        """The moving mass (kg): the virtual mass I / R the device renders natively."""
        self.mass = float(mass)

    def render_natively(self, params) -> tuple[str, ...]:
        """Render the haptic set's plane constraint in the device's own step.

        As :meth:`HapticMasterDevice.render_natively
        <evo_door.render.hapticmaster.HapticMasterDevice.render_natively>` does on the
        real device: ``-k_plane x - c_plane v_x`` becomes part of :func:`sim_step`,
        integrated at the substep instead of held over a loop period, and the names
        ``("k_plane", "c_plane")`` are returned for the host to leave out of its own
        force. Call again with a changed set to change them. ``params`` is a haptic
        ParamSet or kernel vector.
        """
        p = param_vector(params, PARAMS)
        self.k_plane = float(p[K_PLANE])
        self.c_plane = float(p[C_PLANE])
        return ("k_plane", "c_plane")

    def start(self) -> None:
        self.stopped = False
        self._update_user()

    def _update_user(self) -> None:
        s = self.script
        if isinstance(s, ForceScript):
            ym = self.pos[1] + DEVICE_OFFSET_Y
            zm = self.pos[2] + DEVICE_OFFSET_Z
            r = math.hypot(ym, zm)
            f = s.force(self.t) / r if r > 0.0 else 0.0
            self._user[:] = (0.0, f * zm, -f * ym)  # along e_theta = (0, cos, -sin)
            return
        assert self._hand is not None  # set with the script that has no force of its own
        self._hand.force(self.t, self.pos, self.vel, self._user)

    def read(self):
        measured = self._user + self.noise * self._rng.standard_normal(3)
        return self.pos.copy(), self.vel.copy(), measured

    def command(self, force) -> None:
        f = np.asarray(force, dtype=np.float64)
        norm = float(np.sqrt(f @ f))
        if not math.isfinite(norm):
            f = np.zeros(3)
        elif norm > self.max_force:  # the device's own saturation
            f = f * (self.max_force / norm)
        self._cmd[:] = f

    def step(self, dt: float) -> None:
        # enough substeps for the explicit update of the device's own friction and
        # damping to stay stable (coulomb < 2 m v_s / h, damping h / m < 2) and of
        # the native plane spring (omega h < 2), with a factor 2 of margin (4 on the
        # spring), whatever the loop rate and the mass
        rate = max(
            self.coulomb / (2.0 * self.mass * self.v_stick),
            (self.damping + self.c_plane) / self.mass,
            math.sqrt(self.k_plane / self.mass),
        )
        substeps = max(self.substeps, math.ceil(2.0 * dt * rate))
        cmd = self._cmd if not self.stopped else np.zeros(3)
        sim_step(
            self.pos,
            self.vel,
            self._user,
            cmd,
            self.mass,
            self.damping,
            self.coulomb,
            self.v_stick,
            dt,
            substeps,
            self.k_plane,
            self.c_plane,
        )
        self.t += dt
        self._update_user()

    def stop(self) -> None:
        self._cmd[:] = 0.0
        self.stopped = True
