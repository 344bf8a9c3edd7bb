"""A model's registered quasi-static force (``evo_door.sim.hold``): the same numbers as
two calls of ``accel``, to the last bit, wherever the perceptual objective reads them.

The door and the haptic models compute the force-independent part of ``accel`` once in
their ``hold``; a slip there (a term left out, a parameter read from the wrong slot, an
operation reordered) would move every feel the case study judges, by amounts the
pipeline's tolerances might hide. So the comparison is exact, on random parameter sets
and on angles across the stop, the stroke, the latch and the wall.
"""

import math

import numpy as np
import pytest

from evo_door.models import get_model
from evo_door.sim.accel_plant import HOLDS_IN_THREADS, _hold_rows_serial
from evo_door.sim.hold import hold_form, hold_rows_form
from evo_door.sim.simulate import COULOMB_SPEED, coulomb_vector, hold_forces

pytestmark = pytest.mark.numerics

# from past the stop at fully open to past the wall at closed, through the latch
ANGLES = np.linspace(-0.05, 0.5 * math.pi + 0.01, 1501)
SPEEDS = (-COULOMB_SPEED, 0.0, 1e-3, -0.5, 2.0)


def rows(model, n, seed):
    """``n`` parameter sets scattered about the model's default (half of the parameters
    moved by 20 % at random), and its Coulomb vector (the perceptual objective's)."""
    rng = np.random.default_rng(seed)
    p = model.load_params().vector
    moved = [
        p * (1 + 0.2 * rng.standard_normal(p.size) * (rng.random(p.size) < 0.5)) for _ in range(n)
    ]
    return np.ascontiguousarray(np.r_[moved, [coulomb_vector(model, model.load_params())]])


@pytest.mark.parametrize("name", ["door", "haptic", "haptic_tanh"])
def test_the_registered_hold_is_accels_to_the_last_bit(name):
    model = get_model(name)
    assert hold_form(model.accel) is not None  # else the comparison below is of one path
    P = rows(model, 12, seed=len(name))
    for w in SPEEDS:
        ref = np.empty((P.shape[0], ANGLES.size))
        _hold_rows_serial(model.accel, P, ANGLES, w, ref)
        got = model.plant.hold_forces_rows(P, ANGLES, w)  # many: across threads
        assert got.size >= HOLDS_IN_THREADS
        assert np.array_equal(got, ref, equal_nan=True), (name, w)
        one = model.plant.hold_forces_rows(P[:1], ANGLES[:50], w)  # few: one thread
        assert np.array_equal(one, ref[:1, :50], equal_nan=True), (name, w)


def _shared_columns(name):
    """The columns a model's ``hold_rows`` needs the same in every row (the door's
    geometry, the haptic model's window slope), its section scales' eight, and all
    that makes its pad's scale (the door's: the scales and their sharpness)."""
    if name == "door":
        from evo_door.models.door import FRICTION_SCALE_1, POSE_COLUMNS, SCALE_COLUMNS

        shared, pad = list(POSE_COLUMNS), list(SCALE_COLUMNS)
    else:
        from evo_door.models.haptic import FRICTION_SCALE_1, WINDOW_SLOPE

        shared, pad = [WINDOW_SLOPE], list(range(FRICTION_SCALE_1, FRICTION_SCALE_1 + 8))
    return shared, list(range(FRICTION_SCALE_1, FRICTION_SCALE_1 + 8)), pad


