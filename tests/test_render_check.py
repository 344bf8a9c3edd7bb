"""Fit and feel: a render log against the haptic model it rendered (evo-door render-check).

A hand (``--user open-shut``: pulls the latched door open through the latch, lets go
while it moves, takes it again where it came to rest and pushes it shut through the
latch) moves a door rendered on a device; the log keeps the user force it measured
on the door's tangent, theta and dtheta. ``simulate`` of the same set under the
logged force, from the logged state, must give the logged motion, within what the
model leaves out (docs/renderer.md, "Does the log agree with the model?").
"""

from __future__ import annotations

import math
import subprocess
import sys

import h5py
import numpy as np
import pytest

from evo_door.cli import main
from evo_door.errors import UserError
from evo_door.files import read_attrs, reseal, write_attrs
from evo_door.models import get_model
from evo_door.models.haptic import CLOSED, PARAMS
from evo_door.params import param_vector
from evo_door.render.check import felt_vector, format_agreement, render_agreement
from evo_door.render.columns import COLUMNS, N_COLUMNS
from evo_door.render.device import SimDevice
from evo_door.render.log import RenderLog
from evo_door.render.loop import ServoLoop
from evo_door.sim import simulate

HAPTIC = get_model("haptic")
#: the sets rendered: the seed's trial, and a heavier door with a stronger latch and
#: four to five times its dry friction
SETS = {
    "seed_trial": {},
    "latch_and_friction": {
        "inertia": 1.8,
        "open_force": 30.0,
        "friction_closing": 6.0,
        "friction_opening": 5.0,
    },
}
#: the open-shut script's length, and a little rest after it (s)
SCRIPT = 3.6
DAMPING = 2.0  # N s/m, the device's own (the emulator's and the simulated device's)


def _params(name):
    return HAPTIC.load_params("seed_trial", SETS[name])


def _agreement(log) -> dict:
    """The log against the model; the numbers, in degrees for theta, with the loop's
    timing for a failure's message."""
    a = render_agreement(log)
    e = a.errors()
    return {
        "theta_max_deg": math.degrees(e["theta_max"]),
        "theta_rms_deg": math.degrees(e["theta_rms"]),
        "dtheta_rms": e["dtheta_rms"],
        "span_deg": math.degrees(e["theta_span"]),
        "speed_max": e["speed_max"],
        "said": format_agreement(a, log),
    }


