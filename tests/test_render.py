"""The renderer: simulated device, servo loop, safety rules, log, `evo-door render`."""

from __future__ import annotations

import ast
import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from numba import njit

import evo_door.render
from evo_door.cli import main
from evo_door.data.io import read_trials
from evo_door.errors import UserError
from evo_door.files import open_h5, read_attrs
from evo_door.models.haptic import PARAMS, device_force, on_path
from evo_door.params import param_vector
from evo_door.render.columns import COMMAND
from evo_door.render.device import SimDevice, UserScript
from evo_door.render.kernels import compute_command
from evo_door.render.log import N_COLUMNS, RenderLog
from evo_door.render.loop import ServoLoop
from evo_door.render.safety import (
    IMPLICIT,
    NON_FINITE,
    OK,
    SATURATED,
    Watchdog,
    limit_force,
    passivity,
)
from tests.helpers import LOADED_MACHINE_WATCHDOG, assert_kept_time, random_kernel_vectors

LIMIT = 200.0


# -- simulated device ------------------------------------------------------------------
_NO_HAND = UserScript("none", 0.8, 0.8, stiffness=0.0, damping=0.0)


def test_sim_device_viscous_decay_matches_the_analytic_solution():
    """No hand, no command: v(t) = v0 exp(-b t / m), travel v0 m / b (1 - exp(-b t / m))."""
    dev = SimDevice(_NO_HAND, mass=4.0, damping=40.0, coulomb=0.0, noise=0.0)
    x0 = dev.pos.copy()
    dev.vel[:] = [0.2, 0.0, 0.0]
    for _ in range(2500):  # 1 s at 2500 Hz
        dev.step(0.0004)
    decay = math.exp(-10.0)
    assert dev.vel[0] == pytest.approx(0.2 * decay, rel=2e-2)
    assert dev.pos[0] - x0[0] == pytest.approx(0.2 * 0.1 * (1 - decay), rel=1e-3)


def test_sim_device_coulomb_friction_stops_the_mass_in_time():
    """Dry friction F alone: a mass m at v0 stops after m v0 / F, over m v0^2 / 2F."""
    dev = SimDevice(_NO_HAND, mass=2.0, damping=0.0, coulomb=4.0, v_stick=1e-4, noise=0.0)
    x0 = dev.pos.copy()
    dev.vel[:] = [0.0, 0.0, 0.5]
    for _ in range(1000):  # 0.4 s
        dev.step(0.0004)
    assert abs(dev.vel[2]) < 1e-3  # stopped (t_stop = 0.25 s) and stays
    assert dev.pos[2] - x0[2] == pytest.approx(2.0 * 0.25 / 8.0, rel=1e-2)


def test_sim_device_saturates_and_measures_the_hand():
    dev = SimDevice("open", noise=0.0)
    dev.command(np.array([0.0, 300.0, 400.0]))
    dev.start()
    _, _, f = dev.read()
    np.testing.assert_array_equal(f, 0.0)  # the hand sits on its target at t = 0
    assert np.linalg.norm(dev._cmd) == pytest.approx(200.0)


# -- force limit ---------------------------------------------------------------------
@njit
def _largest_commands(params, states, limit):
    """Largest commanded norm and largest raw model norm over every (set, state) pair."""
    out = np.zeros(3)
    row = np.zeros(N_COLUMNS)
    raw = np.zeros(3)
    worst = 0.0
    worst_raw = 0.0
    for i in range(params.shape[0]):
        p = params[i]
        for j in range(states.shape[0]):
            s = states[j]
            compute_command(s[0:3], s[3:6], s[6:9], p, limit, out, row)
            worst = max(worst, math.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2))
            device_force(s[0], s[1], s[2], s[3], s[4], s[5], p, raw)
            n = math.sqrt(raw[0] ** 2 + raw[1] ** 2 + raw[2] ** 2)
            if math.isfinite(n):
                worst_raw = max(worst_raw, n)
    return worst, worst_raw


def test_commanded_force_never_exceeds_the_device_limit():
    """10^6 draws (1000 parameter sets within their bounds x 1000 states): none over."""
    rng = np.random.default_rng(14)
    params = random_kernel_vectors(1000, rng)
    states = np.concatenate(
        [
            rng.uniform(-0.6, 0.6, (1000, 3)),  # position (m)
            rng.uniform(-5.0, 5.0, (1000, 3)),  # velocity (m/s)
            rng.normal(0.0, 30.0, (1000, 3)),  # measured user force (N)
        ],
        axis=1,
    )
    worst, worst_raw = _largest_commands(params, states, LIMIT)
    assert worst_raw > 10 * LIMIT  # the model alone would command far more
    assert worst <= LIMIT


