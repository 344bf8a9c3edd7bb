"""Pipelines: stages that take an earlier stage's answer, one results file, exact resume."""

import json

import h5py
import numpy as np
import pytest

from evo_door.data.io import write_trials
from evo_door.errors import UserError
from evo_door.experiment import Interrupted, Results
from evo_door.experiment.pipeline import (
    PipelineRun,
    is_pipeline,
    load_pipeline,
    resume_pipeline,
)
from evo_door.experiment.pipeline_status import pipeline_summary
from evo_door.reporting.format_text import format_pipeline
from tests.test_cli import cli
from tests.test_optim import make_trial

OSC = "tests.conftest:OSCILLATOR_MODEL"

PIPELINE = f"""\
name: two
stages:
  first:
    model: {OSC}
    target: {{data: trials.h5, trials: all, validate: [v1]}}
    fixed: {{theta_eq: 0.0}}
    free: {{k: [20, 500], c: [0, 10], inertia: [0.2, 8]}}
    objective: {{kind: ise, derivative: 1}}
    algorithm: {{population: 16, generations: 5, seed: 1, polish: slsqp}}
  second:
    model: {OSC}
    params: {{from: first}}
    target: {{model: {OSC}, params: {{from: first}}, set: {{k: 150}}, inputs: trials.h5,
             trials: [t1, t2]}}
    free: {{k: [20, 500]}}
    objective: {{kind: ise, derivative: 1}}
    algorithm: {{population: 12, generations: 4, seed: 2, polish: slsqp}}
"""


@pytest.fixture()
def folder(tmp_path):
    trials = [make_trial(s, 0.75, tid=f"t{s}") for s in (1, 2, 3)] + [make_trial(4, 0.75, tid="v1")]
    write_trials(tmp_path / "trials.h5", trials)
    (tmp_path / "pipe.yaml").write_text(PIPELINE)
    return tmp_path


def run_pipeline(folder, name="out.h5", on_checkpoint=None):
    pipe = load_pipeline(folder / "pipe.yaml")
    return PipelineRun.create(pipe, folder / name).run(on_checkpoint=on_checkpoint)


def test_a_stage_starts_from_the_earlier_stages_answer(folder):
    run = run_pipeline(folder)
    first, second = Results(run.path, "first"), Results(run.path, "second")
    assert first.complete and second.complete
    # everything second did not free is first's answer; its target is first's answer
    # with k = 150, so the fit recovers 150 (noise-free model target)
    values = second.values()
    for name in ("c", "inertia"):
        assert values[name] == pytest.approx(first.best()[name], rel=1e-12)
    assert second.truth()["k"] == 150.0
    assert second.best()["k"] == pytest.approx(150.0, rel=1e-3)
    # one file, one group per stage, each a run's layout
    with h5py.File(run.path) as f:
        assert set(f["stages"]) == {"first", "second"}
        assert f["stages/first"].attrs["format"] == "evo-door run"
        assert json.loads(f["stages/second/experiment/resolved"][()])["params"]["c"] == (
            pytest.approx(first.best()["c"])
        )
    assert pipeline_summary(run.path)["status"] == "complete"
    # a stage reads an earlier one without its arrays: the same values as read whole
    from evo_door.experiment.reader import read_run

    for stage in ("first", "second"):
        light = read_run(run.path, stage, arrays=False)
        assert light.trials == [] and light.tree is None
        assert Results.of(light).values() == Results(run.path, stage).values()


def test_the_results_file_records_which_stage_each_stage_started_from(folder, capsys):
    """Provenance survives the run: the stage's experiment is filled in a copy, so the
    file still says second took its values and its target from first (it said [])."""
    out = run_pipeline(folder).path
    with h5py.File(out) as f:
        stages = json.loads(f["pipeline/resolved"][()])["stages"]
    assert stages["first"]["uses"] == [] and stages["first"]["from"] == {}
    assert stages["second"]["uses"] == ["first"]
    assert stages["second"]["from"] == {"params": "first", "target.params": "first"}
    shown = cli(capsys, "show", out)
    assert shown.returncode == 0, shown.stderr
    head = shown.stdout.split("\n\n")[0].splitlines()
    # a finished pipeline's time is its total, not a count "so far"
    assert head[0].startswith("pipeline two: complete, ") and "so far" not in head[0]
    assert head[1] == "  stage 1 first: complete"
    assert head[2] == (
        "  stage 2 second: complete (params from stage first, target.params from stage first)"
    )
    doc = json.loads(cli(capsys, "show", out, "--json").stdout)
    assert [s["from"] for s in doc["stages"]] == [
        {},
        {"params": "first", "target.params": "first"},
    ]
    assert doc["stages"][1]["uses"] == ["first"]
    assert doc["stage_results"]["second"]["from"] == {"params": "first", "target.params": "first"}
    one = cli(capsys, "show", out, "--stage", "second")
    assert "  stage second: params from stage first, target.params from stage first" in (one.stdout)
    doc = json.loads(cli(capsys, "show", out, "--stage", "first", "--json").stdout)
    assert doc["stage"] == "first" and doc["from"] == {}


