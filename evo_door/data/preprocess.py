"""Preprocessing of trials: filtering, resampling, angle from rate, trimming, force peaks.

All functions are pure: they return new arrays or a new :class:`Trial` and note what
they did in ``trial.meta["preprocess"]``. The filters are scipy's (Butterworth
second-order sections run forward and backward, so without phase lag); nothing here
is hand-rolled signal processing. Each function imports the part of scipy it runs:
``scipy.signal`` alone was most of a ``data import``, which filters nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from evo_door.data.trial import Trial
from evo_door.errors import UserError

#: Defaults for "the door is at rest / the user is not pushing" (rest_mask, trim).
FORCE_TOL = 2.0  # N
SPEED_TOL = 0.03  # rad/s (1.7 deg/s: above a gyroscope's bias, below any motion)
RATE_BIAS_GUARD = 0.05  # s left out of each end of a rest run when measuring the bias


def _noted(trial: Trial, step: dict, **changes) -> Trial:
    meta = dict(trial.meta)
    meta["preprocess"] = [*meta.get("preprocess", []), step]
    return trial.replace(meta=meta, **changes)


# -- filtering ------------------------------------------------------------------------
def lowpass(x, rate: float, cutoff: float, order: int = 4, axis: int = -1) -> np.ndarray:
    """Zero-phase Butterworth low-pass: ``sosfiltfilt(butter(order, cutoff, fs=rate))``.

    The effective order is doubled (forward and backward pass) and the gain at
    ``cutoff`` is 1/2 (-6 dB) instead of 1/sqrt(2).
    """
    from scipy import signal

    if not (0.0 < cutoff < 0.5 * rate):
        raise UserError(
            f"low-pass cutoff {cutoff:g} Hz must lie in (0, {0.5 * rate:g}) Hz "
            f"(half the sampling rate {rate:g} Hz)"
        )
    sos = signal.butter(order, cutoff, btype="low", fs=rate, output="sos")
    x = np.asarray(x, dtype=np.float64)
    try:
        return signal.sosfiltfilt(sos, x, axis=axis)
    except ValueError:
        # too short for the default padding: pad as much as the signal allows
        return signal.sosfiltfilt(sos, x, axis=axis, padlen=x.shape[axis] - 1)


def lowpass_trial(trial: Trial, cutoff: float, channels=None, order: int = 4) -> Trial:
    """``trial`` with the given channels (default: all) low-pass filtered at ``cutoff`` Hz.

    Samples a sensor reported as saturated keep their value (the end of the range),
    so objectives still skip them (:meth:`Trial.unsaturated`).
    """
    channels = tuple(channels or ("force", *trial.channels))
    changes = {}
    for name in channels:
        values = getattr(trial, name)
        if values is None:
            raise UserError(f"{trial.label}: no channel {name!r} to filter")
        filtered = lowpass(values, trial.rate, cutoff, order)
        rng = trial.sensor(name).get("range")
        if rng:  # saturated samples stay pinned to the range ends, so they stay marked
            saturated = ~trial.unsaturated(name)
            filtered = np.where(saturated, values, filtered)
        changes[name] = filtered
    return _noted(
        trial,
        {"lowpass": {"cutoff_hz": cutoff, "order": order, "channels": list(channels)}},
        **changes,
    )


# -- resampling -----------------------------------------------------------------------
def resample(trial: Trial, rate: float) -> Trial:
    """``trial`` at another uniform sampling rate (Hz), by polyphase filtering.

    ``scipy.signal.resample_poly`` applies its own anti-aliasing FIR; the ends are
    padded along a line fitted to the signal, so an angle sitting at pi/2 does not
    ring toward zero at the edges.
    """
    from scipy import signal

    if rate <= 0:
        raise UserError(f"resampling rate must be positive, got {rate:g} Hz")
    ratio = Fraction(rate / trial.rate).limit_denominator(10000)
    if ratio == 0 or abs(float(ratio) * trial.rate - rate) > 1e-6 * rate:
        raise UserError(f"cannot resample {trial.rate:g} Hz to {rate:g} Hz exactly")
    if ratio == 1:
        return trial
    up, down = ratio.numerator, ratio.denominator
    changes = {}
    for name in ("force", *trial.channels):
        changes[name] = signal.resample_poly(getattr(trial, name), up, down, padtype="line")
    n = changes["force"].size
    changes["t"] = trial.t[0] + np.arange(n) / rate
    return _noted(trial, {"resample": {"from_hz": trial.rate, "to_hz": rate}}, **changes)


def to_uniform(t, columns: dict, rate: float) -> tuple[np.ndarray, dict]:
    """Columns sampled at irregular instants ``t``, interpolated onto a uniform grid.

    For loggers with jittery time stamps; low-pass first when the new rate is lower.
    Returns ``(t_uniform, {name: values})``.
    """
    t = np.asarray(t, dtype=np.float64)
    if np.any(np.diff(t) <= 0):
        raise UserError("to_uniform: time stamps must increase")
    grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * rate + 1e-9)) + 1) / rate
    return grid, {
        k: np.interp(grid, t, np.asarray(v, dtype=np.float64)) for k, v in columns.items()
    }


# -- angle from rate (eq. 3.11) -------------------------------------------------------
def integrate_rate(t, dtheta, theta0: float = 0.0) -> np.ndarray:
    """``theta(t) = theta0 + integral of dtheta`` (eq. 3.11), cumulative trapezoid."""
    from scipy import integrate

    return theta0 + integrate.cumulative_trapezoid(dtheta, t, initial=0.0)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of the runs of True in ``mask``."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def rest_mask(
    t,
    force,
    dtheta,
    force_tol: float = FORCE_TOL,
    speed_tol: float = SPEED_TOL,
    min_duration: float = 0.2,
    cutoff: float = 10.0,
) -> np.ndarray:
    """Samples where nobody pushes and the door does not move, in runs of ``min_duration`` s.

    Both signals are low-passed at ``cutoff`` Hz first so that sensor noise does not
    break the runs; ``speed_tol`` must exceed the gyroscope's bias.
    """
    t = np.asarray(t, dtype=np.float64)
    rate = 1.0 / (t[1] - t[0])
    cutoff = min(cutoff, 0.45 * rate)
    quiet = np.abs(lowpass(dtheta, rate, cutoff)) < speed_tol
    if force is not None:
        quiet &= np.abs(lowpass(force, rate, cutoff)) < force_tol
    out = np.zeros_like(quiet)
    need = int(round(min_duration * rate))
    for a, b in _runs(quiet):
        if b - a >= need:
            out[a:b] = True
    return out


def rate_bias(t, dtheta, rest) -> np.ndarray:
    """The gyroscope's bias at every instant, estimated on the rest samples.

    With rest both early and late in the record the bias may drift: a line fitted to
    the rest samples; with rest in one place only, their mean; without rest, zero.
    """
    t = np.asarray(t, dtype=np.float64)
    rest = np.asarray(rest, dtype=bool)
    if not rest.any():
        return np.zeros_like(t)
    runs = _runs(rest)
    span = t[runs[-1][1] - 1] - t[runs[0][0]]
    if len(runs) > 1 and span > 0.5 * (t[-1] - t[0]):
        slope, intercept = np.polyfit(t[rest], np.asarray(dtheta)[rest], 1)
        return intercept + slope * t
    return np.full_like(t, float(np.mean(np.asarray(dtheta)[rest])))


def remove_rate_bias(trial: Trial, where: str = "start") -> Trial:
    """``trial`` with the gyroscope's bias (:func:`rate_bias`) subtracted from ``dtheta``.

    Parameters
    ----------
    where : {"start", "all"}
        Which rest samples (:func:`rest_mask`) carry the bias. ``"start"`` (default):
        only the rest before the first motion. After a push a door may still creep
        (the tanh friction law of eq. 3.1 lets a spring-loaded door slide at a few
        hundredths of a degree per second), and the rest detector cannot tell that
        creep from bias. ``"all"``: every rest run, with a linear drift when there is
        rest both early and late.

    The sensor's range is shifted with the signal, so samples that were saturated
    stay recognisably saturated (:meth:`Trial.unsaturated`).
    """
    if trial.dtheta is None:
        raise UserError(f"{trial.label}: no dtheta channel to remove a gyroscope bias from")
    if where not in ("start", "all"):
        raise UserError(f"rate bias: where must be 'start' or 'all', not {where!r}")
    # rest runs without their last and first GUARD seconds, where the door starts or
    # stops moving below the detector's speed tolerance
    guard = int(round(RATE_BIAS_GUARD * trial.rate))
    runs = [
        (a + guard * (a > 0), b - guard * (b < trial.n))
        for a, b in _runs(rest_mask(trial.t, trial.force, trial.dtheta))
    ]
    if where == "start":
        runs = runs[:1] if runs and runs[0][0] == 0 else []
    rest = np.zeros(trial.n, dtype=bool)
    for a, b in runs:
        rest[a : max(a, b)] = True
    if not rest.any():
        raise UserError(
            f"{trial.label}: no rest {'at the start ' if where == 'start' else ''}"
            f"of the trial to measure the gyroscope's bias on (0.2 s or more with "
            f"|force| < {FORCE_TOL:g} N and |dtheta| < {SPEED_TOL:g} rad/s once "
            "low-passed at 10 Hz; record about half a second of rest before the push)"
        )
    bias = rate_bias(trial.t, trial.dtheta, rest)
    mean_bias = float(np.mean(bias))
    dtheta = trial.dtheta - bias
    info = dict(trial.sensor("dtheta"))
    if info.get("range"):
        # shift the range with the mean bias and keep saturated samples pinned to its ends
        saturated = ~trial.unsaturated("dtheta")
        lo, hi = (float(v) - mean_bias for v in info["range"])
        info["range"] = [lo, hi]
        dtheta = np.where(saturated, np.where(trial.dtheta > 0, hi, lo), dtheta)
    info["bias_removed"] = mean_bias
    sensors = {**trial.sensors, "dtheta": info}
    drift = float((bias[-1] - bias[0]) / (trial.t[-1] - trial.t[0]))
    return _noted(
        trial,
        {
            "remove_rate_bias": {
                "where": where,
                "bias_rad_s": mean_bias,
                "drift_rad_s2": drift,
                "rest_samples": int(rest.sum()),
            }
        },
        dtheta=dtheta,
        sensors=sensors,
    )


def angle_from_rate(
    t, dtheta, theta0: float = 0.0, rest=None, theta_end: float | None = None
) -> np.ndarray:
    """Door angle from the measured rate (eq. 3.11) with the drift handled.

    Parameters
    ----------
    t, dtheta : array
        Time (s) and angular speed (rad/s).
    theta0 : float
        Angle at ``t[0]`` (rad): known from the set-up (0 fully open, pi/2 closed).
    rest : bool array, optional
        Samples where the door is known to be still; the gyroscope's bias estimated
        there (:func:`rate_bias`) is removed before integrating.
    theta_end : float, optional
        Angle known at the end (rad), e.g. back against the end stop: the remaining
        drift is removed as a linear ramp so that the integral ends there.
    """
    t = np.asarray(t, dtype=np.float64)
    rate = np.asarray(dtheta, dtype=np.float64)
    if rest is not None:
        rate = rate - rate_bias(t, rate, rest)
    theta = integrate_rate(t, rate, theta0)
    if theta_end is not None:
        theta = theta - (theta[-1] - theta_end) * (t - t[0]) / (t[-1] - t[0])
    return theta


def add_angle_from_rate(trial: Trial, theta_end: float | None = None, rest="auto") -> Trial:
    """``trial`` with a ``theta`` channel integrated from its ``dtheta`` (see :func:`angle_from_rate`).

    ``rest="auto"`` finds the rest segments with :func:`rest_mask`; ``None`` skips
    the bias removal. Needs ``trial.theta0`` (the known initial angle).
    """
    if trial.dtheta is None:
        raise UserError(f"{trial.label}: no dtheta channel to integrate")
    if trial.theta0 is None:
        raise UserError(
            f"{trial.label}: the initial angle theta0 is unknown; give it "
            "(0 fully open, pi/2 closed)"
        )
    if isinstance(rest, str) and rest == "auto":
        rest = rest_mask(trial.t, trial.force, trial.dtheta)
    theta = angle_from_rate(trial.t, trial.dtheta, trial.theta0, rest, theta_end)
    sensors = dict(trial.sensors)
    sensors["theta"] = {
        "sensor": "integrated angular speed (eq. 3.11)",
        "bias_removed": rest is not None and bool(np.any(rest)),
        "theta_end": theta_end,
    }
    return _noted(
        trial,
        {
            "angle_from_rate": {
                "theta_end": theta_end,
                "rest_samples": int(np.sum(rest)) if rest is not None else 0,
            }
        },
        theta=theta,
        sensors=sensors,
    )


# -- trimming -------------------------------------------------------------------------
def active_mask(
    trial: Trial, force_tol: float = FORCE_TOL, speed_tol: float = SPEED_TOL, cutoff: float = 10.0
) -> np.ndarray:
    """Samples where the user pushes or the door moves (low-passed signals)."""
    rate = trial.rate
    cutoff = min(cutoff, 0.45 * rate)
    active = np.abs(lowpass(trial.force, rate, cutoff)) > force_tol
    if trial.dtheta is not None:
        active |= np.abs(lowpass(trial.dtheta, rate, cutoff)) > speed_tol
    elif trial.theta is not None:
        active |= np.abs(np.gradient(lowpass(trial.theta, rate, cutoff), trial.t)) > speed_tol
    return active


def trim_to_motion(trial: Trial, pad: float = 0.2, **tols) -> Trial:
    """``trial`` cut to its active part (:func:`active_mask`) plus ``pad`` seconds each side.

    The initial state follows: ``theta0`` is carried over the removed start with the
    rate (or the angle) measured there.
    """
    active = active_mask(trial, **tols)
    if not active.any():
        raise UserError(
            f"{trial.label}: nothing happens in this trial (no force above "
            f"{tols.get('force_tol', FORCE_TOL):g} N, no motion); nothing to trim to"
        )
    npad = int(round(pad * trial.rate))
    i0 = max(int(np.flatnonzero(active)[0]) - npad, 0)
    i1 = min(int(np.flatnonzero(active)[-1]) + npad + 1, trial.n)
    if i1 - i0 < 2:
        i1 = min(i0 + 2, trial.n)
    theta0, dtheta0 = trial.theta0, trial.dtheta0
    if theta0 is not None and i0 > 0:
        if trial.dtheta is not None:
            theta0 = float(integrate_rate(trial.t[: i0 + 1], trial.dtheta[: i0 + 1], theta0)[-1])
        elif trial.theta is not None:
            theta0 = float(theta0 + trial.theta[i0] - trial.theta[0])
    if i0 > 0:
        dtheta0 = float(trial.dtheta[i0]) if trial.dtheta is not None else None
    changes = {name: getattr(trial, name)[i0:i1] for name in ("t", "force", *trial.channels)}
    return _noted(
        trial,
        {"trim": {"start_s": float(trial.t[i0]), "stop_s": float(trial.t[i1 - 1])}},
        theta0=theta0,
        dtheta0=dtheta0,
        **changes,
    )


def split_windows(trial: Trial, length: float) -> list[Trial]:
    """``trial`` cut into consecutive windows of ``length`` seconds (the last one takes
    the remainder when it is shorter than half a window), each a trial that starts from
    the state measured there.

    A slow trial (:mod:`evo_door.data.rig`) is a quasi-static stroke: the user's force
    stays within a newton of the door's Coulomb curve, so a model driven open loop by
    that force over the whole stroke drifts away from the measured motion (a force
    noise of 0.15 N moves it by 0.05 rad/s within a few seconds, and an angle off
    changes the force it needs). Short windows, each from the measured state, keep the
    drift small and the fit's objective smooth. The window's ``theta0`` is the angle
    (``theta`` if measured and inside its sensor's range, else ``theta0`` carried by the
    rate, as :func:`trim_to_motion` does), its ``dtheta0`` the measured rate. Window
    ``k`` of trial ``T01`` is ``T01w01``... (from 1).
    """
    if not (np.isfinite(length) and length > 0):
        raise UserError(f"windows: give a length in seconds > 0, got {length!r}")
    n = max(int(round(length * trial.rate)), 2)
    starts = list(range(0, trial.n, n))
    if len(starts) > 1 and trial.n - starts[-1] < n // 2:
        starts.pop()  # a short remainder joins the window before it
    ends = starts[1:] + [trial.n]
    theta0, dtheta0 = trial.initial_state()
    angle = _angle_anchored(trial, theta0)
    out = []
    for k, (i0, i1) in enumerate(zip(starts, ends), start=1):
        th0 = float(angle[i0]) if angle is not None else theta0
        w0 = float(trial.dtheta[i0]) if trial.dtheta is not None else (dtheta0 if i0 == 0 else 0.0)
        changes = {name: getattr(trial, name)[i0:i1] for name in ("t", "force", *trial.channels)}
        window = _noted(
            trial,
            {
                "window": {
                    "index": k,
                    "start_s": float(trial.t[i0]),
                    "stop_s": float(trial.t[i1 - 1]),
                }
            },
            trial_id=f"{trial.trial_id}w{k:02d}",
            theta0=th0 if i0 else theta0,
            dtheta0=w0 if i0 else dtheta0,
            **changes,
        )
        out.append(window)
    return out


def _angle_anchored(trial: Trial, theta0: float) -> np.ndarray | None:
    """The angle at every sample: ``theta`` where its sensor reads it (inside the range),
    elsewhere the last such reading (or ``theta0``) carried by the integrated rate; None
    without a rate. The inclinometer's last reading near closed anchors what follows a
    latch's snap, faster than a gyroscope's range."""
    if trial.dtheta is None:
        return None
    integral = integrate_rate(trial.t, trial.dtheta, 0.0)
    if trial.theta is None:
        return theta0 + integral
    inside = trial.unsaturated("theta")
    last = np.maximum.accumulate(np.where(inside, np.arange(trial.n), -1))
    anchor = np.where(last >= 0, trial.theta[np.maximum(last, 0)], theta0)
    base = np.where(last >= 0, integral[np.maximum(last, 0)], 0.0)
    return anchor + integral - base


# -- unlock / lock force --------------------------------------------------------------
@dataclass(frozen=True)
class ForcePeak:
    """The peak of a force trace: the unlock (``force < 0``) or lock (``> 0``) force."""

    index: int
    t: float  # s
    force: float  # N, signed (+ toward closing)

    @property
    def magnitude(self) -> float:
        return abs(self.force)


def find_force_peak(
    trial_or_force,
    rate: float | None = None,
    direction: int | None = None,
    cutoff: float = 30.0,
    prominence: float = 0.3,
) -> ForcePeak:
    """The unlock / lock force: the peak of the (low-passed) force trace (seed sec. 3.4).

    Parameters
    ----------
    trial_or_force : Trial or array
        A trial, or a force array (N) with ``rate`` (Hz).
    direction : +1, -1 or None
        +1 for pushes toward closing (lock), -1 for pulls toward opening (unlock);
        default from ``trial.kind`` or else the sign of the largest force.
    cutoff : float
        Low-pass cutoff (Hz) that removes sensor noise before the search.
    prominence : float
        A candidate peak must stand out by this fraction of the largest force;
        the highest candidate wins.
    """
    from scipy import signal

    if isinstance(trial_or_force, Trial):
        trial = trial_or_force
        force, rate, t0 = trial.force, trial.rate, float(trial.t[0])
        if direction is None:
            direction = {"unlock": -1, "lock": +1}.get(trial.kind)
        where = trial.label
    else:
        if rate is None:
            raise UserError("find_force_peak: give the sampling rate of the force array")
        force, t0, where = np.asarray(trial_or_force, dtype=np.float64), 0.0, "force"
    smooth = lowpass(force, rate, min(cutoff, 0.45 * rate))
    if direction is None:
        direction = 1 if smooth[np.argmax(np.abs(smooth))] >= 0 else -1
    f = direction * smooth
    top = float(np.max(f))
    if top <= 0:
        raise UserError(
            f"{where}: no force peak toward {'closing' if direction > 0 else 'opening'}"
        )
    peaks, _ = signal.find_peaks(f, prominence=prominence * top)
    if peaks.size == 0:  # monotonic trace: the peak is at an end
        idx = int(np.argmax(f))
    else:
        idx = int(peaks[np.argmax(f[peaks])])
    return ForcePeak(idx, t0 + idx / rate, float(smooth[idx]))


__all__ = [
    "lowpass",
    "lowpass_trial",
    "resample",
    "to_uniform",
    "integrate_rate",
    "rest_mask",
    "rate_bias",
    "angle_from_rate",
    "add_angle_from_rate",
    "active_mask",
    "trim_to_motion",
    "ForcePeak",
    "find_force_peak",
]
