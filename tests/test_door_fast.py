"""The door's fast path: the pose table, the library tanh's replacement, the prepared vector.

The fast path (``accel_tabulated`` on a prepared vector, what ``simulate``,
``simulate_batch`` and the GA run) must be the closed-form model to within far less
than the integrator's own error against a converged reference (5e-5 rad/s, ``test_door.py``).
"""

import math

import numpy as np
import pytest

import evo_door.models.door as door_module
from evo_door.models import get_model
from evo_door.models.door import laws, posetable
from evo_door.models.door.kinematics import Pose, pose
from evo_door.optim.kernels import ISE, population_errors
from evo_door.sim import simulate, simulate_batch
from evo_door.sim.integrators import integrate, prepared_form
from evo_door.sim.simulate import param_vector
from evo_door.sim_settings import DEFAULT_TOLERANCE, DOPRI5, RK4

# compared against references: run again on a generic CPU in CI (pyproject markers)
pytestmark = pytest.mark.numerics

DT = 1.0 / 1024.0
CLOSED = 0.5 * math.pi
GEOMETRY = ("L_OA", "L_Bx", "L_By", "L_Cx", "L_Cy")


def geometry(ps):
    return tuple(float(ps[n]) for n in GEOMETRY)


def pulse(seconds, start, width, amplitude):
    t = np.arange(int(round(seconds / DT))) * DT
    on = (t >= start) & (t < start + width)
    f = np.zeros_like(t)
    f[on] = amplitude * np.sin(np.pi * (t[on] - start) / width)
    return f


def closed_form(ps, force, theta0, dtheta0=0.0):
    """The reference: the same integrator (RK4 x 2, the door's switching surfaces
    located) on the closed-form right-hand side."""
    out = np.empty((3, force.size))
    ok = integrate(
        door_module.accel, door_module.switches, param_vector(ps), force, DT, 2, theta0,
        dtheta0, RK4, DEFAULT_TOLERANCE, door_module.N_SWITCHES, False, *out,
    )  # fmt: skip
    assert ok
    return out


# -- tanh ------------------------------------------------------------------------------
def test_tanh_is_the_library_tanh_to_a_few_ulp():
    rng = np.random.default_rng(3)
    x = np.concatenate(
        [
            10.0 ** rng.uniform(-300, 300, 20000),
            rng.uniform(0.0, 25.0, 50000),
            rng.uniform(0.62, 0.63, 5000),  # either side of the switch at 0.625
            [0.0, 0.625, 19.999, 20.0, 20.001, 1e-320],
        ]
    )
    x = np.concatenate([x, -x])
    got = np.array([laws.tanh(v) for v in x])
    want = np.tanh(x)
    rel = np.abs(got - want) / np.maximum(np.abs(want), 1e-300)
    assert rel.max() < 8e-16, f"worst {rel.max():.2e} at x = {x[rel.argmax()]!r}"
    assert laws.tanh(math.inf) == 1.0 and laws.tanh(-math.inf) == -1.0
    assert math.isnan(laws.tanh(math.nan))
    # tanh(x) / x from x^2, through 0 and the switch
    for v in (0.0, 1e-9, 0.3, 0.6249, 0.6251, 3.0, 40.0):
        want = math.tanh(v) / v if v else 1.0
        assert laws.tanh_ratio(v * v) == pytest.approx(want, rel=1e-15, abs=0.0)


# -- the pose table ----------------------------------------------------------------------
def test_tabulated_slopes_are_the_derivatives_of_the_values(default):
    """pose_rates' derivatives (the chain's second derivatives among them) against
    central differences of its own values."""
    geo = geometry(default)
    h = 1e-5
    a, b, c = np.empty(16), np.empty(16), np.empty(16)
    for theta in np.linspace(-0.2, CLOSED + 0.2, 23):
        posetable.pose_rates(theta, *geo, a)
        posetable.pose_rates(theta + h, *geo, b)
        posetable.pose_rates(theta - h, *geo, c)
        fd = (b[0::2] - c[0::2]) / (2 * h)
        np.testing.assert_allclose(a[1::2], fd, rtol=1e-7, atol=1e-9, err_msg=f"{theta}")
        # and the values are the closed form's
        k = pose(theta, *geo)
        assert (a[4], a[6], a[8], a[14]) == (k.ABy, k.dBy, k.dphi, k.phi)


