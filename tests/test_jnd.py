"""The psychophysics of a JND session, without a device: the psychometric function, its
fit against an independent reference, the procedures, the simulated participant, the
coverage of the interval over many sessions, and JND files read back and used."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest
from scipy import optimize, stats

from evo_door.errors import UserError
from evo_door.perception import JND
from evo_door.perception.jnd_file import (
    LITERATURE,
    is_jnd_file,
    measured_jnd,
    read_jnd_file,
    write_jnd_file,
)
from evo_door.perception.procedures import (
    JndSession,
    Quest,
    SimParticipant,
    Staircase,
    Stimulus,
    run_simulated,
)
from evo_door.perception.psychometric import Psychometric, fit_psychometric


def test_the_function_is_chance_at_no_step_75_percent_at_the_weber_fraction():
    f = Psychometric(0.1, slope=0.4, lapse=0.04)
    assert float(f.p_correct(1e-9)) == pytest.approx(0.5, abs=1e-9)
    assert float(f.p_correct(1e3)) == pytest.approx(1 - 0.04, abs=1e-9)
    # 75 % less half the lapse at the Weber fraction; the inverse takes it back
    assert float(f.p_correct(0.1)) == pytest.approx(0.75 - 0.02)
    for p in (0.6, 0.8, 0.9):
        assert float(f.p_correct(f.step_at(p))) == pytest.approx(p, rel=1e-12)
    with pytest.raises(UserError, match="between 0.5 and 0.96"):
        f.step_at(0.97)


@pytest.mark.parametrize(
    "bad", [dict(weber=0.0), dict(weber=0.1, slope=-1), dict(weber=0.1, lapse=0.5)]
)
def test_a_bad_function_is_refused(bad):
    with pytest.raises(UserError):
        Psychometric(**bad)


def _reference_fit(steps, correct):
    """The same maximum-likelihood problem solved independently: scipy.stats' binomial
    log-pmf, Nelder-Mead from many starts."""
    levels, inv = np.unique(steps, return_inverse=True)
    n = np.bincount(inv)
    k = np.bincount(inv, weights=correct).astype(int)

    def nll(x):
        lw, ls, lapse = x
        if not (math.log(1e-3) <= lw <= math.log(10) and 0.05 <= math.exp(ls) <= 2):
            return 1e9
        if not 0.0 <= lapse <= 0.06:
            return 1e9
        z = (np.log(levels) - lw) / math.exp(ls)
        p = 0.5 + (0.5 - lapse) * stats.norm.cdf(z)
        return -float(np.sum(stats.binom.logpmf(k, n, p)))

    best = None
    for lw0 in np.log([0.03, 0.1, 0.3]):
        for ls0 in np.log([0.2, 0.5, 1.0]):
            for a0 in (0.005, 0.03):
                r = optimize.minimize(
                    nll,
                    [lw0, ls0, a0],
                    method="Nelder-Mead",
                    options={"xatol": 1e-9, "fatol": 1e-12, "maxiter": 20000},
                )
                if best is None or r.fun < best.fun:
                    best = r
    return best


def test_the_fit_is_the_maximum_likelihood_an_independent_solver_finds():
    rng = np.random.default_rng(4)
    truth = Psychometric(0.12, slope=0.45, lapse=0.0)
    steps = np.repeat([0.02, 0.05, 0.08, 0.12, 0.2, 0.35, 0.6], 40)
    correct = rng.random(steps.size) < truth.p_correct(steps)
    fit = fit_psychometric(steps, correct)
    ref = _reference_fit(steps, correct)
    # the log-likelihoods agree (the binomial coefficient aside, a constant)
    const = float(
        np.sum(
            [
                math.lgamma(40 + 1) - math.lgamma(k + 1) - math.lgamma(40 - k + 1)
                for k in np.bincount(
                    np.unique(steps, return_inverse=True)[1], weights=correct
                ).astype(int)
            ]
        )
    )
    assert fit.log_likelihood + const == pytest.approx(-ref.fun, abs=1e-5)
    assert fit.weber == pytest.approx(math.exp(ref.x[0]), rel=2e-3)
    assert fit.slope == pytest.approx(math.exp(ref.x[1]), rel=1e-2)
    assert fit.covers(0.12) and fit.ci95[0] < fit.weber < fit.ci95[1]


def test_a_large_constant_stimuli_session_recovers_its_function():
    rng = np.random.default_rng(7)
    truth = Psychometric(0.2, slope=0.3, lapse=0.0)
    steps = np.repeat(np.geomspace(0.05, 0.8, 9), 300)
    correct = rng.random(steps.size) < truth.p_correct(steps)
    fit = fit_psychometric(steps, correct)
    assert fit.weber == pytest.approx(0.2, rel=0.05)
    assert fit.slope == pytest.approx(0.3, rel=0.2)
    assert fit.ci95[1] / fit.ci95[0] < 1.25  # 2700 answers pin it
    assert fit.open_ended == (False, False)


def test_answers_at_chance_leave_the_interval_open():
    """A participant who cannot tell any step apart does not bound the Weber fraction
    from above: the interval reaches the search's edge and says so."""
    rng = np.random.default_rng(1)
    steps = np.repeat([0.01, 0.02, 0.04], 20)
    fit = fit_psychometric(steps, rng.random(steps.size) < 0.5)
    assert fit.open_ended[1]