# -- on the devices -------------------------------------------------------------------
@pytest.mark.slow
def test_a_render_over_the_emulated_hapticmaster_is_what_simulate_gives(tmp_path):
    """Over real TCP at 1 kHz, the emulator in a process of its own and the renderer
    with its supervisor (whose keep-alive once moved the emulator's script):
    theta within 3 deg of the model everywhere, dtheta within 0.1 rad/s RMS.

    Measured on a 2-core machine under load (2026-11-26, five renders of each set):
    1.32-1.51 deg and 0.049-0.053 rad/s for seed_trial, 1.58-1.71 deg and 0.059-0.060
    rad/s for the heavy latched door, over 54-63 deg of travel at up to 2.3 rad/s.
    Most of it is the latch's snap at the loop period: its release edge (0.5 mrad) is
    crossed within a period or two, and the implicit step over it leaves a speed off
    by 0.02 rad/s at 1 kHz (0.007 at 2500 Hz), which the coast to rest integrates;
    the rest is the command held over the round trip, the handle running outside the
    circle on its radial spring (0.4 % more inertia at 1.2 mm), and the emulator's own
    steps. Before the constraint's damper was made radial it also braked the door
    along the path (4.0 deg for seed_trial).
    """
    from evo_door.render.hapticmaster import HapticMasterDevice
    from evo_door.render.supervised import start_supervisor

    emulator = subprocess.Popen(
        [sys.executable, "-m", "evo_door", "emulate", "hapticmaster", "--port", "0"]
        + ["--user", "open-shut", "--damping", str(DAMPING), "--seconds", "120"],
        stdout=subprocess.PIPE,
        text=True,
    )
    found = {}
    try:
        port = int(emulator.stdout.readline().split("127.0.0.1:")[1].split()[0])
        for name in SETS:  # one device: each render's script starts with its force state
            # a cycle the loaded machine made the loop miss holds the command over it and
            # the door drifts from the model (a CI run: 22 missed, 3.45 deg): the set is
            # rendered again, at most three times, and the render that missed fewest
            # cycles is judged; a render that kept time gives the model's numbers
            fewest = None
            for _ in range(3):
                device = HapticMasterDevice("127.0.0.1", port, damping=DAMPING, init_wait=0.0)
                # the agreement below is the test, not the watchdog's budget (a CI run
                # once stalled the loop 50 cycles)
                loop = ServoLoop(device, _params(name), rate=1000.0, watchdog_misses=1000)
                loop.supervisor = start_supervisor(device, loop, 0.2)
                try:
                    loop.run(SCRIPT)
                finally:
                    loop.supervisor.close()
                assert loop.status == "done", loop.statistics
                missed = loop.statistics["missed_cycles"]
                if fewest is None or missed < fewest:
                    fewest = missed
                    log = tmp_path / f"{name}.h5"
                    loop.write_log(log)
                    found[name] = _agreement(log)
                if missed == 0:
                    break
    finally:
        emulator.terminate()
        emulator.wait(10)
    for got in found.values():
        assert got["span_deg"] > 45 and got["speed_max"] > 1.5, got["said"]  # it moved
        assert got["theta_max_deg"] < 3.0, got["said"]
        assert got["dtheta_rms"] < 0.1, got["said"]


@pytest.mark.parametrize("name", list(SETS))
def test_a_render_on_the_simulated_device_is_what_simulate_gives(name, tmp_path):
    """The simulated device at 2500 Hz, in simulated time (so the same log every
    run): its own damping (2 N s/m) and dry friction (0.3 N, tanh) are in the log and
    the check adds them; its force sensor's noise (0.05 N) is in the logged force.
    theta within 1.2 deg everywhere, dtheta within 0.06 rad/s RMS: measured 0.53 deg
    and 0.026 rad/s for seed_trial, 0.85 deg and 0.039 rad/s for the heavy door (the
    latch's snap at the period, as over the emulator)."""
    params = _params(name)
    loop = ServoLoop(SimDevice("open-shut", radius=params["radius"]), params)
    loop.run(SCRIPT)
    log = tmp_path / "sim.h5"
    loop.write_log(log)
    got = _agreement(log)
    assert got["span_deg"] > 40 and got["speed_max"] > 1.5, got["said"]
    assert got["theta_max_deg"] < 1.2, got["said"]
    assert got["dtheta_rms"] < 0.06, got["said"]
    # what the participant felt is the set plus the device: without the device's
    # damping (0.6 N s/rad of viscous damping) the model runs away from the log
    bare = render_agreement(log, device_damping=0.0, device_friction=0.0).errors()
    assert math.degrees(bare["theta_max"]) > 5 * got["theta_max_deg"]


def test_the_open_shut_hand_lets_go_and_takes_the_handle_where_it_is():
    """The hand's force is zero while it has let go, and when it takes the handle
    again its target starts where the door came to rest: no jump in its force."""
    dev = SimDevice("open-shut", noise=0.0)
    params = _params("seed_trial")
    loop = ServoLoop(dev, params)
    loop.run(SCRIPT)
    a = loop.log.array()
    t = np.arange(a.shape[0]) / loop.log.rate
    force = a[:, COLUMNS.index("force")]
    theta = a[:, COLUMNS.index("theta")]
    released = (t > 0.91) & (t < 1.99)
    assert np.all(force[released] == 0.0)
    assert np.ptp(theta[released]) > 0.1  # it coasted on by itself
    grab = np.searchsorted(t, 2.0)
    assert abs(force[grab + 1]) < 0.5  # took the handle where it was
    assert theta[-1] > CLOSED - math.radians(1.0)  # and pushed it shut