def hermite_error(geo, n):
    """Largest error of a cubic Hermite interpolant of pose_rates' quantities on ``n``
    intervals over the stroke, at points between the nodes (numpy, independent of the
    compiled table)."""
    lo, hi = 0.0, CLOSED
    nodes = np.linspace(lo, hi, n + 1)
    h = nodes[1] - nodes[0]
    vals = np.empty((n + 1, 16))
    for i, th in enumerate(nodes):
        posetable.pose_rates(th, *geo, vals[i])
    worst = 0.0
    buf = np.empty(16)
    for th in np.linspace(lo + 1e-3, hi - 1e-3, 997):
        i = min(int((th - lo) / h), n - 1)
        t = (th - nodes[i]) / h
        w = ((1 + 2 * t) * (1 - t) ** 2, t * (1 - t) ** 2, t * t * (3 - 2 * t), t * t * (t - 1))
        y0, m0, y1, m1 = vals[i, 0::2], vals[i, 1::2], vals[i + 1, 0::2], vals[i + 1, 1::2]
        interp = w[0] * y0 + w[1] * h * m0 + w[2] * y1 + w[3] * h * m1
        posetable.pose_rates(th, *geo, buf)
        worst = max(worst, np.abs(interp - buf[0::2]).max())
    return worst


def test_interpolation_error_falls_as_h_to_the_fourth(default):
    """With exact slopes a cubic Hermite's error is O(h^4): halving h divides it by 16.
    A wrong slope (a sign, a missing term) would leave O(h) and a ratio near 2."""
    geo = geometry(default)
    coarse, fine = hermite_error(geo, 16), hermite_error(geo, 32)
    assert 12.0 < coarse / fine < 20.0, (coarse, fine)


def test_table_pose_is_the_closed_form_between_the_nodes(door):
    """Every Pose field, at angles off the grid (the middle of intervals among them),
    for each preset's geometry: within 1e-11 (m, rad, m/rad)."""
    rng = np.random.default_rng(7)
    h = (posetable.TABLE_HI - posetable.TABLE_LO) / posetable.TABLE_INTERVALS
    mids = posetable.TABLE_LO + (np.arange(posetable.TABLE_INTERVALS) + 0.5) * h
    angles = np.concatenate(
        [rng.uniform(posetable.TABLE_LO, posetable.TABLE_HI, 3000), mids, [posetable.TABLE_HI]]
    )
    for preset in ("default", "table53_min", "table53_max", "table54_spec"):
        geo = geometry(door.load_params(preset))
        q = np.empty(posetable.TABLE_SIZE)
        err = posetable.build_pose_table(*geo, q, 0, np.empty(posetable.NODE))
        assert err < 1e-10
        worst = np.zeros(len(Pose._fields))
        for th in angles:
            exact = pose(th, *geo)
            table = posetable.table_pose(th, geo[0], geo[1], q, 0)
            worst = np.maximum(worst, np.abs(np.subtract(exact, table)))
        assert worst.max() < 1e-11, dict(zip(Pose._fields, worst))


def test_prepared_vector_and_its_header(door, default):
    q = door_module.prepared_vector(default)
    n = len(door.params)
    assert q.size == door_module.PREPARED_SIZE and np.array_equal(q[:n], param_vector(default))
    assert q[door_module.TABLE_OK] == 1.0 and q[door_module.TABLE_ERROR] < 1e-10
    assert q[door_module.PAD_UNIFORM] == 1.0
    g = default.as_dict()
    inertia = g["I_z"] + g["M"] * (g["G_x"] ** 2 + g["G_y"] ** 2)
    assert q[door_module.INV_INERTIA] == pytest.approx(1.0 / inertia, rel=1e-15)
    scaled = door.load_params("default", {"friction_scale_3": 0.5})
    assert door_module.prepared_vector(scaled)[door_module.PAD_UNIFORM] == 0.0
    fast = prepared_form(door.accel)
    assert fast is not None and fast.accel is door_module.accel_tabulated
    assert prepared_form(get_model("haptic").accel).accel is get_model("haptic").accel