def test_limit_keeps_the_direction():
    f = np.array([300.0, -400.0, 0.0])
    assert limit_force(f, LIMIT) == SATURATED
    np.testing.assert_allclose(f, [120.0, -160.0, 0.0], rtol=1e-11)
    g = np.array([1.0, 2.0, 3.0])
    assert limit_force(g, LIMIT) == OK
    np.testing.assert_array_equal(g, [1.0, 2.0, 3.0])


# -- non-finite values ---------------------------------------------------------------
@pytest.mark.parametrize(
    "where",
    ["position", "velocity", "user", "params"],
)
def test_non_finite_input_gives_zero_force(seed_trial, where):
    p = param_vector(seed_trial, PARAMS)
    pos = np.array(on_path(0.8, 0.3)) + np.array([0.0, 0.01, 0.0])  # off the path: a force
    vel = np.array([0.0, 0.1, 0.0])
    user = np.array([0.0, 5.0, 0.0])
    out = np.zeros(3)
    row = np.zeros(N_COLUMNS)
    assert compute_command(pos, vel, user, p, LIMIT, out, row) == OK
    assert np.linalg.norm(out) > 1.0
    {"position": pos, "velocity": vel, "user": user, "params": p}[where][1] = math.nan
    assert compute_command(pos, vel, user, p, LIMIT, out, row) == NON_FINITE
    np.testing.assert_array_equal(out, 0.0)


def test_limit_force_zeroes_inf():
    f = np.array([math.inf, 0.0, 1.0])
    assert limit_force(f, LIMIT) == NON_FINITE
    np.testing.assert_array_equal(f, 0.0)


class _Recorder:
    """A SimDevice wrapper that records the commands and can misbehave."""

    def __init__(self, inner, bad_reads=(), drop_after=None, slow_after=None, slow=0.0):
        self.inner = inner
        self.max_force = inner.max_force
        self.damping = inner.damping
        self.simulated = slow_after is None
        self.commands = []
        self.times = []
        self.reads = 0
        self.bad_reads = set(bad_reads)
        self.drop_after = drop_after
        self.slow_after = slow_after
        self.slow = slow
        self.stopped = 0

    def set_mass(self, m):
        self.inner.set_mass(m)

    def start(self):
        self.inner.start()

    def read(self):
        self.reads += 1
        if self.drop_after is not None and self.reads > self.drop_after:
            raise ConnectionError("connection reset by peer")
        if self.slow_after is not None and self.reads > self.slow_after:
            time.sleep(self.slow)
        pos, vel, f = self.inner.read()
        if self.reads in self.bad_reads:
            pos[1] = math.nan
        return pos, vel, f

    def command(self, force):
        self.commands.append(np.array(force, dtype=float))
        self.times.append(time.perf_counter())
        self.inner.command(force)

    def step(self, dt):
        self.inner.step(dt)

    def stop(self):
        self.stopped += 1
        self.inner.stop()


def test_loop_zeroes_and_logs_a_non_finite_state(seed_trial):
    dev = _Recorder(SimDevice("open", seed=1), bad_reads={100, 101})
    loop = ServoLoop(dev, seed_trial)
    loop.run(0.2)
    norms = np.linalg.norm(np.array(dev.commands), axis=1)
    assert norms[99] == 0.0 and norms[100] == 0.0
    assert norms[98] > 0.0 and norms[102] > 0.0
    faults = [e for e in loop.log.events if e["kind"] == "fault"]
    assert len(faults) == 2 and loop.statistics["faults"] == 2


# -- passivity -----------------------------------------------------------------------
def test_passivity_numbers(seed_trial):
    """b > K T / 2 + |B|: the stop spring 2e4 N/rad on 0.3 m, snap damping 5 N s/rad."""
    c = passivity(seed_trial, 40.0, 1 / 2500)
    k = 2.0e4 / 0.3
    b_neg = 5.0 / 0.3
    assert c["K_name"] == "stop_stiffness"
    assert c["K"] == pytest.approx(k, rel=1e-12)
    assert c["margin"] == pytest.approx(40.0 - k / 2500 / 2 - b_neg, rel=1e-12)
    assert c["ok"]
    assert not passivity(seed_trial, 29.0, 1 / 2500)["ok"]


