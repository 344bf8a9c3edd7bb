"""How a campaign of rig trials is laid out: which user makes which kind of trial, and
from which random numbers (same seed, same trials, value for value).
"""

from __future__ import annotations

import math

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
from evo_door.data.sensors import Sensor
from evo_door.data.trial import Trial
from evo_door.errors import UserError

#: Kinds cycled over the trials: impulses (the fitting targets) every other trial.
DEFAULT_KINDS = ("impulse", "unlock", "impulse", "lock")


def generate_trials(
    model,
    params,
    users: int = 3,
    trials: int = 10,
    seed=1,
    kinds=None,
    settings: RigSettings = DEFAULT_SETTINGS,
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
    check_kinds(model, kinds)
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