# -- the check's own arithmetic, on logs of the model itself ----------------------------
def _model_log(path, segments, rate=1000.0, damping=0.0, missed=()):
    """A render log of the model itself: ``segments`` [(set, force N array)] simulated
    one after the other, each from where the last ended (through the first force of
    the next), with the device's damping ``damping`` (N s/m) felt on top and
    recorded as the loop records it. ``missed``: cycles (in a row) the loop missed, a
    gap: the door moved under their force, which the log did not see."""
    log = RenderLog(rate, PARAMS)
    log.event(0.0, "device", "synthetic", damping=damping, friction=0.0, max_force=200.0)
    theta0, dtheta0, k = 1.2, 0.0, 0
    for j, (params, force) in enumerate(segments):
        after = segments[j + 1][1][:1] if j + 1 < len(segments) else np.zeros(0)
        log.params(k / rate, param_vector(params, PARAMS))
        f = np.concatenate([force, after])
        r = simulate(HAPTIC, felt_vector(params, damping), f, 1.0 / rate, theta0, dtheta0)
        for i in range(force.size):
            row = np.zeros(N_COLUMNS)
            row[COLUMNS.index("force")] = force[i]
            row[COLUMNS.index("theta")] = r.theta[i]
            row[COLUMNS.index("dtheta")] = r.dtheta[i]
            if k not in missed:
                log.add(k / rate, row)
            k += 1
        theta0, dtheta0 = r.theta[-1], r.dtheta[-1]
    if missed:
        log.event(
            max(missed) / rate + 1 / rate, "gap", "a gap", from_t=min(missed) / rate - 1 / rate
        )
    log.write(path, loop_rate=rate, device="synthetic", statistics={})
    return path


def _push(n, amplitude=8.0, rate=1000.0):
    t = np.arange(n) / rate
    return amplitude * np.sin(2 * np.pi * 0.7 * t)


def test_a_log_of_the_model_itself_agrees_to_its_float32_channels(tmp_path):
    seed = _params("seed_trial")
    log = _model_log(tmp_path / "m.h5", [(seed, _push(3000))], damping=DAMPING)
    a = render_agreement(log)
    e = a.errors()
    assert e["samples"] == 3000 and a.starts == [0.0]
    assert e["theta_span"] > 0.3 and e["speed_max"] > 0.5  # a motion, not a door at rest
    assert e["theta_max"] < 1e-5 and e["dtheta_max"] < 1e-3
    assert a.device == {"damping": DAMPING, "friction": 0.0}
    # the device's damping is felt: left out, the model runs off
    off = render_agreement(log, device_damping=0.0).errors()
    assert off["theta_max"] > 0.01


def test_each_set_is_simulated_from_the_time_it_came_into_force(tmp_path):
    seed = _params("seed_trial")
    heavy = _params("latch_and_friction")
    log = _model_log(tmp_path / "two.h5", [(seed, _push(1500)), (heavy, _push(1500, 12.0))])
    a = render_agreement(log)
    assert a.starts == [0.0, 1.5] and "2 sets" in a.model
    assert a.errors()["theta_max"] < 1e-5
    # one set for the whole log (a set fitted to its first half) does not agree
    assert render_agreement(log, seed).errors()["theta_max"] > 0.01
    # and windows start again from the logged state, whatever the sets
    assert render_agreement(log, window=0.7).starts == [0.0, 0.7, 1.4, 1.5, 2.1, 2.8]


