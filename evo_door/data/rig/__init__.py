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
``slow``
    Door closed and latched. The user holds the handle and moves the door through its
    stroke at a slow speed (0.07-0.21 rad/s), a PI controller on the angular speed
    (:class:`~.policies.SlowPolicy`): opens it through the latch to 5 deg from fully
    open, stops, closes it again up to the latch (4-8 deg from closed) and lets go.
    Quasi-static: the force is the door's Coulomb force-angle curve, so friction,
    spring and weight stand apart from inertia. Load cell + inclinometer (the latch's
    snap, faster than the gyroscope's range) + gyroscope; fit it in windows
    (:func:`evo_door.data.preprocess.split_windows`).

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
kinds it supports (``Model.rig_kinds``; the doors all four, any model ``impulse``) and
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

The rig's modules, each answering one question: who the virtual users are
(:mod:`.users`), what a user's hand does in each kind of trial (:mod:`.policies`), how a
trial is simulated with the user in the loop (:mod:`.loop`), what the rig simulates and
what a trial records of it (:mod:`.truth`), how one trial is made and measured
(:mod:`.one_trial`), how a campaign of trials is laid out (:mod:`.campaign`), and how a
rig specification in an experiment file is checked (:mod:`.spec`). The names below are
the rig's library interface.
"""

from evo_door.data.rig.campaign import (
    DEFAULT_KINDS,
    Campaign,
    default_kinds,
    generate_trials,
    trial_user,
)
from evo_door.data.rig.loop import run_closed_loop
from evo_door.data.rig.one_trial import (
    KIND_CHANNELS,
    KIND_RESPONSE,
    KINDS,
    RigSettings,
    generate_trial,
)
from evo_door.data.rig.policies import HandPolicy, ImpulsePolicy, Policy, SlowPolicy
from evo_door.data.rig.spec import SPEC_DEFAULTS, SpecError, check_spec, trials_from_spec
from evo_door.data.rig.truth import TRUTHS, make_truth, params_source
from evo_door.data.rig.users import USER_RANGES, VirtualUser, make_users

__all__ = [
    "DEFAULT_KINDS",
    "Campaign",
    "HandPolicy",
    "ImpulsePolicy",
    "KINDS",
    "KIND_CHANNELS",
    "KIND_RESPONSE",
    "Policy",
    "RigSettings",
    "SPEC_DEFAULTS",
    "SlowPolicy",
    "SpecError",
    "TRUTHS",
    "USER_RANGES",
    "VirtualUser",
    "check_spec",
    "default_kinds",
    "generate_trial",
    "generate_trials",
    "make_truth",
    "make_users",
    "params_source",
    "run_closed_loop",
    "trial_user",
    "trials_from_spec",
]