def test_fast_right_hand_side_is_the_closed_form_at_any_state(door):
    """At random states over the stroke, the latch window, beyond both ends of the table,
    with uniform and with sectioned pad friction, latch on and off."""
    rng = np.random.default_rng(11)
    sets = [
        door.load_params("default"),
        door.load_params("table54_spec"),
        door.load_params("default", {"friction_scale_2": 0.0, "friction_scale_7": 0.5}),
        door.load_params("default", {"unlock_force": 0.0, "lock_force": 0.0}),
    ]
    theta = np.concatenate(
        [
            rng.uniform(-0.1, CLOSED + 0.05, 400),
            rng.uniform(CLOSED - 0.06, CLOSED, 400),  # the latch
            [posetable.TABLE_LO - 0.1, posetable.TABLE_HI + 0.3, 2.5, -1.0],
        ]
    )
    for ps in sets:
        p = param_vector(ps)
        q = door_module.prepared_vector(ps)
        for th in theta:
            for w in (0.0, 1e-4, -0.03, 0.7, -3.0):
                for f in (0.0, 25.0):
                    exact = door_module.accel(th, w, f, p)
                    fast = door_module.accel_tabulated(th, w, f, q)
                    assert fast == pytest.approx(exact, rel=1e-9, abs=1e-8), (th, w, f)


def test_the_prepared_switching_functions_are_the_models_to_the_last_bit(door):
    """switches_prepared reads the latch's angles from the prepared vector's header
    instead of working them out: every one of the nine values is switches' own, bit for
    bit, across the stroke and the latch window, with a catch and a ramp, with the ramp
    alone, without a latch, on the contacts' sides of both ends; and the kernels hand it
    to the integrator with the fast right-hand side."""
    rng = np.random.default_rng(5)
    sets = [
        door.load_params("default"),
        door.load_params("table54_spec"),
        door.load_params("default", {"unlock_force": 0.0}),
        door.load_params("default", {"unlock_force": 0.0, "lock_force": 0.0}),
        door.load_params("default", {"latch_seat_force": 3.0, "latch_loose_angle": 0.01}),
    ]
    theta = np.concatenate(
        [rng.uniform(-0.1, CLOSED + 0.05, 300), rng.uniform(CLOSED - 0.06, CLOSED, 300)]
    )
    plain, fast = np.empty(door_module.N_SWITCHES), np.empty(door_module.N_SWITCHES)
    crossed = set()
    for ps in sets:
        p = param_vector(ps)
        q = door_module.prepared_vector(ps)
        for th in theta:
            for w in (0.0, -0.4, 2.0):
                door_module.switches(th, w, 10.0, p, plain)
                door_module.switches_prepared(th, w, 10.0, q, fast)
                assert np.array_equal(plain.view(np.int64), fast.view(np.int64)), (th, w)
                crossed.update(np.flatnonzero(plain < 0.0))
    assert crossed == set(range(door_module.N_SWITCHES)) - {3}  # each seen on both sides
    assert prepared_form(door.accel).switches is door_module.switches_prepared


def test_a_geometry_through_a_dead_centre_falls_back_to_the_closed_form(door):
    """L_By = 0 puts the plate on its dead centre at fully open: the table fails its own
    check and the fast path is the closed form there and everywhere."""
    ps = door.load_params("default", {"L_By": 0.0})
    q = door_module.prepared_vector(ps)
    assert q[door_module.TABLE_OK] == 0.0
    assert not q[door_module.TABLE_ERROR] <= posetable.TABLE_TOLERANCE
    p = param_vector(ps)
    for th in (0.2, 0.9, 1.4):
        assert door_module.accel_tabulated(th, 0.3, 5.0, q) == pytest.approx(
            door_module.accel(th, 0.3, 5.0, p), rel=1e-14
        )


# -- whole trials -------------------------------------------------------------------------
TRIALS = {
    # impulse from fully open, latch off: the smooth case of test_door_against_radau
    "smooth": ({"unlock_force": 0.0, "lock_force": 0.0}, (1.0, 0.1, 0.2, 11.0), 0.0),
    # the latched door pulled hard: the catch snaps, the door swings onto the open stop
    "unlock": ({}, (2.0, 0.1, 0.6, -60.0), None),
    # pushed closed from 57 deg: up the lock ramp, over the apex, into the wall
    "lock": ({}, (2.0, 0.05, 0.5, 30.0), 1.0),
}


