"""Specification tables (export-spec) and identifiability as recorded by a run."""

import csv
import dataclasses
import io
import math
import re

import numpy as np
import pytest

from evo_door.data.io import write_trials
from evo_door.experiment import Results, load_experiment, run_experiment
from evo_door.experiment.spec import render, spec_table
from evo_door.models import get_model
from tests.test_cli import cli
from tests.test_experiment import EXPERIMENT, OSC
from tests.test_optim import TRUE, make_trial


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A per-trial run with a pooled fit, and a plain one, of noise-free oscillator trials
    that carry their truth."""
    w = tmp_path_factory.mktemp("spec")
    trials = [make_trial(s, 0.75, tid=f"t{s}") for s in (1, 2, 3)] + [make_trial(4, 0.75, tid="v1")]
    for tr in trials:
        tr.truth = {"model": "oscillator", "params": dict(TRUE, theta_eq=0.0)}
    write_trials(w / "trials.h5", trials)
    (w / "exp.yaml").write_text(EXPERIMENT)
    pooled = load_experiment(w / "exp.yaml", ["per_trial=true", "pooled=true"])
    run_experiment(pooled, out=w / "pooled.h5")
    run_experiment(load_experiment(w / "exp.yaml"), out=w / "plain.h5")
    return w


def test_a_per_trial_table_has_the_range_of_the_fits_and_the_pooled_value(runs):
    res = Results(runs / "pooled.h5")
    table = spec_table(res)
    assert table.form == "table 5.3"
    summary = res.summary()
    rows = {r.name: r for r in table.rows}
    assert set(res.free) <= set(rows)
    for name in res.free:
        row = rows[name]
        assert row.status == "estimated"
        assert (
            row.low == summary["table"][name]["min"] and row.high == summary["table"][name]["max"]
        )
        assert row.value == res.best()[name]  # the pooled fit, not the mean
        assert row.true == TRUE[name]
        assert row.verdict in ("identifiable", "correlated", "not identifiable")
    # the pooled fit of noise-free trials recovers the truth
    for name in res.free:
        assert res.best()[name] == pytest.approx(TRUE[name], rel=0.02)


def test_formats_hold_the_same_numbers(runs):
    table = spec_table(Results(runs / "plain.h5"))
    assert table.form == "table 5.4"
    rows = list(csv.reader(io.StringIO(render(table, "csv"))))
    header, body = rows[0], {r[0]: dict(zip(rows[0], r)) for r in rows[1:]}
    assert header[:4] == ["parameter", "symbol", "unit", "value"] and "min" not in header
    for r in table.rows:
        assert float(body[r.name]["value"]) == pytest.approx(r.value, rel=1e-5)
        assert body[r.name]["unit"] == r.unit
    md = render(table, "md")
    assert md.count("\n| ") == len(table.rows) + 1 and "seed table 5.4" in md
    tex = render(table, "tex")
    assert r"\begin{tabular}" in tex and "theta\\_eq" not in tex.split(r"\midrule")[0]
    assert tex.count(r" \\") == len(table.rows) + 1
    page = render(table, "html")
    assert page.startswith("<!DOCTYPE html>") and page.count("<tr") == len(table.rows) + 1


def test_the_csv_is_a_header_and_rows_that_csv_and_numpy_read_as_they_are(runs):
    table = spec_table(Results(runs / "pooled.h5"))
    text = render(table, "csv")
    columns = ["parameter", "symbol", "unit", "value", "min", "max", "true"]
    columns += ["status", "identifiability", "standard error", "note"]
    reader = csv.DictReader(io.StringIO(text))
    rows = list(reader)
    assert reader.fieldnames == columns  # the first line is the header, nothing before it
    assert [r["parameter"] for r in rows] == [r.name for r in table.rows]
    for row, want in zip(rows, table.rows):
        assert float(row["value"]) == pytest.approx(want.value, rel=1e-5)
        if want.has_range:
            assert float(row["min"]) == pytest.approx(want.low, rel=1e-5)
    data = np.genfromtxt(io.StringIO(text), delimiter=",", names=True, dtype=None, encoding="utf-8")
    assert data.dtype.names[:7] == tuple(columns[:7])
    assert len(data) == len(table.rows)
    assert np.allclose(data["value"], [r.value for r in table.rows], rtol=1e-5)
    assert np.allclose(data["true"], [r.true for r in table.rows], equal_nan=True)


def _md_cells(line: str) -> list[str]:
    """The cells of a Markdown table row as GitHub reads them: split at the pipes that
    are not escaped, the outer two dropped, ``\\|`` read back as a pipe."""
    parts = re.split(r"(?<!\\)\|", line.strip())
    assert parts[0] == "" and parts[-1] == "", line
    return [p.strip().replace("\\|", "|") for p in parts[1:-1]]


def test_markdown_keeps_a_pipe_inside_a_cell(runs):
    table = spec_table(Results(runs / "plain.h5"))
    note = "correlation +0.990 with k (|r| > 0.95)"
    table.rows[0] = dataclasses.replace(table.rows[0], note=note, verdict="correlated")
    md = render(table, "md")
    rows = [line for line in md.splitlines() if line.startswith("|")]
    header = _md_cells(rows[0])
    assert len(rows) == len(table.rows) + 2  # header, rule, one row per parameter
    for line in rows[2:]:
        assert len(_md_cells(line)) == len(header), line
    first = dict(zip(header, _md_cells(rows[2])))
    assert first["note"] == note and first["identifiability"] == "correlated"


def test_the_yaml_is_a_parameter_file_that_reads_back_to_the_runs_values(runs, capsys, tmp_path):
    out = tmp_path / "spec.yaml"
    res = cli(capsys, "export-spec", runs / "plain.h5", "--format", "yaml", "--out", out)
    assert res.returncode == 0, res.stderr
    model = get_model(OSC)
    back = model.load_params(str(out))
    values = Results(runs / "plain.h5").values()
    for name in model.params.names:
        assert back[name] == values[name]  # exact: floats written to round-trip


def test_identifiability_is_recorded_and_shown(runs, capsys):
    res = Results(runs / "plain.h5")
    ident = res.identifiability()
    assert ident is not None and ident.names == res.free
    assert all(math.isfinite(se) and se > 0 for se in ident.se)
    # per job, too: every fit has its own
    for job in res.jobs():
        assert "identifiability" in job
    shown = cli(capsys, "show", runs / "plain.h5").stdout
    assert "identifiability at the estimate" in shown
    doc = res.summary()
    assert set(doc["identifiability"]) == set(res.free)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--format", "xls"], "--format 'xls': choose one of csv, md, tex, html, yaml"),
        (["--stage", "physical"], "holds one run, not a pipeline"),
    ],
)
def test_export_spec_refuses_bad_input_in_one_line(runs, capsys, args, message):
    res = cli(capsys, "export-spec", runs / "plain.h5", *args)
    assert res.returncode == 2 and message in res.stderr and len(res.stderr.splitlines()) == 1
