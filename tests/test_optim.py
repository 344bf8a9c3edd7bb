"""The optimisation layer: compiled objectives against numpy, GA operators, determinism, blow-ups."""

import math
import random

import numpy as np
import pytest

from evo_door.data.trial import Trial
from evo_door.optim import GASettings, GeneticAlgorithm, Objective, Problem, polish, slsqp
from evo_door.optim.operators import (
    cx_sbx_bounded,
    mut_gaussian_bounded,
    rng_from_state,
    rng_state,
)
from evo_door.sim import simulate
from tests.conftest import OSCILLATOR_MODEL as OSC

# compared against references: run again on a generic CPU in CI (pyproject markers)
pytestmark = pytest.mark.numerics

DT = 1.0 / 1024.0
TRUE = {"k": 100.0, "c": 2.0, "inertia": 1.5}


def make_trial(seed, seconds=2.0, dt=DT, params=TRUE, theta0=0.1, noise=0.0, tid=None):
    """A forced oscillator trial with a force of a few random sines."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds / dt)) * dt
    amp, freq, phase = rng.uniform(5, 20, 3), rng.uniform(1, 12, 3), rng.uniform(0, 6, 3)
    force = (amp[:, None] * np.sin(freq[:, None] * t + phase[:, None])).sum(axis=0)
    r = simulate(OSC, OSC.params.vector(params), force, dt, theta0=theta0)
    chans = [r.theta, r.dtheta, r.ddtheta]
    if noise:
        chans = [c + noise * np.std(c) * rng.standard_normal(c.size) for c in chans]
    return Trial(t, force, *chans, trial_id=tid or f"t{seed}", theta0=theta0, dtheta0=0.0)


def reference_error(kind, derivative, x_full, trial, mask=None):
    """Plain numpy objective of one trial from the public simulate()."""
    theta0, dtheta0 = trial.initial_state()
    r = simulate(OSC, x_full, trial.force, trial.dt, theta0=theta0, dtheta0=dtheta0)
    e2 = ((r.theta, r.dtheta, r.ddtheta)[derivative] - trial.channel(derivative)) ** 2
    if kind == "max_square":
        return e2[mask].max() if mask is not None else e2.max()
    w = np.full(e2.size, trial.dt)
    w[0] = w[-1] = trial.dt / 2
    if mask is not None:
        w = np.where(mask, w, 0.0)
    return float(np.sum(w * e2)) if mask is not None else float(np.trapezoid(e2, dx=trial.dt))


@pytest.mark.parametrize("kind", ["max_square", "ise"])
@pytest.mark.parametrize("derivative", [0, 1, 2])
def test_objective_kernel_matches_numpy_reference(kind, derivative):
    # two trials of different lengths and sample periods, targets off the model
    trials = [
        make_trial(1, 1.5, params={"k": 80.0, "c": 3.0, "inertia": 1.2}),
        make_trial(2, 1.0, dt=1 / 500.0, params={"k": 130.0, "c": 1.0, "inertia": 2.0}),
    ]
    base = OSC.params.defaults
    prob = Problem(
        OSC,
        ["k", "c", "inertia"],
        [10, 0, 0.1],
        [1000, 10, 10],
        base,
        trials,
        Objective(kind, derivative, "sum"),
    )
    X = np.array([[100.0, 2.0, 1.5], [60.0, 0.5, 3.0], [300.0, 7.0, 0.7]])
    err, ok = prob.trial_errors(X)
    assert ok.all()
    for i, x in enumerate(X):
        for j, tr in enumerate(trials):
            ref = reference_error(kind, derivative, prob.full(x)[0], tr)
            assert err[i, j] == pytest.approx(ref, rel=1e-12, abs=1e-300)
    fit, blown = prob.evaluate(X)
    np.testing.assert_allclose(fit, err.sum(axis=1), rtol=1e-15)
    assert not blown.any()


@pytest.mark.parametrize("kind", ["max_square", "ise"])
def test_masked_samples_do_not_count(kind):
    tr = make_trial(3, 1.0)
    # declare a sensor range on dtheta so that its largest samples count as saturated
    hi = float(np.quantile(tr.dtheta, 0.8))
    tr.sensors = {"dtheta": {"range": [-100.0, hi]}}
    tr.dtheta = np.minimum(tr.dtheta, hi)
    mask = tr.unsaturated("dtheta")
    assert 0 < (~mask).sum() < mask.size
    prob = Problem(
        OSC,
        ["k"],
        [10],
        [1000],
        OSC.params.vector({"c": 2.0, "inertia": 1.5}),
        [tr],
        Objective(kind, 1),
    )
    err, _ = prob.trial_errors([[150.0]])
    ref = reference_error(kind, 1, prob.full([150.0])[0], tr, mask)
    assert err[0, 0] == pytest.approx(ref, rel=1e-12)


@pytest.mark.parametrize("combine, fn", [("sum", np.sum), ("max", np.max), ("mean", np.mean)])
def test_combine_over_trials(combine, fn):
    trials = [make_trial(s, 0.5) for s in (4, 5, 6)]
    prob = Problem(
        OSC,
        ["k", "c"],
        [10, 0],
        [1000, 10],
        OSC.params.vector({"inertia": 1.5}),
        trials,
        Objective("ise", 0, combine),
    )
    X = np.array([[90.0, 1.0], [200.0, 4.0]])
    err, _ = prob.trial_errors(X)
    np.testing.assert_allclose(prob.evaluate(X)[0], fn(err, axis=1), rtol=1e-15)


def test_operators_keep_genes_inside_bounds():
    rng = random.Random(7)
    for _ in range(300):
        n = rng.randint(1, 6)
        low = [rng.uniform(-5, 5) for _ in range(n)]
        up = [lo + rng.choice([1e-9, 1e-3, 1.0, 1e4]) for lo in low]
        pick = lambda lo, hi: rng.choice([lo, hi, rng.uniform(lo, hi)])  # noqa: E731
        a = [pick(lo, hi) for lo, hi in zip(low, up)]
        b = [pick(lo, hi) for lo, hi in zip(low, up)]
        c1, c2 = cx_sbx_bounded(
            list(a),
            list(b),
            eta=rng.choice([0.01, 1.0, 30.0]),
            low=low,
            up=up,
            rng=rng,
            gene_probability=1.0,
        )
        sigma = [rng.choice([0.01, 0.8, 50.0]) * (hi - lo) for lo, hi in zip(low, up)]
        (m,) = mut_gaussian_bounded(list(a), sigma=sigma, low=low, up=up, indpb=1.0, rng=rng)
        for ind in (c1, c2, m):
            assert all(lo <= x <= hi for x, lo, hi in zip(ind, low, up)), (ind, low, up)


def test_ga_never_leaves_bounds_and_counts_evaluations():
    tr = make_trial(8, 0.5)
    prob = Problem(
        OSC,
        ["k", "c", "inertia"],
        [50, 0.5, 1.0],
        [150, 3.0, 2.0],
        OSC.params.defaults,
        [tr],
        Objective("max_square", 1),
    )
    ga = GeneticAlgorithm(
        GASettings(
            population=30,
            generations=8,
            mutation_probability=0.9,
            mutation_amplitude=5.0,
            crossover_eta=0.5,
            seed=3,
        )
    )
    state = ga.run(prob)
    X = np.array(state.history_x)
    assert X.shape == (9, 30, 3)
    assert np.all(X >= prob.lower) and np.all(X <= prob.upper)
    assert state.evaluations == sum(state.logbook.select("evals"))
    assert state.evaluations < 9 * 30  # unchanged survivors are not evaluated again


def test_a_clone_is_what_deepcopy_makes_and_shares_nothing():
    """The GA's clone copies genes and fitness as ``copy.deepcopy`` does (DEAP's default
    clone), and neither copy changes with the other."""
    import copy

    from evo_door.optim.ga import Individual, clone_individual

    ind = Individual([1.5, -2.0, 3.25])
    ind.fitness.values = (0.125,)
    for twin in (clone_individual(ind), copy.deepcopy(ind)):
        assert list(twin) == list(ind) and type(twin) is type(ind)
        assert twin.fitness.valid and twin.fitness.values == (0.125,)
        twin[0] = 9.0
        del twin.fitness.values
        assert ind[0] == 1.5 and ind.fitness.values == (0.125,)
    fresh = Individual([1.0])
    assert not clone_individual(fresh).fitness.valid


def test_same_seed_same_run_and_global_random_untouched():
    tr = make_trial(9, 0.5)
    prob = Problem(
        OSC,
        ["k", "c"],
        [10, 0],
        [1000, 10],
        OSC.params.vector({"inertia": 1.5}),
        [tr],
        Objective("ise", 1),
    )
    random.seed(12345)
    before = random.getstate()
    runs = [
        GeneticAlgorithm(GASettings(population=20, generations=5, seed=s)).run(prob)
        for s in (4, 4, 5)
    ]
    assert random.getstate() == before
    a, b, c = runs
    np.testing.assert_array_equal(np.array(a.history_x), np.array(b.history_x))
    np.testing.assert_array_equal(np.array(a.history_f), np.array(b.history_f))
    assert rng_state(a.rng) == rng_state(b.rng)
    assert not np.array_equal(np.array(a.history_x), np.array(c.history_x))


def test_rng_state_round_trip_including_gauss_cache():
    rng = random.Random(5)
    rng.gauss(0, 1)  # leaves a cached second normal deviate
    clone = rng_from_state(rng_state(rng))
    assert [rng.gauss(0, 1) for _ in range(5)] == [clone.gauss(0, 1) for _ in range(5)]


def test_snapshot_restore_continues_bit_for_bit():
    tr = make_trial(10, 0.5)
    prob = Problem(
        OSC,
        ["k", "c"],
        [10, 0],
        [1000, 10],
        OSC.params.vector({"inertia": 1.5}),
        [tr],
        Objective("max_square", 1),
    )
    ga = GeneticAlgorithm(GASettings(population=16, generations=6, seed=2))
    full = ga.run(prob)
    part = GeneticAlgorithm(GASettings(population=16, generations=3, seed=2)).run(prob)
    resumed = ga.run(prob, state=ga.restore(ga.snapshot(part)))
    np.testing.assert_array_equal(np.array(full.history_x), np.array(resumed.history_x))
    np.testing.assert_array_equal(np.array(full.history_f), np.array(resumed.history_f))
    assert [list(i) for i in full.hof] == [list(i) for i in resumed.hof]
    assert full.logbook.select("min") == resumed.logbook.select("min")


def test_blowup_gets_worst_fitness_is_counted_and_run_goes_on():
    # RK4 with one step per sample is unstable when sqrt(k / inertia) * dt > 2.8:
    # a large part of this search box blows up.
    tr = make_trial(11, 0.5)
    prob = Problem(
        OSC,
        ["k", "inertia"],
        [10.0, 1e-3],
        [1e7, 2.0],
        OSC.params.vector({"c": 2.0}),
        [tr],
        Objective("max_square", 1),
    )
    fit, blown = prob.evaluate([[1e7, 1e-3], [100.0, 1.5]])
    assert blown.tolist() == [True, False] and fit[0] == math.inf and math.isfinite(fit[1])
    state = GeneticAlgorithm(GASettings(population=30, generations=4, seed=1)).run(prob)
    assert state.blowups > 0
    assert state.blowups == sum(state.logbook.select("blowups"))
    assert math.isfinite(state.best_fitness)
    assert state.generation == 4
    assert all(math.isfinite(v) for v in state.logbook.select("mean"))


def test_slsqp_refines_and_never_worsens():
    tr = make_trial(12, 1.0)
    prob = Problem(
        OSC,
        ["k", "c", "inertia"],
        [10, 0, 0.1],
        [1000, 10, 10],
        OSC.params.defaults,
        [tr],
        Objective("ise", 1),
    )
    res = slsqp(prob, [120.0, 1.0, 1.8])
    assert res.fitness <= res.fitness0
    np.testing.assert_allclose(res.x, [100.0, 2.0, 1.5], rtol=1e-3)
    # starting at the optimum it stays there
    again = slsqp(prob, res.x)
    assert again.fitness <= res.fitness


@pytest.mark.parametrize("kind", ["ise", "max_square"])
@pytest.mark.parametrize("noise, tol", [(0.0, 0.01), (0.02, 0.03)])
def test_round_trip_recovery_ga_then_polish(noise, tol, kind):
    """Trials made with known parameters give them back (oscillator: all identifiable)."""
    trials = [make_trial(s, 2.0, noise=noise) for s in (20, 21, 22)]
    prob = Problem(
        OSC,
        ["k", "c", "inertia"],
        [20, 0, 0.2],
        [500, 10, 8],
        OSC.params.defaults,
        trials,
        Objective(kind, 1),
    )
    state = GeneticAlgorithm(GASettings(population=40, generations=10, seed=1)).run(prob)
    res = polish(prob, state.best_x)
    assert res.fitness <= state.best_fitness
    rel = np.abs(res.x / np.array([TRUE["k"], TRUE["c"], TRUE["inertia"]]) - 1)
    print(f"noise {noise}: relative errors {rel}")
    assert np.all(rel < tol), rel
