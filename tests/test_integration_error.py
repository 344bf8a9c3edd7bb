"""Every run states its integration error: estimated a posteriori at the refined settings,
stored in the results file, shown beside the fit error, flagged when it is not small."""

import json
import re

import h5py
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from evo_door.data.io import write_trials
from evo_door.experiment import ExperimentRun, Results, load_experiment, run_experiment
from evo_door.experiment.integration_error import estimate
from evo_door.experiment.reader import read_run
from evo_door.experiment.setup import resolve
from evo_door.files import reseal
from evo_door.reporting.format_text import format_show
from tests.conftest import OSCILLATOR_MODEL
from tests.test_cli import cli
from tests.test_experiment import EXPERIMENT
from tests.test_optim import make_trial

SMALL = ["algorithm.generations=2", "algorithm.polish=none"]


@pytest.fixture()
def folder(tmp_path):
    """The oscillator experiment of test_experiment on trials with 1 % sensor noise: a
    fit error far above rk4's integration error at 1024 Hz."""
    trials = [make_trial(s, 0.75, tid=f"t{s}", noise=0.01) for s in (1, 2, 3)]
    trials.append(make_trial(4, 0.75, tid="v1", noise=0.01))
    write_trials(tmp_path / "trials.h5", trials)
    (tmp_path / "exp.yaml").write_text(EXPERIMENT)
    return tmp_path


def test_a_run_stores_its_integration_error_and_show_prints_it_with_units(folder, capsys):
    out = folder / "run.h5"
    ran = cli(capsys, "run", folder / "exp.yaml", "--out", out, "--quiet", *_sets(SMALL))
    assert ran.returncode == 0, ran.stderr
    with h5py.File(out) as f:
        g = f["integration_error"]
        ids = json.loads(g.attrs["trial_ids"].removeprefix("json:"))
        assert ids == ["t1", "t2", "t3", "v1"] and g["channel_rms"].shape == (4,)
        assert g["theta_max"].attrs["unit"] == "rad" and g["dtheta_max"].attrs["unit"] == "rad/s"
        assert g["error"].attrs["unit"] == "(rad/s)^2 s" and g["ok"][()].all()
        assert g.attrs["method"] == "rk4" and g.attrs["refined_substeps"] == 2
        assert f["setup"].attrs["tolerance"] == OSCILLATOR_MODEL.tolerance
        assert f["timings"].attrs["integration_error_s"] > 0
    shown = cli(capsys, "show", out)
    assert shown.returncode == 0, shown.stderr
    text = shown.stdout
    # beside the fit error: after the fit errors, before the identifiability check
    assert text.index("fit error per trial") < text.index("integration error of the answer")
    assert text.index("integration error of the answer") < text.index("identifiability")
    assert "(rk4, 1 substep per sample, against 2 substeps)" in text
    assert "  simulation rk4, 1 substep per sample" in text
    for pattern in (
        r"objective [0-9.e+-]+ \(rad/s\)\^2 s at the run's settings, [0-9.e+-]+ \(rad/s\)\^2 s",
        r"largest change: theta [0-9.e+-]+ rad, dtheta [0-9.e+-]+ rad/s",
        r"v1 +[0-9.e+-]+, [0-9.e+-]+ rad/s against [0-9.e+-]+ rad/s \([0-9.e+-]+ %\)  "
        r"\(validation\)",
    ):
        assert re.search(pattern, text), pattern
    assert "warning:" not in text
    doc = json.loads(cli(capsys, "show", out, "--json").stdout)
    e = doc["integration_error"]
    assert doc["simulation"] == {"method": "rk4", "substeps": 1, "tolerance": 1e-7}
    assert e["refined"] == {"method": "rk4", "substeps": 2, "tolerance": 1e-7 / 32}
    assert e["units"]["channel_max"] == "rad/s" and e["units"]["objective_change"] == "1"
    assert set(e["trials"]) == {"t1", "t2", "t3", "v1"} and e["warning"] is None
    assert e["trials"]["v1"]["role"] == "validate"
    # the run's objective is the fitness the run reports, recomputed
    assert e["objective"] == pytest.approx(doc["fitness"], rel=1e-9)
    for trial, error in doc["fit_errors"].items():
        assert e["trials"][trial]["error"] == pytest.approx(error, rel=1e-9)
    # rk4 at 1024 Hz on an 8 rad/s oscillator: far below the 1 % noise the fit sees
    assert 0 < e["dtheta_max"] < 1e-6 and abs(e["objective_change"]) < 1e-6


def _sets(overrides):
    return [a for o in overrides for a in ("--set", o)]


