"""The force-angle curve a specification reader expects (``evo-door curve``).

Latch peaks at their declared forces on the default grid, dry friction at its Coulomb
level, the finite-speed curve on request, the speed written where the curve goes.
"""

import csv
import math

import numpy as np
import pytest

from evo_door.commands.curve import HEADER
from evo_door.errors import UserError
from evo_door.models import get_model
from evo_door.sim.simulate import (
    COULOMB_SPEED,
    coulomb_vector,
    force_angle_curve,
    hold_forces,
    quasi_static_force,
    speed_sensitivities,
)
from tests.test_cli import cli
from tests.test_input_files import one_line_error

# compared against references: run again on a generic CPU in CI (pyproject markers)
pytestmark = pytest.mark.numerics

CLOSED = 0.5 * math.pi
#: Names of the latch forces: (pulled to open, pushed to close).
LATCH = {"haptic": ("open_force", "close_force"), "door": ("unlock_force", "lock_force")}

# Parameter sets whose latch bands range from 3e-5 rad to 0.015 rad wide.
PEAK_CASES = [
    # a plain command: 721 uniform points stepped over the 0.0065 rad lock band
    (
        "haptic",
        {"open_force": 27.0, "close_force": 13.0, "friction_closing": 0.0, "friction_opening": 0.0},
    ),  # fmt: skip
    ("haptic", {}),
    # narrow: 8e-5 and 5e-5 rad bands
    (
        "haptic",
        {"latch_stiffness": 1e5, "open_force": 8.0, "close_force": 5.0, "latch_sharpness": 200.0},
    ),  # fmt: skip
    (
        "haptic",
        {
            "loose_angle": 0.03,
            "transition_angle": 0.02,
            "open_force": 45.0,
            "close_force": 20.0,
            "friction_closing": 6.0,
        },
    ),  # fmt: skip
    ("door", {}),
    ("door", {"unlock_force": 25.0, "lock_force": 60.0}),
    # narrow: 4e-5 and 3e-5 rad bands
    (
        "door",
        {"latch_open_stiffness": 1e6, "latch_close_stiffness": 1e6, "latch_sharpness": 1e8},
    ),  # fmt: skip
    (
        "door",
        {
            "unlock_force": 10.0,
            "lock_force": 5.0,
            "latch_open_stiffness": 2e5,
            "latch_close_stiffness": 2e5,
            "latch_sharpness": 1e8,
            "latch_loose_angle": 0.03,
        },
    ),  # fmt: skip
]


#: Free play of the closed door: the latch bands lie below pi/2 minus it.
LOOSE = {"haptic": "loose_angle", "door": "latch_loose_angle"}


def _latch_zone(c, name, ps):
    """The last 15 deg short of the free play, where both latch peaks are (above them
    a seal may push the door out, which is not a latch peak)."""
    t = c["theta"]
    return (t >= CLOSED - math.radians(15.0)) & (t < CLOSED - ps[LOOSE[name]])


@pytest.mark.parametrize("name, overrides", PEAK_CASES)
def test_latch_peaks_are_the_declared_forces_on_the_default_grid(name, overrides):
    model = get_model(name)
    ps = model.load_params(None, overrides)
    pull, push = LATCH[name]
    c = force_angle_curve(model, ps)  # the CLI's settings: 721 points, Coulomb
    near = _latch_zone(c, name, ps)
    i_open = int(np.argmin(np.where(near, c["opening"], np.inf)))
    i_close = int(np.argmax(np.where(near, c["closing"], -np.inf)))
    # what the rest of the mechanism asks at the same angle, latch off
    off = coulomb_vector(model, ps.replace({pull: 0.0, push: 0.0}))
    rest_open = hold_forces(model, off, [c["theta"][i_open]], -COULOMB_SPEED)[0]
    rest_close = hold_forces(model, off, [c["theta"][i_close]], COULOMB_SPEED)[0]
    assert -(c["opening"][i_open] - rest_open) == pytest.approx(ps[pull], rel=0.01)
    assert c["closing"][i_close] - rest_close == pytest.approx(ps[push], rel=0.01)

    # and each peak is the model's own: no point of a 1e-9 rad scan around it goes further
    p = coulomb_vector(model, ps)
    for i, sign in ((i_open, -1.0), (i_close, 1.0)):
        t = c["theta"][i]
        x = np.linspace(t - 1e-5, t + 1e-5, 20001)
        best = (sign * hold_forces(model, p, x, sign * COULOMB_SPEED)).max()
        got = sign * c["closing" if sign > 0 else "opening"][i]
        assert got >= best - 1e-6 * ps[push if sign > 0 else pull]


