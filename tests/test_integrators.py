"""Integrator accuracy against analytic solutions and a converged scipy reference (DOP853)."""

import numpy as np
import pytest
from numba import njit

from evo_door.errors import UserError
from evo_door.models import get_model
from evo_door.models.base import Model
from evo_door.models.door import accel as door_accel
from evo_door.params import Param, ParamTable
from evo_door.sim import simulate, simulate_batch
from tests.reference import converged

# compared against references: run again on a generic CPU in CI (pyproject markers)
pytestmark = pytest.mark.numerics

DT = 1.0 / 1024.0


def damped_free_response(t, k, c, inertia, theta0):
    wn = np.sqrt(k / inertia)
    zeta = c / (2.0 * np.sqrt(k * inertia))
    wd = wn * np.sqrt(1.0 - zeta**2)
    return np.exp(-zeta * wn * t) * theta0 * (np.cos(wd * t) + zeta * wn / wd * np.sin(wd * t))


@pytest.mark.parametrize(
    "method, substeps, bound",
    [
        ("rk4", 1, 1e-8),
        ("rk4", 4, 1e-11),
        ("semi_implicit", 4, 1e-4),
        ("semi_implicit", 16, 1e-5),
    ],
)
def test_free_damped_oscillator_matches_analytic(oscillator, method, substeps, bound):
    p = oscillator.params.vector({"k": 100.0, "c": 1.0, "inertia": 1.0})
    r = simulate(
        oscillator, p, np.zeros(3 * 1024), DT, theta0=1.0, method=method, substeps=substeps
    )
    exact = damped_free_response(r.t, 100.0, 1.0, 1.0, 1.0)
    err = np.max(np.abs(r.theta - exact))
    print(f"{method} x{substeps}: max |theta error| = {err:.3e} rad")
    assert r.ok and err < bound


def test_semi_implicit_is_second_order(oscillator):
    p = oscillator.params.defaults
    errs = []
    for substeps in (4, 8, 16):
        r = simulate(
            oscillator, p, np.zeros(1024), DT, theta0=1.0, method="semi_implicit", substeps=substeps
        )
        errs.append(np.max(np.abs(r.theta - damped_free_response(r.t, 100, 1, 1, 1))))
    ratios = [errs[0] / errs[1], errs[1] / errs[2]]
    assert all(3.5 < q < 4.5 for q in ratios), ratios


def test_constant_force_static_deflection(oscillator):
    # heavily damped spring under a step force settles at F / k
    p = oscillator.params.vector({"k": 400.0, "c": 60.0})
    r = simulate(oscillator, p, np.full(4 * 1024, 20.0), DT, theta0=0.0)
    assert r.theta[-1] == pytest.approx(20.0 / 400.0, rel=1e-9)
    assert r.ddtheta[-1] == pytest.approx(0.0, abs=1e-7)


# A nonlinear, forced test problem: a pendulum-like door with a tanh dry friction.
@njit(cache=True)
def nonlinear_accel(theta, dtheta, force, p):
    return (force - p[0] * np.cos(theta) - p[1] * np.tanh(p[2] * dtheta) - p[3] * dtheta) / p[4]


NONLINEAR = Model(
    "nonlinear",
    "forced pendulum with tanh friction",
    ParamTable(
        "nonlinear",
        [
            Param("weight", "N", 3.0, 0.0, 100.0, "specification", "gravity term"),
            Param("friction", "N", 1.2, 0.0, 100.0, "specification", "dry friction"),
            Param("slope", "s/rad", 20.0, 0.0, 1e4, "numerics", "tanh slope"),
            Param("damping", "N s/rad", 0.3, 0.0, 100.0, "specification", "viscous damping"),
            Param("inertia", "kg m", 1.2, 0.01, 100.0, "specification", "inertia"),
        ],
    ),
    nonlinear_accel,
    method="rk4",
    substeps=2,
)


def forcing(t):
    return 6.0 * np.sin(2.0 * np.pi * 0.7 * t) + 2.0 * np.exp(-(((t - 1.0) / 0.2) ** 2))