def test_the_estimate_is_the_difference_of_the_runs_simulation_and_the_refined_one(folder):
    """Recomputed with the public simulate() at both settings, for each trial's own
    fit (per_trial): the stored numbers are those of the right parameters."""
    from evo_door.sim import simulate

    exp = load_experiment(folder / "exp.yaml", [*SMALL, "per_trial=true"])
    run = run_experiment(exp, folder / "p.h5")
    stored = read_run(run.path).integration_error
    model = OSCILLATOR_MODEL
    fits = {job.name: job.best_x for job in run.jobs}
    shown = {tr.trial_id: (tr, fits[tr.trial_id]) for tr in run.setup.fit}
    shown["v1"] = (run.setup.validation[0], run.result["best_x"])
    assert stored.trial_ids == ["t1", "t2", "t3", "v1"]
    for k, trial_id in enumerate(stored.trial_ids):
        tr, x = shown[trial_id]
        p = run.setup.problem().full(x)[0]
        theta0, dtheta0 = tr.initial_state()
        kwargs = dict(theta0=theta0, dtheta0=dtheta0, t0=float(tr.t[0]), method="rk4")
        a = simulate(model, p, tr.force, tr.dt, substeps=1, **kwargs)
        b = simulate(model, p, tr.force, tr.dt, substeps=2, **kwargs)
        assert stored.theta_max[k] == pytest.approx(np.abs(a.theta - b.theta).max(), rel=1e-12)
        assert stored.dtheta_max[k] == pytest.approx(np.abs(a.dtheta - b.dtheta).max(), rel=1e-12)
        residual = a.dtheta - tr.dtheta
        assert stored.residual_rms[k] == pytest.approx(np.sqrt(np.mean(residual**2)), rel=1e-12)
    # a per_trial run's objective combines each trial's own fit, as its fitness does
    assert stored.objective == pytest.approx(Results(run.path).fitness(), rel=1e-9)


def _exact_oscillator(tr, params) -> np.ndarray:
    """The oscillator's angle under the sampled force, linear between samples as the
    integrators take it: scipy's DOP853 at rtol 1e-12, one sample period at a time."""
    k, c, inertia, theta_eq = params

    def rhs(t, y, t0, f0, f1):
        force = f0 + (f1 - f0) * (t - t0) / tr.dt
        return [y[1], (-k * (y[0] - theta_eq) - c * y[1] + force) / inertia]

    y = np.array([tr.theta0, 0.0])
    out = [y[0]]
    for n in range(tr.n - 1):
        t0 = float(tr.t[n])
        sol = solve_ivp(
            rhs,
            (t0, t0 + tr.dt),
            y,
            method="DOP853",
            rtol=1e-12,
            atol=1e-14,
            args=(t0, tr.force[n], tr.force[n + 1]),
        )
        y = sol.y[:, -1]
        out.append(y[0])
    return np.array(out)


def test_the_estimate_is_close_to_the_true_integration_error(tmp_path):
    """rk4 at a coarse 64 Hz on the oscillator: the difference to twice the substeps is
    15/16 of the true error (order 4), which scipy gives independently."""
    truth = {"k": 100.0, "c": 2.0, "inertia": 1.5}
    tr = make_trial(7, 1.0, dt=1 / 64, params=truth, tid="t7")
    write_trials(tmp_path / "trials.h5", [tr])
    text = EXPERIMENT.replace("validate: [v1]", "validate: []")
    (tmp_path / "exp.yaml").write_text(text)
    setup = resolve(load_experiment(tmp_path / "exp.yaml"))
    x = np.array([truth["k"], truth["c"], truth["inertia"]])
    found = estimate(setup, [x], x)
    rk4 = setup.problem().responses(x)[0].theta
    true_error = np.abs(rk4 - _exact_oscillator(tr, [*x, 0.0])).max()
    assert 1e-8 < true_error < 1e-3  # measurable, and rk4 still in its asymptotic range
    assert found.theta_max[0] / true_error == pytest.approx(15 / 16, abs=0.03)


def test_simulation_tolerance_reaches_the_problem_and_the_record(folder):
    exp = load_experiment(folder / "exp.yaml", ["simulation.tolerance=2e-5"])
    assert exp.resolved()["simulation"] == {"method": "rk4", "substeps": 1, "tolerance": 2e-5}
    run = ExperimentRun.new(exp, folder / "r.h5")
    assert run.setup.problem().tolerance == 2e-5
    assert run.setup.refined().tolerance == 2e-5 / 32 and run.setup.refined().substeps == 2
    default = load_experiment(folder / "exp.yaml")
    assert default.tolerance == OSCILLATOR_MODEL.tolerance


def _haptic_unlock_experiment(tmp_path, overrides):
    """The haptic model's unlock force fitted to two noisy rig trials of its own unlock
    (the latch crossed in each): a fit at the inclinometer's noise."""
    from evo_door.data.rig import trials_from_spec

    spec = {"model": "haptic", "params": "seed_trial", "users": 1, "trials": 2, "seed": 1}
    trials = trials_from_spec({**spec, "kinds": ["unlock"]})
    write_trials(tmp_path / "unlock.h5", trials)
    (tmp_path / "h.yaml").write_text("""\
name: unlock
model: haptic
params: seed_trial
target: {data: unlock.h5}
free: {open_force: [19.9, 20.1]}
objective: {kind: ise, derivative: 0}
algorithm: {population: 6, generations: 1, seed: 1}
""")
    return load_experiment(tmp_path / "h.yaml", overrides)


