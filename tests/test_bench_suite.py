"""The benchmark suite (``python -m benchmarks``): a quick run writes its JSON and
figure, ``--compare`` prints new / old per metric, bad options are one-line errors."""

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

#: the sections whose quick run is the main job itself (each some 25 s): casestudy's
#: run by its own test, seeds' runs stood in for by a small pipeline
MAIN_JOB_SECTIONS = ("casestudy", "seeds")
#: sections with a test of their own below (the FMU's needs CMake and FMPy; trial and
#: control, the longest quick sections, are not run a second time in the quick run)
OWN_TEST_SECTIONS = ("fmu", "trial", "control")
#: their metrics
MAIN_JOB_REQUIRED = (
    "casestudy.wall",
    "casestudy.physical.seconds",
    "casestudy.physical.M.error",
    "casestudy.latch.unlock_force.error",
    "casestudy.redesign.fitness",
    "casestudy.specification.perceptual.opening",
    "casestudy.haptic.perceptual.closing",
    "casestudy.haptic_latch.perceptual.closing",
    "casestudy.specification.yield",
    "casestudy.specification.yield.independent",
)
#: metrics the trial section's quick run has (its own test)
REQUIRED_TRIAL = (
    "trial.door.workbench",
    "trial.door.rk45_compiled",
    "trial.door.lsoda_compiled",
    "trial.door.rk45_python",
    "trial.door.lsoda_python",
    "trial.door.workbench.error_dtheta",
    "trial.door.lsoda_compiled.error_theta",
    "trial.haptic.workbench",
    "trial.haptic.rk45_compiled",
    "trial.haptic.lsoda_python",
)
#: metrics every other section's quick run has (the ratios and targets the suite states)
REQUIRED = (
    "ga.door.workbench",
    "ga.door.plain",
    "ga.haptic.workbench",
    "ga.haptic.plain",
    "scaling.population.25",
    "scaling.trials.1",
    "scaling.trials.2",
    "scaling.generations.flatness",
    "scaling.threads.1",
    "executors.local",
    "executors.processes",
    "device.force_python",
    "device.force_compiled",
    "device.servo.on_time",
    "device.log.final_per_hour",
    "startup.help",
    "startup.params_haptic",
    "jnd.staircase.40.within",
    "jnd.quest.40.coverage",
    "jnd.quest.40.bias",
)


#: the main job of the casestudy section's smoke run, smaller still than --quick makes it
#: (benchmarks.bench_casestudy.QUICK_EXTRA_ENV): the same six stages and checks, the
#: latch and redesign scans on 3 points polished from one start, the haptic stages on 3
#: of the users' trials
SMALLER_MAIN_JOB = " ".join(
    (
        "stages.latch.algorithm.scan=3",
        "stages.latch.algorithm.starts=1",
        "stages.redesign.algorithm.scan=3",
        "stages.redesign.algorithm.starts=1",
        "stages.haptic.target.inputs.trials=3",
        "stages.haptic_latch.algorithm.scan=3",
        "stages.haptic_latch.target.inputs.trials=3",
    )
)


