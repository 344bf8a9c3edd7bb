"""The virtual test rig: realistic trials from any model, with known true parameters.

It replays the seed's measurement campaign (section 3.4, figures 3.16-3.20) on a
model instead of a dishwasher:

``unlock``
    Door closed and latched. The user's hand pulls the handle toward opening, harder
    and harder, until the latch gives; the door then runs away from the hand (the
    force trace drops: its peak is the unlock force), and the user lets go after a
    reaction time. Measured: load cell + inclinometer (angle near closed).
``lock``
    Door a few degrees from closed. The user pushes it shut; resistance rises in the
    lock band until the latch snaps; the user lets go. Load cell + inclinometer.
``impulse``
    Door fully open, at rest. A short push toward closing (a half-sine, cut short
    once the door moves at the speed the user intends), then free decay. Load cell +
    gyroscope. These are the main fitting targets (speed decays ~linearly: friction).

**The hand** is a spring-damper between the handle and a target the user moves at
his own pace (pull / push speed) with a one-sided contact (a hand pulls or pushes,
it does not do both) and a maximum force; so the force builds up against a latched
door and falls when the door gives way, as in the seed's traces, whatever the model.
The loop is closed by simulating in chunks of a few samples (the model's integrator
continues from the end state of each chunk, so chunking changes nothing else).

**Users** differ in hand stiffness, pace, strength, reaction time, push size and
tremor (:func:`make_users`); each trial jitters its user's traits by ~10 %.

**What a model can do**: unlock and lock trials need a latch near closed that the
hand can feel, and the inclinometer only reads +-10 deg about closed; a model lists the
kinds it supports (``Model.rig_kinds``; the doors all three, any model ``impulse``) and
other kinds are refused. A trial whose measured response sits at a sensor's limit for
more than half of the time that matters (the whole impulse trial; an unlock or lock
trial up to the latch event) is refused too: the model moves outside the sensors'
range and the trial would tell a fit nothing.

**Determinism**: everything random comes from ``numpy.random.SeedSequence(seed)``,
spawned into one generator for the users and one per trial (so trial k is the same
whatever the number of trials); no global state.

**The truth**: by default the rig simulates the model it is given, so a fit of that
model can match the trials but for noise. ``truth="rich"`` (``--truth rich``) makes
the physical door's trials with a richer truth instead
(:mod:`evo_door.models.door.truth`: Stribeck friction, play and compliance at the
handle, load cell and gyroscope with low-pass dynamics); the trials then carry the
door's parameters as before (what a fit is scored against) and the truth's own under
``truth["effects"]``. The default path never touches that module.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from evo_door import __version__
from evo_door.data.sensors import CLOSED, DEG, SEED_SENSORS, FilteredSensor, Sensor
from evo_door.data.trial import Trial
from evo_door.errors import UserError
from evo_door.sim.simulate import simulate

KINDS = ("unlock", "lock", "impulse")
#: What the rig simulates: the model itself, or the door's richer truth.
TRUTHS = ("model", "rich")
#: Kinds cycled over the trials: impulses (the fitting targets) every other trial.
DEFAULT_KINDS = ("impulse", "unlock", "impulse", "lock")
#: Channels each kind measures (seed 3.4: inclinometer near closed, gyroscope in motion).
KIND_CHANNELS = {
    "unlock": ("force", "theta"),
    "lock": ("force", "theta"),
    "impulse": ("force", "dtheta"),
}
#: The channel of each kind a fit compares; it must stay inside its sensor's range.
KIND_RESPONSE = {"unlock": "theta", "lock": "theta", "impulse": "dtheta"}
#: Largest fraction of saturated response samples a trial may have (see module doc).
MAX_SATURATED = 0.5


@dataclass(frozen=True)
class VirtualUser:
    """How one virtual person opens and closes a door (SI units)."""

    user_id: str
    hand_stiffness: float  # N/m, hand + arm at the handle
    hand_damping: float  # N s/m
    pull_speed: float  # m/s, pace of the hand's target when pulling to unlock
    push_speed: float  # m/s, pace when pushing to lock
    max_force: float  # N, the most the user will pull or push
    reaction_time: float  # s, from feeling the latch give to letting go
    release_time: float  # s, to let go completely
    impulse_force: float  # N, peak of the push given to the open door
    impulse_duration: float  # s, length of that push
    impulse_speed: float  # rad/s, door speed the user means to give
    tremor: float  # N, amplitude of the 8-12 Hz physiological tremor
    rest_time: float  # s, still before acting
    lock_start: float  # rad, from closed, where the push to lock starts

    def jittered(self, rng: np.random.Generator, spread: float = 0.1) -> VirtualUser:
        """This user on one particular day: every trait times ``1 + spread * N(0, 1)``."""
        changes = {}
        for f in fields(self):
            if f.name != "user_id":
                changes[f.name] = getattr(self, f.name) * float(
                    np.clip(1.0 + spread * rng.standard_normal(), 0.7, 1.3)
                )
        return replace(self, **changes)


#: Ranges the users' traits are drawn from (uniform).
USER_RANGES = {
    "hand_stiffness": (500.0, 1200.0),
    "hand_damping": (10.0, 25.0),
    "pull_speed": (0.05, 0.15),
    "push_speed": (0.06, 0.16),
    "max_force": (150.0, 300.0),
    "reaction_time": (0.12, 0.25),
    "release_time": (0.08, 0.20),
    "impulse_force": (15.0, 35.0),
    "impulse_duration": (0.10, 0.20),
    "impulse_speed": (40.0 * DEG, 80.0 * DEG),
    "tremor": (0.2, 0.8),
    "rest_time": (0.3, 0.6),
    "lock_start": (4.0 * DEG, 8.0 * DEG),
}


def make_users(n: int, rng: np.random.Generator) -> list[VirtualUser]:
    """``n`` distinct users; user i's traits are stratified so the users really differ."""
    if n < 1:
        raise UserError("the rig needs at least one user")
    users = []
    # each trait: one value per stratum of its range, strata shuffled across users
    draws = {}
    for name, (lo, hi) in USER_RANGES.items():
        strata = (rng.permutation(n) + rng.uniform(0.0, 1.0, n)) / n
        draws[name] = lo + (hi - lo) * strata
    for i in range(n):
        users.append(VirtualUser(f"U{i + 1}", **{k: float(v[i]) for k, v in draws.items()}))
    return users