@pytest.mark.parametrize("stage, generation", [("first", 2), ("second", 1)])
def test_a_killed_pipeline_resumes_at_its_stage_and_generation_to_the_same_numbers(
    folder, stage, generation
):
    whole = run_pipeline(folder, "whole.h5")

    def kill(run, job):
        if run.config["name"] == stage and job.ga is not None and job.ga.generation == generation:
            raise Interrupted

    with pytest.raises(Interrupted):
        run_pipeline(folder, "cut.h5", kill)
    summary = pipeline_summary(folder / "cut.h5")
    assert summary["status"] == "interrupted" and stage in summary["status_text"]
    assert " s so far, created " in format_pipeline(summary).splitlines()[0]
    assert f"generation {generation}" in summary["status_text"]
    resumed = resume_pipeline(folder / "cut.h5")
    assert resumed.status == "complete"
    for name in ("first", "second"):
        a, b = Results(whole.path, name), Results(folder / "cut.h5", name)
        assert a.best() == b.best() and a.fitness() == b.fitness()
        la = a.jobs()[0]["ga"]["logbook"]
        lb = b.jobs()[0]["ga"]["logbook"]
        assert np.array_equal(la["min"], lb["min"]) and np.array_equal(la["mean"], lb["mean"])


@pytest.mark.parametrize(
    "old, new, message",
    [
        (
            "params: {from: first}\n    target",
            "params: {from: third}\n    target",
            "pipe.yaml:12: from: 'third' is not a stage of this pipeline; stages: first, second",
        ),
        (
            "    params: {from: first}\n",
            "    params: {from: second}\n",
            "pipe.yaml:12: from: 'second' is a later stage",
        ),
        (
            "    free: {k: [20, 500]}\n",
            "    free: {kk: [20, 500]}\n",
            "pipe.yaml:15: free.kk: model 'oscillator' has no parameter 'kk'",
        ),
        ("name: two\n", "name: two\nstage: 3\n", "pipe.yaml:2: stage: unknown key"),
        (
            "name: two\n",
            "name: two\nreport: {jdn: 0.1}\n",
            "pipe.yaml:2: report.jdn: unknown key (did you mean 'jnd'?)",
        ),
        ("name: two\n", "name: two\nreport: {jnd: 2}\n", "report.jnd: must be <= 1"),
    ],
)
def test_pipeline_files_are_checked_before_any_stage_starts(folder, old, new, message):
    text = PIPELINE.replace(old, new, 1)
    assert text != PIPELINE
    (folder / "pipe.yaml").write_text(text)
    with pytest.raises(UserError) as err:
        load_pipeline(folder / "pipe.yaml")
    assert message in str(err.value)


def test_from_outside_a_pipeline_is_refused_with_its_line(folder):
    from evo_door.experiment import load_experiment

    (folder / "exp.yaml").write_text(
        f"model: {OSC}\nparams: {{from: physical}}\ntarget: {{data: trials.h5}}\n"
        "free: {k: [20, 500]}\n"
    )
    with pytest.raises(UserError, match=r"exp.yaml:2: \{from: physical\} .* pipeline"):
        load_experiment(folder / "exp.yaml")


def test_the_commands_take_a_pipeline(folder, capsys):
    assert is_pipeline(folder / "pipe.yaml")
    out = folder / "p.h5"
    code, text, _ = cli(capsys, "run", str(folder / "pipe.yaml"), "--out", str(out), "--quiet")
    assert code == 0 and out.exists()
    code, text, _ = cli(capsys, "show", str(out))
    assert code == 0 and "pipeline two: complete" in text and "== stage second ==" in text
    code, text, _ = cli(capsys, "show", str(out), "--stage", "second", "--json")
    assert code == 0 and json.loads(text)["best"]["k"] > 0
    code, _, err = cli(capsys, "show", str(out), "--stage", "thrid")
    assert code == 2 and "'thrid' is not a stage" in err and "did you mean 'third'" not in err
    code, _, err = cli(capsys, "show", str(out), "--plot", str(folder / "f.png"))
    assert code == 2 and "--stage" in err
    code, text, _ = cli(capsys, "runs", str(folder))
    assert "p.h5 [first]" in text and "p.h5 [second]" in text
    code, text, _ = cli(capsys, "resume", str(out))
    assert code == 0 and "already complete" in text
    # a complete pipeline is not replaced without --force
    code, _, err = cli(capsys, "run", str(folder / "pipe.yaml"), "--out", str(out), "--quiet")
    assert code == 2 and "holds a complete pipeline" in err