def test_the_curve_follows_the_model_between_its_points():
    """Straight lines between the written points stay within 1 % of the force range."""
    model = get_model("haptic")
    scales = {f"friction_scale_{k}": s for k, s in enumerate((1, 0.2, 1, 0.5, 0, 1, 0.7, 1), 1)}
    ps = model.load_params(None, {**scales, "window_slope": 1e4, "friction_closing": 5.0})
    c = force_angle_curve(model, ps, n=41)
    p = coulomb_vector(model, ps)
    x = np.random.default_rng(1).uniform(0.0, CLOSED, 4000)
    span = np.ptp(np.concatenate([c["opening"], c["closing"]]))
    for direction, sign in (("opening", -1.0), ("closing", 1.0)):
        exact = hold_forces(model, p, x, sign * COULOMB_SPEED)
        assert np.abs(np.interp(x, c["theta"], c[direction]) - exact).max() < 0.01 * span
    # 41 uniform points cannot: the section steps (1e-4 rad) need the added ones
    assert 20 < c["added"].sum() < 400


# -- the Coulomb level -------------------------------------------------------------------
def _section_scale(theta, scales, slope):
    """Independent A(theta) of the haptic model (eq. 4.48 / 5.8), in numpy."""
    width = CLOSED / len(scales)
    a = np.full_like(theta, scales[0])
    for k in range(1, len(scales)):
        a += (scales[k] - scales[k - 1]) * (np.tanh(slope * (theta - k * width)) + 1) / 2
    return a


@pytest.mark.parametrize("slope", [10.0, 2000.0])
def test_haptic_free_motion_is_the_friction_level_whatever_the_tanh_slope(slope):
    model = get_model("haptic_tanh")  # the seed's tanh form (haptic's is its sign limit)
    scales = (1.0, 0.5, 0.0, 0.25, 1.0, 0.75, 0.1, 0.9)
    ps = model.load_params(
        None,
        {
            "open_force": 0.0,
            "close_force": 0.0,
            "gasket_stiffness": 0.0,
            "return_stiffness": 0.0,
            "viscous_damping": 0.7,
            "friction_closing": 3.0,
            "friction_opening": 2.0,
            "friction_slope": slope,
            **{f"friction_scale_{k}": s for k, s in enumerate(scales, 1)},
        },
    )
    c = force_angle_curve(model, ps)
    a = _section_scale(c["theta"], scales, ps["window_slope"])
    np.testing.assert_allclose(c["closing"], 3.0 * a, atol=1e-9)
    np.testing.assert_allclose(c["opening"], -2.0 * a, atol=1e-9)
    assert c["coulomb"] and c["speed"] == 0.0

    # at a finite speed: the tanh law, its smooth closing / opening selector
    # S(w, 0, a) = (tanh(a w) + 1) / 2 (docs/haptic-model.md) and the viscous part
    w = 0.05
    f = force_angle_curve(model, ps, speed=w)
    a = _section_scale(f["theta"], scales, ps["window_slope"])
    level = math.tanh(slope * w)
    closing = 2.0 + (3.0 - 2.0) * (level + 1) / 2
    opening = 2.0 + (3.0 - 2.0) * (1 - level) / 2
    np.testing.assert_allclose(f["closing"], closing * level * a + 0.7 * w, atol=1e-9)
    np.testing.assert_allclose(f["opening"], -(opening * level * a + 0.7 * w), atol=1e-9)
    assert not f["coulomb"] and f["speed"] == w


def test_slow_closing_below_the_speed_threshold_feels_the_opening_friction():
    """friction_closing takes over above friction_speed_threshold only: the slow limit."""
    model = get_model("haptic")
    base = {"open_force": 0.0, "close_force": 0.0, "gasket_stiffness": 0.0}
    ps = model.load_params(None, {**base, "friction_speed_threshold": 0.1})
    c = force_angle_curve(model, ps, n=11)
    np.testing.assert_allclose(c["closing"], ps["friction_opening"], atol=1e-9)
    fast = force_angle_curve(model, ps, n=11, speed=1.0)
    assert fast["closing"].min() > ps["friction_closing"]