# -- closed-loop simulation -----------------------------------------------------------
class _Policy:
    """What the user does, decided chunk by chunk from what has happened so far."""

    finished = False

    def plan(self, ts, tk, theta_k, dtheta_k) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def observe(self, ts, theta, dtheta) -> None:
        pass


def _cos_fade(x):
    """1 -> 0 over x in [0, 1] (raised cosine), 1 before, 0 after."""
    x = np.clip(x, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(math.pi * x))


class HandPolicy(_Policy):
    """Pull to unlock (``direction = -1``) or push to lock (``+1``) with a compliant hand."""

    def __init__(
        self,
        user: VirtualUser,
        direction: int,
        radius: float,
        tremor,
        dt: float,
        theta_contact: float,
        detect: float,
        tail: float,
        t_max: float,
    ):
        self.u, self.dir, self.R, self.tremor, self.dt = user, direction, radius, tremor, dt
        self.t_start = user.rest_time
        self.speed = user.pull_speed if direction < 0 else user.push_speed
        self.s0 = None
        self.detect, self.tail, self.t_max = detect, tail, t_max
        self.theta_contact = theta_contact
        self.t_event = None  # latch gave way (unlock) / snapped (lock)
        self.t_release = None  # user starts letting go
        self.t_saturated = None
        self.gave_up = False

    def grip(self, ts):
        g = (ts >= self.t_start).astype(float)
        if self.t_release is not None:
            g *= _cos_fade((ts - self.t_release) / self.u.release_time)
        return g

    def plan(self, ts, tk, theta_k, dtheta_k):
        if self.s0 is None and ts[-1] >= self.t_start:
            self.s0 = self.R * theta_k
        if self.s0 is None:
            return np.zeros_like(ts)
        # the hand's target advances at the user's pace until the latch gives or snaps;
        # then the user stops moving it forward (and lets go after the reaction time)
        moving = ts if self.t_event is None else np.minimum(ts, self.t_event)
        target = self.s0 + self.dir * self.speed * np.maximum(moving - self.t_start, 0.0)
        handle = self.R * (theta_k + dtheta_k * (ts - tk))  # predicted over the chunk
        f = self.u.hand_stiffness * (target - handle) + self.u.hand_damping * (
            self.dir * self.speed - self.R * dtheta_k
        )
        f = f + self.tremor(ts)
        # one-sided contact, bounded by the user's strength
        f = np.clip(self.dir * f, 0.0, self.u.max_force) * self.dir
        if self.t_saturated is None and abs(f[-1]) >= self.u.max_force and self.t_event is None:
            self.t_saturated = ts[-1]
        return f * self.grip(ts)

    def observe(self, ts, theta, dtheta):
        t = ts[-1]
        if self.t_event is None:
            if self.dir < 0:
                hit = np.flatnonzero(theta < self.theta_contact - self.detect)
            else:
                hit = np.flatnonzero(theta > CLOSED - self.detect)
            if hit.size and ts[hit[0]] > self.t_start:
                self.t_event = float(ts[hit[0]])
                self.t_release = self.t_event + self.u.reaction_time
            elif self.t_saturated is not None and t > self.t_saturated + 0.5:
                self.gave_up = True  # cannot move it: let go
                self.t_event = float(t)
                self.t_release = float(t)
        if self.t_release is not None and t > self.t_release + self.u.release_time + self.tail:
            self.finished = True
        if t >= self.t_max:
            self.finished = True


