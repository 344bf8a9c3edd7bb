"""How one rig trial is made: the door settled, the user's policy run in the loop, the
response measured by the sensors, the trial refused when the sensors saw nothing useful.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from evo_door import __version__
from evo_door.data.rig.loop import run_closed_loop, settle_model, settle_truth
from evo_door.data.rig.policies import HandPolicy, ImpulsePolicy, SlowPolicy
from evo_door.data.rig.truth import truth_record, with_dynamics
from evo_door.data.rig.users import VirtualUser, make_tremor
from evo_door.data.sensors import CLOSED, DEG, SEED_SENSORS, Sensor
from evo_door.data.trial import Trial
from evo_door.errors import UserError
from evo_door.models.base import RIG_KINDS

#: The kinds of trial the rig makes (:mod:`evo_door.data.rig`), declared with the models.
KINDS = RIG_KINDS
#: Channels each kind measures (seed 3.4: inclinometer near closed, gyroscope in motion).
KIND_CHANNELS = {
    "unlock": ("force", "theta"),
    "lock": ("force", "theta"),
    "impulse": ("force", "dtheta"),
    "slow": ("force", "theta", "dtheta"),
}
#: The channel of each kind a fit compares; it must stay inside its sensor's range.
KIND_RESPONSE = {"unlock": "theta", "lock": "theta", "impulse": "dtheta", "slow": "dtheta"}
#: Largest fraction of saturated response samples a trial may have (:mod:`evo_door.data.rig`).
MAX_SATURATED = 0.5


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
    # the settings below are recorded apart, in each trial's sensors and truth
    #: sensor models replacing the seed's (channel -> Sensor; evo_door.data.sensors)
    sensors: dict[str, Sensor] | None = None
    method: str | None = None  # integrator (default: the model's)
    substeps: int | None = None  # integrator sub-steps per sample (default: the model's)

    def record(self) -> dict:
        """What a trial records of the rig's settings (``meta["rig"]["settings"]``)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name not in _APART}


#: RigSettings recorded in another place of a trial than ``meta["rig"]["settings"]``.
_APART = ("sensors", "method", "substeps")


#: The rig's settings when none are given.
DEFAULT_SETTINGS = RigSettings()


def generate_trial(
    model,
    params,
    kind: str,
    user: VirtualUser,
    rng: np.random.Generator,
    trial_id: str = "T01",
    settings: RigSettings = DEFAULT_SETTINGS,
    truth=None,
) -> Trial:
    """One rig trial of ``kind`` by ``user`` (already jittered) on ``model`` with ``params``.

    Raises UserError when the model does not support ``kind`` (``Model.rig_kinds``) or
    when its response leaves the sensor's range (:mod:`evo_door.data.rig`, "What a model
    can do"). ``truth`` (a :class:`~evo_door.models.door.truth.DoorTruth`) is simulated
    in the model's place, and measured by sensors with its dynamics.
    """
    check_kinds(model, [kind])
    dt = 1.0 / settings.rate
    tremor = make_tremor(user, rng)
    theta0, dtheta0, state0 = _start(model, params, kind, user, dt, settings, truth)
    policy = _policy(model, kind, user, tremor, dt, theta0, settings)
    clean = run_closed_loop(
        model,
        params,
        policy,
        dt,
        theta0,
        dtheta0,
        getattr(policy, "t_max", settings.t_max),
        settings.chunk,
        method=settings.method,
        substeps=settings.substeps,
        truth=truth,
        state0=state0,
    )
    _warn_if_nothing_happened(model, kind, trial_id, user, policy, clean)
    sensors = dict(SEED_SENSORS, **(settings.sensors or {}))
    if truth is not None:
        sensors = with_dynamics(sensors, truth.sensor_dynamics())
    channels = ("force", "theta", "dtheta") if settings.all_sensors else KIND_CHANNELS[kind]
    # the sensing element's dynamics (none for the seed's sensors), then noise, bias,
    # quantisation and range
    measured = {ch: sensors[ch].measure(sensors[ch].respond(clean[ch], dt), rng) for ch in channels}
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
        truth=truth_record(model, params, settings.method, settings.substeps, truth),
        source=f"rig:{trial_id}",
        meta={"rig": _rig_record(settings, user, policy, clean)},
    )
    _refuse_if_saturated(model, trial, policy)
    return trial


