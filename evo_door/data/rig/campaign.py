"""How a campaign of rig trials is laid out: which user makes which kind of trial, and
from which random numbers (same seed, same trials, value for value).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from evo_door.data.rig.one_trial import (
    DEFAULT_SETTINGS,
    KINDS,
    RigSettings,
    check_kinds,
    generate_trial,
)
from evo_door.data.rig.truth import make_truth
from evo_door.data.rig.users import make_users
from evo_door.data.trial import Trial
from evo_door.errors import UserError

#: Kinds cycled over the trials: impulses (the fitting targets) every other trial.
DEFAULT_KINDS = ("impulse", "unlock", "impulse", "lock")


@dataclass(frozen=True)
class Campaign:
    """What is asked of the rig: ``trials`` trials by ``users`` virtual users, from ``seed``
    (an int >= 0 or a ``numpy.random.SeedSequence``; same campaign, same trials, value for
    value).

    ``kinds`` (a sequence of "unlock", "lock", "impulse") are cycled over the trials;
    None: :data:`DEFAULT_KINDS` without the kinds the model does not support
    (``Model.rig_kinds``). An unsupported kind asked for is refused.
    """

    users: int = 3
    trials: int = 10
    seed: int | np.random.SeedSequence = 1
    kinds: Sequence[str] | None = None


#: The campaign when none is given: the bundled data's (3 users, 10 trials, seed 1).
DEFAULT_CAMPAIGN = Campaign()


def generate_trials(
    model,
    params,
    campaign: Campaign = DEFAULT_CAMPAIGN,
    settings: RigSettings = DEFAULT_SETTINGS,
    truth=None,
    progress: bool | None = None,
) -> list[Trial]:
    """A measurement campaign: ``campaign.trials`` trials by ``campaign.users`` users.

    Trial k (ids ``T01``...) is of kind ``kinds[k % len(kinds)]`` and is done by the user
    :func:`trial_user` gives (ids ``U1``...): the users take turns, and every user makes
    every kind of the cycle once in ``users * len(kinds)`` trials.

    Parameters
    ----------
    model : Model
    params : ParamSet
        The true parameters, stored with every trial (``trial.truth``).
    campaign : Campaign
        Users, trials, seed and kinds.
    settings : RigSettings
        The rig: its sampling, hand, sensors and integrator.
    truth : None, "model", "rich" or a truth
        What is simulated (:func:`~evo_door.data.rig.truth.make_truth`, which also sets
        the rich truth's parameters): the model itself (default), or the physical door's
        richer truth (:mod:`evo_door.models.door.truth`).
    progress : bool or None
        tqdm bar (None: only on a terminal).
    """
    from tqdm.auto import tqdm

    kinds = _checked_kinds(model, campaign)
    truth = make_truth(model, params, truth, None, settings.method, settings.substeps)
    seed = campaign.seed
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
    user_seq, trial_root = root.spawn(2)
    people = make_users(campaign.users, np.random.default_rng(user_seq))
    out = []
    n = campaign.trials
    bar = tqdm(
        range(n), desc="rig", unit="trial", disable=None if progress is None else not progress
    )
    for k, child in zip(bar, trial_root.spawn(n)):
        rng = np.random.default_rng(child)
        user = people[trial_user(k, campaign.users, len(kinds))].jittered(rng)
        kind, trial_id = kinds[k % len(kinds)], f"T{k + 1:02d}"
        trial = generate_trial(model, params, kind, user, rng, trial_id, settings, truth)
        trial.meta["rig"].update(
            seed=int(root.entropy) if isinstance(root.entropy, int) else None, trial_index=k
        )
        out.append(trial)
    return out


def _checked_kinds(model, campaign: Campaign) -> tuple[str, ...]:
    """The campaign's kinds (the model's default ones if it names none), after checking
    the number of trials, the seed and each kind; one line for the first wrong."""
    seed = campaign.seed
    if campaign.trials < 1:
        raise UserError("the rig needs at least one trial")
    if not isinstance(seed, np.random.SeedSequence) and not (
        isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0
    ):
        raise UserError(f"the rig's seed must be a whole number >= 0, got {seed!r}")
    kinds = default_kinds(model) if campaign.kinds is None else tuple(campaign.kinds)
    if not kinds:
        raise UserError("the rig needs at least one trial kind")
    check_kinds(model, kinds)
    return kinds


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