def test_door_hinge_friction_is_its_torque_over_the_door_length():
    door = get_model("door")
    no_friction = {
        "unlock_force": 0.0,
        "lock_force": 0.0,
        **{k: 0.0 for k in ("T_atO", "T_atA", "T_atB", "mu", "F_atC", "F_atD")},
    }
    ps = door.load_params("default", {**no_friction, "T_atO": 0.05})
    c = force_angle_curve(door, ps, n=91)
    np.testing.assert_allclose((c["closing"] - c["opening"]) / 2, 0.05 / ps["L"], rtol=1e-9)
    # what is left is the mechanism at rest, on the plain Python path
    still = quasi_static_force(door, door.load_params("default", no_friction), c["theta"], 0.0)
    np.testing.assert_allclose((c["closing"] + c["opening"]) / 2, still, atol=1e-9)


def test_door_coulomb_curve_is_the_limit_of_steep_tanh_laws():
    """Every friction of the door at once, against its own steepest declared laws."""
    door = get_model("door")
    latch_off = {"unlock_force": 0.0, "lock_force": 0.0}
    ps = door.load_params("default", latch_off)
    assert set(speed_sensitivities(door)) == {"a", "a_rot"}
    theta = np.linspace(0.01, 1.5, 150)
    p = coulomb_vector(door, ps)
    coulomb = (hold_forces(door, p, theta, COULOMB_SPEED) - hold_forces(door, p, theta, -1e-15)) / 2
    steep = door.load_params("default", {**latch_off, "a": 1e6, "a_rot": 1e5})
    w = 0.02
    limit = (
        quasi_static_force(door, steep, theta, w) - quasi_static_force(door, steep, theta, -w)
    ) / 2
    np.testing.assert_allclose(coulomb, limit, rtol=1e-6)
    # the default tanh laws at 0.02 rad/s fall well short of it (63-92 % of it)
    slow = (quasi_static_force(door, ps, theta, w) - quasi_static_force(door, ps, theta, -w)) / 2
    ratio = slow / coulomb
    assert 0.5 < ratio.min() and ratio.max() < 0.95


def test_bad_arguments_are_user_errors():
    model = get_model("haptic")
    ps = model.load_params()
    for kwargs, words in (
        ({"n": 1}, "at least 2"),
        ({"speed": 0.0}, "above 0"),
        ({"speed": float("nan")}, "above 0"),
        ({"lo": 1.0, "hi": 0.5}, "range"),
    ):
        with pytest.raises(UserError, match=words):
            force_angle_curve(model, ps, **kwargs)


# -- the command ---------------------------------------------------------------------------
def _read(path):
    rows = list(csv.DictReader(path.open()))
    table = np.genfromtxt(path, delimiter=",", names=True, dtype=None, encoding=None)
    assert len(table) == len(rows)
    return rows, table


def test_curve_command_writes_the_coulomb_curve_by_default(tmp_path, capsys):
    out = tmp_path / "c.csv"
    args = ["curve", "haptic", "--set", "open_force=27", "--set", "close_force=13"]
    args += ["--set", "friction_closing=0", "--set", "friction_opening=0", "--out", out]
    res = cli(capsys, *args)
    assert res.returncode == 0, res.stderr
    assert "Coulomb curve" in res.stdout
    assert out.read_text().splitlines()[0] == HEADER
    rows, table = _read(out)
    assert {r["speed"] for r in rows} == {"0"}
    closing = table["force"][table["direction"] == "closing"]
    opening = table["force"][table["direction"] == "opening"]
    assert closing.max() == pytest.approx(13.0, rel=0.01)
    assert opening.min() == pytest.approx(-27.0, rel=0.01)
    # --coulomb says the same thing out loud
    again = tmp_path / "again.csv"
    assert cli(capsys, *args[:-1], again, "--coulomb").returncode == 0
    assert again.read_bytes() == out.read_bytes()


def test_curve_command_at_a_speed_writes_it(tmp_path, capsys):
    out = tmp_path / "c.csv"
    res = cli(capsys, "curve", "door", "--speed", "0.02", "--points", "31", "--out", out)
    assert res.returncode == 0, res.stderr
    assert "at 0.02 rad/s" in res.stdout
    rows, table = _read(out)
    assert {r["speed"] for r in rows} == {"0.02"}
    assert np.all(table["speed"] == 0.02)
    theta = table["theta"][table["direction"] == "opening"]
    np.testing.assert_array_equal(theta, table["theta"][table["direction"] == "closing"])
    assert np.all(np.diff(theta) > 0) and theta[0] == 0.0 and theta[-1] == pytest.approx(CLOSED)


def test_curve_command_refuses_coulomb_and_a_speed_together(tmp_path, capsys):
    res = cli(capsys, "curve", "door", "--coulomb", "--speed", "0.02", "--out", tmp_path / "c.csv")
    one_line_error(res, "--coulomb", "--speed 0.02")
    assert list(tmp_path.iterdir()) == []