@pytest.mark.parametrize("method, substeps, bound", [("rk4", 2, 1e-9), ("semi_implicit", 8, 1e-6)])
def test_nonlinear_forced_against_converged_reference(method, substeps, bound):
    n = 3 * 1024
    t = np.arange(n) * DT
    force = forcing(t)
    p = NONLINEAR.params.defaults
    r = simulate(NONLINEAR, p, force, DT, theta0=0.3, method=method, substeps=substeps)
    theta, dtheta = converged(nonlinear_accel.py_func, p, force, DT, 0.3, bound=bound)
    err_theta = np.max(np.abs(r.theta - theta))
    err_speed = np.max(np.abs(r.dtheta - dtheta))
    print(f"{method} x{substeps}: theta {err_theta:.2e} rad, dtheta {err_speed:.2e} rad/s")
    assert err_theta < bound and err_speed < 10 * bound


def test_semi_implicit_stays_stable_where_rk4_blows_up(oscillator):
    # a latch-like spring: omega * h = sqrt(1e8) / 1024 ~ 10, far outside RK4's region
    p = oscillator.params.vector({"k": 1e7, "c": 10.0, "inertia": 0.1})
    stiff = simulate(
        oscillator, p, np.zeros(2048), DT, theta0=0.01, method="semi_implicit", substeps=1
    )
    assert stiff.ok and np.all(np.abs(stiff.theta) <= 0.01 + 1e-12)
    blown = simulate(oscillator, p, np.zeros(2048), DT, theta0=0.01, method="rk4", substeps=1)
    assert not blown.ok and np.isnan(blown.theta[-1])


def test_batch_equals_single_runs(oscillator):
    rng = np.random.default_rng(7)
    P = np.tile(oscillator.params.defaults, (9, 1))
    P[:, 0] = rng.uniform(50, 500, 9)
    P[:, 1] = rng.uniform(0, 5, 9)
    force = forcing(np.arange(2048) * DT)
    theta, dtheta, ddtheta, ok = simulate_batch(oscillator, P, force, DT, theta0=0.1)
    assert ok.all()
    for i in (0, 4, 8):
        r = simulate(oscillator, P[i], force, DT, theta0=0.1)
        np.testing.assert_array_equal(theta[i], r.theta)
        np.testing.assert_array_equal(ddtheta[i], r.ddtheta)


def test_batch_flags_only_the_blown_up_individual(oscillator):
    P = np.tile(oscillator.params.defaults, (3, 1))
    P[1, 0] = 1e7  # unstable for rk4 at one step per sample
    P[1, 2] = 0.01
    _, _, _, ok = simulate_batch(
        oscillator, P, np.zeros(1024), DT, theta0=0.1, method="rk4", substeps=1
    )
    assert ok.tolist() == [True, False, True]


def test_bad_inputs_are_user_errors(oscillator):
    p = oscillator.params.defaults
    with pytest.raises(UserError, match="at least two samples"):
        simulate(oscillator, p, [1.0], DT)
    with pytest.raises(UserError, match="non-finite sample at index 2"):
        simulate(oscillator, p, [0.0, 1.0, np.nan], DT)
    with pytest.raises(UserError, match="unknown integration method 'euler'"):
        simulate(oscillator, p, [0.0, 1.0], DT, method="euler")
    with pytest.raises(UserError, match="takes 4 parameters"):
        simulate(oscillator, p[:3], [0.0, 1.0], DT)


# -- nothing computed twice: the acceleration a step ends with serves the next ----------
@njit
def counted_accel(theta, dtheta, force, p):
    """A gentle oscillator with sign-law dry friction (``p[2]``) that counts its calls
    in ``p[3]``."""
    p[3] += 1.0
    friction = p[2] * (1.0 if dtheta > 0.0 else (-1.0 if dtheta < 0.0 else 0.0))
    return force - p[0] * theta - p[1] * dtheta - friction


def _calls_per_sample(force, friction, theta0, stick, rates=True, damping=0.5):
    from evo_door.sim.integrators import integrate_compiled, scratch
    from evo_door.sim.located import no_switches
    from evo_door.sim_settings import DOPRI5

    p = np.array([40.0, damping, friction, 0.0])
    n = force.size
    out = [np.empty(n) for _ in range(3)]
    ok = integrate_compiled(
        counted_accel, no_switches, p, force, 1 / 1024, 1, theta0, 0.0, DOPRI5, 1e-7, 0,
        stick, *out, rates, *scratch(0),
    )  # fmt: skip
    assert ok
    return (p[3] - 1) / (n - 1), out


