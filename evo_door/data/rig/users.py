"""Who the virtual users are: their traits, how they differ, and their tremor.

Users differ in hand stiffness, pace, strength, reaction time, push size and tremor
(:func:`make_users`); each trial jitters its user's traits by ~10 %
(:meth:`VirtualUser.jittered`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from evo_door.data.sensors import DEG
from evo_door.errors import UserError


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


def make_tremor(user: VirtualUser, rng: np.random.Generator):
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