class ImpulsePolicy(_Policy):
    """A short push toward closing from fully open, then hands off."""

    CUT = 0.015  # s, to let go once the intended speed is reached

    def __init__(self, user: VirtualUser, tremor, settle: float, t_max: float):
        self.u, self.tremor, self.t_max = user, tremor, t_max
        self.t_start = user.rest_time
        self.t_cut = None
        self.t_end = self.t_start + user.impulse_duration
        self.settle = settle
        self.t_still = None

    def plan(self, ts, tk, theta_k, dtheta_k):
        x = (ts - self.t_start) / self.u.impulse_duration
        f = np.where(
            (x > 0) & (x < 1), self.u.impulse_force * np.sin(math.pi * np.clip(x, 0, 1)), 0.0
        )
        f = f + self.tremor(ts) * ((x > 0) & (x < 1))
        if self.t_cut is not None:
            f = f * _cos_fade((ts - self.t_cut) / self.CUT)
        return np.maximum(f, 0.0)

    def observe(self, ts, theta, dtheta):
        t = ts[-1]
        if self.t_cut is None and t > self.t_start and np.any(dtheta >= self.u.impulse_speed):
            self.t_cut = float(ts[np.argmax(dtheta >= self.u.impulse_speed)])
            self.t_end = min(self.t_end, self.t_cut + self.CUT)
        if t > self.t_end:
            if np.all(np.abs(dtheta) < 0.005):
                self.t_still = self.t_still if self.t_still is not None else float(ts[0])
            else:
                self.t_still = None
            if self.t_still is not None and t > self.t_still + self.settle:
                self.finished = True
        if t >= self.t_max:
            self.finished = True


def run_closed_loop(
    model,
    params,
    policy: _Policy,
    dt: float,
    theta0: float,
    dtheta0: float,
    t_max: float,
    chunk: int = 4,
    method=None,
    substeps=None,
    truth=None,
    state0=None,
) -> dict:
    """Simulate ``model`` under a user ``policy`` deciding the force chunk by chunk.

    Each chunk of ``chunk`` samples is one :func:`~evo_door.sim.simulate` call starting
    from the previous chunk's end state with the force sample they share, which is
    exactly what one call over the whole force would compute (the integrators are
    one-step methods). Returns ``t, force, theta, dtheta, ddtheta`` (truth, no noise).

    With a ``truth`` (:class:`~evo_door.models.door.truth.DoorTruth`) that truth is
    simulated instead, from its ``state0`` (default: at rest with the door at
    ``theta0``); the hand then acts on the truth's handle.
    """
    if truth is not None:
        if state0 is None:
            state0 = truth.state(theta0, dtheta0)
        return _run_truth_loop(truth, policy, dt, state0, t_max, chunk)
    n_max = int(round(t_max / dt)) + 1
    t = dt * np.arange(n_max)
    force = np.zeros(n_max)
    theta = np.empty(n_max)
    dtheta = np.empty(n_max)
    ddtheta = np.empty(n_max)
    theta[0], dtheta[0] = theta0, dtheta0
    k = 0
    while k < n_max - 1 and not policy.finished:
        k1 = min(k + chunk, n_max - 1)
        force[k + 1 : k1 + 1] = policy.plan(t[k + 1 : k1 + 1], t[k], theta[k], dtheta[k])
        r = simulate(
            model,
            params,
            force[k : k1 + 1],
            dt,
            theta0=theta[k],
            dtheta0=dtheta[k],
            method=method,
            substeps=substeps,
        )
        if not r.ok:
            raise UserError(
                f"rig: the simulation of model {model.name!r} blew up at "
                f"t = {t[k]:.3f} s; check the parameters or the integration settings"
            )
        theta[k : k1 + 1], dtheta[k : k1 + 1], ddtheta[k : k1 + 1] = r.theta, r.dtheta, r.ddtheta
        policy.observe(t[k : k1 + 1], r.theta, r.dtheta)
        k = k1
    n = k + 1
    return {
        "t": t[:n],
        "force": force[:n],
        "theta": theta[:n],
        "dtheta": dtheta[:n],
        "ddtheta": ddtheta[:n],
    }


def _run_truth_loop(truth, policy: _Policy, dt, state0, t_max, chunk) -> dict:
    """:func:`run_closed_loop` on a truth with a handle state: the hand feels the handle,
    the policy watches the door (what the inclinometer and gyroscope see)."""
    n_max = int(round(t_max / dt)) + 1
    t = dt * np.arange(n_max)
    force = np.zeros(n_max)
    out = {name: np.empty(n_max) for name in ("theta", "dtheta", "ddtheta", "theta_h", "dtheta_h")}
    state = np.array(state0, dtype=np.float64)
    out["theta"][0], out["dtheta"][0] = state[0], state[1]
    out["theta_h"][0], out["dtheta_h"][0] = state[2], state[3]
    k = 0
    while k < n_max - 1 and not policy.finished:
        k1 = min(k + chunk, n_max - 1)
        force[k + 1 : k1 + 1] = policy.plan(
            t[k + 1 : k1 + 1], t[k], out["theta_h"][k], out["dtheta_h"][k]
        )
        r, state, ok = truth.simulate(force[k : k1 + 1], dt, state)
        if not ok:
            raise UserError(
                f"rig: the simulation of the {truth.name} truth blew up at t = {t[k]:.3f} s; "
                "check its parameters"
            )
        for name, values in r.items():
            out[name][k : k1 + 1] = values
        policy.observe(t[k : k1 + 1], r["theta"], r["dtheta"])
        k = k1
    n = k + 1
    return {"t": t[:n], "force": force[:n], **{name: v[:n] for name, v in out.items()}}


