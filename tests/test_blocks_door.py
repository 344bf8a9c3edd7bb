"""The seed's door as blocks (``examples/blocks/door.yaml``, docs/blocks.md): the
mechanism file built from the library's rotary body, tanh friction, end stop and the
seed's two subsystem blocks (slotted plate, latch) is the built-in door: its trials,
its force-angle curve and the case study's physical-stage estimates; and the words
the door needed (a centre-of-mass inertia, an offset arm, the integration settings)
are checked like the rest of a mechanism file.
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

from evo_door.data import read_trials
from evo_door.errors import UserError
from evo_door.models import get_model
from evo_door.models.blocks import CACHE_ENV
from evo_door.params import param_vector
from evo_door.sim import simulate
from evo_door.sim.simulate import force_angle_curve
from tests.test_cli import cli

ROOT = Path(__file__).resolve().parents[1]
DOOR_FILE = ROOT / "examples" / "blocks" / "door.yaml"
DATA = ROOT / "experiments" / "data" / "default.h5"

#: the door's parameter -> the mechanism's (examples/blocks/door.yaml)
NAMES = {
    "I_z": "door.inertia", "M": "door.mass", "G_x": "door.arm", "G_y": "door.arm_normal",
    "L": "door.hand_lever", "T_atO": "hinge.level", "a_rot": "hinge.slope",
    **{n: f"plate.{n}" for n in ("L_OA", "L_Bx", "L_By", "L_Cx", "L_Cy", "L_Dx", "L_Dy")},
    **{n: f"plate.{n}" for n in ("K", "F_load", "F_atC", "T_atA", "T_atB", "mu", "F_atD", "a")},
    "unlock_force": "latch.unlock_force", "lock_force": "latch.lock_force",
    "latch_loose_angle": "latch.loose_angle", "latch_open_stiffness": "latch.open_stiffness",
    "latch_close_stiffness": "latch.close_stiffness", "latch_open_hold": "latch.open_hold",
    "latch_close_hold": "latch.close_hold", "latch_seat_force": "latch.seat_force",
    "latch_damping": "latch.damping", "latch_sharpness": "latch.sharpness",
    "wall_stiffness": "latch.wall_stiffness", "wall_damping": "latch.wall_damping",
    "stop_stiffness": "stop.k", "stop_damping": "stop.c",
}  # fmt: skip


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    """Generated mechanisms in a tmp folder of the session (not the user's cache)."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path_factory.getbasetemp() / "mechanisms"))


@pytest.fixture(scope="module")
def both():
    return get_model("door"), get_model(str(DOOR_FILE))


def test_the_file_holds_the_built_in_doors_numbers(both):
    """Every parameter the door's physics reads has the built-in default in the file
    (the section scales of the pad are 1: uniform, the block has none)."""
    door, blocks = both
    d, b = door.load_params("default").as_dict(), blocks.load_params().as_dict()
    for door_name, name in NAMES.items():
        assert b[name] == d[door_name], (door_name, name)
    assert all(d[f"friction_scale_{k}"] == 1.0 for k in range(1, 9))
    assert b["latch.lever"] == d["L"] and b["latch.closed"] == np.pi / 2
    assert blocks.theta_range == door.theta_range and blocks.method == door.method
    units = {p.name: p.unit for p in blocks.params}
    assert units["plate.K"] == "N/m" and units["latch.open_stiffness"] == "N/rad"
    assert units["door.inertia"] == "kg m^2" and units["hinge.level"] == "N m"


def test_the_door_as_blocks_runs_the_bundled_trials_as_the_built_in_door(both):
    """Every trial of the bundled data (impulses, unlocks, locks: the latch crossed),
    each model at its own integration settings: within 1e-6 of the range."""
    door, blocks = both
    pd, pb = door.load_params("default"), blocks.load_params()
    trials = read_trials(DATA)
    assert {t.kind for t in trials} >= {"impulse", "unlock", "lock"}
    for tr in trials:
        dt = float(tr.t[1] - tr.t[0])
        a = simulate(door, pd, tr.force, dt, theta0=tr.theta0, dtheta0=tr.dtheta0)
        b = simulate(blocks, pb, tr.force, dt, theta0=tr.theta0, dtheta0=tr.dtheta0)
        assert a.ok and b.ok
        assert np.max(np.abs(a.theta - b.theta)) < 1e-6 * np.ptp(a.theta), tr.trial_id
        assert np.max(np.abs(a.dtheta - b.dtheta)) < 1e-6 * np.max(np.abs(a.dtheta))


def test_the_door_as_blocks_has_the_built_in_force_angle_curve(both):
    """The Coulomb curve (latch peaks, pad and slot at their full level)."""
    door, blocks = both
    a = force_angle_curve(door, door.load_params("default"))
    b = force_angle_curve(blocks, blocks.load_params())
    assert a["theta"].size == b["theta"].size > 700
    np.testing.assert_allclose(a["theta"], b["theta"], rtol=0, atol=1e-6)  # polished peaks
    for side in ("opening", "closing"):
        scale = np.max(np.abs(a[side]))
        assert np.max(np.abs(a[side] - b[side])) < 1e-6 * scale, side


def test_a_changed_parameter_changes_both_alike(both):
    """Not just the defaults: a stiffer spring, a heavier door, another latch."""
    door, blocks = both
    change = {"K": 520.0, "M": 1.9, "G_y": 0.02, "unlock_force": 55.0, "F_atD": 30.0}
    pd = door.load_params("default", overrides=change)
    pb = blocks.load_params(overrides={NAMES[k]: v for k, v in change.items()})
    (tr,) = [t for t in read_trials(DATA) if t.kind == "unlock"][:1]
    dt = float(tr.t[1] - tr.t[0])
    a = simulate(door, pd, tr.force, dt, theta0=tr.theta0, dtheta0=tr.dtheta0, tolerance=1e-10)
    b = simulate(blocks, pb, tr.force, dt, theta0=tr.theta0, dtheta0=tr.dtheta0, tolerance=1e-10)
    assert np.max(np.abs(a.theta - b.theta)) < 1e-7 * np.ptp(a.theta)
    default = simulate(door, door.load_params("default"), tr.force, dt, theta0=tr.theta0)
    assert np.max(np.abs(a.theta - default.theta)) > 1e-3  # the change mattered


@pytest.mark.slow
def test_the_case_studys_physical_stage_on_the_blocks_gives_the_same_estimates(tmp_path, capsys):
    """``examples/blocks/door_physical.yaml`` against the same stage on the built-in
    door (a smaller GA than the case study's, the same for both, then SLSQP)."""
    small = ["--set", "algorithm.population=30", "--set", "algorithm.generations=6"]
    built_in = tmp_path / "builtin.yaml"
    text = (ROOT / "examples" / "blocks" / "door_physical.yaml").read_text()
    text = text.replace("model: door.yaml", "model: door")
    text = text.replace("../../experiments/data/default.h5", str(DATA))
    for door_name in ("F_load", "M", "F_atD"):
        text = text.replace(f"{NAMES[door_name]}:", f"{door_name}:")
    built_in.write_text(text)
    runs = {}
    for name, file in (("blocks", ROOT / "examples" / "blocks" / "door_physical.yaml"),
                       ("door", built_in)):  # fmt: skip
        out = tmp_path / f"{name}.h5"
        run = cli(capsys, "run", str(file), "--out", str(out), "--quiet", *small, cwd=tmp_path)
        assert run.returncode == 0, run.stderr
        shown = cli(capsys, "show", str(out), "--json", cwd=tmp_path)
        runs[name] = json.loads(shown.stdout)["best"]
    for door_name in ("F_load", "M", "F_atD"):
        got, want = runs["blocks"][NAMES[door_name]], runs["door"][door_name]
        assert abs(got / want - 1.0) < 1e-3, (door_name, got, want)


GOOD = """
mechanism:
  name: arm
  handle: lever
  bodies:
    lever: {kind: rotary, inertia: 0.1, mass: 1.0, arm: 0.2, arm_normal: 0.01, inertia_about: centre_of_mass}
  elements:
    rub: {kind: friction, on: lever, level: 0.1}
  integration: {method: dopri5, tolerance: 1.0e-8, substeps: 2}
"""

BAD = [
    (("inertia_about: centre_of_mass", "inertia_about: middle"), "'lever': inertia_about must be one of axis, centre"),
    (("mass: 1.0, arm: 0.2, arm_normal: 0.01, ", ""), "inertia_about: centre_of_mass needs the body's mass"),
    (("method: dopri5", "method: euler"), "integration: method 'euler' is not one of"),
    (("substeps: 2", "substeps: 0"), "integration: substeps must be a whole number from 1 to 64"),
    (("tolerance: 1.0e-8", "tolerance: 0.5"), "integration: tolerance 0.5 is outside"),
    (("tolerance: 1.0e-8", "tol: 1.0e-8"), "integration: unknown key 'tol' (did you mean 'tolerance'?)"),
    (("friction, on: lever, level: 0.1", "latch, on: lever, unlock_force: 900"), "'rub': unlock_force = 900 N is"),
]  # fmt: skip


def test_the_doors_words_work_on_another_lever(tmp_path):
    """The centre-of-mass inertia and the offset arm: the law by hand."""
    (tmp_path / "arm.yaml").write_text(textwrap.dedent(GOOD))
    model = get_model(str(tmp_path / "arm.yaml"))
    assert (model.method, model.tolerance, model.substeps) == ("dopri5", 1e-8, 2)
    x, dx = np.array([0.7, 0.3]), np.empty(2)
    model.rhs(x, 2.0, param_vector(model.load_params(), model.params), dx)
    weight = -1.0 * 9.80665 * (0.2 * np.cos(0.7) - 0.01 * np.sin(0.7))
    inertia = 0.1 + 1.0 * (0.2**2 + 0.01**2)
    assert dx[1] == pytest.approx((2.0 * 1.0 + weight - 0.1) / inertia, rel=1e-14)


@pytest.mark.parametrize("change, message", BAD, ids=[m[:40] for _, m in BAD])
def test_a_bad_door_word_is_one_line(tmp_path, change, message):
    old, new = change
    text = textwrap.dedent(GOOD)
    assert old in text
    (tmp_path / "bad.yaml").write_text(text.replace(old, new, 1))
    with pytest.raises(UserError) as err:
        get_model(str(tmp_path / "bad.yaml"))
    assert message in str(err.value) and "\n" not in str(err.value), str(err.value)


def test_the_door_as_blocks_stores_the_built_in_doors_energy(both, tmp_path):
    """The generated ``energy(x, p)`` against the door's own (kinetic, gravity, the
    spring at C, the latch's springs, the wall and the stop) over the stroke and past
    both ends; both zero-referenced alike but for the gravity and spring constants of
    the fully-open pose, which the difference at theta = 0 removes."""
    from evo_door.models.blocks import mechanism_energy
    from evo_door.models.door import energy

    door, blocks = both
    pd = param_vector(door.load_params("default", overrides={"G_y": 0.03}), door.params)
    pb = param_vector(blocks.load_params(overrides={"door.arm_normal": 0.03}), blocks.params)
    e_blocks = mechanism_energy(DOOR_FILE)
    rng = np.random.default_rng(5)
    thetas = np.concatenate([[-0.01, 0.0, 1.55, 1.563, 1.5705, 1.575], rng.uniform(0, 1.57, 40)])
    offset = e_blocks(np.array([0.0, 0.0]), pb) - energy(0.0, 0.0, pd)
    for theta in thetas:
        w = rng.uniform(-2.0, 2.0)
        want = energy(float(theta), w, pd)
        got = e_blocks(np.array([theta, w]), pb) - offset
        assert got == pytest.approx(want, rel=1e-11, abs=1e-11), theta