def _start(model, params, kind, user, dt, settings, truth):
    """Where the trial starts: ``(theta0, dtheta0, the truth's state or None)``, the door
    settled with no force from where the kind begins (closed, a few degrees from closed,
    fully open)."""
    if kind in ("unlock", "slow"):
        theta = CLOSED
    elif kind == "lock":
        # a door that pulls itself shut over its last degrees comes to rest on the lock
        # ramp before the hand arrives: the push starts from where it rests
        theta = CLOSED - user.lock_start
    else:
        theta = 0.0
    if truth is None:
        theta0, dtheta0 = settle_model(
            model, params, theta, dt, method=settings.method, substeps=settings.substeps
        )
        return theta0, dtheta0, None
    state0 = settle_truth(truth, theta, dt)
    return float(state0[0]), float(state0[1]), state0


def _policy(model, kind, user, tremor, dt, theta0, settings):
    """What the user does in a trial of ``kind``: pull to unlock or push to lock with a
    compliant hand, give the open door a short push (impulse), or move the door through
    its stroke slowly and back (slow, whose time limit is its own: the stroke at the
    user's pace)."""
    if kind == "slow":
        lo, hi = (float(v) for v in getattr(model, "theta_range", (0.0, CLOSED)))
        return SlowPolicy(user, tremor, settings.handle_radius, theta0, (lo, hi), settings.tail)
    if kind not in ("unlock", "lock"):
        return ImpulsePolicy(user, tremor, settings.settle, settings.t_max)
    unlock = kind == "unlock"
    return HandPolicy(
        user,
        -1 if unlock else +1,
        settings.handle_radius,
        tremor,
        dt,
        theta0,
        settings.unlock_detect if unlock else settings.lock_detect,
        settings.tail,
        settings.t_max,
    )


def _rig_record(settings, user, policy, clean) -> dict:
    """What a trial records of the rig (``meta["rig"]``): the settings, the user, the
    policy's event times and the true peak force."""
    events = {"t_start": policy.t_start}
    if isinstance(policy, HandPolicy):
        events.update(t_event=policy.t_event, t_release=policy.t_release, gave_up=policy.gave_up)
    elif isinstance(policy, SlowPolicy):
        events.update(
            t_turn=policy.t_turn,
            t_stop=policy.t_stop,
            t_release=policy.t_release,
            speed_open=policy.speed_open,
            speed_close=policy.speed_close,
        )
    else:
        events.update(t_cut=policy.t_cut, t_push_end=policy.t_end)
    return {
        "evo_door": __version__,
        "settings": settings.record(),
        "user": asdict(user),
        "events": events,
        "peak_force_true": float(clean["force"][np.argmax(np.abs(clean["force"]))]),
    }


def check_kinds(model, kinds) -> None:
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
    if isinstance(policy, SlowPolicy) and policy.t_stop is None:
        leg = "open" if policy.t_turn is None else "close"
        warnings.warn(
            f"rig: trial {trial_id} (slow, {user.user_id}): the user could not {leg} the door "
            f"of model {model.name!r} through its stroke (user's strength "
            f"{user.max_force:.0f} N, {clean['t'][-1]:.1f} s); check the parameters",
            stacklevel=3,
        )
    if isinstance(policy, ImpulsePolicy) and np.max(np.abs(clean["dtheta"])) < 5 * DEG:
        warnings.warn(
            f"rig: trial {trial_id} (impulse, {user.user_id}): the door of model "
            f"{model.name!r} hardly moved (peak speed "
            f"{np.degrees(np.max(np.abs(clean['dtheta']))):.1f} deg/s)",
            stacklevel=3,
        )