def _settle_truth(truth, theta0, dt, duration=0.5) -> np.ndarray:
    """The truth's state after resting with no force for ``duration`` s from ``theta0``."""
    n = int(round(duration / dt)) + 1
    _, end, ok = truth.simulate(np.zeros(n), dt, truth.state(theta0, 0.0))
    if not ok:
        raise UserError(
            f"rig: the {truth.name} truth blew up while resting at theta = {theta0:.4f} rad"
        )
    return end


def _settle(model, params, theta0, dt, duration=0.5, method=None, substeps=None):
    """State after resting with no force for ``duration`` s from ``theta0``."""
    n = int(round(duration / dt)) + 1
    r = simulate(
        model, params, np.zeros(n), dt, theta0=theta0, dtheta0=0.0, method=method, substeps=substeps
    )
    if not r.ok:
        raise UserError(
            f"rig: model {model.name!r} blew up while resting at theta = {theta0:.4f} rad"
        )
    return float(r.theta[-1]), float(r.dtheta[-1])


def _tremor(user: VirtualUser, rng: np.random.Generator):
    """Physiological tremor: two random tones at 8-12 Hz plus a slow 0.5-2 Hz sway."""
    f1, f2, f3 = rng.uniform(8.0, 12.0), rng.uniform(8.0, 12.0), rng.uniform(0.5, 2.0)
    p1, p2, p3 = rng.uniform(0.0, 2.0 * math.pi, 3)
    a = user.tremor

    def tremor(ts):
        return a * (
            0.6 * np.sin(2 * math.pi * f1 * ts + p1)
            + 0.4 * np.sin(2 * math.pi * f2 * ts + p2)
            + 0.8 * np.sin(2 * math.pi * f3 * ts + p3)
        )

    return tremor


# -- one trial ------------------------------------------------------------------------
@dataclass(frozen=True)
class RigSettings:
    """Rig-wide settings (SI)."""

    rate: float = 1024.0  # Hz
    handle_radius: float = 0.6  # m, where the hand acts (seed: L = 0.6 m)
    chunk: int = 4  # samples per closed-loop step
    unlock_detect: float = 2.0 * DEG  # rad of motion the user feels as "it opened"
    #: rad from closed felt as "it locked": past the latch apex of both bundled models
    #: (door: 0.46 deg, haptic: inside the 0.5 deg loose band, where the push holds it)
    lock_detect: float = 0.3 * DEG
    tail: float = 1.0  # s recorded after letting go (unlock / lock)
    settle: float = 0.4  # s of stillness that ends an impulse trial
    t_max: float = 8.0  # s, longest trial
    all_sensors: bool = False  # record every sensor in every trial


def generate_trial(
    model,
    params,
    kind: str,
    user: VirtualUser,
    rng: np.random.Generator,
    trial_id: str = "T01",
    settings: RigSettings = RigSettings(),
    sensors: dict[str, Sensor] | None = None,
    method=None,
    substeps=None,
    truth=None,
) -> Trial:
    """One rig trial of ``kind`` by ``user`` (already jittered) on ``model`` with ``params``.

    Raises UserError when the model does not support ``kind`` (``Model.rig_kinds``) or
    when its response leaves the sensor's range (see the module docstring). ``truth``
    (a :class:`~evo_door.models.door.truth.DoorTruth`) is simulated in the model's
    place, and measured by sensors with its dynamics.
    """
    _check_kinds(model, [kind])
    sensors = dict(SEED_SENSORS, **(sensors or {}))
    dt = 1.0 / settings.rate
    tremor = _tremor(user, rng)
    opts = {"method": method, "substeps": substeps}
    state0 = None

    def settle(theta):
        nonlocal state0
        if truth is None:
            return _settle(model, params, theta, dt, **opts)
        state0 = _settle_truth(truth, theta, dt)
        return float(state0[0]), float(state0[1])

    if truth is not None:
        sensors = with_dynamics(sensors, truth.sensor_dynamics())
    if kind == "unlock":
        theta0, dtheta0 = settle(CLOSED)
        policy = HandPolicy(
            user,
            -1,
            settings.handle_radius,
            tremor,
            dt,
            theta0,
            settings.unlock_detect,
            settings.tail,
            settings.t_max,
        )
    elif kind == "lock":
        # a door that pulls itself shut over its last degrees comes to rest on the lock
        # ramp before the hand arrives: the push starts from where it rests
        theta0, dtheta0 = settle(CLOSED - user.lock_start)
        policy = HandPolicy(
            user,
            +1,
            settings.handle_radius,
            tremor,
            dt,
            theta0,
            settings.lock_detect,
            settings.tail,
            settings.t_max,
        )
    else:
        theta0, dtheta0 = settle(0.0)
        policy = ImpulsePolicy(user, tremor, settings.settle, settings.t_max)
    clean = run_closed_loop(
        model,
        params,
        policy,
        dt,
        theta0,
        dtheta0,
        settings.t_max,
        settings.chunk,
        **opts,
        truth=truth,
        state0=state0,
    )

    _warn_if_nothing_happened(model, kind, trial_id, user, policy, clean)
    channels = ("force", "theta", "dtheta") if settings.all_sensors else KIND_CHANNELS[kind]
    # the sensing element's dynamics (none for the seed's sensors), then noise, bias,
    # quantisation and range
    measured = {ch: sensors[ch].measure(sensors[ch].respond(clean[ch], dt), rng) for ch in channels}
    events = {"t_start": policy.t_start}
    if isinstance(policy, HandPolicy):
        events.update(t_event=policy.t_event, t_release=policy.t_release, gave_up=policy.gave_up)
    else:
        events.update(t_cut=policy.t_cut, t_push_end=policy.t_end)
    trial = Trial(
        t=clean["t"],
        force=measured["force"],
        theta=measured.get("theta"),
        dtheta=measured.get("dtheta"),
        trial_id=trial_id,
        user_id=user.user_id,
        kind=kind,
        theta0=theta0,
        dtheta0=dtheta0,
        sensors={ch: sensors[ch].info() for ch in channels},
        truth=_truth(model, params, method, substeps, truth),
        source=f"rig:{trial_id}",
        meta={
            "rig": {
                "evo_door": __version__,
                "settings": asdict(settings),
                "user": asdict(user),
                "events": events,
                "peak_force_true": float(clean["force"][np.argmax(np.abs(clean["force"]))]),
            }
        },
    )
    _refuse_if_saturated(model, trial, policy)
    return trial


