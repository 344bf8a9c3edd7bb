"""The virtual test rig: determinism, sensors, true parameters, the physics of its trials, CLI."""

import math
from dataclasses import replace

import h5py
import numpy as np
import pytest
from numba import njit

from evo_door.data import read_trials, rig, write_trials
from evo_door.data.preprocess import find_force_peak
from evo_door.data.sensors import CLOSED, DEG, GYROSCOPE, INCLINOMETER, LOAD_CELL, Sensor
from evo_door.errors import UserError
from evo_door.models.base import Model
from evo_door.params import Param, ParamTable
from evo_door.sim import simulate
from tests.test_cli import cli


@njit(cache=True)
def toy_door_accel(theta, dtheta, force, p):
    """A door in miniature: dry friction, a latch detent near closed, stops at both ends.

    x = pi/2 - theta (from closed): in [0.3, 1.5] deg the latch holds the door shut
    (a bump of height open_force); in [1.5, 3] deg it resists closing (close_force).
    """
    inertia, friction, open_force, close_force = p[0], p[1], p[2], p[3]
    deg = math.pi / 180.0
    x = math.pi / 2 - theta
    f = force - friction * math.tanh(50.0 * dtheta)
    if 0.3 * deg < x < 1.5 * deg:
        f += open_force * math.sin(math.pi * (x - 0.3 * deg) / (1.2 * deg))
    elif 1.5 * deg <= x < 3.0 * deg:
        f -= close_force * math.sin(math.pi * (x - 1.5 * deg) / (1.5 * deg))
    if theta < 0.0:
        f += -2e4 * theta - 200.0 * dtheta
    if x < 0.0:
        f += 2e4 * x - 200.0 * dtheta
    return f / inertia


#: Importable as "tests.test_rig:TOY_DOOR" wherever a model name is accepted.
TOY_DOOR = Model(
    "toy_door",
    "toy door",
    ParamTable(
        "toy_door",
        [
            Param(
                "inertia",
                "kg m",
                4.0,
                0.1,
                100.0,
                "specification",
                "equivalent inertia at the handle",
            ),
            Param("friction", "N", 5.0, 0.0, 100.0, "specification", "dry friction"),
            Param("open_force", "N", 40.0, 0.0, 500.0, "sensation", "latch bump against opening"),
            Param("close_force", "N", 25.0, 0.0, 500.0, "sensation", "latch bump against closing"),
        ],
    ),
    toy_door_accel,
    method="semi_implicit",
    substeps=4,
    rig_kinds=("impulse", "unlock", "lock"),
)
TOY = "tests.test_rig:TOY_DOOR"


@pytest.fixture(scope="module")
def campaign():
    params = TOY_DOOR.load_params()
    return params, rig.generate_trials(
        TOY_DOOR, params, rig.Campaign(users=3, trials=4, seed=7), progress=False
    )


def test_same_seed_same_bytes_other_seed_other_trials(tmp_path, campaign):
    params, trials = campaign
    again = rig.generate_trials(
        TOY_DOOR, params, rig.Campaign(users=3, trials=4, seed=7), progress=False
    )
    for a, b in zip(trials, again):
        for ch in ("t", "force", "theta", "dtheta"):
            x, y = getattr(a, ch), getattr(b, ch)
            assert (x is None and y is None) or np.array_equal(x, y)
    write_trials(tmp_path / "a.h5", trials)
    write_trials(tmp_path / "b.h5", again)
    assert (tmp_path / "a.h5").read_bytes() == (tmp_path / "b.h5").read_bytes()
    other = rig.generate_trials(
        TOY_DOOR, params, rig.Campaign(users=3, trials=1, seed=8), progress=False
    )
    assert not np.array_equal(other[0].force[:500], trials[0].force[:500])
    # trial k does not depend on how many trials follow it
    short = rig.generate_trials(
        TOY_DOOR, params, rig.Campaign(users=3, trials=2, seed=7), progress=False
    )
    assert np.array_equal(short[1].force, trials[1].force)


