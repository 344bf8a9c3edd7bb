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

#: The pace of a slow trial: this fraction of the user's pull / push speed at the handle
#: (0.05-0.16 m/s at 0.6 m: about 0.07-0.21 rad/s)
SLOW_PACE = 0.8


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


class SlowPolicy(Policy):
    """Move the door through its stroke slowly, holding the handle: open it from closed
    (through the latch) to near fully open, stop, close it again up to the latch, let go.

    The hand is a PI controller on the door's angular speed toward a slow target speed
    (the user's pace, :data:`SLOW_PACE` of the pull / push speed at the handle): its
    proportional gain is the hand's damping and its integral gain the hand's stiffness,
    both at the handle (``c R`` in N s/rad, ``k R`` in N/rad), so the integral is the
    lead of the hand's target angle over the door. The force is bounded by the user's
    strength both ways (the hand grips the handle: it pulls and pushes), and so is the
    lead (no wind-up beyond what the user would pull). Closed on the true motion: the
    user feels the door, not the sensors.
    """

    RAMP = 0.5  # s, raised-cosine ramps of the target speed (start, stop, turn)
    PAUSE = 0.5  # s at rest where the stroke turns
    #: angle (rad) before fully open where the opening leg stops (5 deg)
    OPEN_MARGIN = 5.0 * math.pi / 180.0

    def __init__(
        self,
        user: VirtualUser,
        tremor,
        radius: float,
        theta_start: float,
        theta_range: tuple[float, float],
        tail: float,
    ):
        self.u, self.tremor, self.tail = user, tremor, tail
        self.speed_open = SLOW_PACE * user.pull_speed / radius
        self.speed_close = SLOW_PACE * user.push_speed / radius
        self.kp = user.hand_damping * radius
        self.ki = user.hand_stiffness * radius
        self.lead_max = user.max_force / self.ki
        self.theta_open = theta_range[0] + self.OPEN_MARGIN
        self.theta_close = theta_range[1] - user.lock_start
        self.t_start = user.rest_time
        self.t_turn = None  # the door reached theta_open: the target speed turns
        self.t_stop = None  # the door reached theta_close: the target speed stops
        self.t_release = None  # the user starts letting go
        self.theta_ref = theta_start
        stroke = abs(theta_start - self.theta_open) + abs(self.theta_close - self.theta_open)
        expected = (
            self.t_start
            + stroke / min(self.speed_open, self.speed_close)
            + 4 * self.RAMP
            + self.PAUSE
            + user.release_time
            + tail
        )
        #: s, the trial's time limit: twice what the stroke should take
        self.t_max = 2.0 * expected

    def speed_target(self, ts) -> np.ndarray:
        """The target speed (rad/s) at times ``ts``, from the events seen so far."""

        def rise(t0):
            return 1.0 - _cos_fade((ts - t0) / self.RAMP)

        v = -self.speed_open * rise(self.t_start)
        if self.t_turn is not None:
            v = v * _cos_fade((ts - self.t_turn) / self.RAMP)
            v = v + self.speed_close * rise(self.t_turn + self.RAMP + self.PAUSE)
        if self.t_stop is not None:
            v = v * _cos_fade((ts - self.t_stop) / self.RAMP)
        return np.where(ts >= self.t_start, v, 0.0)

    def plan(self, ts, tk, theta_k, dtheta_k):
        if ts[-1] < self.t_start:
            return np.zeros_like(ts)
        v_ref = self.speed_target(ts)
        dt = ts[1] - ts[0] if ts.size > 1 else ts[0] - tk
        ref = self.theta_ref + np.cumsum(v_ref) * dt
        # the hand's target leads the door by what the user's strength allows at most
        ref = np.clip(ref, theta_k - self.lead_max, theta_k + self.lead_max)
        self.theta_ref = float(ref[-1])
        theta = theta_k + dtheta_k * (ts - tk)  # predicted over the chunk
        f = self.ki * (ref - theta) + self.kp * (v_ref - dtheta_k) + self.tremor(ts)
        f = np.clip(f, -self.u.max_force, self.u.max_force)
        if self.t_release is not None:
            f = f * _cos_fade((ts - self.t_release) / self.u.release_time)
        return np.where(ts >= self.t_start, f, 0.0)

    def observe(self, ts, theta, dtheta):
        t = ts[-1]
        if self.t_turn is None and np.any(theta <= self.theta_open):
            self.t_turn = float(ts[np.argmax(theta <= self.theta_open)])
        closing = self.t_turn is not None and t > self.t_turn + self.RAMP + self.PAUSE
        if closing and self.t_stop is None and np.any(theta >= self.theta_close):
            self.t_stop = float(ts[np.argmax(theta >= self.theta_close)])
            self.t_release = self.t_stop + self.RAMP
        if self.t_release is not None and t > self.t_release + self.u.release_time + self.tail:
            self.finished = True
        if t >= self.t_max:
            self.finished = True