def _check_kinds(model, kinds) -> None:
    """Every kind known to the rig and supported by the model, or one line saying not."""
    supported = tuple(getattr(model, "rig_kinds", KINDS))
    for kind in kinds:
        if kind not in KINDS:
            raise UserError(f"unknown trial kind {kind!r}; kinds: {', '.join(KINDS)}")
        if kind not in supported:
            raise UserError(
                f"rig: model {model.name!r} cannot make {kind} trials; it supports "
                f"{', '.join(supported)} (Model.rig_kinds)"
            )


def _refuse_if_saturated(model, trial: Trial, policy) -> None:
    """A UserError when the kind's response is pinned at its sensor's limit too long.

    Unlock and lock trials are judged up to the latch event: after it the door swings
    wide open (unlock) and leaves the inclinometer's +-10 deg, which is expected.
    """
    channel = KIND_RESPONSE[trial.kind]
    saturated = ~trial.unsaturated(channel)
    t_event = getattr(policy, "t_event", None)
    if t_event is not None:
        saturated = saturated[trial.t <= t_event]
    share = float(saturated.mean()) if saturated.size else 0.0
    if share > MAX_SATURATED:
        info = trial.sensor(channel)
        lo, hi = info["range"]
        part = "of the samples before the latch event" if t_event is not None else "of the trial"
        raise UserError(
            f"rig: trial {trial.trial_id} ({trial.kind}, {trial.user_id}): the {info['sensor']} "
            f"({channel}) is saturated in {100 * share:.0f} % {part}: model {model.name!r} moves "
            f"outside the sensor's range [{lo:.4g}, {hi:.4g}]; nothing written"
        )


def _warn_if_nothing_happened(model, kind, trial_id, user, policy, clean) -> None:
    """A trial where the user could not do what the kind says is kept, but flagged."""
    import warnings

    if isinstance(policy, HandPolicy) and (policy.gave_up or policy.t_event is None):
        warnings.warn(
            f"rig: trial {trial_id} ({kind}, {user.user_id}): the door of model "
            f"{model.name!r} did not {kind} (user's strength {user.max_force:.0f} N, "
            f"{clean['t'][-1]:.1f} s); check the parameters",
            stacklevel=3,
        )
    if isinstance(policy, ImpulsePolicy) and np.max(np.abs(clean["dtheta"])) < 5 * DEG:
        warnings.warn(
            f"rig: trial {trial_id} (impulse, {user.user_id}): the door of model "
            f"{model.name!r} hardly moved (peak speed "
            f"{np.degrees(np.max(np.abs(clean['dtheta']))):.1f} deg/s)",
            stacklevel=3,
        )


def params_source(model, params) -> str:
    """Where a parameter set came from, and what was set on top, as trial files record it.

    A preset by its name (``"default"``), not by the path of its file on this machine:
    the same command then writes the same file anywhere; the declared defaults as
    ``"defaults"``; a file of the user's by the path given. Values set on top (``--set``,
    a specification's ``set``) follow: ``"defaults, changed: M=1.5"``.
    """
    source = getattr(params, "source", "") or ""
    label, base = _named_source(model, source)
    if base is None:
        return label
    changed = [
        f"{name}={params[name]:g}"
        for name, value in base.as_dict().items()
        if params[name] != value
    ]
    return label + (f", changed: {', '.join(changed)}" if changed else "")