@pytest.mark.slow
def test_compare_takes_a_stage_of_each_pipeline_or_one_file_s_stage(folder, capsys):
    """compare --stage S: stage S of every pipeline given; P.h5:S one file's stage, beside a
    run's own file or another stage of the same pipeline. Refusals: one line, exit 2, the
    folder untouched."""
    import shutil

    from evo_door.experiment import load_experiment, run_experiment
    from tests.test_bad_input import snapshot
    from tests.test_experiment import EXPERIMENT

    a, b = run_pipeline(folder, "a.h5").path, folder / "b.h5"
    shutil.copy(a, b)  # a second pipeline's file, as far as compare can tell
    (folder / "exp.yaml").write_text(EXPERIMENT)
    single = run_experiment(load_experiment(folder / "exp.yaml"), folder / "single.h5").path
    res = cli(capsys, "compare", a, b, "--stage", "second", "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["stages"] == ["second", "second"] and doc["runs"][0]["stage"] == "second"
    assert doc["runs"][0]["params"]["k"]["value"] == Results(a, "second").best()["k"]
    # a run's own file beside a stage: by --stage (it applies to the pipeline) or FILE:STAGE
    for args in ([single, b, "--stage", "first"], [single, f"{b}:first"]):
        res = cli(capsys, "compare", *args)
        assert res.returncode == 0, res.stderr
        assert res.stdout.splitlines()[0].split() == ["single.h5", "b.h5", "[first]"]
    res = cli(capsys, "compare", f"{a}:first", f"{a}:second", "--json")
    assert json.loads(res.stdout)["differences"]["name"] == ["first", "second"]
    before = snapshot(folder)
    for args, message in [
        ([single, b], f"{b}: a pipeline of stages first, second: name the stage to compare "
                      f"with --stage NAME, or {b}:NAME"),
        ([a, b, "--stage", "thrid"], "stage 'thrid' is not a stage of it; stages with "
                                     "results: first, second"),
        ([single, f"{b}:third"], "stage 'third' is not a stage of it; stages with results: "
                                 "first, second"),
        ([single, f"{b}:"], "name the stage after the colon"),
        ([single, f"{single}:first"], "single.h5: holds one run, not a pipeline"),
        ([single, single, "--stage", "first"], "--stage first: none of the files given is a "
                                               "pipeline's"),
        ([single, f"{folder}/missing.h5:first"], "missing.h5: results file not found"),
    ]:  # fmt: skip
        res = cli(capsys, "compare", *args)
        lines = res.stderr.splitlines()
        assert res.returncode == 2 and len(lines) == 1 and res.stdout == "", res.stderr
        assert lines[0].startswith("evo-door: error: ") and message in lines[0], lines[0]
    assert snapshot(folder) == before


@pytest.mark.slow
def test_compare_objectives_runs_on_a_stage_that_starts_from_earlier_ones(folder, capsys):
    out = run_pipeline(folder).path
    args = ["compare-objectives", folder / "pipe.yaml", "--stage", "second", "--kinds", "ise"]
    args += ["--derivatives", "1", "--out", folder / "cmp", "--quiet"]
    res = cli(capsys, *args)
    assert res.returncode == 2 and "--from RUN.h5" in res.stderr
    res = cli(capsys, *args, "--from", out)
    assert res.returncode == 0, res.stderr
    (run,) = sorted((folder / "cmp").glob("*.h5"))
    # the stage's {from: first} came from the pipeline's results: first's answer
    assert Results(run).values()["c"] == pytest.approx(Results(out, "first").best()["c"])


def test_the_progress_display_names_the_stage(folder, capsys):
    pipe = load_pipeline(folder / "pipe.yaml")
    PipelineRun.create(pipe, folder / "progress.h5").run(progress=True)
    err = capsys.readouterr().err
    assert "stage 1/2 first: model" in err and "stage 2/2 second: model" in err
    assert "free: k, from first\n" in err  # the stage's sources, kept while it runs
    # the GA's own lines carry the stage too
    assert "stage 2/2 second: best fitness" in err