@pytest.mark.parametrize(
    "overrides, warned",
    [
        ([], False),  # dopri5, tolerance 1e-7: the haptic model's defaults
        # ROS2, one step per sample: second order across the latch's snap (a change of
        # the objective of some 20 %; rk4 x 1 and dopri5 at a loose tolerance, with the
        # surfaces located, stay under the 1 % rule on these trials)
        (["simulation.method=semi_implicit", "simulation.substeps=1"], True),
    ],
)
def test_coarse_settings_get_the_warning_and_the_defaults_do_not(tmp_path, overrides, warned):
    run = run_experiment(_haptic_unlock_experiment(tmp_path, overrides), tmp_path / "h.h5")
    res = Results(run.path)
    e = res.summary()["integration_error"]
    text = format_show(res)
    warnings = [line for line in text.splitlines() if line.startswith("warning:")]
    if not warned:
        assert e["warning"] is None and not warnings
        assert abs(e["objective_change"]) < 0.01
        return
    assert len(warnings) == 1 and warnings[0] == f"warning: {e['warning']}"
    assert "the integration error is not small against the fit error" in e["warning"]
    assert abs(e["objective_change"]) > 0.01  # the 1 % rule fired
    assert "simulation.substeps: " in e["warning"]  # and it says what to try


@pytest.mark.slow
def test_a_file_without_the_estimate_shows_not_recorded(folder, capsys, tmp_path):
    exp = load_experiment(folder / "exp.yaml", SMALL)
    out = run_experiment(exp, folder / "old.h5").path
    with h5py.File(out, "r+") as f:  # as a file written before the estimate existed
        del f["integration_error"]
        del f["setup"].attrs["tolerance"]
        reseal(f)
    record = read_run(out)
    assert record.integration_error is None and record.settings.tolerance is None
    shown = cli(capsys, "show", out)
    assert shown.returncode == 0, shown.stderr
    assert "integration error: not recorded" in shown.stdout and "warning:" not in shown.stdout
    assert "simulation rk4, 1 substep per sample" in shown.stdout
    doc = json.loads(cli(capsys, "show", out, "--json").stdout)
    assert doc["integration_error"] is None and doc["simulation"]["tolerance"] is None
    # the other views read it as well: a report, a comparison with a new run
    new = run_experiment(load_experiment(folder / "exp.yaml", SMALL), folder / "new.h5").path
    assert cli(capsys, "compare", out, new).returncode == 0
    assert cli(capsys, "report", out, "--out", tmp_path / "rep").returncode == 0
    assert "integration error: not recorded" in (tmp_path / "rep" / "report.html").read_text()


@pytest.mark.slow
def test_each_stage_of_a_pipeline_states_its_own(tmp_path, capsys):
    from tests.test_pipeline import PIPELINE, run_pipeline

    trials = [make_trial(s, 0.75, tid=f"t{s}") for s in (1, 2, 3)] + [make_trial(4, 0.75, tid="v1")]
    write_trials(tmp_path / "trials.h5", trials)
    (tmp_path / "pipe.yaml").write_text(PIPELINE)
    out = run_pipeline(tmp_path).path
    text = cli(capsys, "show", out).stdout
    stages = text.split("== stage ")[1:]
    assert len(stages) == 2
    for stage in stages:
        assert "integration error of the answer, a posteriori (rk4" in stage
    doc = json.loads(cli(capsys, "show", out, "--json").stdout)
    for stage in doc["stage_results"].values():
        e = stage["integration_error"]
        assert e["method"] == "rk4" and set(e["trials"]) >= set(stage["fit_errors"])
    report = cli(capsys, "report", out, "--out", tmp_path / "rep")
    assert report.returncode == 0, report.stderr
    html = (tmp_path / "rep" / "report.html").read_text()
    assert html.count("integration error of the answer") == 2


@pytest.mark.parametrize("scale", [1e-200, 1e-3, 1.0, 1e200])
def test_the_rms_of_any_finite_numbers_is_a_number_without_a_warning(scale):
    """A damaged file's numbers as large as 1e200 (their squares overflow) or as small as
    1e-200 (they vanish): the RMS is still theirs, printed without a RuntimeWarning
    (which a user would have read as a second line)."""
    import warnings

    from evo_door.experiment.integration_error import _rms

    values = scale * np.array([3.0, -4.0, 0.0, 5.0, 12.0])
    mask = np.array([True, True, False, False, False])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _rms(values, mask) == pytest.approx(scale * np.sqrt(12.5), rel=1e-15, abs=0.0)
        assert _rms(np.zeros(3), np.ones(3, bool)) == 0.0
        assert _rms(values, np.zeros(5, bool)) != _rms(values, np.zeros(5, bool))  # NaN
        assert _rms(np.array([np.inf, 1.0]), np.ones(2, bool)) == np.inf