@pytest.mark.parametrize(
    "steps, correct, match",
    [([], [], "no answers"), ([0.1, -0.1], [1, 0], "above 0"), ([0.1], [1, 0], "one length")],
)
def test_the_fit_refuses_bad_answers(steps, correct, match):
    with pytest.raises(UserError, match=match):
        fit_psychometric(steps, correct)


def test_the_simulated_participant_answers_by_its_function():
    p = SimParticipant(0.1, slope=0.4, lapse=0.02, seed=3)
    n = 4000
    for order in (1, 2):
        s = Stimulus(0, 0.1, 10.0, 11.0, order)
        right = sum(p.answer(s) == order for _ in range(n))
        expected = float(p.function.p_correct(0.1))
        assert abs(right / n - expected) < 3 * math.sqrt(expected * (1 - expected) / n)
    # no difference: a coin
    same = Stimulus(0, 0.0, 10.0, 10.0, 1)
    ones = sum(p.answer(same) == 1 for _ in range(n))
    assert abs(ones / n - 0.5) < 0.03


@pytest.mark.parametrize(
    "spec, match",
    [
        ("person", "sim:WEBER"),
        ("sim:", "sim:WEBER"),
        ("sim:a", "numbers"),
        ("sim:0.1,1,0.1,2", "at most"),
        ("sim:0", "above 0"),
    ],
)
def test_a_bad_participant_is_refused(spec, match):
    with pytest.raises(UserError, match=match):
        SimParticipant.from_spec(spec)


def test_the_interval_order_is_random_and_the_values_follow_it():
    s = JndSession("viscous_damping", "N s/rad", 2.0, trials=200, seed=5, upper=100.0)
    p = SimParticipant(0.2, seed=6)
    orders = []
    while not s.done:
        stim = s.next_trial()
        assert s.next_trial() is stim  # the same trial until it is answered
        a, b = stim.values
        assert (a, b) == ((stim.comparison, 2.0) if stim.order == 1 else (2.0, stim.comparison))
        assert stim.comparison == pytest.approx(2.0 * (1 + stim.step))
        orders.append(stim.order)
        s.record(p.answer(stim), time=0.0)
    assert 80 < sum(o == 1 for o in orders) < 120
    t = s.table()
    assert t["correct"].tolist() == (t["answer"] == t["order"]).tolist()
    assert s.word == "more damped"


def test_the_same_seed_gives_the_same_session():
    def run(seed):
        s = JndSession("friction_closing", "N", 3.0, "quest", trials=30, seed=seed, upper=100.0)
        run_simulated(s, SimParticipant(0.1, seed=seed + 1))
        return s.table()

    a, b, c = run(1), run(1), run(2)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert not np.array_equal(a["order"], c["order"])


def test_a_three_down_staircase_hovers_at_79_percent():
    """Levitt (1971): 3-down 1-up converges where P(correct)^3 = 1/2, 79.4 %."""
    f = Psychometric(0.1, slope=0.4, lapse=0.0)
    target = f.step_at(0.5 ** (1 / 3))
    means = []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        st = Staircase(start=0.5, down=3)
        steps = []
        for _ in range(400):
            x = st.next_step()
            steps.append(x)
            st.update(x, bool(rng.random() < f.p_correct(x)))
        late = st.reversals[6:]
        means.append(math.exp(np.mean(np.log([steps[i] for i in late]))))
    assert math.exp(np.mean(np.log(means))) == pytest.approx(target, rel=0.15)


def test_quest_converges_on_the_threshold_it_assumes():
    f = Psychometric(0.07, slope=0.4, lapse=0.02)
    rng = np.random.default_rng(2)
    q = Quest(guess=0.3, sd=1.2, slope=0.4, lapse=0.02)
    for _ in range(300):
        x = q.next_step()
        q.update(x, bool(rng.random() < f.p_correct(x)))
    assert q.next_step() == pytest.approx(0.07, rel=0.15)
    assert q.state()["log_weber_sd"] < 0.15


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(reference=0.0), "above 0"),
        (dict(reference=-1.0), "above 0"),
        (dict(trials=5), "at least 10"),
        (dict(reference=98.0, upper=100.0), "within 5 %"),
        (dict(method="bisection"), "staircase, quest"),
    ],
)
def test_a_session_refuses_what_cannot_be_measured(kwargs, match):
    args = dict(param="p", unit="N", reference=3.0, upper=100.0)
    args.update(kwargs)
    with pytest.raises(UserError, match=match):
        JndSession(**args)


def test_a_session_refuses_answers_out_of_turn():
    s = JndSession("p", "N", 3.0, trials=10, upper=10.0)
    with pytest.raises(UserError, match="no trial is waiting"):
        s.record(1, 0.0)
    s.next_trial()
    with pytest.raises(UserError, match="1 or 2"):
        s.record(3, 0.0)