def _named_source(model, source: str):
    """(the name a trial file records for ``source``, the set it names or None)."""
    from evo_door.params.sets import preset_path

    if source == "defaults":
        return source, model.load_params(None)
    path = Path(source)
    if path.suffix not in (".yaml", ".yml") or not path.is_file():
        return source, None
    try:
        preset = preset_path(model.name, path.stem, model.preset_dirs)
    except UserError:
        preset = None
    name = path.stem if preset is not None and preset.resolve() == path.resolve() else source
    try:
        return name, model.load_params(str(path))
    except UserError:  # the file changed under us: its name alone
        return name, None


def _truth(model, params, method, substeps, truth=None) -> dict:
    values = params.as_dict() if hasattr(params, "as_dict") else model.params.as_dict(params)
    out = {
        "model": model.name,
        "params": values,
        "units": {p.name: p.unit for p in model.params},
        "params_source": params_source(model, params),
        "method": method or model.method,
        "substeps": int(substeps or model.substeps),
    }
    if truth is not None:
        out.update(
            method=truth.method, substeps=truth.substeps, variant=truth.name, effects=truth.record()
        )
    return out


def with_dynamics(sensors: dict[str, Sensor], dynamics: dict) -> dict[str, Sensor]:
    """``sensors`` with the channels of ``dynamics`` (channel -> (bandwidth Hz, order))
    made :class:`~evo_door.data.sensors.FilteredSensor` (same range, noise, resolution)."""
    out = dict(sensors)
    for ch, (bandwidth, order) in dynamics.items():
        base = {f.name: getattr(sensors[ch], f.name) for f in fields(Sensor)}
        out[ch] = FilteredSensor(**base, bandwidth=bandwidth, order=order)
    return out


def make_truth(model, params, truth=None, truth_params=None, method=None, substeps=None):
    """The truth the rig simulates: None for the model itself, else a ``DoorTruth``.

    ``truth`` is None, ``"model"``, ``"rich"`` or a ready truth object;
    ``truth_params`` (a mapping name -> value, a YAML path or a ParamSet) sets the rich
    truth's parameters on top of its declared defaults.
    """
    if truth is None or (isinstance(truth, str) and truth == "model"):
        if truth_params:
            raise UserError("truth parameters need the rich truth (--truth rich)")
        return None
    if not isinstance(truth, str):
        return truth
    if truth not in TRUTHS:
        from evo_door.params.declaration import suggest

        raise UserError(
            f"unknown truth {truth!r}" + suggest(truth, TRUTHS) + f"; truths: {', '.join(TRUTHS)}"
        )
    from evo_door.models.door.truth import DoorTruth, load_truth_params
    from evo_door.params import ParamSet

    if isinstance(truth_params, ParamSet):
        values = truth_params
    elif isinstance(truth_params, (str, Path)):
        values = load_truth_params(truth_params)
    else:
        values = load_truth_params(None, dict(truth_params or {}))
        changed = sorted(truth_params or {})
        values = replace(
            values, source="defaults" + (f", changed: {', '.join(changed)}" if changed else "")
        )
    return DoorTruth(model, params, values, method, substeps)


# -- a campaign -----------------------------------------------------------------------
def generate_trials(
    model,
    params,
    users: int = 3,
    trials: int = 10,
    seed=1,
    kinds=None,
    settings: RigSettings = RigSettings(),
    sensors: dict[str, Sensor] | None = None,
    method=None,
    substeps=None,
    progress: bool | None = None,
    truth=None,
    truth_params=None,
) -> list[Trial]:
    """A measurement campaign: ``trials`` trials by ``users`` virtual users.

    Trial k (ids ``T01``...) is of kind ``kinds[k % len(kinds)]`` and is done by the user
    :func:`trial_user` gives (ids ``U1``...): the users take turns, and every user makes
    every kind of the cycle once in ``users * len(kinds)`` trials. Same ``seed``, same
    trials, value for value.

    Parameters
    ----------
    model : Model
    params : ParamSet
        The true parameters, stored with every trial (``trial.truth``).
    seed : int or numpy.random.SeedSequence
    kinds : sequence of "unlock", "lock", "impulse", optional
        Kinds cycled over the trials; default :data:`DEFAULT_KINDS` without the kinds
        the model does not support (``Model.rig_kinds``). An unsupported kind asked for
        is refused.
    settings : RigSettings
    sensors : dict, optional
        Sensor models replacing the seed's (:data:`~evo_door.data.sensors.SEED_SENSORS`).
    progress : bool or None
        tqdm bar (None: only on a terminal).
    truth : None, "model" or "rich"
        What is simulated (:func:`make_truth`): the model itself (default), or the
        physical door's richer truth (:mod:`evo_door.models.door.truth`).
    truth_params : mapping, YAML path or ParamSet, optional
        The rich truth's parameters on top of its declared defaults.
    """
    from tqdm.auto import tqdm

    if trials < 1:
        raise UserError("the rig needs at least one trial")
    if not isinstance(seed, np.random.SeedSequence) and not (
        isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0
    ):
        raise UserError(f"the rig's seed must be a whole number >= 0, got {seed!r}")
    kinds = default_kinds(model) if kinds is None else tuple(kinds)
    if not kinds:
        raise UserError("the rig needs at least one trial kind")
    _check_kinds(model, kinds)
    truth = make_truth(model, params, truth, truth_params, method, substeps)
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
    user_seq, trial_root = root.spawn(2)
    people = make_users(users, np.random.default_rng(user_seq))
    out = []
    bar = tqdm(
        range(trials), desc="rig", unit="trial", disable=None if progress is None else not progress
    )
    for k, child in zip(bar, trial_root.spawn(trials)):
        rng = np.random.default_rng(child)
        user = people[trial_user(k, users, len(kinds))].jittered(rng)
        trial = generate_trial(
            model,
            params,
            kinds[k % len(kinds)],
            user,
            rng,
            f"T{k + 1:02d}",
            settings,
            sensors,
            method,
            substeps,
            truth,
        )
        trial.meta["rig"].update(
            seed=int(root.entropy) if isinstance(root.entropy, int) else None, trial_index=k
        )
        out.append(trial)
    return out