def _ring_energy_ratio(seed_trial, device_damping, seconds=1.0, rate=2500.0):
    """A stiff radial spring (1e5 N/m, no virtual damping) sampled by the servo loop
    on the simulated device, released 1 mm off the circle: energy after / before."""
    k = 1.0e5
    values = {"k_radial": k, "c_radial": 0.0, "friction_closing": 0.0}
    values.update(friction_opening=0.0, viscous_damping=0.0, transition_damping=0.0)
    p = param_vector(seed_trial.replace(values), PARAMS)
    dev = SimDevice(_NO_HAND, mass=4.0, damping=device_damping, coulomb=0.0, noise=0.0)
    dev.pos[:] = on_path(0.8, 0.301)
    out = np.zeros(3)
    row = np.zeros(N_COLUMNS)

    def energy():
        r = math.hypot(dev.pos[1] + 0.158, dev.pos[2] + 0.138) - 0.3
        return 0.5 * k * r * r + 0.5 * 4.0 * float(dev.vel @ dev.vel)

    e0 = energy()
    for _ in range(int(seconds * rate)):
        pos, vel, f = dev.read()
        compute_command(pos, vel, f, p, 1.0e4, out, row)
        dev.command(out)
        dev.step(1.0 / rate)
    return energy() / e0


def test_the_passivity_bound_is_where_a_sampled_spring_goes_unstable(seed_trial):
    """K T / 2 = 20 N s/m at 2500 Hz: device damping 30 dissipates, 5 does not.

    The bound is sufficient, not exact: here the energy stays level near 15 N s/m.
    Above it by 10 N s/m on 4 kg the energy falls at least as exp(-2.5 t)."""
    assert _ring_energy_ratio(seed_trial, 30.0) < math.exp(-2.5)
    assert _ring_energy_ratio(seed_trial, 5.0) > 2.0


def test_a_set_that_is_not_passive_is_refused_with_the_reason(seed_trial):
    """The radial spring is sampled explicitly: 2e4 N/m needs b > 4 N s/m at 2500 Hz;
    the simulated device has 2 N s/m."""
    stiff = seed_trial.replace({"k_radial": 2.0e4})
    with pytest.raises(UserError, match=r"not passive.*k_radial.*K T / 2"):
        ServoLoop(SimDevice("hold"), stiff)
    # the same set at an 8x faster loop passes: T is what matters
    ServoLoop(SimDevice("hold"), stiff, rate=20000.0)


def test_the_implicit_law_lifts_the_bound_for_the_door_springs_only(seed_trial):
    """The latch and the end stops are solved over the step (any stiffness); the same
    springs sampled explicitly (the tanh law) must pass Colgate-Schenkel."""
    stiff = seed_trial.replace({"latch_stiffness": 5.0e4, "stop_stiffness": 1.0e5})
    loop = ServoLoop(SimDevice("hold"), stiff)  # implicit: accepted
    assert loop.params["stop_stiffness"] == 1.0e5
    assert not passivity(stiff, 2.0, loop.period)["ok"]  # as an explicit law it is not
    with pytest.raises(UserError, match=r"not passive.*stop_stiffness"):
        ServoLoop(SimDevice("hold"), stiff, friction="tanh")
    ServoLoop(SimDevice("hold", damping=100.0), stiff, friction="tanh")  # damped enough


def test_clamp_makes_it_passive_and_logs_it(seed_trial):
    stiff = seed_trial.replace({"k_radial": 2.0e4})
    dev = SimDevice("hold")
    loop = ServoLoop(dev, stiff, clamp=True)
    assert loop.params["k_radial"] < 2.0e4
    assert passivity(loop.params, dev.damping, loop.period, loop.exclude)["ok"]
    loop.run(0.01)
    clamps = [e for e in loop.log.events if e["kind"] == "clamp"]
    assert clamps and "k_radial" in clamps[0]["changes"]


# -- watchdog ------------------------------------------------------------------------
def test_connection_drop_ramps_to_zero_within_10_ms_and_stops(seed_trial):
    dev = _Recorder(SimDevice("open", seed=2), drop_after=1500)  # 0.6 s: on the latch
    loop = ServoLoop(dev, seed_trial)
    loop.run(1.0)
    norms = np.linalg.norm(np.array(dev.commands), axis=1)
    ramp = norms[1500:]  # commands after the drop (loop time 0.4 ms per cycle)
    assert norms[1499] > 5.0
    assert np.all(np.diff(ramp) <= 1e-12)
    assert ramp[-1] == 0.0
    assert len(ramp) * loop.period <= 0.010 + 1e-9
    assert dev.stopped >= 1 and loop.status == "watchdog"
    assert "device read failed" in loop.statistics["watchdog"]