@pytest.mark.numerics
def test_the_compiled_integrator_runs_on_its_callers_scratch_without_numbas_runtime():
    """``integrate_compiled`` is compiled with ``_nrt=False`` (its reference counts took
    8-10 % of a trial) and allocates nothing: the caller's scratch, reused from a latch
    trial of the door to a swing of it, gives the swing bit for bit as fresh scratch
    does, and as ``simulate`` gives it."""
    from evo_door.models.door import N_SWITCHES
    from evo_door.models.door import switches as door_switches
    from evo_door.params.sets import param_vector
    from evo_door.sim.integrators import integrate_compiled, kernel_form, scratch
    from evo_door.sim_settings import METHODS, tolerance_of

    assert integrate_compiled.targetoptions.get("_nrt") is False
    door = get_model("door")
    ps = door.load_params()
    form = kernel_form(door.accel, len(param_vector(ps)))
    q = form.vector(param_vector(ps))
    code, tol = METHODS[door.method], tolerance_of(door)
    t = np.arange(2048) / 1024
    latch = np.where(t < 0.5, 60.0, 0.0)  # pulled open through the latch from closed
    swing = 25.0 * np.sin(2.0 * np.pi * 0.5 * t)

    def run(force, work):
        out = [np.empty(force.size) for _ in range(3)]
        ok = integrate_compiled(
            form.accel, door_switches, q, force, 1 / 1024, 1, 0.0, 0.0, code, tol,
            N_SWITCHES, door.stick_slip, *out, True, *work,
        )  # fmt: skip
        assert ok
        return out

    used = scratch(N_SWITCHES)
    run(latch, used)
    again = run(swing, used)
    fresh = run(swing, scratch(N_SWITCHES))
    for a, b in zip(again, fresh):
        np.testing.assert_array_equal(a, b)
    ref = simulate(door, ps, swing, 1 / 1024)
    np.testing.assert_array_equal(again[1], ref.dtheta)


@pytest.mark.numerics
def test_a_smooth_sample_costs_the_six_new_stages_of_one_step():
    """Dormand-Prince's seven stages share the first with the step before (first same as
    last), and the acceleration a sample reports is that last stage: six calls a sample
    where the motion is smooth (eight when the period and the output each evaluated it
    again)."""
    force = 2.0 * np.sin(np.arange(2048) / 1024 * 3.0)
    per_sample, (theta, dtheta, ddtheta) = _calls_per_sample(force, 0.0, 0.1, False)
    assert 5.9 < per_sample <= 6.05, per_sample
    # the reported acceleration is the model's at the reported state and force
    p = np.array([40.0, 0.5, 0.0, 0.0])
    for k in (1, 700, 2047):
        assert ddtheta[k] == pytest.approx(
            counted_accel(theta[k], dtheta[k], force[k], p), rel=1e-12, abs=1e-12
        )


@pytest.mark.numerics
def test_a_stuck_sample_costs_the_four_calls_that_decide_it_holds():
    """Held by its dry friction a whole period, the door's friction is read on both sides
    at the period's start and end (four calls), and its rate there is 0 without asking
    again."""
    force = np.full(2048, 1.0)  # well inside the friction's 5 N
    per_sample, (theta, dtheta, ddtheta) = _calls_per_sample(force, 5.0, 0.0, True)
    assert np.all(dtheta == 0.0) and np.all(theta == 0.0) and np.all(ddtheta == 0.0)
    assert per_sample <= 4.01, per_sample


@njit
def counted_door(theta, dtheta, force, p):
    """The door's right-hand side, counting its calls in the last element of ``p``
    (after the door's own parameters, which it reads by their index)."""
    p[p.shape[0] - 1] += 1.0
    return door_accel(theta, dtheta, force, p)