def trial_user(k: int, users: int, cycle: int) -> int:
    """The user (0-based) of trial ``k`` when ``cycle`` kinds are cycled over the trials.

    Users take turns: trial k is user ``k % users``'s, as long as that spreads every
    kind over every user, i.e. when ``users`` and ``cycle`` have no common factor (the
    bundled data: 3 users, 4 kinds). Otherwise taking turns runs in lockstep with the
    kinds (4 users, 4 kinds: user i would make kind i only; 2 users: user 1 only
    impulses): each new cycle of kinds then starts ``shift`` users further on, the
    smallest shift that breaks the lockstep. Either way every user makes every position
    of the cycle exactly once in ``users * cycle`` trials.

    >>> [trial_user(k, 3, 4) for k in range(8)]  # as ever: k % 3
    [0, 1, 2, 0, 1, 2, 0, 1]
    >>> [trial_user(k, 4, 4) for k in range(8)]  # the second cycle starts with user 1
    [0, 1, 2, 3, 1, 2, 3, 0]
    """
    # trial k = q * cycle + p is user (p + q * (cycle + shift)) % users: for each
    # position p of the cycle, q = 0 .. users - 1 visits every user once when
    # cycle + shift and users have no common factor
    shift = next(c for c in range(users + 1) if math.gcd(cycle + c, users) == 1)
    return (k + shift * (k // cycle)) % users


def default_kinds(model) -> tuple[str, ...]:
    """:data:`DEFAULT_KINDS` restricted to what ``model`` supports (its ``rig_kinds``)."""
    supported = tuple(getattr(model, "rig_kinds", KINDS))
    return tuple(k for k in DEFAULT_KINDS if k in supported) or supported


#: Keys of a rig specification (an experiment's ``inputs:`` mapping) and their defaults
#: (``kinds: None``: the model's, :func:`default_kinds`).
SPEC_DEFAULTS = {
    "model": "door",
    "params": None,
    "set": {},
    "users": 3,
    "trials": 10,
    "seed": 1,
    "kinds": None,
    "rate": 1024.0,
    "all_sensors": False,
}


class SpecError(UserError):
    """A bad entry of a rig specification: ``key`` names it (None: the whole mapping),
    ``reason`` says what is wrong. An experiment file puts its own file and line in front
    (:mod:`evo_door.experiment.config`); on its own it reads ``rig specification: KEY: ...``.
    """

    def __init__(self, key: str | None, reason: str):
        super().__init__("rig specification: " + (f"{key}: " if key else "") + reason)
        self.key = key
        self.reason = reason


def _shown(value) -> str:
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return repr(value)


def _whole(spec: dict, key: str, lowest: int) -> int:
    """``spec[key]`` as a whole number >= ``lowest`` (3.0 is 3; 2.5, "3" and true are not),
    the same rule as ``rig generate``'s flags."""
    v = spec[key]
    if isinstance(v, float) and v.is_integer():
        v = int(v)
    if isinstance(v, bool) or not isinstance(v, int):
        raise SpecError(key, f"expected a whole number, got {_shown(v)}")
    if v < lowest:
        raise SpecError(key, f"must be at least {lowest}, got {v}")
    return v


def _spec_kinds(model, value) -> list[str] | None:
    """``kinds`` as a list (a comma-separated text is split), each known and supported."""
    from evo_door.params.declaration import suggest

    if value is None:
        return None
    if isinstance(value, str):
        value = value.split(",")
    if not isinstance(value, list) or not all(isinstance(k, str) for k in value):
        raise SpecError(
            "kinds", f"expected a list of trial kinds (e.g. [impulse]), got {_shown(value)}"
        )
    kinds = [k.strip() for k in value if k.strip()]
    if not kinds:
        raise SpecError("kinds", f"no trial kind given; kinds: {', '.join(KINDS)}")
    supported = tuple(getattr(model, "rig_kinds", KINDS))
    for kind in kinds:
        if kind not in KINDS:
            raise SpecError(
                "kinds",
                f"unknown trial kind {kind!r}"
                + suggest(kind, KINDS)
                + f"; kinds: {', '.join(KINDS)}",
            )
        if kind not in supported:
            raise SpecError(
                "kinds",
                f"model {model.name!r} cannot make {kind} trials; it supports {', '.join(supported)}",
            )
    return kinds


def check_spec(spec) -> dict:
    """A rig specification checked entry by entry, completed with :data:`SPEC_DEFAULTS`.

    The rules of ``evo-door rig generate``'s flags: ``users`` and ``trials`` whole numbers
    >= 1, ``seed`` a whole number >= 0, ``rate`` a number > 0 (Hz), ``kinds`` known to the
    rig and made by the model, ``model`` a model, ``params`` a preset, a parameter file or
    a mapping of numbers, ``set`` a mapping of the model's parameters to numbers,
    ``all_sensors`` true or false; an unknown key is refused with a suggestion. The first
    bad entry raises :class:`SpecError` naming its key.

    >>> check_spec({"model": "door", "trials": 2})["users"]
    3
    >>> check_spec({"model": "door", "users": "abc"})
    Traceback (most recent call last):
    ...
    evo_door.data.rig.SpecError: rig specification: users: expected a whole number, got 'abc'
    """
    from evo_door.models import get_model
    from evo_door.params.declaration import suggest

    if not isinstance(spec, dict):
        raise SpecError(
            None, f"expected a mapping of keys ({', '.join(SPEC_DEFAULTS)}), got {_shown(spec)}"
        )
    for key in spec:
        if key not in SPEC_DEFAULTS:
            raise SpecError(
                str(key),
                "unknown key"
                + suggest(str(key), SPEC_DEFAULTS)
                + f"; keys: {', '.join(SPEC_DEFAULTS)}",
            )
    s = {**SPEC_DEFAULTS, **spec}
    if not isinstance(s["model"], str) or not s["model"].strip():
        raise SpecError("model", f"expected a model's name, got {_shown(s['model'])}")
    try:
        model = get_model(s["model"])
    except UserError as exc:
        raise SpecError("model", str(exc)) from None
    params = s["params"]
    if isinstance(params, dict) and "from" in params:
        raise SpecError(
            "params", "{from: STAGE} is for params and target.params, not the rig's inputs"
        )
    if params is not None and not isinstance(params, (str, dict)):
        raise SpecError(
            "params", f"expected a preset name, a parameter file or a mapping, got {_shown(params)}"
        )
    if s["set"] is None:
        s["set"] = {}
    if not isinstance(s["set"], dict):
        raise SpecError(
            "set", f"expected a mapping of parameter names to numbers, got {_shown(s['set'])}"
        )
    try:
        base = model.load_params(params)
    except UserError as exc:
        raise SpecError("params", str(exc)) from None
    for name, value in s["set"].items():
        if name not in model.params:
            raise SpecError(
                "set",
                f"model {model.name!r} has no parameter {name!r}"
                + suggest(str(name), model.params.names),
            )
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SpecError(f"set.{name}", f"expected a number, got {_shown(value)}")
    try:
        base.replace({str(k): float(v) for k, v in s["set"].items()})
    except UserError as exc:
        raise SpecError("set", str(exc)) from None
    rate = s["rate"]
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not math.isfinite(rate):
        raise SpecError("rate", f"expected a number of samples per second (Hz), got {_shown(rate)}")
    if rate <= 0:
        raise SpecError("rate", f"must be positive (Hz), got {rate:g}")
    if not isinstance(s["all_sensors"], bool):
        raise SpecError("all_sensors", f"expected true or false, got {_shown(s['all_sensors'])}")
    s.update(
        users=_whole(s, "users", 1),
        trials=_whole(s, "trials", 1),
        seed=_whole(s, "seed", 0),
        kinds=_spec_kinds(model, s["kinds"]),
        rate=float(rate),
    )
    return s


def trials_from_spec(spec: dict) -> list[Trial]:
    """Rig trials from a mapping, e.g. an experiment's ``inputs:``::

        inputs: {model: door, params: default, users: 3, trials: 10, seed: 1}

    Keys and defaults: :data:`SPEC_DEFAULTS` (``set`` overrides parameters by name;
    ``kinds`` a list or a comma-separated string), checked by :func:`check_spec`.
    """
    from evo_door.models import get_model

    s = check_spec(spec)
    model = get_model(s["model"])
    params = model.load_params(s["params"], {str(k): float(v) for k, v in s["set"].items()})
    return generate_trials(
        model,
        params,
        users=s["users"],
        trials=s["trials"],
        seed=s["seed"],
        kinds=s["kinds"],
        settings=RigSettings(rate=s["rate"], all_sensors=s["all_sensors"]),
    )
