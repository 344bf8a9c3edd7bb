"""Identifiability of a fit: residuals, finite-difference sensitivities, covariance, verdicts.

References: the closed form of linear least squares (numpy's lstsq, scipy's curve_fit),
the exact sensitivities of the linear oscillator (its sensitivity equations discretised
exactly with a matrix exponential), scipy's approx_fprime, the compiled objective
kernel, and a Monte Carlo of a regression with coloured noise.
"""

import math
import warnings

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.optimize import approx_fprime, curve_fit
from scipy.signal import lfilter

from evo_door import files
from evo_door.data.trial import Trial
from evo_door.errors import UserError
from evo_door.models import get_model
from evo_door.optim import Objective, Problem, slsqp
from evo_door.optim.covariance import autocorrelation_time, covariance
from evo_door.optim.identifiability import (
    CORRELATED,
    IDENTIFIABLE,
    NOT_IDENTIFIABLE,
    Identifiability,
    identifiability,
)
from evo_door.optim.sensitivity import jacobians, residuals
from evo_door.sim import simulate
from tests.conftest import OSCILLATOR_MODEL as OSC
from tests.test_optim import TRUE, make_trial

# compared against references: run again on a generic CPU in CI (pyproject markers)
pytestmark = pytest.mark.numerics

FREE = ["k", "c", "inertia"]
LOWER, UPPER = [20.0, 0.0, 0.2], [500.0, 10.0, 8.0]
X_TRUE = np.array([TRUE[n] for n in FREE])


ISE_SPEED = Objective("ise", 1, "sum")


def oscillator_problem(trials, objective=ISE_SPEED, lower=LOWER, upper=UPPER):
    return Problem(OSC, FREE, lower, upper, OSC.params.vector(TRUE), trials, objective)


@pytest.fixture(scope="module")
def noisy_fit():
    """Oscillator trials with noise on every channel, fitted by SLSQP from the truth."""
    trials = [make_trial(s, 1.5, noise=0.02) for s in (1, 2)]
    prob = oscillator_problem(trials)
    return prob, slsqp(prob, X_TRUE).x


# -- the core statistics against the closed form of linear least squares ---------------
def linear_data(seed=0, n=400):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, n)
    # columns of very different scales, as parameters in different units would give
    A = np.column_stack([np.ones(n) * 1e3, t, np.sin(3.0 * t) * 1e-3, t**2])
    beta = np.array([0.002, -1.0, 500.0, 2.0])
    y = A @ beta + 0.05 * rng.standard_normal(n)
    return A, y


def test_covariance_of_linear_least_squares_is_the_closed_form():
    A, y = linear_data()
    n, p = A.shape
    beta, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = A @ beta - y
    ref = (r @ r) / (n - p) * np.linalg.inv(A.T @ A)
    got = covariance(A, r)
    assert got.reasons == {}
    np.testing.assert_allclose(got.se, np.sqrt(np.diag(ref)), rtol=1e-9)
    ref_corr = ref / np.sqrt(np.outer(np.diag(ref), np.diag(ref)))
    np.testing.assert_allclose(got.correlation, ref_corr, rtol=1e-9, atol=1e-12)
    assert got.sigma2 == pytest.approx((r @ r) / (n - p), rel=1e-14)
    # scipy's own estimate of the same covariance (absolute_sigma=False: scaled by SSR)
    _, pcov = curve_fit(lambda X, *b: X @ np.array(b), A, y, p0=beta, jac=lambda X, *b: X)
    np.testing.assert_allclose(got.se, np.sqrt(np.diag(pcov)), rtol=1e-9)
    # fewer effective samples: the variance grows as SSR / (N_eff - p)
    n_eff = n / 8.0
    wider = covariance(A, r, n_effective=n_eff)
    np.testing.assert_allclose(wider.se, got.se * math.sqrt((n - p) / (n_eff - p)), rtol=1e-12)
    np.testing.assert_allclose(wider.correlation, got.correlation, rtol=1e-12)


def test_covariance_sets_aside_a_singular_combination_and_a_dead_column():
    A, y = linear_data(1)
    # column 4 = 2 col0 / 1e3 - 3 col1: only a combination of the three is determined;
    # column 5 never changes the residual
    A = np.column_stack([A, 2e-3 * A[:, 0] - 3.0 * A[:, 1], np.zeros(len(y))])
    names = ["a", "b", "c", "d", "e", "f"]
    beta, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = A @ beta - y
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = covariance(A, r, names=names)
    assert got.reasons[5].startswith("no sensitivity")
    singular = [j for j, why in got.reasons.items() if why.startswith("singular")]
    assert len(singular) == 1 and singular[0] in (0, 1, 4)
    trio = {"a", "b", "e"} - {names[singular[0]]}
    assert all(n in got.reasons[singular[0]] for n in trio)
    assert np.isinf(got.se[[5, singular[0]]]).all()
    assert np.isnan(got.correlation[5]).all()
    # the others: the closed form of the fit with the set-aside parameters held
    keep = [j for j in range(6) if j not in got.reasons]
    B = A[:, keep]
    ref = (r @ r) / (len(y) - len(keep)) * np.linalg.inv(B.T @ B)
    np.testing.assert_allclose(got.se[keep], np.sqrt(np.diag(ref)), rtol=1e-8)
    assert math.isinf(got.condition) or got.condition > 1e20