@pytest.mark.numerics
def test_a_door_resting_on_its_stop_under_a_noisy_force_is_not_refused_a_step_a_sample():
    """A measured force kinks at every sample (its noise), and a door resting on its stiff
    stop answers each kink with a transient that the period's first step must follow: a
    step of a whole period is too coarse there, sample after sample. Each period's first
    step starts from the length the last period's first step asked for, so the steps are
    not refused one a sample (about 21 calls of the model a sample when every period
    started from a whole one, under 0.2 N of noise; about 17 now), and the door stays
    within the tolerance's reach of a converged reference."""
    from evo_door.models.door import N_SWITCHES
    from evo_door.models.door import switches as door_switches
    from evo_door.sim.integrators import integrate_compiled, scratch
    from evo_door.sim_settings import DOPRI5

    door = get_model("door")
    base = np.asarray(door.params.defaults, dtype=float)
    p = np.append(base, 0.0)
    force = np.random.default_rng(7).normal(0.0, 0.2, 1024)  # N, the rig's noise at rest
    out = [np.empty(force.size) for _ in range(3)]
    ok = integrate_compiled(
        counted_door, door_switches, p, force, DT, 1, 0.0, 0.0, DOPRI5, 1e-7, N_SWITCHES,
        False, *out, True, *scratch(N_SWITCHES),
    )  # fmt: skip
    per_sample = (p[-1] - 1) / (force.size - 1)
    assert ok and per_sample < 18.5, per_sample
    theta, dtheta, _ = out
    assert np.all(theta <= 0.0) and theta.min() < -2e-5  # pressed on the stop throughout
    ref_theta, ref_dtheta = converged(
        door_accel, base, force, DT, 0.0, bound=1e-7, switches=door_switches,
        n_switches=N_SWITCHES,
    )  # fmt: skip
    assert np.max(np.abs(theta - ref_theta)) < 1e-9
    assert np.max(np.abs(dtheta - ref_dtheta)) < 1e-7


# -- steps over several samples where the force is linear -------------------------------
def _free_swing(n, theta0=0.1):
    """The counted oscillator (no dry friction) swinging free from ``theta0``: ``n``
    samples of zero force; its angle and speed exactly (k 40 N m/rad, c 0.5, inertia 1)."""
    t = np.arange(n) / 1024
    theta = damped_free_response(t, 40.0, 0.5, 1.0, theta0)
    return np.zeros(n), t, theta


@pytest.mark.numerics
def test_a_free_swing_is_stepped_over_several_samples_at_the_accuracy_of_one():
    """With no force (a door let go), one dopri5 step spans several sample periods and
    the samples inside it come from its dense output: a fraction of the six calls a
    sample costs stepped period by period, within 1e-8 rad of the exact swing (one
    step a period gives some 1e-11; the tolerance, 1e-7 per step, is what is asked);
    the acceleration at every sample is the model's at the reported state."""
    force, t, exact = _free_swing(4096)
    per_sample, (theta, dtheta, ddtheta) = _calls_per_sample(force, 0.0, 0.1, False)
    assert per_sample < 2.0, per_sample  # 1 of them the output's acceleration
    assert np.max(np.abs(theta - exact)) < 1e-8
    speed = np.gradient(exact, t)  # only a check that the speed is the swing's
    assert np.max(np.abs(dtheta[1:-1] - speed[1:-1])) < 2e-3
    p = np.array([40.0, 0.5, 0.0, 0.0])
    for k in (1, 5, 1001, 4095):
        assert ddtheta[k] == pytest.approx(counted_accel(theta[k], dtheta[k], 0.0, p), abs=1e-12)


@pytest.mark.numerics
def test_without_rates_a_step_over_several_samples_leaves_their_acceleration_out():
    """``rates=False`` (the objective's, unless it compares accelerations): the samples
    inside a step over several periods get NaN for their acceleration, at no call of the
    model each; every angle and speed and every other acceleration are the same to the
    bit as with the rates."""
    force, _, _ = _free_swing(4096)
    with_rates, (theta, dtheta, ddtheta) = _calls_per_sample(force, 0.0, 0.1, False)
    without, (theta2, dtheta2, ddtheta2) = _calls_per_sample(force, 0.0, 0.1, False, False)
    assert np.array_equal(theta, theta2) and np.array_equal(dtheta, dtheta2)
    inside = np.isnan(ddtheta2)
    assert 0.5 * force.size < inside.sum() < force.size  # most samples, never all
    assert not inside[0] and not inside[-1] and np.all(np.isfinite(ddtheta))
    assert np.array_equal(ddtheta[~inside], ddtheta2[~inside])
    calls_saved = round((with_rates - without) * (force.size - 1))
    assert calls_saved == inside.sum()  # one call of the model a sample left out


