"""Preprocessing against analytic results and scipy references."""

import math

import numpy as np
import pytest
from scipy import signal

from evo_door.data import Trial
from evo_door.data import preprocess as pp
from evo_door.errors import UserError

RATE = 1024.0


def test_lowpass_is_zero_phase_on_a_sine():
    t = np.arange(4096) / RATE
    x = np.sin(2 * np.pi * 3.0 * t)
    y = pp.lowpass(x, RATE, cutoff=20.0)
    mid = slice(512, -512)
    # no lag: a causal 4th-order Butterworth at 20 Hz would lag a 3 Hz sine by ~9 ms
    lags = np.arange(-20, 21)
    xc = [np.dot(y[mid], np.roll(x, k)[mid]) for k in lags]
    assert lags[int(np.argmax(xc))] == 0
    assert np.max(np.abs(y[mid] - x[mid])) < 2e-3
    causal = signal.sosfilt(signal.butter(4, 20.0, fs=RATE, output="sos"), x)
    assert np.max(np.abs(causal[mid] - x[mid])) > 0.1  # the reference lag is real


def test_lowpass_attenuation_matches_scipy_reference():
    t = np.arange(8192) / RATE
    sos = signal.butter(4, 30.0, fs=RATE, output="sos")
    for f in (45.0, 60.0, 120.0):
        x = np.sin(2 * np.pi * f * t)
        y = pp.lowpass(x, RATE, cutoff=30.0)
        np.testing.assert_allclose(y, signal.sosfiltfilt(sos, x))
        _, h = signal.sosfreqz(sos, worN=[f], fs=RATE)
        gain = abs(h[0]) ** 2  # forward + backward pass
        measured = np.std(y[1024:-1024]) * math.sqrt(2)
        assert measured == pytest.approx(gain, rel=0.02, abs=1e-6)
        assert measured < 0.25
    with pytest.raises(UserError, match="cutoff 600 Hz"):
        pp.lowpass(np.zeros(100), RATE, 600.0)


def test_integrated_angle_matches_analytic():
    t = np.arange(3 * 1024) / RATE
    w = 2 * np.pi * 0.7
    dtheta = 0.4 * w * np.cos(w * t)
    theta = pp.integrate_rate(t, dtheta, theta0=0.25)
    np.testing.assert_allclose(theta, 0.25 + 0.4 * np.sin(w * t), atol=1e-6)


def _gyro_trial(bias0=0.01, bias_slope=0.0, seed=0):
    """Rest 1 s, a smooth 1 rad swing in 1 s, rest 1.5 s; gyro with bias and noise."""
    t = np.arange(int(3.5 * RATE)) / RATE
    x = np.clip(t - 1.0, 0.0, 1.0)
    true_theta = 0.2 + (x - np.sin(2 * np.pi * x) / (2 * np.pi))  # 0.2 -> 1.2 rad
    true_rate = np.gradient(true_theta, t)
    rng = np.random.default_rng(seed)
    measured = true_rate + bias0 + bias_slope * t + 0.002 * rng.standard_normal(t.size)
    return t, true_theta, measured


def test_drift_removed_with_rest_segments():
    t, truth, gyro = _gyro_trial(bias0=0.01, bias_slope=0.004)
    raw = pp.angle_from_rate(t, gyro, theta0=0.2)
    assert abs(raw[-1] - truth[-1]) > 0.04  # the bias drifts 6 deg in 3.5 s
    rest = pp.rest_mask(t, None, gyro)
    assert rest[:900].all() and not rest[1100:2000].any() and rest[-1000:].all()
    fixed = pp.angle_from_rate(t, gyro, theta0=0.2, rest=rest)
    assert np.max(np.abs(fixed - truth)) < 3e-3
    # a known end angle instead of rest segments removes a constant bias too
    t, truth, gyro = _gyro_trial(bias0=0.02)
    ended = pp.angle_from_rate(t, gyro, theta0=0.2, theta_end=truth[-1])
    assert np.max(np.abs(ended - truth)) < 2e-3