def test_autocorrelation_time_of_white_coloured_and_constant_residuals():
    rng = np.random.default_rng(5)
    white = rng.standard_normal(20000)
    assert 0.8 < autocorrelation_time(white) < 1.3
    phi = 0.9  # AR(1): tau = (1 + phi) / (1 - phi) = 19
    ar = lfilter([1.0], [1.0, -phi], rng.standard_normal(200000))
    assert autocorrelation_time(ar) == pytest.approx((1 + phi) / (1 - phi), rel=0.2)
    # a bias: one value per trial
    assert autocorrelation_time(np.full(500, 0.3)) == pytest.approx(500.0, rel=1e-12)
    assert autocorrelation_time(np.zeros(10)) == 1.0


def test_effective_samples_give_the_spread_of_estimates_under_coloured_noise():
    """Monte Carlo: the SE with N_eff matches the real spread; the white-noise one does not."""
    rng = np.random.default_rng(7)
    n, runs, phi = 4000, 300, 0.95
    t = np.linspace(0.0, 1.0, n)
    A = np.column_stack([np.ones(n), t, np.sin(2 * np.pi * t)])
    noise = lfilter([1.0], [1.0, -phi], rng.standard_normal((runs, n)), axis=1)
    betas, se, se_white = [], [], []
    for e in noise:
        beta, *_ = np.linalg.lstsq(A, e, rcond=None)
        r = A @ beta - e
        betas.append(beta)
        se.append(covariance(A, r, n / autocorrelation_time(r)).se)
        se_white.append(covariance(A, r).se)
    spread = np.std(betas, axis=0)
    ratio = np.mean(se, axis=0) / spread
    assert np.all((ratio > 0.75) & (ratio < 1.33)), ratio
    assert np.all(np.mean(se_white, axis=0) / spread < 0.3)


# -- residuals and Jacobian on a model --------------------------------------------------
@pytest.mark.parametrize("derivative", [0, 1, 2])
def test_sum_of_squared_residuals_is_the_ise_fitness(derivative):
    saturating = make_trial(3, 1.0, params={"k": 90.0, "c": 1.0, "inertia": 1.4})
    channel = ("theta", "dtheta", "ddtheta")[derivative]
    top = np.quantile(getattr(saturating, channel), 0.9)  # 10 % of the samples saturated
    sensors = {channel: {"range": [-1e9, float(top)]}}
    trials = [make_trial(1, 1.0, params={"k": 80.0, "c": 3.0, "inertia": 1.2})]
    trials.append(saturating.replace(sensors=sensors))
    prob = oscillator_problem(trials, Objective("ise", derivative, "sum"))
    assert not prob.fit.mask.all()
    r = residuals(prob, X_TRUE)
    assert [len(rj) for rj in r] == [int(tr.unsaturated(channel).sum()) for tr in trials]
    err, ok = prob.trial_errors(X_TRUE)
    assert ok.all()
    np.testing.assert_allclose([rj @ rj for rj in r], err[0], rtol=1e-10)


def exact_speed_sensitivities(trial, k, c, inertia):
    """d dtheta / d(k, c, inertia) of the oscillator (theta_eq = 0), force linear between
    samples, by the exact discretisation of its sensitivity equations."""
    # state: theta, dtheta, s_k, s_k', s_c, s_c', s_I, s_I', force, dforce/dt
    M = np.zeros((10, 10))
    w2, g = k / inertia, c / inertia
    M[0, 1] = 1.0
    M[1, [0, 1, 8]] = -w2, -g, 1.0 / inertia
    for i in (2, 4, 6):
        M[i, i + 1] = 1.0
        M[i + 1, [i, i + 1]] = -w2, -g
    M[3, 0] = -1.0 / inertia  # d/dk of -k theta / I
    M[5, 1] = -1.0 / inertia  # d/dc of -c dtheta / I
    M[7, [0, 1, 8]] = k / inertia**2, c / inertia**2, -1.0 / inertia**2  # -ddtheta / I
    M[8, 9] = 1.0
    E = expm(M * trial.dt)
    theta0, dtheta0 = trial.initial_state()
    z = np.zeros(10)
    z[:2] = theta0, dtheta0
    out = np.empty((trial.n, 3))
    f = trial.force
    for i in range(trial.n):
        out[i] = z[[3, 5, 7]]
        if i + 1 < trial.n:
            z[8], z[9] = f[i], (f[i + 1] - f[i]) / trial.dt
            z = E @ z
    return out


