"""``evo-door compare-objectives``: max-square and ISE on derivatives 0-2 over GA seeds."""

import csv
import math

import numpy as np
import pytest

from evo_door.data.io import write_trials
from evo_door.errors import UserError
from evo_door.experiment import ExperimentRun, Interrupted, Results
from evo_door.experiment.comparison import (
    parse_derivatives,
    parse_kinds,
    parse_seeds,
    plan_comparison,
    run_comparison,
)
from evo_door.experiment.comparison_summary import run_records, summarise
from evo_door.reporting.comparison_outputs import write_outputs
from evo_door.reporting.format_json import compare
from evo_door.sim import simulate
from tests.conftest import OSCILLATOR_MODEL
from tests.test_cli import cli
from tests.test_experiment import EXPERIMENT
from tests.test_optim import TRUE, make_trial

TRUTH = {"model": "oscillator", "params": {**TRUE, "theta_eq": 0.0}}


def trials_with_truth(**changes):
    """Three fitted and one validation oscillator trial, noise-free, truth stored."""
    ids = ["t1", "t2", "t3", "v1"]
    return [
        make_trial(seed, 0.75, tid=tid).replace(truth=TRUTH, **changes)
        for seed, tid in zip((1, 2, 3, 4), ids)
    ]


def experiment_folder(folder, **changes):
    """``folder`` with the oscillator experiment and its trials (truth stored)."""
    write_trials(folder / "trials.h5", trials_with_truth(**changes))
    (folder / "exp.yaml").write_text(EXPERIMENT)
    return folder


#: GA 16 x 2 then SLSQP: enough on noise-free trials, and 12 runs stay near 4 s
QUICK = ["algorithm.generations=2"]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """One comparison of every kind x derivative x 2 seeds (12 small runs, ~6 s)."""
    folder = experiment_folder(tmp_path_factory.mktemp("objectives"))
    comp = plan_comparison(folder / "exp.yaml", QUICK, seeds=2, out=folder / "cmp")
    run_comparison(comp)
    records = run_records(comp)
    rows = summarise(records)
    paths = write_outputs(comp, records, rows)
    return folder, comp, records, rows, paths


