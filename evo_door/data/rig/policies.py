"""What a user's hand does in each kind of trial: the force, decided as the trial goes.

A policy plans the force of the next few samples from the door's state and watches what
happened (the latch giving way, the door coming to rest); :func:`.loop.run_closed_loop`
alternates the two with the simulation.
"""

from __future__ import annotations

import math

import numpy as np

from evo_door.data.rig.users import VirtualUser
from evo_door.data.sensors import CLOSED


class Policy:
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


class HandPolicy(Policy):
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


class ImpulsePolicy(Policy):
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