def test_a_log_whose_time_is_not_uniform_is_refused_in_one_line(tmp_path):
    """The log's rows are on an exact grid (the loop's cycles interpolated onto its
    ticks), which the check takes as it is: a file whose time was changed is refused,
    as a trial reader refuses it."""
    log = _model_log(tmp_path / "j.h5", [(_params("seed_trial"), _push(200))])
    with h5py.File(log, "r+") as f:  # a stamp a fifth of a step off its grid
        f["trials/render/t"][100] += 2e-4
        reseal(f)
    with pytest.raises(UserError, match="not the uniform grid of a render log"):
        render_agreement(log)


def test_a_fault_row_restarts_the_simulation_after_it(tmp_path):
    seed = _params("seed_trial")
    log = _model_log(tmp_path / "f.h5", [(seed, _push(2000))])
    with h5py.File(log, "r+") as f:
        f["trials/render/theta"][800] = np.nan
        reseal(f)
    a = render_agreement(log)
    assert a.starts == [0.0, 0.801] and np.isnan(a.theta_sim[800])
    assert a.errors()["samples"] == 1999


def test_nothing_is_simulated_across_a_gap_of_the_loop(tmp_path):
    """The loop missed 100 ms (a loaded machine, a watchdog budget that let it go on):
    the hand pushed 25 N harder meanwhile, which the log did not see; its rows
    across the gap are an interpolation. The check compares nothing inside the gap
    and starts again from the logged state after it: the model's own log agrees, and
    the gap is said. Simulated across, the model runs off."""
    seed = _params("seed_trial")
    force = _push(2000)
    force[800:900] += 25.0
    log = _model_log(tmp_path / "g.h5", [(seed, force)], missed=range(800, 900))
    a = render_agreement(log)
    assert a.starts == [0.0, 0.9] and np.isnan(a.theta_sim[800:900]).all()
    e = a.errors()
    assert e["samples"] == 1900 and e["theta_max"] < 1e-5 and e["dtheta_max"] < 1e-3
    assert "not across 1 gap of the loop (the longest 101 ms at 0.80 s)" in a.model
    with h5py.File(log, "r+") as f:  # the same log without its gap event
        events = read_attrs(f["render"])["events"]
        write_attrs(f["render"], {"events": [e for e in events if e["kind"] != "gap"]})
        reseal(f)
    assert render_agreement(log).errors()["theta_max"] > 0.01


def test_render_check_prints_the_agreement_with_units(tmp_path, capsys):
    seed = _params("seed_trial")
    log = _model_log(tmp_path / "m.h5", [(seed, _push(2000))], damping=DAMPING)
    assert main(["render-check", str(log)]) == 0
    out = capsys.readouterr().out
    assert "device's damping 2 N s/m (viscous_damping +0.6 N s/rad)" in out
    assert "theta:  RMS" in out and " deg, largest " in out and "rad/s" in out
    assert main(["render-check", str(log), "--json", "--device-damping", "0"]) == 0
    import json

    got = json.loads(capsys.readouterr().out)
    assert got["device"] == {"damping": 0.0, "friction": 0.0}
    assert got["theta_max_rad"] > 0.01 and got["samples"] == 2000


@pytest.mark.parametrize(
    "args, message",
    [
        (["--window", "0"], "--window 0: must be > 0"),
        (["--device-damping", "-1"], "--device-damping -1: must be"),
        (["--set", "inertia=2"], "--set goes with --params"),
    ],
)
def test_render_check_refuses_bad_options_in_one_line(args, message, tmp_path, capsys):
    log = _model_log(tmp_path / "m.h5", [(_params("seed_trial"), _push(100))])
    assert main(["render-check", str(log), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def test_a_trial_file_that_is_no_render_log_is_refused(tmp_path):
    from evo_door.data import write_trials
    from evo_door.data.trial import Trial

    t = np.arange(10) / 1000.0
    write_trials(tmp_path / "t.h5", [Trial(t=t, force=t, theta=t, dtheta=t, trial_id="a")])
    with pytest.raises(UserError, match="not a render log"):
        render_agreement(tmp_path / "t.h5")