@pytest.mark.parametrize("scales", ["shared", "each row's own"])
@pytest.mark.parametrize("name", ["door", "haptic"])
def test_rows_that_share_work_per_angle_get_accels_numbers_to_the_last_bit(name, scales):
    """A tolerance's sample (doors of one geometry and pad) and a population fitting the
    section scales: the model's ``hold_rows`` computes the door's pose (and its pad's
    scale) or the haptic scale's steps once an angle, and gives what two calls of
    ``accel`` give. A row of a geometry (a slope) of its own: it declines, writes
    nothing, and the plant's answer is still accel's."""
    model = get_model(name)
    hold_rows = hold_rows_form(model.accel)
    assert hold_rows is not None  # else the comparison below is of the other path
    shared, scale_columns, pad = _shared_columns(name)
    P = rows(model, 12, seed=11)
    P[:, shared] = P[0, shared]
    if scales == "shared":  # one pad for all
        P[0, scale_columns] = np.linspace(0.4, 1.0, len(scale_columns))
        P[:, pad] = P[0, pad]
    else:
        P[:, scale_columns] = np.random.default_rng(5).uniform(
            0.2, 1.1, (len(P), len(scale_columns))
        )
    for w in SPEEDS:
        ref = np.empty((P.shape[0], ANGLES.size))
        _hold_rows_serial(model.accel, P, ANGLES, w, ref)
        out = np.full_like(ref, np.nan)
        assert hold_rows(P, ANGLES, w, out)
        assert np.array_equal(out, ref, equal_nan=True), (name, w)
        got = model.plant.hold_forces_rows(P, ANGLES, w)
        assert np.array_equal(got, ref, equal_nan=True), (name, w)
    P[3, shared[0]] *= 1.01
    out = np.zeros((P.shape[0], ANGLES.size))
    assert not hold_rows(P, ANGLES, 0.2, out) and not out.any()
    ref = np.empty_like(out)
    _hold_rows_serial(model.accel, P, ANGLES, 0.2, ref)
    assert np.array_equal(model.plant.hold_forces_rows(P, ANGLES, 0.2), ref, equal_nan=True)


@pytest.mark.parametrize("name", ["door", "haptic"])
def test_the_hold_force_holds_the_model_still(name):
    """Physics, not agreement: at the hold force the acceleration is zero."""
    model = get_model(name)
    p = model.load_params().vector
    theta = np.linspace(0.05, 1.4, 41)
    for w in (-0.3, 0.3):
        f = hold_forces(model, p, theta, w)
        a = np.array([model.accel(t, w, fi, p) for t, fi in zip(theta, f)])
        scale = np.array(
            [abs(model.accel(t, w, 1.0, p) - model.accel(t, w, 0.0, p)) for t in theta]
        )
        assert np.all(np.abs(a) <= 1e-9 * scale * (1.0 + np.abs(f))), (name, w)


def test_a_model_without_a_hold_gets_it_from_accel():
    """The tanh-friction haptic model's accel, wrapped so that no hold is registered for
    it: its forces come from two calls of accel, and agree with the registered one's."""
    from dataclasses import replace

    from numba import njit

    tanh = get_model("haptic_tanh")
    inner = tanh.accel

    @njit(cache=False)
    def accel(theta, dtheta, force, p):
        return inner(theta, dtheta, force, p)

    bare = replace(tanh, name="haptic_tanh_bare", accel=accel)
    assert hold_form(bare.accel) is None
    P = rows(tanh, 3, seed=7)
    got = bare.plant.hold_forces_rows(P, ANGLES, 0.2)
    assert np.array_equal(got, tanh.plant.hold_forces_rows(P, ANGLES, 0.2), equal_nan=True)


@pytest.mark.parametrize("name", ["door", "haptic"])
def test_each_row_at_angles_of_its_own_gets_what_the_whole_grid_gives_there(name):
    """``hold_forces_at`` (a latch peak refined around where each door's coarse search
    found it): row by row the numbers of ``hold_forces_rows`` on the whole grid, on one
    thread (few) and across threads (many), and by ``accel`` where no hold is
    registered."""
    from dataclasses import replace

    from numba import njit

    model = get_model(name)
    P = rows(model, 40, seed=3)
    whole = model.plant.hold_forces_rows(P, ANGLES, -COULOMB_SPEED)
    rng = np.random.default_rng(4)
    pick = np.sort(rng.integers(0, ANGLES.size, (len(P), 33)), axis=1)  # each row its own
    got = model.plant.hold_forces_at(P, ANGLES[pick], -COULOMB_SPEED)
    assert got.size >= HOLDS_IN_THREADS
    assert np.array_equal(got, np.take_along_axis(whole, pick, axis=1), equal_nan=True)
    few = model.plant.hold_forces_at(P[:2], ANGLES[pick[:2, :5]], -COULOMB_SPEED)
    assert np.array_equal(few, whole[:2][np.arange(2)[:, None], pick[:2, :5]], equal_nan=True)
    inner = model.accel

    @njit(cache=False)
    def accel(theta, dtheta, force, p):
        return inner(theta, dtheta, force, p)

    bare = replace(model, name=f"{name}_bare", accel=accel)
    slow = bare.plant.hold_forces_at(P[:3], ANGLES[pick[:3]], -COULOMB_SPEED)
    assert np.array_equal(slow, got[:3], equal_nan=True)