def test_jacobian_matches_exact_sensitivities_and_scipy_approx_fprime():
    trials = [make_trial(s, 1.5) for s in (1, 2)]
    prob = oscillator_problem(trials)
    x = np.array([120.0, 1.5, 1.7])  # off the truth: a residual that is not zero
    r, (J,), blown = jacobians(prob, x)
    assert not blown.any()
    ref = []
    for tr in trials:
        w = np.full(tr.n, tr.dt)
        w[0] = w[-1] = tr.dt / 2
        ref.append(np.sqrt(w)[:, None] * exact_speed_sensitivities(tr, *x))
    ref = np.concatenate(ref)
    scale = np.linalg.norm(ref, axis=0)
    assert np.max(np.abs(J - ref) / scale) < 1e-6
    # and the plain forward difference of scipy, at its own accuracy
    flat = lambda v: np.concatenate(residuals(prob, v))  # noqa: E731
    np.testing.assert_allclose(r, flat(x), rtol=0, atol=0)
    Jf = approx_fprime(x, flat, 1e-6 * x)
    assert np.max(np.abs(Jf - ref) / scale) < 1e-4


def test_jacobian_at_a_bound_steps_inward_and_agrees_with_central():
    trials = [make_trial(1, 1.5)]
    x = X_TRUE
    wide = oscillator_problem(trials)
    at_bound = oscillator_problem(trials, lower=[20.0, TRUE["c"], 0.2])
    _, (J_wide,), _ = jacobians(wide, x)
    _, (J_edge,), _ = jacobians(at_bound, x)  # would step below c's lower bound if central
    scale = np.linalg.norm(J_wide, axis=0)
    assert np.max(np.abs(J_edge - J_wide) / scale) < 1e-6
    res = identifiability(at_bound, x)
    assert "lower bound" in res.reasons[1] and "lower bound" not in res.reasons[0]


def test_standard_errors_do_not_depend_on_the_step(noisy_fit):
    prob, x = noisy_fit
    ses = np.array([identifiability(prob, x, step=s).se for s in (1e-5, 1e-4, 1e-3)])
    np.testing.assert_allclose(ses, ses[1][None, :].repeat(3, axis=0), rtol=1e-3)
    res = identifiability(prob, x)
    assert res.step_agreement < 1e-5
    # the data fix the natural frequency sqrt(k / inertia) best: k and inertia trade
    assert res.verdicts == [CORRELATED, IDENTIFIABLE, CORRELATED]
    assert res.partners[0] == "inertia" and res.partners[2] == "k" and res.partner_r[0] > 0.95
    assert np.all(res.ci_rel < 0.1) and np.all(np.abs(x - X_TRUE) < 4 * res.se)


def test_max_square_objective_uses_the_ise_residuals_and_says_so(noisy_fit):
    prob, x = noisy_fit
    ise = identifiability(prob, x)
    maxsq = identifiability(prob.with_objective(Objective("max_square", 1, "sum")), x)
    np.testing.assert_allclose(maxsq.se, ise.se, rtol=1e-14)
    assert ise.note == "" and "not a sum of squares" in maxsq.note


# -- the door: frictions that brake it the same way, a latch it never reaches ------------
@pytest.fixture(scope="module")
def door_impulses():
    """Noise-free impulse trials from fully open (16-24 deg, far from the latch)."""
    door = get_model("door")
    truth = door.load_params("default").vector
    dt = 1.0 / 1024.0
    t = np.arange(2048) * dt
    trials = []
    for i, (peak, duration) in enumerate([(20.0, 0.1), (28.0, 0.08), (15.0, 0.15)]):
        on = (t > 0.05) & (t < 0.05 + duration)
        force = np.where(on, peak * np.sin(np.pi * (t - 0.05) / duration), 0.0)
        r = simulate(door, truth, force, dt, theta0=0.0)
        assert r.ok and r.theta.max() < np.radians(30.0)
        trials.append(
            Trial(t, force, r.theta, r.dtheta, r.ddtheta, trial_id=f"i{i}", theta0=0.0, dtheta0=0.0)
        )
    return door, truth, trials


def door_check(door_impulses, free, lower, upper, noise=0.0):
    door, truth, trials = door_impulses
    if noise:
        rng = np.random.default_rng(3)
        trials = [tr.replace(dtheta=tr.dtheta + noise * rng.standard_normal(tr.n)) for tr in trials]
    prob = Problem(door, free, lower, upper, truth, trials, Objective("ise", 1, "sum"))
    x = np.array([truth[door.params.index(n)] for n in free])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning spam, singular or not
        return identifiability(prob, x)