class _SendFails(_Recorder):
    def command(self, force):
        if self.reads > 300:
            raise BrokenPipeError("broken pipe")
        super().command(force)


def test_a_failed_send_trips_the_watchdog_and_stops(seed_trial):
    dev = _SendFails(SimDevice("open", seed=6))
    loop = ServoLoop(dev, seed_trial)
    loop.run(1.0)  # does not raise
    assert loop.status == "watchdog" and "command failed" in loop.statistics["watchdog"]
    assert loop.statistics["cycles"] < 310 and dev.stopped >= 1


def test_missed_deadlines_trip_the_watchdog_in_real_time(seed_trial):
    dev = _Recorder(SimDevice("open", seed=3), slow_after=150, slow=0.001)
    loop = ServoLoop(dev, seed_trial, rate=2500.0, watchdog_misses=5)
    assert loop.realtime
    t0 = time.perf_counter()
    loop.run(2.0)
    assert time.perf_counter() - t0 < 1.0  # stopped early
    assert loop.status == "watchdog" and "missed their deadline" in loop.statistics["watchdog"]
    norms = np.linalg.norm(np.array(dev.commands), axis=1)
    times = np.array(dev.times)
    last_full = int(np.flatnonzero(norms > 0)[-1])
    assert norms[-1] == 0.0
    tripped = next(e for e in loop.log.events if e["kind"] == "watchdog")
    # the ramp (8 ms) reached zero within 10 ms of wall time after the trip, give or
    # take one cycle slowed by the 1 ms read
    assert times[-1] - (loop.t0 + tripped["t"]) < 0.010 + 0.0015
    assert last_full < len(norms) - 1 and dev.stopped >= 1
    assert loop.statistics["missed_cycles"] >= 5


def test_passivity_is_checked_again_with_the_measured_period(seed_trial):
    """Passive at the nominal 0.4 ms, not at the ~1 ms a slow link really gives."""
    params = seed_trial.replace({"k_radial": 6000.0})  # K T / 2: 1.2 N s/m at 0.4 ms
    assert passivity(params, 2.0, 0.0004, IMPLICIT)["ok"]
    assert not passivity(params, 2.0, 0.001, IMPLICIT)["ok"]
    dev = _Recorder(SimDevice("hold", seed=5), slow_after=0, slow=0.0009)
    loop = ServoLoop(dev, params, rate=2500.0, watchdog_misses=10**6)
    loop.run(2.0)
    assert loop.status == "watchdog" and "measured period" in loop.statistics["watchdog"]
    assert "not passive" in loop.statistics["watchdog"] and dev.stopped >= 1


def test_watchdog_ramp():
    w = Watchdog(misses=3, ramp_time=0.008)
    for t in (0.0, 0.001):
        w.cycle(t, late=True)
    assert not w.tripped
    w.cycle(0.002, late=False)
    for t in (0.003, 0.004, 0.005):
        w.cycle(t, late=True)
    assert w.tripped_at == 0.005
    assert w.factor(0.005) == 1.0 and w.factor(0.009) == pytest.approx(0.5)
    assert w.factor(0.013) == 0.0


# -- parameter changes ---------------------------------------------------------------
class _ChangeDuringRead(_Recorder):
    def __init__(self, inner, at, values):
        super().__init__(inner)
        self.at = at
        self.values = values
        self.loop = None
        self.error = None

    def read(self):
        out = super().read()
        if self.reads == self.at:  # mid-cycle, as a control thread would
            self.loop.request_change(self.values)
        return out


def test_a_change_applies_between_two_cycles(seed_trial):
    dev = _ChangeDuringRead(SimDevice("open", seed=4), at=200, values={"k_radial": 100.0})
    loop = ServoLoop(dev, seed_trial)
    dev.loop = loop
    loop.run(0.2)
    assert loop.params["k_radial"] == 100.0
    # in force from the next cycle (index 200, t = 0.08 s), not in the one that asked
    assert loop.log.param_times == [0.0, pytest.approx(200 / 2500)]
    assert loop.log.param_sets[1][PARAMS.index("k_radial")] == 100.0