def bench(*args, timeout=600, env=None):
    return subprocess.run(
        [sys.executable, "-m", "benchmarks", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout,
        env=None if env is None else {**os.environ, **env},
    )


def suite_doc(metrics):
    return {
        "date": "2026-01-01T00:00:00",
        "machine_line": "test",
        "metrics": [
            {"name": n, "value": v, "unit": "s", "section": n.split(".")[0]} for n, v in metrics
        ],
    }


@pytest.mark.slow
def test_quick_run_writes_json_with_every_metric_and_a_png(tmp_path):
    from benchmarks.suite import SECTIONS

    others = [s for s in SECTIONS if s not in MAIN_JOB_SECTIONS + OWN_TEST_SECTIONS]
    done = bench("--quick", "--only", ",".join(others), "--out", str(tmp_path), timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    (js,) = tmp_path.glob("suite-*.json")
    png = js.with_suffix(".png")  # the suite's figure (the work-precision one beside it)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    doc = json.loads(js.read_text())
    assert doc["quick"] is True and doc["machine"]["cpus"] >= 1
    assert doc["machine"]["versions"]["numba"]
    metrics = {m["name"]: m for m in doc["metrics"]}
    missing = [n for n in REQUIRED if n not in metrics]
    assert not missing, missing
    check_pathsim_section(metrics)
    for m in metrics.values():
        assert set(m) >= {"name", "value", "unit", "ratio", "target", "met"}
    # the plain GA is slower than the workbench's, its ratio says by how much
    m = metrics["ga.door.plain"]
    assert m["ratio_to"].endswith(".workbench")
    assert m["ratio"] == pytest.approx(m["value"] / metrics[m["ratio_to"]]["value"])
    assert m["ratio"] > 1
    # the targets carry their verdict
    for name in ("startup.help", "startup.params_haptic"):
        assert metrics[name]["target"] is not None and isinstance(metrics[name]["met"], bool)
    # every section announced its progress, the table was printed
    for section in others:
        assert f"{section} done in" in done.stderr
    assert "## Targets" in done.stdout
    # and a run compares with it
    again = bench("--compare", str(js), str(js))
    assert again.returncode == 0, again.stderr
    assert "ga.door.workbench" in again.stdout and "1.000" in again.stdout


def check_pathsim_section(metrics) -> None:
    """The PathSim side by side: measured where PathSim is installed (the test extra has
    it), else skipped with its one-line reason."""
    m = metrics["pathsim.trial.speedup"]
    if importlib.util.find_spec("pathsim") is None:
        assert m["value"] is None and m["note"].startswith("skipped: PathSim is not installed")
        return
    assert m["value"] > 1 and m["target_text"] == ">= 100x" and isinstance(m["met"], bool)
    for tool in ("workbench", "pathsim"):
        assert metrics[f"pathsim.trial.{tool}.error_x"]["value"] <= 1e-6
        assert metrics[f"pathsim.trial.{tool}.error_v"]["value"] <= 1e-5
    ga = metrics["pathsim.ga.pathsim"]
    assert ga["ratio_to"] == "pathsim.ga.workbench" and ga["ratio"] > 1


@pytest.mark.slow
def test_control_section_floods_a_render_and_reads_its_log(tmp_path):
    """The control section's code path: a render in its own process, 200 clients, the
    figures from its log; each limit was met by the flood (it refused something of
    each kind) and the log kept its session events within the cap."""
    done = bench("--quick", "--only", "control", "--out", str(tmp_path), timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    (js,) = tmp_path.glob("suite-*.json")
    metrics = {m["name"]: m for m in json.loads(js.read_text())["metrics"]}
    for name in ("control.flood.memory_growth", "control.flood.events_kept"):
        assert metrics[name]["value"] is not None, name
    flood = metrics["control.flood.on_time"]
    assert flood["target"] is None and flood["target_text"] == ">= 99.9 %"
    assert isinstance(flood["met"], bool) and 0 < flood["value"] <= 100
    assert 0 < metrics["control.alone.on_time"]["value"] <= 100
    for kind in ("ok", "refused_client_cap", "refused_input"):
        assert metrics[f"control.flood.{kind}"]["value"] > 0, kind
    # whether a 4 s flood fills the log's cap depends on how busy the machine is (the
    # cap itself: test_render_control.py); what the log kept is within it either way
    assert 0 < metrics["control.flood.events_kept"]["value"] <= 10_000
    assert metrics["control.flood.events_kept"]["met"] is True
    dropped = metrics["control.flood.events_dropped"]["value"]
    assert (dropped > 0) == (metrics["control.flood.refused_log_cap"]["value"] > 0)
    assert "## control" in done.stdout and "control done in" in done.stderr


def test_compare_prints_new_over_old_per_metric(tmp_path):
    old, new = tmp_path / "old.json", tmp_path / "new.json"
    old.write_text(json.dumps(suite_doc([("trial.door.workbench", 0.006), ("only.old", 1.0)])))
    new.write_text(json.dumps(suite_doc([("trial.door.workbench", 0.003), ("only.new", 1.0)])))
    done = bench("--compare", str(old), str(new), timeout=120)
    assert done.returncode == 0, done.stderr
    (row,) = [line for line in done.stdout.splitlines() if line.startswith("trial.door")]
    assert row.split()[-1] == "0.500"
    assert "6 ms" in row and "3 ms" in row
    assert "only.new" in done.stdout and "only.old" in done.stdout  # in one run only


@pytest.mark.parametrize(
    "args, words",
    [
        (["--only", "trial,bogus"], "unknown section 'bogus'"),
        (["--compare", "missing.json", "other.json"], "no such file"),
    ],
)
def test_bad_options_are_one_line_errors(tmp_path, args, words):
    done = bench(*args, "--out", str(tmp_path), timeout=120)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("benchmarks: error:")
    assert words in lines[0]
    assert not list(tmp_path.iterdir())  # nothing ran, nothing written


def test_compare_refuses_a_file_that_is_not_a_suite(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"metrics": 3}')
    done = bench("--compare", str(bad), str(bad), timeout=120)
    assert done.returncode == 2
    assert (
        done.stderr.strip() == f"benchmarks: error: {bad}: not a suite JSON file (no metrics list)"
    )


def test_evo_door_bench_runs_the_suite_of_the_checkout():
    done = subprocess.run(
        [sys.executable, "-m", "evo_door", "bench", "--only", "nope"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert done.returncode == 2
    assert done.stderr.strip().startswith("evo-door: error: --only: unknown section 'nope'")


@pytest.mark.slow
def test_casestudy_section_runs_the_main_job_and_leaves_the_quoted_figures_alone(tmp_path):
    pages = [ROOT / "benchmarks" / "casestudy.md", ROOT / "benchmarks" / "seeds.md"]
    pages.append(ROOT / "docs" / "case-study.md")
    before = [p.read_bytes() if p.exists() else None for p in pages]
    from benchmarks.bench_casestudy import QUICK_EXTRA_ENV

    small = {QUICK_EXTRA_ENV: SMALLER_MAIN_JOB}
    done = bench("--quick", "--only", "casestudy", "--out", str(tmp_path), timeout=900, env=small)
    assert done.returncode == 0, done.stderr[-2000:]
    (js,) = tmp_path.glob("suite-*.json")
    doc = json.loads(js.read_text())
    metrics = {m["name"]: m for m in doc["metrics"]}
    missing = [n for n in MAIN_JOB_REQUIRED if n not in metrics]
    assert not missing, missing
    stages = ("physical", "latch", "haptic", "haptic_latch", "specification", "redesign")
    for stage in stages:
        assert metrics[f"casestudy.{stage}.seconds"]["value"] > 0
        assert metrics[f"casestudy.{stage}.evaluations"]["value"] > 0
    # the stages fitted to the virtual door's trials are scored against its truth
    error = metrics["casestudy.physical.F_load.error"]
    assert error["unit"] == "%"
    truth = 101.45  # the default door's pre-load, which made the bundled trials
    value = metrics["casestudy.physical.F_load"]["value"]
    assert error["value"] == pytest.approx(100 * (value - truth) / truth)
    assert metrics["casestudy.wall"]["value"] >= metrics["casestudy.total"]["value"]
    assert doc["machine"]["cpu"]
    assert "| physical | F_load |" in done.stdout and "--quick" in done.stdout
    # a smoke run is no measurement: the figures the docs quote stay as they were
    assert [p.read_bytes() if p.exists() else None for p in pages] == before


def test_casestudy_markdown_states_each_estimate_against_the_truth():
    from benchmarks.bench_casestudy import markdown

    def param(name, value, true, unit="N"):
        return {
            "name": name,
            "unit": unit,
            "value": value,
            "true": true,
            "error_pct": None if true is None else 100 * (value - true) / true,
            "ci_pct": 2.0,
            "verdict": "identifiable",
            "partner": "",
            "partner_r": None,
        }

    stage = {
        "stage": "physical",
        "model": "door",
        "seconds": 12.3,
        "evaluations": 2100,
        "fitness": 1e-5,
        "fitness_unit": "(rad/s)^2 s",
        "channel": "dtheta",
        "channel_unit": "rad/s",
        "rms_fit": [0.02, 0.03],
        "rms_validation": [0.04],
        "params": [param("F_load", 103.0, 100.0), param("M", 1.2, 1.25, "kg")],
    }
    free = dict(stage, stage="haptic", params=[param("inertia", 1.1, None, "kg m")])
    text = markdown({"wall": 65.4, "total": 60.1, "stages": [stage, free], "perceptual": None})
    assert "**65 s**" in text and "own time 60 s" in text
    assert "| physical | F_load | - | 103 N | 100 N | +3.00 % | +-2 % | identifiable |" in text
    assert "| physical | M | - | 1.2 kg | 1.25 kg | -4.00 % |" in text
    assert "| haptic | inertia | - | 1.1 kg m | - | - |" in text
    assert "Largest error against the truth: 4.00 %." in text
    assert "0.02 .. 0.03 rad/s (dtheta)" in text


def test_evo_door_bench_help_names_every_section():
    from benchmarks.suite import SECTIONS

    done = subprocess.run(
        [sys.executable, "-m", "evo_door", "bench", "--help"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert ", ".join(SECTIONS) in " ".join(done.stdout.split())


def test_the_render_log_growth_is_measured_and_the_log_is_compressed(tmp_path, seed_trial):
    """The figure the README gives for the log's growth per hour comes from here."""
    from benchmarks.bench_render import log_growth
    from evo_door.render.log import N_COLUMNS

    g = log_growth(seed_trial, 2.0, tmp_path)
    # the side file: float64 rows, 1000 an s, plus its header
    assert 3600 * 1000 * N_COLUMNS * 8 <= g["partial"] < 1.1 * 3600 * 1000 * N_COLUMNS * 8
    assert g["final"] < 0.5 * g["partial"]  # float32, shuffled, compressed
    assert 0 < g["held"] < 10e6 and list(tmp_path.iterdir()) == []


def damped_oscillator(t, k=1e4, c=10.0, theta0=0.1):
    """Exact ``(theta, dtheta)`` of ``ddtheta = -k theta - c dtheta`` from rest at ``theta0``."""
    a = -0.5 * c
    wd = np.sqrt(k - a * a)
    b = -a * theta0 / wd
    theta = np.exp(a * t) * (theta0 * np.cos(wd * t) + b * np.sin(wd * t))
    dtheta = np.exp(a * t) * (
        (a * theta0 + wd * b) * np.cos(wd * t) + (a * b - wd * theta0) * np.sin(wd * t)
    )
    return theta, dtheta


@pytest.mark.parametrize("method", ["RK45", "LSODA"])
def test_the_plain_way_converges_to_the_exact_oscillator_as_rtol_tightens(method):
    from benchmarks.plain import run_plain
    from tests.conftest import oscillator_accel

    dt = 1 / 1024
    t = dt * np.arange(2048)
    exact = damped_oscillator(t)
    p = np.array([1e4, 10.0, 1.0, 0.0])
    errors = {}
    for rtol in (1e-3, 1e-9):
        run = run_plain(oscillator_accel, p, dt, np.zeros(t.size), (0.1, 0.0), method, rtol=rtol)
        assert run.complete and run.stopped == "" and run.reached == pytest.approx(t[-1])
        errors[rtol] = np.abs(run.theta - exact[0]).max(), np.abs(run.dtheta - exact[1]).max()
    assert errors[1e-9][0] < 1e-8 and errors[1e-9][1] < 1e-6  # rad, rad/s
    assert errors[1e-3][1] > 100 * errors[1e-9][1]  # rtol reaches the solver


def test_a_plain_run_past_its_time_limit_gives_no_answer():
    from benchmarks.plain import run_plain
    from tests.conftest import oscillator_accel

    p = np.array([1e4, 10.0, 1.0, 0.0])
    run = run_plain(oscillator_accel, p, 1 / 1024, np.zeros(64), (0.1, 0.0), "RK45", time_limit=0.0)
    assert not run.complete and run.stopped == "time limit" and run.reached == 0.0
    assert np.isnan(run.theta).all() and np.isnan(run.dtheta).all()


def bench_trial(model, key, latch, legacy=False):
    from benchmarks.precision import BenchTrial

    return BenchTrial(
        model, key, "a trial", "default", np.zeros(8), 1 / 1024, 0.0, 0.0, latch, legacy
    )


def test_trial_points_keep_the_earlier_names_and_are_judged_as_printed():
    from benchmarks.precision import Point
    from benchmarks.precision_report import record
    from benchmarks.suite import Suite, targets_table

    suite = Suite(quick=False)
    smooth = bench_trial("door", "smooth", latch=False, legacy=True)
    points = [
        Point("default", "rk4 x2", "default", 2.6849e-3, 31, (2.5249e-8, 1.2851e-5, 1e-7)),
        Point("LSODA", "rtol 1e-06", "lsoda.rtol1e-06", 0.06, 3, (1e-7, 1e-6, 1e-7)),
        Point("rk4", "x4", "rk4.x4", 0.005, 11, (1e-9, 1e-7, 1e-8)),
    ]
    record(suite, smooth, points)
    m = {x.name: x for x in suite.metrics}
    wb = m["trial.door.workbench"]
    assert wb.value == 2.6849e-3 and wb.target == 2.68e-3 and wb.met is True  # printed 2.68 ms
    assert m["trial.door.workbench.error_theta"].met is True  # printed 2.52e-08
    assert m["trial.door.workbench.error_dtheta"].met is False  # printed 1.29e-05 > 1.28e-05
    lsoda = m["trial.door.lsoda_compiled"]
    assert (
        lsoda.ratio == pytest.approx(0.06 / 2.6849e-3) and lsoda.ratio_to == "trial.door.workbench"
    )
    assert m["trial.door.smooth.rk4.x4"].ratio is None  # only the earlier plain ways have one
    assert m["trial.door.smooth.rk4.x4.error_dtheta_rms"].value == 1e-8

    latch = bench_trial("haptic", "rig", latch=True)
    limited = Point("LSODA", "rtol 1e-06", "lsoda.rtol1e-06", stopped="no answer within 20 s")
    limited.extra["lower_bound"] = 20.0
    record(
        suite, latch, [Point("default", "dopri5", "default", 0.01, 31, (2e-4, 2e-2, 1e-3)), limited]
    )
    m = {x.name: x for x in suite.metrics}
    assert m["trial.haptic.rig.default.error_theta"].met is False  # 1e-4 rad
    assert m["trial.haptic.rig.default.error_dtheta"].met is False  # 1e-2 rad/s
    ratio = m["trial.haptic.rig.lsoda_over_default"]
    assert ratio.value == pytest.approx(2000) and ratio.met is True and "at least" in ratio.note

    failed = bench_trial("door", "latch", latch=True)
    gave_up = Point("LSODA", "rtol 1e-06", "lsoda.rtol1e-06", stopped="stopped at t = 1 s")
    record(
        suite, failed, [Point("default", "rk4", "default", 0.01, 31, (1e-6, 1e-3, 1e-4)), gave_up]
    )
    m = {x.name: x for x in suite.metrics}
    assert m["trial.door.latch.default.error_dtheta"].met is True
    assert m["trial.door.latch.lsoda_over_default"].met is None
    assert "| door latch: LSODA rtol 1e-6 time / the default's: >= 10x | n/a | not measured" in (
        targets_table(suite)
    )


@pytest.mark.slow
def test_quick_trial_section_measures_every_trial_and_draws_the_work_precision(tmp_path):
    latest = [ROOT / "benchmarks" / n for n in ("suite.md", "trial.md", "work-precision.png")]
    before = [p.read_bytes() if p.exists() else None for p in latest]
    from benchmarks.precision import QUICK_LIMIT_ENV

    # solve_ivp stopped after 1 s of CPU, not 2: the haptic trials' runs all reach the
    # limit (a lower bound either way), the door's take under half of it
    short = {QUICK_LIMIT_ENV: "1.0"}
    done = bench("--quick", "--only", "trial", "--out", str(tmp_path), timeout=600, env=short)
    assert done.returncode == 0, done.stderr[-2000:]
    (js,) = tmp_path.glob("suite-*.json")
    (png,) = tmp_path.glob("suite-*-work-precision.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"]({png})" in done.stdout  # the Markdown links the figure
    metrics = {m["name"]: m for m in json.loads(js.read_text())["metrics"]}
    missing = [n for n in REQUIRED_TRIAL if n not in metrics]
    assert not missing, missing
    for m in metrics.values():
        assert set(m) >= {"name", "value", "unit", "ratio", "target", "met"}
    # the plain way is slower than the compiled integrator, its ratio says by how much
    m = metrics["trial.door.rk45_python"]
    assert m["ratio_to"].endswith(".workbench")
    assert m["ratio"] == pytest.approx(m["value"] / metrics[m["ratio_to"]]["value"])
    assert m["ratio"] > 1
    door = metrics["trial.door.workbench"]
    assert door["target"] is not None and isinstance(door["met"], bool)
    # the compiled door trial agrees with Radau (the quick reference is loose)
    assert metrics["trial.door.workbench.error_theta"]["value"] < 1e-3
    for model in ("door", "haptic"):
        for trial in ("smooth", "latch", "rig"):
            base = {("door", "smooth"): "trial.door.workbench"}.get((model, trial))
            base = base or {("haptic", "latch"): "trial.haptic.workbench"}.get((model, trial))
            base = base or f"trial.{model}.{trial}.default"
            assert metrics[base]["value"] > 0
            for way in ("dopri5.tol1e-05", "rk4.x8", "semi_implicit.x1"):
                name = base.rsplit(".", 1)[0] + f".{way}"
                if base.endswith("workbench"):
                    name = f"trial.{model}.{trial}.{way}"
                assert metrics[f"{name}.error_dtheta"]["value"] >= 0, name
            # the default's accuracy targets carry their verdict
            verdicts = [metrics[f"{base}.{e}"]["met"] for e in ("error_theta", "error_dtheta")]
            assert all(isinstance(v, bool) for v in verdicts), base
            if trial != "smooth":
                assert metrics[f"trial.{model}.{trial}.lsoda_over_default"]["target_text"]
    # the reference: dopri5 at tol 1e-12 agrees with the default on the smooth door
    assert metrics["trial.door.workbench.error_theta"]["value"] < 1e-6
    # a smoke run replaces none of the latest figures
    assert [p.read_bytes() if p.exists() else None for p in latest] == before


def test_the_case_study_page_takes_its_figures_from_the_benchmark(tmp_path):
    from benchmarks.suite import GENERATED_BEGIN, GENERATED_END, replace_generated

    doc = (ROOT / "docs" / "case-study.md").read_text()
    assert doc.count(GENERATED_BEGIN) == 1 and doc.count(GENERATED_END) == 1
    page = tmp_path / "page.md"
    page.write_text(f"intro\n{GENERATED_BEGIN}\nold 87 s\n{GENERATED_END}\nafter\n")
    replace_generated(page, "# title\n\nnew table 42 s\n")
    assert page.read_text() == f"intro\n{GENERATED_BEGIN}\nnew table 42 s\n{GENERATED_END}\nafter\n"
    bare = tmp_path / "bare.md"
    bare.write_text("no markers\n")
    with pytest.raises(RuntimeError, match="no generated block"):
        replace_generated(bare, "# t\nx\n")


def test_seeds_flags_an_estimate_that_spreads_wider_than_it_claims():
    from benchmarks.bench_seeds import agreement, markdown

    done = {
        "seed 1": (
            10.0,
            {"latch": {"u": (40.0, 0.01, "identifiable"), "k": (5.0, 0.5, "not identifiable")}},
        ),
        "seed 2": (
            11.0,
            {"latch": {"u": (42.0, 0.01, "identifiable"), "k": (7.0, 0.5, "not identifiable")}},
        ),
    }
    rows = {r["name"]: r for r in agreement(done)}
    # u: half its spread is 1 / 41 = 2.4 %, against a claimed 1 %: the claim fails
    assert rows["u"]["spread"] == pytest.approx(1.0 / 41.0) and rows["u"]["fails"]
    # k spreads by 17 % but claims nothing
    assert rows["k"]["spread"] == pytest.approx(1.0 / 6.0) and not rows["k"]["fails"]
    assert "Claims the runs do not bear out: latch.u." in markdown(done, list(rows.values()))


def test_seeds_runs_the_main_job_once_a_run_and_reads_every_estimate(tmp_path, monkeypatch):
    """``measure``: each run of RUNS into its own file, with its settings and its
    environment (a cache of its own for the generic CPU), then each stage's estimates
    read back; a small pipeline stands in for the main job."""
    import benchmarks.bench_casestudy as casestudy
    from benchmarks.bench_seeds import RUNS, agreement, measure
    from evo_door.data.io import write_trials
    from evo_door.experiment.pipeline import PipelineRun, load_pipeline
    from tests.test_optim import make_trial
    from tests.test_pipeline import PIPELINE

    folder = tmp_path  # the two-stage pipeline of tests/test_pipeline.py and its trials
    trials = [make_trial(s, 0.75, tid=f"t{s}") for s in (1, 2, 3)]
    write_trials(folder / "trials.h5", [*trials, make_trial(4, 0.75, tid="v1")])
    (folder / "pipe.yaml").write_text(PIPELINE)
    calls = []

    def small(out, quick, settings=(), env=None):
        calls.append((tuple(settings), dict(env or {})))
        PipelineRun.create(load_pipeline(folder / "pipe.yaml"), out).run()
        return 1.0

    monkeypatch.setattr(casestudy, "run_pipeline", small)
    done = measure(quick=False)
    assert list(done) == [label for label, _, _ in RUNS]
    assert [c[0] for c in calls] == [settings for _, settings, _ in RUNS]
    assert calls[-1][1]["NUMBA_CPU_NAME"] == "generic" and "NUMBA_CACHE_DIR" in calls[-1][1]
    wall, estimates = done["seed 1"]
    assert wall == 1.0 and set(estimates) == {"first", "second"}
    assert set(estimates["first"]) == {"k", "c", "inertia"}
    rows = agreement(done)
    assert {r["stage"] for r in rows} == {"first", "second"} and not any(r["fails"] for r in rows)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("cmake") is None, reason="cmake is not installed")
def test_fmu_section_builds_the_fmu_and_compares_with_fmpy(tmp_path):
    """The fmu section's plumbing: the FMU built, each way's error against the scipy
    reference, the ratios against FMPy, a small GA through `evo-door run`; a smoke run
    leaves benchmarks/fmu.md alone."""
    pytest.importorskip("fmpy")
    page = ROOT / "benchmarks" / "fmu.md"
    before = page.read_bytes() if page.exists() else None
    done = bench("--quick", "--only", "fmu", "--out", str(tmp_path), timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    (js,) = tmp_path.glob("suite-*.json")
    metrics = {m["name"]: m for m in json.loads(js.read_text())["metrics"]}
    for interface in ("me", "cs"):
        wb = metrics[f"fmu.trial.{interface}.workbench.sandbox_on"]
        assert 0 < metrics[f"fmu.trial.{interface}.workbench.sandbox_off"]["value"] < 1.0
        # the workbench's response agrees with the independent reference (rad)
        assert metrics[f"fmu.trial.{interface}.workbench.sandbox_on.error_theta"]["value"] < 1e-8
        plain = metrics[f"fmu.trial.{interface}.plain.default"]
        assert plain["ratio_to"] == wb["name"]
        assert plain["ratio"] == pytest.approx(plain["value"] / wb["value"])
        speedup = metrics[f"fmu.trial.{interface}.speedup"]
        assert speedup["target_text"] == ">= 5x" and isinstance(speedup["met"], bool)
    # FMPy's co-simulation is the same RK4 in the same C: the same response
    assert metrics["fmu.trial.cs.plain.default.error_theta"]["value"] < 1e-10
    assert metrics["fmu.ga.evaluations"]["value"] >= 8
    assert metrics["fmu.ga.plain"]["ratio_to"] == "fmu.ga.workbench"
    for name in ("inertia", "spring_stiffness", "damping"):
        assert metrics[f"fmu.ga.{name}.error"]["unit"] == "%"
    assert "| inertia | 0.9 |" in done.stdout and "fmu done in" in done.stderr
    assert (page.read_bytes() if page.exists() else None) == before


def test_fmu_reference_agrees_with_the_exact_free_swing():
    """The section's scipy reference integrates what it says: with the door's weight,
    spring torque, damping and friction off, a constant force gives theta = a t^2 / 2."""
    from benchmarks import bench_fmu

    t = np.arange(64) * bench_fmu.DT
    force = np.full(t.size, 10.0)
    zero = {"weight_moment": 0.0, "spring_preload": 0.0, "spring_stiffness": 0.0}
    zero |= {"damping": 0.0, "friction": 0.0, "inertia": 0.5}
    theta, dtheta = bench_fmu.reference(zero, t, force, hold=True)
    a = 0.55 * 10.0 / 0.5  # lever arm x force / inertia (rad/s^2)
    assert theta == pytest.approx(0.5 * a * t**2, abs=1e-12)
    assert dtheta == pytest.approx(a * t, abs=1e-10)
    # a ramp of force: held, it lags the linear one, which gives theta = a' t^3 / 6
    ramp = 1000.0 * t
    linear = bench_fmu.reference(zero, t, ramp, hold=False)[0]
    held = bench_fmu.reference(zero, t, ramp, hold=True)[0]
    assert linear == pytest.approx(0.55 * 1000.0 / 0.5 * t**3 / 6, abs=1e-12)
    assert (held[1:] < linear[1:]).all()
