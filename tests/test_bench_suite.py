"""The benchmark suite (``python -m benchmarks``): a quick run writes its JSON and
figure, ``--compare`` prints new / old per metric, bad options are one-line errors."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: metrics every run of the whole suite has (the ratios and targets the suite states)
REQUIRED = (
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
    "casestudy.wall",
    "casestudy.physical.seconds",
    "casestudy.physical.M.error",
    "casestudy.latch.unlock_force.error",
    "casestudy.redesign.fitness",
    "casestudy.perceptual.opening",
    "control.flood.on_time",
    "control.flood.memory_growth",
    "control.flood.events_kept",
)


def bench(*args, timeout=600):
    return subprocess.run(
        [sys.executable, "-m", "benchmarks", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout,
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
    done = bench("--quick", "--out", str(tmp_path), timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    (js,) = tmp_path.glob("suite-*.json")
    (png,) = tmp_path.glob("suite-*.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    doc = json.loads(js.read_text())
    assert doc["quick"] is True and doc["machine"]["cpus"] >= 1
    assert doc["machine"]["versions"]["numba"]
    metrics = {m["name"]: m for m in doc["metrics"]}
    missing = [n for n in REQUIRED if n not in metrics]
    assert not missing, missing
    for m in metrics.values():
        assert set(m) >= {"name", "value", "unit", "ratio", "target", "met"}
    # the plain way is slower than the compiled integrator, its ratio says by how much
    for name in ("trial.door.rk45_python", "ga.door.plain"):
        m = metrics[name]
        assert m["ratio_to"].endswith(".workbench")
        wb = metrics[m["ratio_to"]]
        assert m["ratio"] == pytest.approx(m["value"] / wb["value"])
        assert m["ratio"] > 1
    # the targets carry their verdict
    for name in ("trial.door.workbench", "startup.help", "startup.params_haptic"):
        assert metrics[name]["target"] is not None and isinstance(metrics[name]["met"], bool)
    # the compiled door trial agrees with Radau (the quick reference is loose)
    assert metrics["trial.door.workbench.error_theta"]["value"] < 1e-3
    # every section announced its progress, the table was printed
    for section in (
        "trial",
        "ga",
        "scaling",
        "executors",
        "device",
        "startup",
        "casestudy",
        "control",
    ):
        assert f"{section} done in" in done.stderr
    assert "## Targets" in done.stdout
    # and a run compares with it
    again = bench("--compare", str(js), str(js))
    assert again.returncode == 0, again.stderr
    assert "trial.door.workbench" in again.stdout and "1.000" in again.stdout


@pytest.mark.slow
def test_control_section_floods_a_render_and_reads_its_log(tmp_path):
    """The control section's code path: a render in its own process, 200 clients, the
    figures from its log; each limit was met by the flood (it refused something of
    each kind) and the log kept its session events within the cap."""
    done = bench("--quick", "--only", "control", "--out", str(tmp_path), timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    (js,) = tmp_path.glob("suite-*.json")
    metrics = {m["name"]: m for m in json.loads(js.read_text())["metrics"]}
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
    quoted = ROOT / "benchmarks" / "casestudy.md"
    before = quoted.read_bytes() if quoted.exists() else None
    done = bench("--quick", "--only", "casestudy", "--out", str(tmp_path), timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    (js,) = tmp_path.glob("suite-*.json")
    doc = json.loads(js.read_text())
    metrics = {m["name"]: m for m in doc["metrics"]}
    stages = ("physical", "latch", "haptic", "specification", "redesign")
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
    assert (quoted.read_bytes() if quoted.exists() else None) == before


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