def test_campaign_layout_and_truth(campaign, tmp_path):
    params, trials = campaign
    assert [t.trial_id for t in trials] == ["T01", "T02", "T03", "T04"]
    assert [t.user_id for t in trials] == ["U1", "U2", "U3", "U1"]
    assert [t.kind for t in trials] == ["impulse", "unlock", "impulse", "lock"]
    assert trials[0].channels == ("dtheta",) and trials[1].channels == ("theta",)
    assert all(t.rate == 1024.0 for t in trials)
    for t in trials:
        assert t.truth["model"] == "toy_door" and t.truth["params"] == params.as_dict()
        assert t.truth["units"]["friction"] == "N"
        assert t.sensors["force"]["range"] == [-445.0, 445.0]
    write_trials(tmp_path / "c.h5", trials)
    back = read_trials(tmp_path / "c.h5")
    assert back[2].truth == trials[2].truth
    assert back[3].meta["rig"]["user"] == trials[3].meta["rig"]["user"]


def test_rig_settings_reach_the_trial_and_are_recorded_where_they_were(campaign):
    """The sensors, integrator and sub-steps of RigSettings act on the trial and are recorded
    in its sensors and truth; meta rig.settings keeps the fields it always had (the bundled
    data's), so a trial file does not change with where the settings are grouped."""
    params, trials = campaign
    recorded = list(trials[0].meta["rig"]["settings"])
    assert recorded == [
        "rate", "handle_radius", "chunk", "unlock_detect", "lock_detect", "tail", "settle",
        "t_max", "all_sensors",
    ]  # fmt: skip
    first = rig.Campaign(users=3, trials=1, seed=7)  # the campaign's first trial

    def trial(**settings):
        (tr,) = rig.generate_trials(
            TOY_DOOR, params, first, rig.RigSettings(**settings), progress=False
        )
        assert list(tr.meta["rig"]["settings"]) == recorded
        return tr

    assert trials[0].truth["method"] == "semi_implicit" and trials[0].truth["substeps"] == 4
    for changed in ({"method": "rk4"}, {"substeps": 3}):
        integrated = trial(**changed)
        assert {k: integrated.truth[k] for k in changed} == changed
        assert not np.array_equal(integrated.dtheta, trials[0].dtheta)  # the trial changed
    coarse = trial(sensors={"dtheta": replace(GYROSCOPE, resolution=0.01, noise_std=0.0)})
    assert coarse.sensors["dtheta"]["resolution"] == 0.01
    inside = coarse.dtheta[coarse.unsaturated("dtheta")]
    assert np.allclose(inside, np.round(inside / 0.01) * 0.01)  # quantised by the sensor given
    np.testing.assert_array_equal(trial().dtheta, trials[0].dtheta)


def test_users_differ(campaign):
    users = rig.make_users(3, np.random.default_rng(0))
    assert [u.user_id for u in users] == ["U1", "U2", "U3"]
    for name, (lo, hi) in rig.USER_RANGES.items():
        values = sorted(getattr(u, name) for u in users)
        assert lo <= values[0] and values[-1] <= hi
        assert values[-1] - values[0] > 0.2 * (hi - lo), name  # stratified: really different


def test_sensor_saturation_quantisation_and_noise():
    rng = np.random.default_rng(0)
    coarse = Sensor("force", "test", "coarse", -10.0, 10.0, noise_std=0.0, resolution=0.5)
    x = np.linspace(-20, 20, 401)
    y = coarse.measure(x, rng)
    assert np.all(np.isin(y, np.arange(-10.0, 10.01, 0.5)))  # on the 0.5 N grid
    assert np.all(y[x <= -10.25] == -10.0) and np.all(y[x >= 10.25] == 10.0)
    assert np.max(np.abs(y - x)[np.abs(x) < 10]) <= 0.25 + 1e-12
    # the inclinometer's grid runs through closed; its range is +-10 deg about closed
    z = INCLINOMETER.measure(np.array([0.0, CLOSED, CLOSED + 1.0]), rng)
    assert z[0] == INCLINOMETER.lo and z[2] == INCLINOMETER.hi
    assert abs(z[1] - CLOSED) < 5 * INCLINOMETER.noise_std
    assert GYROSCOPE.hi == pytest.approx(100 * DEG) and LOAD_CELL.hi == 445.0
    noisy = replace(LOAD_CELL, noise_std=0.5).measure(np.zeros(20000), rng)
    assert np.std(noisy) == pytest.approx(0.5, rel=0.03)