def test_add_angle_from_rate_on_a_trial():
    t, truth, gyro = _gyro_trial(bias0=-0.015)
    tr = Trial(t, np.zeros_like(t), dtheta=gyro, theta0=0.2, trial_id="g")
    out = pp.add_angle_from_rate(tr)
    assert np.max(np.abs(out.theta - truth)) < 3e-3
    assert out.meta["preprocess"][-1]["angle_from_rate"]["rest_samples"] > 1000
    with pytest.raises(UserError, match="theta0"):
        pp.add_angle_from_rate(tr.replace(theta0=None))


def _latch_trace(peak=-55.0, t_peak=1.2, seed=1):
    t = np.arange(int(2.5 * RATE)) / RATE
    ramp = np.clip((t - 0.4) / (t_peak - 0.4), 0.0, 1.0) * peak
    drop = np.clip(1.0 - (t - t_peak) / 0.03, 0.0, 1.0)
    f = np.where(t <= t_peak, ramp, peak * drop)
    return t, f + 0.3 * np.random.default_rng(seed).standard_normal(t.size)


def test_force_peak_of_unlock_and_lock_traces():
    t, f = _latch_trace(peak=-55.0, t_peak=1.2)
    tr = Trial(t, f, kind="unlock")
    peak = pp.find_force_peak(tr)
    assert peak.force == pytest.approx(-55.0, abs=1.5)
    assert peak.t == pytest.approx(1.2, abs=0.015) and peak.magnitude > 50
    # a lock push is positive, found from the array and its rate alone
    t, f = _latch_trace(peak=38.0, t_peak=0.9, seed=2)
    f[1500:1600] -= 10.0  # a small dip later: not the peak
    peak = pp.find_force_peak(f, rate=RATE)
    assert peak.force == pytest.approx(38.0, abs=1.5) and peak.t == pytest.approx(0.9, abs=0.015)


def test_resample_keeps_signal_and_edges():
    t = np.arange(2048) / RATE
    tr = Trial(t, np.sin(2 * np.pi * 2 * t), theta=np.pi / 2 + 0.01 * np.sin(2 * np.pi * t))
    half = pp.resample(tr, 512.0)
    assert half.rate == pytest.approx(512.0) and half.n == 1024
    np.testing.assert_allclose(half.force, np.sin(2 * np.pi * 2 * half.t), atol=5e-3)
    np.testing.assert_allclose(half.theta, np.pi / 2 + 0.01 * np.sin(2 * np.pi * half.t), atol=5e-4)
    assert pp.resample(tr, RATE) is tr


def test_to_uniform_from_jittery_stamps():
    rng = np.random.default_rng(0)
    t = np.cumsum(np.full(500, 1e-3) + rng.uniform(-2e-4, 2e-4, 500))
    grid, cols = pp.to_uniform(t, {"force": 3 * t}, 1000.0)
    assert np.ptp(np.diff(grid)) < 1e-12
    np.testing.assert_allclose(cols["force"], 3 * grid, atol=1e-12)


def test_trim_to_motion_carries_the_initial_angle():
    t, truth, _ = _gyro_trial()
    rate = np.gradient(truth, t)
    force = np.where((t > 0.9) & (t < 1.5), 10.0, 0.0)
    tr = Trial(t, force, dtheta=rate, theta0=0.2, trial_id="m")
    cut = pp.trim_to_motion(tr, pad=0.1)
    assert cut.t[0] == pytest.approx(0.8, abs=0.03)  # the low-passed step starts a bit early
    assert cut.t[-1] < 2.2 and cut.t[-1] > 2.0
    assert cut.theta0 == pytest.approx(0.2, abs=1e-6)
    # start cut inside the motion: theta0 follows the integrated rate
    late = pp.trim_to_motion(tr.replace(t=t, force=np.where(t > 1.5, 5.0, 0.0)), pad=0.0)
    i0 = int(round((late.t[0] - t[0]) * RATE))
    assert late.theta0 == pytest.approx(truth[i0], abs=1e-4)
    with pytest.raises(UserError, match="nothing happens"):
        pp.trim_to_motion(Trial(t, np.zeros_like(t), dtheta=np.zeros_like(t)))


def test_lowpass_trial_is_recorded():
    t = np.arange(512) / RATE
    tr = Trial(t, np.random.default_rng(0).standard_normal(512), dtheta=np.zeros(512))
    out = pp.lowpass_trial(tr, 10.0)
    assert np.std(out.force) < 0.3 * np.std(tr.force)
    assert out.meta["preprocess"] == [
        {"lowpass": {"cutoff_hz": 10.0, "order": 4, "channels": ["force", "dtheta"]}}
    ]
    assert tr.meta == {}