def test_door_two_pad_frictions_are_flagged_and_the_mass_is_not(door_impulses):
    free, lower, upper = ["M", "F_atC", "F_atD"], [0.3, 5.0, 5.0], [2.5, 70.0, 70.0]
    # noise-free, at the truth: the residual is zero, so only the correlation can tell
    res = door_check(door_impulses, free, lower, upper)
    assert res.ssr == 0.0 and "residual is zero" in res.note
    assert res.verdict("M") == IDENTIFIABLE
    assert res.verdict("F_atC") == CORRELATED and res.verdict("F_atD") == CORRELATED
    assert res.partners[1:] == ["F_atD", "F_atC"] and res.partner_r[1] < -0.999
    assert abs(res.cosine[1, 2]) > 0.9999
    # with the gyroscope's white noise (0.00087 rad/s) they are not identifiable at all
    noisy = door_check(door_impulses, free, lower, upper, noise=0.00087)
    assert noisy.verdict("M") == IDENTIFIABLE and noisy.ci_rel[0] < 0.01
    assert noisy.verdict("F_atC") == NOT_IDENTIFIABLE == noisy.verdict("F_atD")
    assert np.all(noisy.ci_rel[1:] > 0.1) and "F_atD" in noisy.reasons[1]


def test_door_latch_parameter_on_impulse_trials_is_not_identifiable(door_impulses):
    res = door_check(door_impulses, ["M", "unlock_force"], [0.3, 5.0], [2.5, 100.0], noise=1e-3)
    assert res.verdicts == [IDENTIFIABLE, NOT_IDENTIFIABLE]
    assert math.isinf(res.se[1]) and math.isinf(res.ci_rel[1])
    assert res.reasons[1].startswith("no sensitivity") and res.sensitivity_range[1] == 0.0
    assert res.partners[1] == "" and np.isnan(res.correlation[1]).all()
    assert np.isfinite(res.se[0])
    text = res.format()
    assert "unlock_force: no sensitivity" in text and " inf " in text


# -- the result: tree round trip, table -------------------------------------------------
def test_result_round_trips_through_an_hdf5_tree(tmp_path, door_impulses):
    res = door_check(door_impulses, ["M", "F_atD", "unlock_force"], [0.3, 5, 5], [2.5, 70, 100])
    path = tmp_path / "id.h5"
    files.write_h5(path, {"identifiability": res.to_tree()})
    with files.open_h5(path) as f:
        back = Identifiability.from_tree(files.read_group(f["identifiability"]))
    for key, value in vars(res).items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(getattr(back, key), value)  # NaN == NaN here
        elif isinstance(value, float) and math.isnan(value):  # no ratio of a zero residual
            assert math.isnan(getattr(back, key)), key
        else:
            assert getattr(back, key) == value, key
    assert back.format() == res.format()


def test_format_is_a_table_with_units(noisy_fit):
    prob, x = noisy_fit
    text = identifiability(prob, x).format()
    lines = text.splitlines()
    assert lines[0].startswith("identifiability at the estimate: dtheta residual over 2 trials")
    assert "rad/s" in lines[0]
    assert lines[1].split() == [
        "parameter",
        "value",
        "unit",
        "SE",
        "95",
        "%",
        "CI",
        "verdict",
        "most",
        "correlated",
    ]
    rows = {line.split()[0]: line for line in lines[3:6]}
    for name, unit in {"k": "N/rad", "c": "N s/rad", "inertia": "kg m"}.items():
        assert f"  {unit}  " in rows[name]
    assert rows["c"].split()[-3] == IDENTIFIABLE and rows["k"].split()[-3] == CORRELATED
    assert rows["k"].endswith("inertia +0.974")
    assert lines[6] == "k: correlation +0.974 with inertia (|r| > 0.95)"


@pytest.mark.parametrize(
    "x, kwargs, message",
    [
        ([100.0, 2.0], {}, "needs 3 values"),
        ([100.0, 2.0, 50.0], {}, "inertia = 50 is outside its search range"),
        ([100.0, math.nan, 1.5], {}, "non-finite"),
        ([100.0, 2.0, 1.5], {"step": 0.0}, "finite-difference step"),
        ([100.0, 2.0, 1.5], {"confidence": 1.5}, "confidence"),
    ],
)
def test_bad_input_is_a_one_line_user_error(x, kwargs, message):
    prob = oscillator_problem([make_trial(1, 0.5)])
    with pytest.raises(UserError, match=message):
        identifiability(prob, x, **kwargs)