@pytest.mark.slow  # the shared grid of 12 runs takes ~6 s
def test_table_has_every_combination_and_every_file(made):
    folder, comp, records, rows, paths = made
    combos = [(k, d) for k in ("max_square", "ise") for d in (0, 1, 2)]
    assert [(r["kind"], r["derivative"]) for r in rows] == combos
    assert all(r["seeds"] == [1, 2] for r in rows)
    assert comp.skipped == {}
    # one normal results file per run, made with that objective and seed
    assert len(records) == 12
    for rec in records:
        res = Results(folder / "cmp" / rec["file"])
        assert res.complete
        assert res.config["objective"]["kind"] == rec["kind"]
        assert res.config["objective"]["derivative"] == rec["derivative"]
        assert res.config["algorithm"]["seed"] == rec["seed"]
        assert rec["file"] == f"osc-{rec['kind']}-d{rec['derivative']}-s{rec['seed']}.h5"
        # everything else as the experiment file says
        assert res.config["algorithm"]["population"] == 16
        assert res.config["algorithm"]["generations"] == 2
        assert res.config["free"] == {"k": [20, 500], "c": [0, 10], "inertia": [0.2, 8]}
    assert [p.name for p in paths] == ["compare.csv", "compare.md", "compare.png", "runs.csv"]
    with open(folder / "cmp" / "compare.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [(t["kind"], int(t["derivative"])) for t in table] == combos
    assert {
        "k mean [N/rad]",
        "k error mean [%]",
        "rms dtheta error validation mean [deg/s]",
    } <= set(table[0])
    with open(folder / "cmp" / "runs.csv", newline="") as fh:
        assert len(list(csv.DictReader(fh))) == 12
    md = (folder / "cmp" / "compare.md").read_text()
    table_lines = [line for line in md.splitlines() if line.startswith("| ") and " on " in line]
    assert len(table_lines) == 6 and table_lines[3].startswith("| ise on theta (d0) | 2 |")
    assert "--derivatives 0,1,2 --seeds 2 --set algorithm.generations=2" in md
    assert (folder / "cmp" / "compare.png").read_bytes().startswith(b"\x89PNG")


@pytest.mark.slow  # the shared grid of 12 runs takes ~6 s
def test_truth_errors_are_those_of_the_runs_own_results(made):
    folder, comp, records, rows, _ = made
    for rec in records:
        res = Results(folder / "cmp" / rec["file"])
        best, truth = res.best(), res.truth()
        assert truth == {"k": 100.0, "c": 2.0, "inertia": 1.5}
        assert rec["values"] == best
        for n in truth:
            assert rec["errors"][n] == pytest.approx(
                100 * (best[n] - truth[n]) / truth[n], rel=1e-12
            )
        assert rec["fitness"] == res.fitness()
        assert rec["evaluations"] == res.tree["timings"]["@attrs"]["evaluations"]
    # `evo-door compare` computes the same errors its own way
    doc = compare([Results(folder / "cmp" / rec["file"]) for rec in records[:2]])
    for entry, rec in zip(doc["runs"], records[:2]):
        for n in ("k", "c", "inertia"):
            assert entry["params"][n]["error_percent"] == pytest.approx(rec["errors"][n], rel=1e-12)
    # a row's statistics are those of its seeds' runs
    for row in rows:
        mine = [
            r for r in records if (r["kind"], r["derivative"]) == (row["kind"], row["derivative"])
        ]
        for n, p in row["params"].items():
            errors = [r["errors"][n] for r in mine]
            assert p["error"]["mean"] == pytest.approx(np.mean(errors), rel=1e-12)
            assert (p["error"]["min"], p["error"]["max"]) == (min(errors), max(errors))
            assert p["value"]["std"] == pytest.approx(
                np.std([r["values"][n] for r in mine], ddof=1)
            )
        assert row["seconds_total"] == pytest.approx(sum(r["seconds"] for r in mine))


@pytest.mark.slow  # the shared grid of 12 runs takes ~6 s
def test_on_noise_free_data_every_objective_recovers_the_truth(made):
    _, _, _, rows, _ = made
    for row in rows:
        for n, p in row["params"].items():
            worst = max(abs(p["error"]["min"]), abs(p["error"]["max"]))
            assert worst < 0.05, (row["kind"], row["derivative"], n, worst)
        # and the common yardstick: well under 0.01 deg/s of speed error on v1
        assert row["rms_validation"]["max"] < 1e-3 * math.pi / 180


@pytest.mark.slow  # the shared grid of 12 runs takes ~6 s
def test_the_yardstick_is_the_rms_speed_error_of_an_independent_simulation(made):
    folder, _, records, _, _ = made
    v1 = trials_with_truth()[3]
    for rec in records[:: len(records) // 4]:
        res = Results(folder / "cmp" / rec["file"])
        p = np.asarray(res.tree["best"]["full"])
        r = simulate(OSCILLATOR_MODEL, p, v1.force, v1.dt, theta0=v1.theta0, dtheta0=v1.dtheta0)
        expected = math.sqrt(np.mean((r.dtheta - v1.dtheta) ** 2))
        assert rec["yardstick"]["channel"] == "dtheta"
        assert rec["yardstick"]["validation"] == pytest.approx(expected, rel=1e-9)
        largest = np.max(np.abs(r.dtheta - v1.dtheta))
        assert rec["yardstick"]["validation_max"] == pytest.approx(largest, rel=1e-9)
        # far from zero for a wrong answer: it would catch a yardstick that ignores x
        off = simulate(OSCILLATOR_MODEL, p * [1.1, 1, 1, 1], v1.force, v1.dt, theta0=v1.theta0)
        assert math.sqrt(np.mean((off.dtheta - v1.dtheta) ** 2)) > 100 * expected


def test_a_derivative_the_trials_cannot_serve_is_left_out_or_refused(tmp_path):
    experiment_folder(tmp_path, theta=None, ddtheta=None)
    out = tmp_path / "cmp"
    # not asked for by name: left out, with a note saying why
    comp = plan_comparison(tmp_path / "exp.yaml", out=out)
    assert comp.derivatives == [1] and sorted(comp.skipped) == [0, 2]
    assert "trial 't1' has no 'theta' channel (it has dtheta)" in comp.notes()[0]
    assert {v.derivative for v in comp.variants} == {1}
    # asked for by name: one line that says which derivatives the trials allow
    with pytest.raises(UserError, match=r"^--derivatives 0: trial 't1' has no 'theta' channel"):
        plan_comparison(tmp_path / "exp.yaml", derivatives=[1, 0], out=out)
    with pytest.raises(
        UserError, match="'ddtheta' channel .*; these trials allow --derivatives 1$"
    ):
        plan_comparison(tmp_path / "exp.yaml", derivatives=[2], out=out)
    # a problem of every derivative is the run's own error, as `evo-door run` gives it
    with pytest.raises(
        UserError, match=r"^--set target.validate=\[v9\]: target.validate: .* no trial 'v9'"
    ):
        plan_comparison(tmp_path / "exp.yaml", ["target.validate=[v9]"], out=out)
    assert not out.exists()


@pytest.mark.slow  # the shared grid of 12 runs takes ~6 s
def test_runs_already_there_are_refused_kept_or_continued(made, tmp_path):
    folder, comp, records, _, _ = made
    with pytest.raises(
        UserError, match=r"already holds osc-max_square-d0-s1.h5 and 11 more.*--force"
    ):
        plan_comparison(folder / "exp.yaml", QUICK, seeds=2, out=comp.folder)
    kept = plan_comparison(folder / "exp.yaml", QUICK, seeds=2, out=comp.folder, resume=True)
    assert kept.kept == set(kept.variants)
    stamps = {p: p.stat().st_mtime_ns for p in comp.folder.glob("*.h5")}
    run_comparison(kept)
    assert {p: p.stat().st_mtime_ns for p in comp.folder.glob("*.h5")} == stamps
    with pytest.raises(UserError, match=r"made with other settings \(algorithm.generations"):
        plan_comparison(
            folder / "exp.yaml", ["algorithm.generations=3"], seeds=2, out=comp.folder, resume=True
        )
    # an interrupted run is continued to the result of an uninterrupted one
    part = plan_comparison(
        folder / "exp.yaml", QUICK, kinds=["ise"], derivatives=[2], seeds=1, out=tmp_path / "p"
    )
    (v,) = part.variants

    def stop(run, job):
        if job.ga is not None and job.ga.generation >= 1:
            raise Interrupted

    with pytest.raises(Interrupted):
        ExperimentRun.create(part.experiments[v], part.path(v)).run(on_checkpoint=stop)
    again = plan_comparison(
        folder / "exp.yaml",
        QUICK,
        kinds=["ise"],
        derivatives=[2],
        seeds=1,
        out=tmp_path / "p",
        resume=True,
    )
    assert again.kept == set()
    run_comparison(again)
    whole = next(r for r in records if r["file"] == v.file_name("osc"))
    assert Results(part.path(v)).best() == whole["values"]


@pytest.mark.slow
def test_cli_prints_the_table_and_writes_the_files(tmp_path, capsys):
    folder = experiment_folder(tmp_path)
    out = folder / "cli"
    res = cli(
        capsys, "compare-objectives", folder / "exp.yaml", "--kinds", "ise,max-square",
        "--derivatives", "1", "--out", out, "--set", "algorithm.generations=2",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert lines[0].startswith("osc: 2 run(s): ise, max_square on derivative(s) 1, seed(s) 1;")
    assert any(line.startswith("ise on dtheta (d1)") for line in lines)
    assert any(line.startswith("closest to the true values: ") for line in lines)
    assert sorted(p.name for p in out.iterdir()) == [
        "compare.csv", "compare.md", "compare.png", "osc-ise-d1-s1.h5",
        "osc-max_square-d1-s1.h5", "runs.csv",
    ]  # fmt: skip
    assert res.stderr == ""  # no progress bar off a terminal
    assert Results(out / "osc-ise-d1-s1.h5").config["algorithm"]["generations"] == 2
    quiet = cli(
        capsys, "compare-objectives", folder / "exp.yaml", "--kinds", "ise", "--derivatives",
        "1", "--out", out, "--set", "algorithm.generations=2", "--resume", "--quiet",
    )  # fmt: skip
    assert quiet.returncode == 0 and quiet.stdout == "" and quiet.stderr == ""


@pytest.mark.parametrize(
    "parse, text, message",
    [
        (parse_kinds, "ise,msq", r"--kinds ise,msq: 'msq' is not an objective kind"),
        (parse_kinds, "max_sqare", r"did you mean 'max_square'"),
        (parse_kinds, "ise,", r"--kinds 'ise,': expected a comma-separated list"),
        (parse_derivatives, "0,3", r"--derivatives 0,3: '3' is not a derivative"),
        (parse_derivatives, "-1", r"'-1' is not a derivative"),
        (parse_seeds, "0", r"--seeds 0: from 1 to 100"),
        (parse_seeds, "1000000000", r"--seeds 1000000000: from 1 to 100"),
        (parse_seeds, "two", r"--seeds two: expected a whole number"),
    ],
)
def test_bad_options_are_one_line_naming_the_option(parse, text, message):
    with pytest.raises(UserError, match=message):
        parse(text)