def test_unlock_lock_impulse_behave_like_the_seed(campaign):
    params, trials = campaign
    impulse, unlock, _, lock = trials
    # impulse from open: pushed toward closing, then the speed decays linearly at
    # friction / inertia (dry friction dominates, seed fig. 3.19)
    ev = impulse.meta["rig"]["events"]
    w = impulse.dtheta
    assert impulse.force.max() > 15 and w.max() > 10 * DEG
    i_top = int(np.argmax(w))
    decay = (w > 0.2 * w.max()) & (np.arange(w.size) > i_top + 20)
    slope = np.polyfit(impulse.t[decay], w[decay], 1)[0]
    assert slope == pytest.approx(-params["friction"] / params["inertia"], rel=0.05)
    assert ev["t_push_end"] < impulse.t[decay][0]
    # unlock: the peak pull is the latch bump plus friction; then the door opens
    # past the inclinometer's range (saturated samples flagged)
    peak = find_force_peak(unlock)
    assert -1.35 * (params["open_force"] + params["friction"]) < peak.force < -params["open_force"]
    assert not unlock.unsaturated("theta")[-100:].any()
    assert unlock.theta[0] == pytest.approx(CLOSED, abs=0.5 * DEG)
    # lock: pushed from a few degrees open over the lock bump, ends closed
    peak = find_force_peak(lock)
    assert params["close_force"] < peak.force < 1.6 * (params["close_force"] + params["friction"])
    assert lock.theta[0] < CLOSED - 3.5 * DEG and lock.theta[-1] == pytest.approx(
        CLOSED, abs=0.3 * DEG
    )


def test_chunked_closed_loop_equals_one_simulation():
    params = TOY_DOOR.load_params()
    force = 30.0 * np.sin(np.linspace(0, 3 * np.pi, 700)) ** 2

    class Replay(rig.Policy):
        def plan(self, ts, tk, theta_k, dtheta_k):
            return force[np.rint(ts * 1024).astype(int)]

    out = rig.run_closed_loop(
        TOY_DOOR, params, Replay(), 1 / 1024, 0.2, 0.0, t_max=699 / 1024, chunk=7
    )
    ref = simulate(TOY_DOOR, params, force, 1 / 1024, theta0=0.2)
    np.testing.assert_array_equal(out["theta"], ref.theta)
    np.testing.assert_array_equal(out["dtheta"], ref.dtheta)


def test_trials_from_spec_for_experiments():
    trials = rig.trials_from_spec({"model": TOY, "trials": 1, "seed": 2, "kinds": "lock"})
    assert trials[0].kind == "lock" and trials[0].truth["model"] == "toy_door"
    with pytest.raises(UserError, match="user: unknown key .did you mean 'users'"):
        rig.trials_from_spec({"model": TOY, "user": 2})
    # every entry checked before a trial is made: one line naming the key, no traceback
    for spec, message in [
        ({"users": "abc"}, "users: expected a whole number, got 'abc'"),
        ({"trials": 2.5}, "trials: expected a whole number, got 2.5"),
        ({"seed": -1}, "seed: must be at least 0, got -1"),
        ({"rate": 0}, "rate: must be positive"),
        ({"kinds": 5}, "kinds: expected a list of trial kinds"),
        ({"set": 3}, "set: expected a mapping"),
        ({"params": 3}, "params: expected a preset name"),
    ]:
        with pytest.raises(rig.SpecError, match=message):
            rig.trials_from_spec({"model": TOY, **spec})


def test_a_campaign_is_made_once_a_process_and_handed_out_as_copies(monkeypatch):
    """The case study's stages that share their users' inputs share one campaign: the
    same trials, made once; each caller gets its own copy; another door, another make."""
    from evo_door.data.rig import spec as rig_spec

    made = []

    def counted(*args):
        made.append(args[2])
        return generate(*args)

    generate = rig_spec.generate_trials
    monkeypatch.setattr(rig_spec, "generate_trials", counted)
    monkeypatch.setattr(rig_spec, "_MADE", {})
    spec = {"model": TOY, "trials": 2, "seed": 4, "kinds": "lock"}
    first = rig.trials_from_spec(spec)
    first[0].force[:] = 0.0  # a caller's own copy
    again = rig.trials_from_spec(dict(spec))
    assert len(made) == 1
    fresh = generate(TOY_DOOR, TOY_DOOR.load_params(), made[0], rig.RigSettings())
    assert [t.digest() for t in again] == [t.digest() for t in fresh]
    assert np.any(again[0].force != 0.0)
    other = rig.trials_from_spec({**spec, "seed": 5})
    assert len(made) == 2 and other[0].digest() != again[0].digest()
    rig.trials_from_spec({**spec, "set": {"friction": 7.0}})  # another door, same campaign
    assert len(made) == 3