def test_remove_rate_bias_measures_it_before_the_motion_only():
    """A door that creeps after the push (tanh friction) must not be read as bias."""
    t, _, gyro = _gyro_trial(bias0=0.0)
    true_rate = gyro.copy()
    creep = np.where(t > 2.2, -0.012, 0.0)  # 0.7 deg/s of creep at the end
    bias = 0.0025  # 0.14 deg/s, a typical gyro bias
    measured = true_rate + creep + bias
    sensors = {"dtheta": {"range": [-3.0, 3.0]}}
    tr = Trial(t, np.zeros_like(t), dtheta=measured, theta0=0.2, trial_id="g", sensors=sensors)
    start = pp.remove_rate_bias(tr)
    assert start.meta["preprocess"][-1]["remove_rate_bias"]["bias_rad_s"] == pytest.approx(
        bias, abs=2e-4
    )
    np.testing.assert_allclose(start.dtheta, true_rate + creep, atol=3e-4)
    assert start.sensor("dtheta")["range"] == pytest.approx([-3.0 - bias, 3.0 - bias], abs=2e-4)
    # every rest run: the creep at the end drags the estimate away from the true bias
    every = pp.remove_rate_bias(tr, "all")
    assert np.max(np.abs(every.dtheta - (true_rate + creep))) > 3 * 3e-4
    with pytest.raises(UserError, match="'start' or 'all'"):
        pp.remove_rate_bias(tr, "end")


def test_remove_rate_bias_keeps_saturated_samples_saturated():
    t, _, gyro = _gyro_trial(bias0=0.004)
    hi = 0.9 * gyro.max()
    clipped = np.minimum(gyro, hi)
    tr = Trial(
        t,
        np.zeros_like(t),
        dtheta=clipped,
        theta0=0.2,
        trial_id="g",
        sensors={"dtheta": {"range": [-hi, hi]}},
    )
    before = ~tr.unsaturated("dtheta")
    out = pp.remove_rate_bias(tr)
    assert before.sum() > 20
    np.testing.assert_array_equal(~out.unsaturated("dtheta"), before)


def test_remove_rate_bias_needs_rest_at_the_start():
    t, _, gyro = _gyro_trial()
    moving = Trial(t[1100:], np.zeros(t.size - 1100), dtheta=gyro[1100:], theta0=0.2, trial_id="m")
    with pytest.raises(UserError, match="no rest at the start"):
        pp.remove_rate_bias(moving)
    with pytest.raises(UserError, match="no dtheta"):
        pp.remove_rate_bias(Trial(t, np.zeros_like(t), theta=np.zeros_like(t), trial_id="a"))


def test_lowpass_keeps_saturated_samples_marked():
    t, truth, gyro = _gyro_trial(bias0=0.0)
    hi = 0.9 * gyro.max()
    tr = Trial(
        t,
        np.zeros_like(t),
        dtheta=np.minimum(gyro, hi),
        theta0=0.2,
        trial_id="g",
        sensors={"dtheta": {"range": [-hi, hi]}},
    )
    before = ~tr.unsaturated("dtheta")
    out = pp.lowpass_trial(tr, 20.0)
    assert before.sum() > 20
    np.testing.assert_array_equal(~out.unsaturated("dtheta"), before)
    rest = slice(0, 900)  # the noise is filtered there
    error = out.dtheta[rest] - np.gradient(truth, t)[rest]
    assert np.std(error) < 0.5 * 0.002


def test_reading_trials_leaves_scipys_signal_processing_unimported():
    """``data import`` of a CSV spent most of its time importing ``scipy.signal`` for
    filters it does not run: the module imports it where a filter needs it. A fresh
    interpreter imports the trial readers and the preprocessing and finds it absent."""
    import subprocess
    import sys

    code = (
        "import sys, evo_door.cli, evo_door.data.io, evo_door.data.preprocess\n"
        "print(sorted(m for m in sys.modules if m.startswith(('scipy.signal', 'scipy.integrate'))))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