def test_a_refused_change_leaves_the_set_as_it_was(seed_trial):
    loop = ServoLoop(SimDevice("hold"), seed_trial)
    before = loop.params.vector.copy()
    with pytest.raises(UserError, match="open_force"):
        loop.request_change({"friction_closing": 5.0, "open_force": 1.0e6})  # out of bounds
    with pytest.raises(UserError, match="not passive"):
        loop.request_change({"friction_closing": 5.0, "k_radial": 1.0e5})
    with pytest.raises(UserError, match="no_such"):
        loop.request_change({"friction_closing": 5.0, "no_such": 1.0})
    loop.run(0.01)
    np.testing.assert_array_equal(loop.params.vector, before)
    assert len(loop.log.param_times) == 1
    assert sum(e["kind"] == "refused" for e in loop.log.events) == 3


# -- log -----------------------------------------------------------------------------
def test_log_resamples_cycles_onto_a_uniform_grid():
    """Jittered cycle times, a linear signal: the ticks match np.interp."""
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.0002, 0.0006, 3000))
    t -= t[0]
    log = RenderLog(1000.0)
    for ti in t:
        log.add(ti, np.full(N_COLUMNS, 3.0 * ti + 1.0))
    a = log.array()
    ticks = np.arange(a.shape[0]) / 1000.0
    assert ticks[-1] <= t[-1] < ticks[-1] + 0.001
    np.testing.assert_allclose(a[:, 0], np.interp(ticks, t, 3.0 * t + 1.0), rtol=1e-12)


# -- the command -----------------------------------------------------------------------
def test_one_second_render_log_layout(tmp_path):
    log = tmp_path / "l.h5"
    args = ["render", "--params", "seed_trial", "--user", "open", "--duration", "1"]
    assert main([*args, "--log", str(log), "--log-rate", "500"]) == 0
    (tr,) = read_trials(log)
    assert tr.rate == pytest.approx(500.0) and tr.n == 500
    assert tr.theta[-1] < tr.theta[0] - 0.1  # on its way open
    with open_h5(log) as f:
        render = read_attrs(f["render"])
        assert render["rate"] == 2500.0 and render["log_rate"] == 500.0
        assert f["render/position"].shape == (500, 3)
        names = read_attrs(f["render/params"])["names"]
        assert list(names) == list(PARAMS.names)


def test_an_unpaced_render_says_so_and_gives_no_period(tmp_path, capsys):
    """On the simulated device with only --duration the loop runs as fast as it can:
    its summary gave the nominal period as if kept ("period mean 0.4 ms")."""
    args = ["render", "--params", "seed_trial", "--user", "hold", "--duration", "0.2"]
    log = tmp_path / "l.h5"
    assert main([*args, "--log", str(log)]) == 0
    out = capsys.readouterr().out
    assert "unpaced: 0.2 s of simulated time in " in out and "period mean" not in out, out
    assert main(["show", str(log)]) == 0
    out = capsys.readouterr().out
    assert "unpaced (simulated time)" in out and "on time" not in out, out
    assert main([*args, "--realtime", *LOADED_MACHINE_WATCHDOG]) == 0  # paced beside the workers
    out = capsys.readouterr().out
    assert_kept_time(out, 0.4)


@pytest.mark.slow
def test_headless_render_writes_a_log_data_show_reads(tmp_path, capsys):
    log = tmp_path / "l.h5"
    args = ["render", "--params", "seed_trial", "--device", "sim", "--user", "open"]
    assert main([*args, "--duration", "5", "--log", str(log)]) == 0
    (tr,) = read_trials(log)
    assert tr.rate == pytest.approx(1000.0) and tr.n == 5000
    assert tr.theta[0] > 1.5 and tr.theta[-1] < tr.theta[0] - 0.8  # opened
    assert tr.dtheta.min() < -0.3 and tr.force.min() < -5.0  # pulled toward opening
    with open_h5(log) as f:
        stats = read_attrs(f["render"])["statistics"]
        assert f["render/command"].shape == (5000, 3)
        assert f["render/params/values"].shape == (1, len(PARAMS))
    for key in ("period_mean_s", "lateness_p99_s", "missed_cycles", "cycles"):
        assert key in stats
    assert stats["cycles"] == 12500
    capsys.readouterr()
    assert main(["data", "show", str(log)]) == 0
    assert "render" in capsys.readouterr().out