def test_the_step_never_leaves_the_parameter_bounds():
    s = JndSession("p", "N", 60.0, trials=40, seed=1, upper=100.0)
    run_simulated(s, SimParticipant(0.9, lapse=0.0, seed=1))  # needs big steps
    assert s.table()["comparison"].max() <= 100.0 + 1e-9


@pytest.mark.slow
@pytest.mark.parametrize("method", ["staircase", "quest"])
def test_the_interval_covers_the_truth_in_about_95_percent_of_sessions(method):
    """Over many simulated 80-trial sessions the estimate is unbiased within 10 % and
    the 95 % interval covers the participant's Weber fraction in at least 88 % of them
    (binomial spread of 60 sessions around 95 %: about 3 %)."""
    truth, n = 0.15, 60
    estimates, covered = [], 0
    for seed in range(n):
        s = JndSession("p", "N", 10.0, method, trials=80, seed=seed, upper=100.0)
        fit = run_simulated(s, SimParticipant(truth, seed=10_000 + seed))
        estimates.append(fit.weber)
        covered += fit.covers(truth)
    assert covered / n >= 0.88
    assert float(np.exp(np.median(np.log(estimates)))) == pytest.approx(truth, rel=0.10)


def _session_file(path, weber, unit="N", param="friction_closing", status="complete", seed=1):
    s = JndSession(param, unit, 4.0, "quest", trials=80, seed=seed, upper=100.0)
    fit = run_simulated(s, SimParticipant(weber, seed=seed))
    write_jnd_file(
        path,
        s,
        fit,
        status=status,
        participant=f"sim:{weber}",
        device="none",
        model="haptic",
        reference_params={param: 4.0},
        settings={"trials": 80},
        seed=seed,
        created="2026-11-26T00:00:00Z",
        wall_s=0.0,
        versions={"numpy": np.__version__},
    )
    return s, fit


def test_a_jnd_file_reads_back_whole(tmp_path):
    path = tmp_path / "j.h5"
    s, fit = _session_file(path, 0.1)
    assert is_jnd_file(path) and not is_jnd_file(tmp_path / "none.h5")
    r = read_jnd_file(path)
    assert (r.param, r.unit, r.word, r.reference, r.method) == (
        "friction_closing",
        "N",
        "stronger",
        4.0,
        "quest",
    )
    assert r.fit == fit and r.setting == "force" and r.complete
    t = s.table()
    assert all(np.array_equal(r.trials[k], t[k]) for k in t)
    assert r.summary()["ci95"] == list(fit.ci95) and r.summary()["trials"] == 80
    with h5py.File(path) as f:
        assert f["jnd/trials/time"].attrs["unit"] == "s"
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["format"] = "evo-door trials"
    assert not is_jnd_file(other)
    with pytest.raises(UserError, match="not a JND file"):
        read_jnd_file(other)


def test_measured_jnds_replace_the_literature_with_their_sources(tmp_path):
    _, f1 = _session_file(tmp_path / "a.h5", 0.05, seed=1)
    _, f2 = _session_file(tmp_path / "b.h5", 0.05, seed=2)
    _, f3 = _session_file(tmp_path / "c.h5", 0.3, unit="N s/rad", param="viscous_damping")
    table = {"inertia": {"weber": 0.12, "source": "lab study, 12 participants"}}
    jnd, sources = measured_jnd(
        JND(), [tmp_path / "a.h5", tmp_path / "b.h5", tmp_path / "c.h5"], table
    )
    assert jnd.force == pytest.approx(math.sqrt(f1.weber * f2.weber))
    assert jnd.viscosity == pytest.approx(f3.weber) and jnd.inertia == 0.12
    assert jnd.stiffness == JND().stiffness and jnd.force_floor == JND().force_floor
    assert sources["stiffness"] == LITERATURE and sources["inertia"] == "lab study, 12 participants"
    assert sources["force"].startswith("geometric mean of 2") and "a.h5" in sources["force"]
    assert "viscous_damping at 4 N s/rad" in sources["viscosity"]


def test_unusable_jnd_files_and_tables_are_refused(tmp_path):
    _session_file(tmp_path / "stopped.h5", 0.1, status="stopped")
    _session_file(tmp_path / "angle.h5", 0.1, unit="rad", param="loose_angle")
    _session_file(tmp_path / "force.h5", 0.1)
    with pytest.raises(UserError, match="stopped; only a complete one"):
        measured_jnd(JND(), [tmp_path / "stopped.h5"])
    with pytest.raises(UserError, match="loose_angle is in rad"):
        measured_jnd(JND(), [tmp_path / "angle.h5"])
    with pytest.raises(UserError, match="also set by a JND file"):
        measured_jnd(JND(), [tmp_path / "force.h5"], {"force": {"weber": 0.1}})
    for bad, match in [
        ({"speed": {"weber": 0.1}}, "not a Weber fraction setting"),
        ({"force": {"weber": 1.5}}, "between 0 and 1"),
        ({"force": 0.1}, "expected {weber"),
        ({"force": {"weber": 0.1, "sauce": "x"}}, "expected {weber"),
    ]:
        with pytest.raises(UserError, match=match):
            measured_jnd(JND(), (), bad)