def _creep(n, c, theta0=0.1, k=40.0):
    """The counted oscillator overdamped (``c`` N m s/rad, inertia 1) creeping back from
    ``theta0`` at rest: zero force for ``n`` samples, and its angle and speed exactly."""
    t = np.arange(n) / 1024
    disc = np.sqrt(c * c - 4.0 * k)
    r1, r2 = 0.5 * (-c + disc), 0.5 * (-c - disc)  # the slow root and the stiff one
    a, b = theta0 * r2 / (r2 - r1), -theta0 * r1 / (r2 - r1)
    theta = a * np.exp(r1 * t) + b * np.exp(r2 * t)
    return np.zeros(n), theta, a * r1 * np.exp(r1 * t) + b * r2 * np.exp(r2 * t)


@pytest.mark.numerics
def test_a_stiff_creep_is_stepped_over_several_samples_by_the_l_stable_step():
    """A door creeping against a steep friction is stiff: an explicit step over several
    periods is held to some three of them by its stability (2.8 periods for a slope of
    1200 s^-1), not by its accuracy, and costs some 3.2 calls of the model a sample. There
    the span is a ROS2 step (``stiff_span_step``), as long as its error allows (up to
    sixteen periods): under 1.6 calls a sample (one the output's acceleration), the
    angle within 5e-9 rad and the speed within 5e-8 rad/s of the exact creep."""
    force, exact, speed = _creep(8192, 1200.0)
    per_sample, (theta, dtheta, ddtheta) = _calls_per_sample(force, 0.0, 0.1, False, damping=1200.0)
    assert per_sample < 1.6, per_sample
    assert np.max(np.abs(theta - exact)) < 5e-9
    assert np.max(np.abs(dtheta - speed)) < 5e-8
    p = np.array([40.0, 1200.0, 0.0, 0.0])
    for k in (1, 7, 1001, 8191):
        assert ddtheta[k] == pytest.approx(counted_accel(theta[k], dtheta[k], 0.0, p), abs=1e-12)


@pytest.mark.numerics
def test_a_creep_under_a_changing_force_is_left_to_dopri5():
    """The L-stable step spans only periods of a constant force (the problem autonomous,
    so that ROS2 keeps its order without the force's rate): under a ramp the same creep
    is stepped by ``dopri5`` as before, some three calls a sample, and as accurately."""
    force = 1e-3 * np.arange(8192) / 8192  # N: a ramp that barely moves the creep
    per_sample, (theta, _, _) = _calls_per_sample(force, 0.0, 0.1, False, damping=1200.0)
    assert 2.5 < per_sample < 4.0, per_sample
    base = np.array([40.0, 1200.0, 0.0, 0.0])
    ref_theta, _ = converged(counted_accel, base, force, DT, 0.1, bound=1e-8)
    assert np.max(np.abs(theta - ref_theta)) < 1e-8


@pytest.mark.numerics
@pytest.mark.parametrize("run, spans", [(3, False), (4, True)])
def test_a_force_that_kinks_every_few_samples_is_stepped_period_by_period(run, spans):
    """A step spans periods only where the force is linear over at least four of them
    (``MIN_SPAN``): a measured force's quantised noise makes three samples in a row
    collinear by chance, and a step there would change its numbers for nothing. A force
    that ramps up and down with a kink every ``run`` samples is stepped sample by sample
    (six calls a sample) at 3, over several samples at 4."""
    n = 4096
    k = np.arange(n)
    force = 0.5 * np.where((k // run) % 2 == 0, k % run, run - k % run)
    per_sample, _ = _calls_per_sample(force, 0.0, 0.1, False)
    assert (per_sample < 5.0) == spans, per_sample