def test_cli_generate_show_plot_and_bad_file(tmp_path, capsys):
    from evo_door.cli import main

    out = tmp_path / "rig.h5"
    assert (
        main(
            [
                "rig",
                "generate",
                "--model",
                TOY,
                "--set",
                "friction=6",
                "--trials",
                "3",
                "--seed",
                "4",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    stdout = capsys.readouterr().out
    assert "T03" in stdout and "peak [N]" in stdout
    # what --set changed is said, not "(defaults)"
    assert "generated from model toy_door (defaults, changed: friction=6)" in stdout
    with h5py.File(out) as f:
        assert f.attrs["description"] == (
            "virtual rig: model toy_door, params defaults, changed: friction=6, 3 users, "
            "3 trials, seed 4"
        )
    trials = read_trials(out)
    assert len(trials) == 3 and trials[0].truth["params"]["friction"] == 6.0
    png = tmp_path / "rig.png"
    assert main(["data", "show", str(out), "--trial", "T02", "--plot", str(png)]) == 0
    assert "unlock" in capsys.readouterr().out and png.stat().st_size > 10000
    # a bad file, as the command line reports it: one line, exit 2, nothing written
    bad = tmp_path / "bad.csv"
    bad.write_text("t,force\n0,1\n0.001,nan\n")
    res = cli(capsys, "data", "import", bad, "--out", tmp_path / "never.h5")
    assert res.returncode == 2
    assert (
        res.stderr.count("\n") == 1
        and "channel 'force'" in res.stderr
        and "row 1 (line 3)" in res.stderr
    )
    assert not (tmp_path / "never.h5").exists()


def test_a_door_that_will_not_open_is_flagged():
    params = TOY_DOOR.load_params(None, {"open_force": 400.0})
    user = replace(rig.make_users(1, np.random.default_rng(0))[0], max_force=100.0)
    with pytest.warns(UserWarning, match="did not unlock"):
        tr = rig.generate_trial(TOY_DOOR, params, "unlock", user, np.random.default_rng(1))
    assert tr.meta["rig"]["events"]["gave_up"] and np.min(tr.force) >= -100.5


# -- who makes which kind -------------------------------------------------------------
@pytest.mark.parametrize("users", range(1, 9))
def test_every_user_makes_every_kind_once_per_users_times_kinds_trials(users):
    """With 4 users and the 4-kind cycle each user made one kind only (users and kinds
    in lockstep); now each makes every position of the cycle once in users x 4 trials,
    and where taking turns already did that (users and cycle coprime) nothing changed."""
    import math

    for cycle in range(1, 7):
        made = [(rig.trial_user(k, users, cycle), k % cycle) for k in range(users * cycle)]
        # each (user, position) once: every user every kind, and as many trials each
        assert sorted(made) == [(u, p) for u in range(users) for p in range(cycle)]
        if math.gcd(users, cycle) == 1:
            assert [u for u, _ in made] == [k % users for k in range(users * cycle)]


def test_two_users_both_make_every_kind(campaign):
    params, _ = campaign
    trials = rig.generate_trials(
        TOY_DOOR, params, rig.Campaign(users=2, trials=8, seed=3), progress=False
    )
    assert [t.kind for t in trials] == ["impulse", "unlock", "impulse", "lock"] * 2
    kinds = {u: {t.kind for t in trials if t.user_id == u} for u in ("U1", "U2")}
    assert kinds == {"U1": {"impulse", "unlock", "lock"}, "U2": {"impulse", "unlock", "lock"}}


def test_the_bundled_data_keeps_its_users_and_kinds():
    """3 users x 10 trials (experiments/data): the same user makes the same kind of trial
    as when the file was made (its arrays are then the same: tests/test_rig_truth.py)."""
    from pathlib import Path

    bundled = read_trials(Path(__file__).resolve().parents[1] / "experiments/data/default.h5")
    assert [t.trial_id for t in bundled] == [f"T{k + 1:02d}" for k in range(10)]
    for k, t in enumerate(bundled):
        assert t.user_id == f"U{rig.trial_user(k, 3, 4) + 1}"
        assert t.kind == rig.DEFAULT_KINDS[k % 4]
