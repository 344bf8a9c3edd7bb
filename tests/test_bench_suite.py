"""The benchmark suite (``python -m benchmarks``), tested on stand-ins.

The harness (sections chosen, the JSON with every metric, the figures, the Markdown,
``--compare``, one-line option errors, ``evo-door bench``) runs a fake section in this
process. Each real section runs in this process on a tiny problem (its measuring code,
the metrics it states), the sizes made smaller here and only here; the casestudy
section runs a two-stage pipeline in place of the main job, which CI runs on its own
and checks. A --quick run writes none of the pages the docs quote (a measured one
does): :func:`test_a_quick_run_leaves_every_page_alone_a_measured_one_replaces_them`.
"""

import json
import shutil
import subprocess
import sys
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from benchmarks import suite as harness

ROOT = Path(__file__).resolve().parents[1]
PNG = b"\x89PNG\r\n\x1a\n"


def bench(*args, timeout=120):
    """``python -m benchmarks ARGS`` in a fresh process."""
    return subprocess.run(
        [sys.executable, "-m", "benchmarks", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout,
    )


def run_main(capsys, *args) -> tuple[int, str, str]:
    """``python -m benchmarks ARGS`` in this process: exit status, stdout, stderr."""
    code = harness.main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def suite_doc(metrics):
    return {
        "date": "2026-01-01T00:00:00",
        "machine_line": "test",
        "metrics": [
            {"name": n, "value": v, "unit": "s", "section": n.split(".")[0]} for n, v in metrics
        ],
    }


# -- the harness, on a fake section ------------------------------------------------------
def fake_section(suite) -> None:
    """A stand-in section: in no time, what a real one adds (a speed-up over its plain
    way, a target and its verdict, a scaling curve, a table, a figure of its own)."""
    from matplotlib.figure import Figure

    suite.add("fake.workbench", "fake", "fake: the workbench", 0.002, "s")
    suite.add(
        "fake.plain",
        "fake",
        "fake: the plain way",
        0.02,
        "s",
        ratio=10.0,
        ratio_to="fake.workbench",
    )
    suite.add("fake.start", "fake", "fake: start-up", 0.1, "s", target=0.3, target_text="< 0.3 s")
    suite.curves["population"] = {"x": [25, 50], "y": [0.01, 0.02], "label": "1 trial"}
    suite.tables["fake"] = "| the fake section's table |"
    fig = Figure()
    fig.subplots().plot([1, 2], [3, 4])
    suite.figures["fake-figure"] = ("fake", fig, "the fake section's figure")


def broken_section(suite) -> None:
    """A section that fails half-way, its message on two lines."""
    suite.add("broken.first", "broken", "broken: before it failed", 1.0, "s")
    raise RuntimeError("no such\n   device")


#: what the stand-in host probe answers, in turn (:func:`fake_sections`)
PROBES = (0.25, 0.5)


@pytest.fixture()
def fake_sections(monkeypatch, tmp_path):
    """The suite's only section the fake one (the broken one there to ask for); the
    folder of the latest pages (``benchmarks/``) one of the test's own; the host probe
    answering :data:`PROBES` in turn, at once (the real one takes a fraction of a
    second: :func:`test_the_host_probe_times_a_loop_and_its_sentence_names_it`)."""
    answers = iter(PROBES)  # a run's start and end
    monkeypatch.setattr(harness, "host_probe", lambda: next(answers))
    monkeypatch.setattr(harness, "SECTIONS", ("fake",))
    monkeypatch.setitem(harness.RUNNERS, "fake", fake_section)
    monkeypatch.setitem(harness.RUNNERS, "broken", broken_section)
    here = tmp_path / "benchmarks"
    here.mkdir()
    monkeypatch.setattr(harness, "HERE", here)
    return here


@pytest.fixture()
def blank_suite_figure(monkeypatch):
    """The suite's figure a blank one, quick to save (the first test below draws the
    real one)."""
    from matplotlib.figure import Figure

    monkeypatch.setattr(harness, "figure", lambda suite: Figure(figsize=(1, 1)))


def test_a_run_writes_json_with_every_metric_the_figures_and_the_markdown(
    tmp_path, capsys, fake_sections
):
    """``--quick --only fake``: the JSON (every metric, the machine), the suite's figure
    and the section's own, the Markdown printed and written, the progress on stderr."""
    out_dir = tmp_path / "out"
    code, out, err = run_main(capsys, "--quick", "--only", "fake", "--out", str(out_dir))
    assert code == 0, err
    (js,) = out_dir.glob("suite-*.json")
    stem = js.name.removesuffix(".json")
    own_figure = out_dir / f"{stem}-fake-figure.png"
    for png in (js.with_suffix(".png"), own_figure):
        assert png.read_bytes()[:8] == PNG
    doc = json.loads(js.read_text())
    assert doc["quick"] is True and doc["sections"] == ["fake"]
    assert doc["machine"]["cpus"] >= 1 and doc["machine"]["cpu"]
    assert doc["machine"]["versions"]["numba"]
    metrics = {m["name"]: m for m in doc["metrics"]}
    assert set(metrics) == {"fake.workbench", "fake.plain", "fake.start"}
    for m in metrics.values():
        assert set(m) >= {"name", "value", "unit", "ratio", "ratio_to", "target", "met", "note"}
    assert metrics["fake.plain"]["ratio"] == 10.0
    assert metrics["fake.plain"]["ratio_to"] == "fake.workbench"
    assert metrics["fake.start"]["met"] is True  # 0.1 s against its target, 0.3 s
    assert doc["curves"]["population"]["x"] == [25, 50]
    # the Markdown, printed and written: the targets, the section's table and figure
    assert "## Targets" in out and "| fake: start-up: < 0.3 s | 100 ms | met |" in out
    assert "## fake" in out and "| the fake section's table |" in out
    assert f"]({own_figure})" in out
    assert f"]({own_figure.name})" in js.with_suffix(".md").read_text()
    assert f"wrote {js}" in out
    assert "[suite] 1/1 fake done in" in err
    assert not list(fake_sections.iterdir())  # --quick: no latest figures, no summary
    assert doc["machine"]["probe"] == [] and "Host probe" not in out  # nor a host probe


def test_a_broken_section_loses_no_other_sections_figures(
    tmp_path, capsys, monkeypatch, fake_sections, blank_suite_figure
):
    """A full run whose first section fails: the rest run, the run says which failed
    and exits 1, the summary of the latest full run stays as it was."""
    monkeypatch.setattr(harness, "SECTIONS", ("broken", "fake"))
    out_dir = tmp_path / "out"
    code, out, err = run_main(capsys, "--out", str(out_dir))
    assert code == 1
    line = "RuntimeError: no such device"
    assert f"[suite] 1/2 broken FAILED: {line}" in err and "[suite] 2/2 fake done in" in err
    assert err.strip().splitlines()[-1] == "benchmarks: 1 section(s) failed: broken"
    doc = json.loads(next(out_dir.glob("suite-*.json")).read_text())
    assert f"section broken failed: {line}" in doc["notes"]
    names = {m["name"] for m in doc["metrics"]}
    assert names == {"broken.first", "fake.workbench", "fake.plain", "fake.start"}
    assert not (fake_sections / "suite.md").exists()


@pytest.mark.parametrize(
    "args, replaced",
    [([], True), (["--quick"], False), (["--only", "fake"], False)],
    ids=["full", "quick", "only"],
)
def test_only_a_full_measured_run_replaces_the_latest_summary(
    tmp_path, capsys, fake_sections, blank_suite_figure, args, replaced
):
    code, _, err = run_main(capsys, *args, "--out", str(tmp_path / "out"))
    assert code == 0, err
    assert (fake_sections / "suite.md").exists() == replaced
    # a measured run states the host probe at its start and end (a smoke run none)
    doc = json.loads(next((tmp_path / "out").glob("suite-*.json")).read_text())
    assert doc["machine"]["probe"] == ([] if "--quick" in args else list(PROBES))
    if replaced:
        head = (fake_sections / "suite.md").read_text().splitlines()[2]
        assert head.endswith(": 0.25 s at the start and 0.50 s at the end.")
    # a measured run keeps its sections' figures next to the pages (README links them)
    assert (fake_sections / "fake-figure.png").exists() == ("--quick" not in args)


def test_every_page_a_run_writes_states_the_host_probe_it_made():
    """The host's speed at the hour beside the figures, on the pages the sections write
    (:func:`benchmarks.suite.page_machine`; the summary page's and the JSON's:
    :func:`test_only_a_full_measured_run_replaces_the_latest_summary`)."""
    info = harness.machine([0.3, 0.4])
    run = every_page_stand_in(quick=False)
    pages = (harness.casestudy_markdown, harness.seeds_markdown, harness.trial_markdown)
    for written in (*pages, harness.fmu_markdown, harness.jnd_markdown, harness.pathsim_markdown):
        first = written(run, info).splitlines()[2]
        assert first.startswith("Machine: ") and "Host probe (20 million additions" in first
        assert first.endswith(": 0.30 s at the start and 0.40 s at the end.")
    assert "Host probe" not in harness.casestudy_markdown(run, {**info, "probe": []})


def test_the_host_probe_times_a_loop_and_its_sentence_names_it():
    from benchmarks import probe

    small, large = probe.host_probe(20_000), probe.host_probe(2_000_000)
    assert 0.0 < small < large < 60.0  # a hundred times the work: longer on any host
    assert probe.probe_sentence([]) == "" and probe.probe_sentence(None) == ""
    one = probe.probe_sentence([1.234])
    assert one.endswith("): 1.23 s.") and "at the end" not in one


def test_a_run_compares_with_an_earlier_one(tmp_path, capsys, fake_sections, blank_suite_figure):
    old = tmp_path / "old.json"
    old.write_text(json.dumps(suite_doc([("fake.workbench", 0.004)])))
    out_dir = str(tmp_path / "out")
    code, out, err = run_main(
        capsys, "--quick", "--only", "fake", "--out", out_dir, "--compare", str(old)
    )
    assert code == 0, err
    (row,) = [line for line in out.splitlines() if line.startswith("fake.workbench ")]
    assert row.split()[-1] == "0.500"  # 2 ms now, 4 ms then


def every_page_stand_in(quick: bool):
    """A suite as a run of every section that writes a page leaves it (stand-in tables
    and figures)."""
    from matplotlib.figure import Figure

    run = harness.Suite(quick=quick)
    for section in ("trial", "casestudy", "seeds", "fmu", "jnd", "pathsim"):
        run.tables[section] = f"the {section} table"
    run.add("pathsim.trial.speedup", "pathsim", "PathSim / workbench", 300.0, "1")
    run.figures["work-precision"] = ("trial", Figure(), "work-precision")
    run.figures["jnd-planning"] = ("jnd", Figure(), "JND planning")
    return run


@pytest.mark.parametrize("quick", [True, False], ids=["quick", "measured"])
def test_a_quick_run_leaves_every_page_alone_a_measured_one_replaces_them(
    tmp_path, monkeypatch, blank_suite_figure, quick
):
    """The pages README.md and the docs quote (``benchmarks/*.md``, the block of
    ``docs/case-study.md``) and the latest figures, here in folders of the test's own."""
    here, docs = tmp_path / "benchmarks", tmp_path / "docs"
    here.mkdir()
    docs.mkdir()
    page = f"intro\n{harness.GENERATED_BEGIN}\nold\n{harness.GENERATED_END}\n"
    (docs / "case-study.md").write_text(page)
    monkeypatch.setattr(harness, "HERE", here)
    monkeypatch.setattr(harness, "ROOT", tmp_path)
    sections = ["trial", "casestudy", "seeds", "fmu", "jnd", "pathsim"]
    paths = harness.save(every_page_stand_in(quick), tmp_path / "out", sections, 1.0, False)
    assert {"json", "png", "md", "work-precision", "jnd-planning"} <= set(paths)
    written = sorted(p.name for p in here.iterdir())
    pages = ["casestudy.md", "fmu.md", "jnd.md", "pathsim.md", "seeds.md", "trial.md"]
    figures = ["jnd-planning.png", "work-precision.png"]
    assert written == ([] if quick else sorted(pages + figures))
    quoted = (docs / "case-study.md").read_text()
    assert (quoted == page) == quick
    if not quick:
        assert "the casestudy table" in quoted


def test_compare_prints_new_over_old_per_metric(tmp_path):
    old, new = tmp_path / "old.json", tmp_path / "new.json"
    old.write_text(json.dumps(suite_doc([("trial.door.workbench", 0.006), ("only.old", 1.0)])))
    new.write_text(json.dumps(suite_doc([("trial.door.workbench", 0.003), ("only.new", 1.0)])))
    done = bench("--compare", str(old), str(new))
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
    done = bench(*args, "--out", str(tmp_path))
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("benchmarks: error:")
    assert words in lines[0]
    assert not list(tmp_path.iterdir())  # nothing ran, nothing written


def test_compare_refuses_a_file_that_is_not_a_suite(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"metrics": 3}')
    done = bench("--compare", str(bad), str(bad))
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


def test_evo_door_bench_help_names_every_section():
    done = subprocess.run(
        [sys.executable, "-m", "evo_door", "bench", "--help"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert ", ".join(harness.SECTIONS) in " ".join(done.stdout.split())


def test_evo_door_command_runs_a_fresh_process_and_says_why_it_failed():
    """What the sections that start ``evo-door`` as a user types it call (the tests
    below run the same commands in this process: :func:`evo_door_in_this_process`)."""
    from benchmarks._util import evo_door_command

    wall, out = evo_door_command(["--version"])
    assert wall > 0 and out.startswith("evo-door ")
    with pytest.raises(RuntimeError) as info:
        evo_door_command(["--bogus"])  # its usage first, then the error
    assert str(info.value) == "evo-door: error: unrecognized arguments: --bogus"


@pytest.fixture()
def evo_door_in_this_process(monkeypatch):
    """``evo-door ARGS`` run by ``evo_door.cli.main`` in this process, not in a fresh
    one (a fresh process's start-up is its cost; the command is the same)."""
    import contextlib
    import io
    import time

    from benchmarks import _util
    from evo_door.cli import main

    def command(args, env=None, cwd=None, timeout=None):
        assert not env, "an environment of its own needs a process of its own"
        out = io.StringIO()
        t0 = time.perf_counter()
        with contextlib.chdir(cwd or Path.cwd()), contextlib.redirect_stdout(out):
            code = main([str(a) for a in args])
        assert code == 0, args
        return time.perf_counter() - t0, out.getvalue()

    monkeypatch.setattr(_util, "evo_door_command", command)


# -- the sections, each on a tiny problem ---------------------------------------------------
def run_section(name: str):
    """Section ``name`` of a --quick run, in this process: its metrics by name and the
    suite, once its figures went through what a run writes (JSON, figure, Markdown)."""
    run = harness.Suite(quick=True)
    harness.RUNNERS[name](run)
    assert name in run.tables, "no table"
    json.dumps([asdict(m) for m in run.metrics], default=harness._json_default)
    harness.figure(run)
    text = harness.to_markdown(run, harness.machine(), [name], 1.0)
    assert f"## {name}" in text
    return {m.name: m for m in run.metrics}, run


def shorter_ga_trials(monkeypatch) -> None:
    """GA and scaling on trials of 0.25 s (bench_ga's are 5 s long)."""
    from benchmarks import bench_ga

    monkeypatch.setattr(bench_ga, "make_problem", partial(bench_ga.make_problem, seconds=0.25))


def evo_door_run_stood_in(monkeypatch) -> None:
    """``evo-door run`` answered at once (two fresh processes each, whose start-up is
    the cost; the fmu section's test runs the same function, its commands in this
    process): local in 2 s, the others in 1 s, each with the same answer."""

    def run(exp, out, executor):
        assert (exp.parent / "trials.h5").is_file() and "population: 20" in exp.read_text()
        wall = 2.0 if executor == "local" else 1.0
        return {"wall": wall, "run": wall / 2, "params": {"M": 1.2}, "evaluations": 60}

    monkeypatch.setattr(harness, "run_experiment_cli", run)


def one_timed_start(monkeypatch) -> None:
    """Each command started twice (once untimed), not three times."""
    from benchmarks import bench_startup

    timed = bench_startup.wall_time
    monkeypatch.setattr(bench_startup, "wall_time", lambda cmd, repeat: timed(cmd, 1))


def one_session(monkeypatch) -> None:
    """One simulated JND session per setting, not four."""
    from benchmarks import bench_jnd

    monkeypatch.setattr(bench_jnd, "SESSIONS", (200, 1))


def shorter_drawer_trial(monkeypatch) -> None:
    """The drawer's trial 0.4 s long, not 0.8 s."""
    from benchmarks import bench_pathsim

    monkeypatch.setattr(bench_pathsim, "QUICK_SECONDS", 0.4)


def same_size(monkeypatch) -> None:
    """As --quick makes it (a second of the servo loop, the device force's costs)."""


def check_ga(metrics) -> None:
    """The plain GA is slower than the workbench's, its ratio says by how much."""
    for model in ("door", "haptic"):
        m = metrics[f"ga.{model}.plain"]
        assert m.ratio_to == f"ga.{model}.workbench"
        assert m.ratio == pytest.approx(m.value / metrics[m.ratio_to].value) and m.ratio > 1


def check_scaling(metrics) -> None:
    """Per generation of a GA run (generation 0 counted), the slope against the batch
    with its fit, two numba threads against one."""
    for g in (2, 4):
        run = metrics[f"scaling.generations.{g}"].value
        assert metrics[f"scaling.generations.{g}.per_generation"].value == pytest.approx(
            run / (g + 1)
        )
    assert metrics["scaling.per_trial_individual"].note.startswith("R^2 = ")
    two = metrics["scaling.threads.2"]
    if two.value is not None:  # (a machine of one core has no second thread)
        assert two.ratio_to == "scaling.threads.1"
        assert two.ratio == pytest.approx(metrics["scaling.threads.1"].value / two.value)


def check_executors(metrics) -> None:
    """Each executor against local: its ratio and whether it gave the same answer."""
    m = metrics["executors.processes"]
    assert m.ratio == 2.0 and m.ratio_to == "executors.local"
    assert m.note == "same best parameters and evaluation count as local: True"


def check_device(metrics) -> None:
    """The targets the suite states carry their verdict."""
    for name in ("device.force_python", "device.force_compiled", "device.log.final_per_hour"):
        assert metrics[name].value > 0 and isinstance(metrics[name].met, bool), name
    on_time = metrics["device.servo.on_time"]
    assert 0 < on_time.value <= 100 and isinstance(on_time.met, bool)


def check_startup(metrics) -> None:
    """The targets, and a first command on an empty numba cache timed to its first word
    and against the next ones (--quick: ``params haptic``, which compiles nothing, so
    it says nothing and its first word is its end)."""
    for name in ("startup.help", "startup.params_haptic"):
        assert metrics[name].target == 0.3 and isinstance(metrics[name].met, bool)
    cold, first = metrics["startup.params.cold"], metrics["startup.params.first_word"]
    assert first.target == 5.0 and first.met is True
    assert first.value == pytest.approx(cold.value) and first.note == "no line"
    warm = metrics["startup.params.warm"]
    assert warm.ratio_to == "startup.params.cold"
    assert warm.ratio == pytest.approx(cold.value / warm.value)


def test_a_first_command_is_timed_to_its_first_line(tmp_path):
    """``first_run`` times a command to the first line it writes on stderr, on the numba
    cache it is given: a stand-in that says a line, waits, then ends."""
    from benchmarks.bench_startup import first_run

    code = (
        "import os, sys, time; print('compiling', os.environ['NUMBA_CACHE_DIR'], "
        "file=sys.stderr); time.sleep(1.0)"
    )
    wall, first_at, line = first_run([sys.executable, "-c", code], tmp_path / "c", tmp_path)
    assert line == f"compiling {tmp_path / 'c'}"
    assert first_at < 0.8 and wall >= 1.0 + first_at - 0.05
    with pytest.raises(RuntimeError, match="failed"):
        first_run([sys.executable, "-c", "raise SystemExit(3)"], tmp_path / "c", tmp_path)


def check_jnd(metrics) -> None:
    for method in ("staircase", "quest"):
        coverage = metrics[f"jnd.{method}.40.coverage"]
        assert 0 <= coverage.value <= 100 and coverage.target_text == ">= 90 %"


def check_pathsim(metrics) -> None:
    """The PathSim side by side: measured where PathSim is installed (the test extra has
    it), else skipped with its one-line reason."""
    import importlib.util

    m = metrics["pathsim.trial.speedup"]
    if importlib.util.find_spec("pathsim") is None:
        assert m.value is None and m.note.startswith("skipped: PathSim is not installed")
        return
    assert m.value > 1 and m.target_text == ">= 100x" and isinstance(m.met, bool)
    for tool in ("workbench", "pathsim"):
        assert metrics[f"pathsim.trial.{tool}.error_x"].value <= 1e-6
        assert metrics[f"pathsim.trial.{tool}.error_v"].value <= 1e-5
    ga = metrics["pathsim.ga.pathsim"]
    assert ga.ratio_to == "pathsim.ga.workbench" and ga.ratio > 1


#: per section: its tiny problem (sizes changed here only), the metrics it must state
#: (the ratios and targets the suite gives), a check of their values
SECTION_CASES = {
    "ga": (
        shorter_ga_trials,
        ("ga.door.workbench", "ga.door.plain", "ga.haptic.workbench", "ga.haptic.plain"),
        check_ga,
    ),
    "scaling": (
        shorter_ga_trials,
        (
            "scaling.population.25",
            "scaling.population.50",
            "scaling.trials.1",
            "scaling.trials.2",
            "scaling.generations.flatness",
            "scaling.threads.1",
        ),
        check_scaling,
    ),
    "executors": (
        evo_door_run_stood_in,
        ("executors.local", "executors.processes"),
        check_executors,
    ),
    "device": (
        same_size,
        (
            "device.force_python",
            "device.force_compiled",
            "device.servo.on_time",
            "device.log.final_per_hour",
        ),
        check_device,
    ),
    "startup": (
        one_timed_start,
        ("startup.help", "startup.params_haptic", "startup.params.cold", "startup.params.warm"),
        check_startup,
    ),
    "jnd": (
        one_session,
        ("jnd.staircase.40.within", "jnd.quest.40.coverage", "jnd.quest.40.bias"),
        check_jnd,
    ),
    "pathsim": (shorter_drawer_trial, ("pathsim.trial.speedup",), check_pathsim),
}


@pytest.mark.parametrize("section", list(SECTION_CASES))
def test_a_section_on_a_tiny_problem_states_every_metric(monkeypatch, section):
    tiny, required, check = SECTION_CASES[section]
    tiny(monkeypatch)
    metrics, _ = run_section(section)
    missing = [n for n in required if n not in metrics]
    assert not missing, missing
    assert all(m.section == section and m.name.startswith(f"{section}.") for m in metrics.values())
    check(metrics)


def test_every_section_has_a_tiny_case_or_a_test_of_its_own():
    """A new section gets a case in SECTION_CASES, or a test of its own below (as
    trial, control, fmu, casestudy and seeds have)."""
    own = {"trial", "control", "fmu", "casestudy", "seeds"}
    assert set(harness.SECTIONS) == set(SECTION_CASES) | own


# -- the sections with tests of their own ---------------------------------------------------
@pytest.mark.slow
def test_control_section_floods_a_render_and_reads_its_log(monkeypatch):
    """The control section's code path: a render in its own process, 200 clients, the
    figures from its log; each limit was met by the flood (it refused something of
    each kind) and the log kept its session events within the cap. Renders of 2 s, not
    4 s: the flood fills the log's cap in about a second, the events past it are
    dropped and counted."""
    from benchmarks import bench_control

    monkeypatch.setattr(bench_control, "QUICK_SECONDS", 2.0)
    metrics, _ = run_section("control")
    for name in ("control.flood.memory_growth", "control.flood.events_kept"):
        assert metrics[name].value is not None, name
    flood = metrics["control.flood.on_time"]
    assert flood.target is None and flood.target_text == ">= 99.9 %"
    assert isinstance(flood.met, bool) and 0 < flood.value <= 100
    assert 0 < metrics["control.alone.on_time"].value <= 100
    assert "2 s" in flood.label
    for kind in ("ok", "refused_client_cap", "refused_input"):
        assert metrics[f"control.flood.{kind}"].value > 0, kind
    # what the log kept is within its cap (the cap itself: test_render_control.py)
    assert 0 < metrics["control.flood.events_kept"].value <= 10_000
    assert metrics["control.flood.events_kept"].met is True
    dropped = metrics["control.flood.events_dropped"].value
    assert (dropped > 0) == (metrics["control.flood.refused_log_cap"].value > 0)


#: the casestudy section's stand-in for the main job: a stage fitted to the virtual
#: door's trials (they carry its truth), then a door fitted to a chosen feel (the
#: perceptual check, the specification a supplier builds, its yield); --quick makes each
#: GA 8 x 1 and each polish two SLSQP iterations, as it does the main job's
STAND_IN_PIPELINE = """\
name: stand-in
stages:
  physical:
    model: door
    params: default
    target: {data: default.h5, trials: [T01, T03], validate: [T05],
             preprocess: {rate_bias: start}}
    free: {F_load: [80.0, 120.0], M: [0.3, 2.5]}
    objective: {kind: ise, derivative: 1}
    algorithm: {population: 100, generations: 20, seed: 1, polish: slsqp}
    per_trial: true
    pooled: true
  specification:
    model: door
    params: {from: physical}
    target: {model: haptic, params: seed_trial}
    free: {K: [200.0, 800.0]}
    objective: {kind: perceptual}
    algorithm: {population: 100, generations: 20, seed: 1, polish: slsqp}
"""


def smaller_yield_samples(monkeypatch) -> None:
    """100 doors for the specification's yield (the fewest it accepts, not 2000), for
    its design (not 400) and for the section's independent check of the yield (not
    500): the doors are what a specification costs (``evo_door.optim.tolerance``)."""
    from benchmarks import bench_casestudy
    from evo_door.experiment import run_specification
    from evo_door.optim import tolerance

    monkeypatch.setattr(run_specification, "specify", partial(tolerance.specify, samples=100))
    monkeypatch.setattr(tolerance, "DESIGN_SAMPLES", 100)
    monkeypatch.setattr(bench_casestudy, "QUICK_CHECK_DOORS", 100)


@pytest.mark.slow
def test_casestudy_section_runs_a_stand_in_pipeline_and_reads_every_figure(
    tmp_path, monkeypatch, evo_door_in_this_process
):
    """The section's code path (``evo-door run`` of the pipeline, its figures read
    back, the Markdown) on :data:`STAND_IN_PIPELINE` in place of the main job."""
    import benchmarks.bench_casestudy as casestudy

    shutil.copy(ROOT / "experiments" / "data" / "default.h5", tmp_path)
    (tmp_path / "stand-in.yaml").write_text(STAND_IN_PIPELINE)
    monkeypatch.setattr(casestudy, "PIPELINE", tmp_path / "stand-in.yaml")
    smaller_yield_samples(monkeypatch)
    metrics, run = run_section("casestudy")
    for stage in ("physical", "specification"):
        assert metrics[f"casestudy.{stage}.seconds"].value > 0
        assert metrics[f"casestudy.{stage}.fitness"].value >= 0
        # --quick: GA 8 x 1 (and two SLSQP iterations), not the file's 100 x 20
        assert 0 < metrics[f"casestudy.{stage}.evaluations"].value < 200
    assert metrics["casestudy.wall"].value >= metrics["casestudy.total"].value
    # the stage fitted to the virtual door's trials is scored against its truth
    error = metrics["casestudy.physical.F_load.error"]
    assert error.unit == "%" and "casestudy.physical.M.error" in metrics
    truth = 101.45  # the default door's pre-load, which made the bundled trials
    value = metrics["casestudy.physical.F_load"].value
    assert error.value == pytest.approx(100 * (value - truth) / truth)
    assert metrics["casestudy.physical.rms_fit_max"].unit == "rad/s"
    assert "casestudy.specification.K.error" not in metrics  # a chosen feel: no truth
    # the stage fitted to a chosen feel: its perceptual check and its specification's
    # yield, as the run states it and as the independent check finds it
    for direction in ("opening", "closing"):
        assert metrics[f"casestudy.specification.perceptual.{direction}"].unit == "JND"
    for name in ("casestudy.specification.yield", "casestudy.specification.yield.independent"):
        assert 0 <= metrics[name].value <= 100, name
    table = run.tables["casestudy"]
    assert "| physical | F_load |" in table and "--quick" in table
    assert "of 100 doors built to the process" in table


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


#: metrics the trial section's quick run has (the earlier suite's names among them)
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


@pytest.mark.slow
def test_quick_trial_section_measures_every_trial_and_draws_the_work_precision(monkeypatch):
    """The trial section's code path on its six trials, each cut to its first quarter
    second (their length is its cost), solve_ivp stopped after 0.2 s of CPU, not 2 s
    (the haptic trials' runs all reach the limit, a lower bound; the door's end well
    within it)."""
    from benchmarks import precision

    six = precision.bench_trials
    monkeypatch.setattr(
        precision, "bench_trials", lambda: [replace(t, force=t.force[:256]) for t in six()]
    )
    monkeypatch.setitem(precision.QUICK, "limit", 0.2)
    metrics, run = run_section("trial")
    missing = [n for n in REQUIRED_TRIAL if n not in metrics]
    assert not missing, missing
    # the plain way is slower than the compiled integrator, its ratio says by how much
    m = metrics["trial.door.rk45_python"]
    assert m.ratio_to == "trial.door.workbench"
    assert m.ratio == pytest.approx(m.value / metrics[m.ratio_to].value) and m.ratio > 1
    door = metrics["trial.door.workbench"]
    assert door.target is not None and isinstance(door.met, bool)
    for model in ("door", "haptic"):
        for trial in ("smooth", "latch", "rig"):
            base = {("door", "smooth"): "trial.door.workbench"}.get((model, trial))
            base = base or {("haptic", "latch"): "trial.haptic.workbench"}.get((model, trial))
            base = base or f"trial.{model}.{trial}.default"
            assert metrics[base].value > 0
            for way in ("dopri5.tol1e-05", "rk4.x8", "semi_implicit.x1"):
                name = base.rsplit(".", 1)[0] + f".{way}"
                if base.endswith("workbench"):
                    name = f"trial.{model}.{trial}.{way}"
                assert metrics[f"{name}.error_dtheta"].value >= 0, name
            # the default's accuracy targets carry their verdict
            verdicts = [metrics[f"{base}.{e}"].met for e in ("error_theta", "error_dtheta")]
            assert all(isinstance(v, bool) for v in verdicts), base
            if trial != "smooth":
                assert metrics[f"trial.{model}.{trial}.lsoda_over_default"].target_text
    # the reference: dopri5 at tol 1e-12 agrees with the default on the smooth door
    assert metrics["trial.door.workbench.error_theta"].value < 1e-6
    # the figure: a panel per trial, a line per way
    section, fig, _ = run.figures["work-precision"]
    assert section == "trial" and all(ax.lines for ax in fig.axes[:6])


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


#: a GA that tries a few candidates, and the polish after it
TINY_GA = ("population=4", "generations=1", "max_iterations=2")


def test_seeds_runs_the_main_job_once_a_run_and_reads_every_estimate(tmp_path, monkeypatch):
    """``measure``: each run of RUNS into its own file, with its settings and its
    environment (a cache of its own for the generic CPU), then each stage's estimates
    read back; one run of a small pipeline stands in for every run of the main job.
    Then the section's metrics from a --quick run (one run)."""
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
    small_ga = [f"stages.{s}.algorithm.{k}" for s in ("first", "second") for k in TINY_GA]
    pipe = load_pipeline(folder / "pipe.yaml", small_ga)
    made = PipelineRun.create(pipe, folder / "made.h5").run()
    calls = []

    def small(out, quick, settings=(), env=None):
        calls.append((tuple(settings), dict(env or {})))
        shutil.copy(made.path, out)  # (once is enough: measure reads what is there)
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
    # the section: --quick, one run; each estimate's spread, the claims that fail
    metrics, _ = run_section("seeds")
    assert metrics["seeds.seed_1.wall"].value == 1.0 and len(calls) == len(RUNS) + 1
    assert metrics["seeds.first.k.spread"].value == 0.0  # (one run: no spread)
    assert metrics["seeds.claims_failing"].value == 0


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("cmake") is None, reason="cmake is not installed")
def test_fmu_section_builds_the_fmu_and_compares_with_fmpy(monkeypatch, evo_door_in_this_process):
    """The fmu section's plumbing: the FMU built, each way's error against the scipy
    reference, the ratios against FMPy, a small GA through ``evo-door run`` and ``show``
    (:func:`benchmarks.suite.run_experiment_cli`); trials of a quarter second, not 2 s
    (the scipy reference steps sample by sample in Python)."""
    pytest.importorskip("fmpy")
    from benchmarks import bench_fmu

    monkeypatch.setattr(bench_fmu, "SECONDS", 0.25)
    metrics, run = run_section("fmu")
    for interface in ("me", "cs"):
        wb = metrics[f"fmu.trial.{interface}.workbench.sandbox_on"]
        assert 0 < metrics[f"fmu.trial.{interface}.workbench.sandbox_off"].value < 1.0
        # the workbench's response agrees with the independent reference (rad)
        assert metrics[f"fmu.trial.{interface}.workbench.sandbox_on.error_theta"].value < 1e-8
        plain = metrics[f"fmu.trial.{interface}.plain.default"]
        assert plain.ratio_to == wb.name
        assert plain.ratio == pytest.approx(plain.value / wb.value)
        speedup = metrics[f"fmu.trial.{interface}.speedup"]
        assert speedup.target_text == ">= 5x" and isinstance(speedup.met, bool)
    # FMPy's co-simulation is the same RK4 in the same C: the same response
    assert metrics["fmu.trial.cs.plain.default.error_theta"].value < 1e-10
    assert metrics["fmu.ga.evaluations"].value >= 8
    assert metrics["fmu.ga.plain"].ratio_to == "fmu.ga.workbench"
    for name in ("inertia", "spring_stiffness", "damping"):
        assert metrics[f"fmu.ga.{name}.error"].unit == "%"
    assert "| inertia | 0.9 |" in run.tables["fmu"]


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