@pytest.mark.parametrize("name", sorted(TRIALS))
def test_fast_trial_is_the_closed_form_trial(door, name):
    """Far below RK4's own error against a converged reference (5e-5 rad/s, 1e-7 rad)."""
    values, shape, theta0 = TRIALS[name]
    ps = door.load_params("default", values)
    if theta0 is None:
        theta0 = CLOSED - ps["latch_loose_angle"]
    f = pulse(*shape)
    r = simulate(door, ps, f, DT, theta0=theta0, method="rk4", substeps=2)
    ref = closed_form(ps, f, theta0)
    assert r.ok
    assert np.abs(r.theta - ref[0]).max() < 1e-9
    assert np.abs(r.dtheta - ref[1]).max() < 1e-7
    if name == "unlock":
        assert r.theta.min() < 0.0  # it did reach the open stop
    if name == "lock":
        assert r.theta.max() > CLOSED  # and the wall


def _ise_errors(door, P, f, target):
    """population_errors of the rows of ``P`` on one trial (force ``f``, dopri5, ISE of
    the speed against ``target``): each row's error and whether it integrated."""
    err = np.empty((len(P), 1))
    good = np.zeros((len(P), 1), dtype=np.bool_)
    population_errors(
        door, P, f, target, np.ones(f.size, dtype=np.bool_),
        np.array([0, f.size]), np.array([DT]), np.zeros(1), np.zeros(1),
        1, DOPRI5, door.tolerance, 1, ISE, err, good,
    )  # fmt: skip
    return err[:, 0], good[:, 0]


def test_batch_and_population_kernels_run_the_fast_path_per_row(door, default):
    """Rows with different geometry (each its own table): every row of simulate_batch is
    simulate of that row, and population_errors is the ISE of those responses."""
    rng = np.random.default_rng(5)
    p = param_vector(default)
    P = np.tile(p, (6, 1))
    for name in GEOMETRY + ("K", "F_atD"):
        i = door.params.index(name)
        P[:, i] *= rng.uniform(0.95, 1.05, len(P))
    f = pulse(0.6, 0.05, 0.2, 12.0)
    theta, dtheta, _, ok = simulate_batch(door, P, f, DT, theta0=0.0)
    assert ok.all()
    target = simulate(door, p, f, DT, theta0=0.0).dtheta
    err, good = _ise_errors(door, P, f, target)
    assert good.all()
    for i in range(len(P)):
        r = simulate(door, P[i], f, DT, theta0=0.0)
        np.testing.assert_array_equal(theta[i], r.theta)
        np.testing.assert_array_equal(dtheta[i], r.dtheta)
        e = r.dtheta - target
        ise = DT * (np.sum(e**2) - 0.5 * (e[0] ** 2 + e[-1] ** 2))
        assert err[i] == pytest.approx(ise, rel=1e-10)
    assert len(set(np.round(err, 12))) == len(P)  # the rows did differ


def test_a_vector_prepared_again_keeps_its_table_only_for_the_same_geometry(door, default):
    """The pose table is built where the vector's stamp does not match the new set: a
    set of the same geometry keeps it (the stamp matches), another geometry or a table
    changed since builds it afresh, and either way the vector is the one a fresh
    preparation gives, bit for bit."""
    p = param_vector(default)
    stiffer, wider = p.copy(), p.copy()
    stiffer[door.params.index("K")] *= 1.3
    wider[door.params.index("L_Cx")] *= 1.02

    def fresh(x):
        q = np.full(door_module.PREPARED_SIZE, np.nan)
        door_module.prepare(x, q)
        return q

    def bits(q):
        return q.view(np.int64)

    q = fresh(p)
    stamp = bits(q)[door_module.TABLE_STAMP]
    assert stamp == door_module.table_stamp(p, q) == door_module.table_stamp(stiffer, q)
    assert door_module.table_stamp(wider, q) != stamp
    for x in (stiffer, wider, p, wider, wider, stiffer):  # one vector, set after set
        door_module.prepare(x, q)
        assert np.array_equal(bits(q), bits(fresh(x)))
    q[door_module.TABLE_START + 100] += 1e-9  # a table changed since: built again
    assert door_module.table_stamp(stiffer, q) != bits(q)[door_module.TABLE_STAMP]
    door_module.prepare(stiffer, q)
    assert np.array_equal(bits(q), bits(fresh(stiffer)))
    garbage = np.random.default_rng(2).normal(size=door_module.PREPARED_SIZE)
    door_module.prepare(p, garbage)  # never prepared: built
    assert np.array_equal(bits(garbage), bits(fresh(p)))