@pytest.mark.slow
def test_data_show_plots_a_render_log(tmp_path):
    log = tmp_path / "l.h5"
    args = ["render", "--params", "seed_trial", "--user", "close", "--duration", "3"]
    assert main([*args, "--log", str(log)]) == 0
    (tr,) = read_trials(log)
    assert tr.theta[-1] > tr.theta[0] + 0.8  # closed
    assert main(["data", "show", str(log), "--plot", str(tmp_path / "l.png")]) == 0
    assert (tmp_path / "l.png").stat().st_size > 1000


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--user", "jump", "--duration", "1"], "unknown script"),
        (["--user", "open"], "--duration"),
        (["--user", "open", "--duration", "1", "--device", "usb"], "expected 'sim'"),
        (["--user", "open", "--duration", "-1"], "must be > 0"),
        (["--user", "open", "--duration", "1", "--rate", "5"], "--rate"),
        (["--user", "open", "--duration", "1", "--set", "k_radial=1e5"], "not passive"),
        (["--user", "open", "--duration", "1", "--watchdog-misses", "0"], "1..1000"),
    ],
)
def test_render_bad_input(extra, message, capsys):
    assert main(["render", "--params", "seed_trial", *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("evo-door: error:") and message in err and err.count("\n") == 1


# -- over TCP, against the HapticMaster emulator ----------------------------------------
def test_render_over_the_emulator_then_a_pulled_cable(seed_trial):
    """Real TCP on loopback: a render ends with the bias force cleared; a dropped
    connection trips the watchdog and the loop stops."""
    emulator = pytest.importorskip("evo_door.render.emulator")
    hapticmaster = pytest.importorskip("evo_door.render.hapticmaster")
    start = on_path(1.2, 0.31)  # off the 0.3 m circle: the radial spring pushes
    with emulator.HapticMasterEmulator(position=start) as emu:
        dev = hapticmaster.HapticMasterDevice("127.0.0.1", emu.port, damping=2.0, init_wait=0.0)
        loop = ServoLoop(dev, seed_trial, rate=2000.0, watchdog_misses=1000)
        loop.run(0.2)
        assert loop.status == "done" and loop.statistics["round_trip_mean_s"] > 0
        assert (
            np.abs(loop.log.array()[:, COMMAND : COMMAND + 3]).max() > 1.0
        )  # it did command forces
        np.testing.assert_array_equal(emu.bias_force(), 0.0)  # cleared by stop()

        dev = hapticmaster.HapticMasterDevice("127.0.0.1", emu.port, damping=2.0, init_wait=0.0)
        loop = ServoLoop(dev, seed_trial, rate=2000.0, watchdog_misses=1000)
        timer = threading.Timer(0.1, emu.drop_clients)
        timer.start()
        t0 = time.perf_counter()
        loop.run(2.0)
        timer.join()
        assert time.perf_counter() - t0 < 1.0
        assert loop.status == "watchdog" and "device read failed" in loop.statistics["watchdog"]


def _class_attributes_assigned_through_self(source: str) -> list[str]:
    """``Class.name`` for each name a class assigns in its body and its methods assign
    through ``self``: a class attribute standing in for state the object owns."""
    found = []
    for cls in ast.walk(ast.parse(source)):
        if not isinstance(cls, ast.ClassDef):
            continue
        in_body = {
            target.id
            for node in cls.body
            if isinstance(node, ast.Assign)
            for target in node.targets
            if isinstance(target, ast.Name)
        }
        through_self = {
            node.attr
            for node in ast.walk(cls)
            if isinstance(node, ast.Attribute)
            and isinstance(node.ctx, ast.Store)
            and isinstance(node.value, ast.Name)
            and node.value.id == "self"
        }
        found += [f"{cls.name}.{name}" for name in sorted(in_body & through_self)]
    return found


def test_no_renderer_class_keeps_instance_state_in_class_attributes():
    """ServoLoop's ``_now`` and ``_k`` were class attributes that ``run`` then set on
    the instance: the loop's state hid outside its ``__init__``."""
    made = "class Loop:\n    _k = 0\n    LIMIT = 1\n    def run(self):\n        self._k = 1\n"
    assert _class_attributes_assigned_through_self(made) == ["Loop._k"]
    package = Path(evo_door.render.__file__).parent
    found = {
        str(path.relative_to(package)): _class_attributes_assigned_through_self(path.read_text())
        for path in sorted(package.rglob("*.py"))
    }
    assert not {path: names for path, names in found.items() if names}