def test_a_population_gives_each_row_its_own_errors_whatever_its_neighbours(door, default):
    """The population kernel prepares a block's rows into one vector, one after another:
    rows of one geometry share its table, rows of another build theirs; each row's
    error is the one it gets alone, bit for bit."""
    rng = np.random.default_rng(9)
    p = param_vector(default)
    P = np.tile(p, (40, 1))
    P[:, door.params.index("K")] *= rng.uniform(0.9, 1.1, len(P))
    moved = rng.random(len(P)) < 0.3
    P[moved, door.params.index("L_Cx")] *= rng.uniform(0.98, 1.02, moved.sum())
    f = pulse(0.6, 0.05, 0.2, 12.0)
    target = simulate(door, p, f, DT, theta0=0.0).dtheta

    err, good = _ise_errors(door, P, f, target)
    alone = [_ise_errors(door, P[i : i + 1], f, target) for i in range(len(P))]
    assert good.all() and all(g[0] for _, g in alone)
    assert np.array_equal(err, [e[0] for e, _ in alone])


def test_a_plant_prepares_again_when_the_parameters_change():
    """The door's plant keeps the last prepared vector (a closed-loop rig trial simulates
    a few samples at a time with one set): another set, even one number changed in place
    in the same array, is prepared afresh, and the same set gives the same numbers."""
    model = get_model("door")
    p = param_vector(model.load_params(), model.params)
    force = pulse(0.5, 0.05, 0.1, -25.0)
    first = model.plant.simulate(p, force, DT, theta0=1.2)
    again = model.plant.simulate(p, force, DT, theta0=1.2)
    assert np.array_equal(first.dtheta, again.dtheta)
    p[model.params.index("K")] *= 1.5  # the same array, changed in place
    stiffer = model.plant.simulate(p, force, DT, theta0=1.2)
    fresh = type(model.plant)(model).simulate(p.copy(), force, DT, theta0=1.2)
    assert np.array_equal(stiffer.dtheta, fresh.dtheta)
    assert np.max(np.abs(stiffer.dtheta - first.dtheta)) > 1e-3


def test_the_objective_spans_the_samples_the_simulation_spans():
    """The GA's objective kernel makes the same steps as :func:`simulate` on a door's
    trial with a push and a free swing (where the steps span samples): its max-square
    speed error is the simulated one's, to the bit, for every candidate."""
    from evo_door.data.trial import Trial
    from evo_door.models import get_model
    from evo_door.optim import Objective, Problem

    door = get_model("door")
    p = door.load_params()
    n = 3072
    k = np.arange(n)
    force = np.where(k < 200, 20.0 * np.sin(np.pi * k / 200), 0.0)
    r = simulate(door, p, force, DT, theta0=0.0)
    target = r.dtheta + 0.01 * np.sin(k / 50.0)
    trial = Trial(k * DT, force, r.theta, target, r.ddtheta, trial_id="s", theta0=0.0)
    stiffness = p.as_dict()["K"]
    problem = Problem(
        door,
        ["K"],
        [0.5 * stiffness],
        [1.5 * stiffness],
        door.params.defaults,
        [trial],
        Objective("max_square", 1),
    )
    scales = np.array([0.8, 1.0, 1.2])
    err, ok = problem.trial_errors(scales[:, None] * stiffness)
    assert ok.all()
    for scale, e in zip(scales, err[:, 0]):
        q = door.load_params(overrides={"K": scale * stiffness})
        sim = simulate(door, q, force, DT, theta0=0.0)
        assert e == np.max((sim.dtheta - target) ** 2)
