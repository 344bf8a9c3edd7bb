"""The results reader: one open of a file per command, typed records, errors by type."""

import ast
import json
from pathlib import Path

import h5py
import pytest

import evo_door
from evo_door.errors import NotResultsFileError, UserError
from evo_door.experiment.reader import PipelineRecord, RunRecord, pick, read_results
from tests.test_cli import cli
from tests.test_pipeline import folder, run_pipeline  # noqa: F401 (a fixture)


@pytest.fixture()
def pipeline_file(folder):  # noqa: F811 (the fixture imported above)
    return run_pipeline(folder).path


@pytest.fixture()
def opens(monkeypatch):
    """Every HDF5 file opened from here on, in order (h5py.File, however reached)."""
    seen = []
    real = h5py.File

    def counting(name, *args, **kwargs):
        seen.append(Path(name).name)
        return real(name, *args, **kwargs)

    monkeypatch.setattr(h5py, "File", counting)
    return seen


def test_show_of_a_pipeline_opens_its_file_once(pipeline_file, opens, capsys):
    # once for the text, once for --json: a second open per command would double these
    shown = cli(capsys, "show", pipeline_file)
    assert shown.returncode == 0, shown.stderr
    assert "== stage first ==" in shown.stdout and "== stage second ==" in shown.stdout
    assert opens == [pipeline_file.name]
    doc = json.loads(cli(capsys, "show", pipeline_file, "--json").stdout)
    assert set(doc["stage_results"]) == {"first", "second"}
    assert opens == [pipeline_file.name] * 2


def test_the_other_views_open_each_file_once(pipeline_file, opens, capsys, tmp_path):
    p = str(pipeline_file)
    assert cli(capsys, "show", p, "--stage", "second").returncode == 0
    assert cli(capsys, "compare", f"{p}:first", f"{p}:second").returncode == 0
    assert cli(capsys, "export-spec", p, "--stage", "second").returncode == 0
    assert cli(capsys, "runs", pipeline_file.parent).returncode == 0
    assert cli(capsys, "report", p, "--out", tmp_path / "rep").returncode == 0
    # runs also opens the folder's trial file once, to skip it
    assert opens == [pipeline_file.name] * 3 + sorted(["out.h5", "trials.h5"]) + ["out.h5"]


def test_a_pipeline_reads_into_typed_records_of_its_stages(pipeline_file):
    record = read_results(pipeline_file)
    assert isinstance(record, PipelineRecord) and record.stages == ["first", "second"]
    second = pick(record, "second")
    assert isinstance(second, RunRecord) and second.stage == "second" and second.complete
    assert second.sources == {"params": "first", "target.params": "first"}
    assert second.settings.free == ["k"] and second.settings.bounds == {"k": (20.0, 500.0)}
    assert second.best is not None and set(second.best.values) == {"k"}
    assert [r.trial_id for r in second.responses] == ["t1", "t2"]
    assert second.jobs[0].ga.logbook is not None
    light = read_results(pipeline_file, arrays=False)
    assert light.runs["second"].jobs[0].ga.logbook is None and not light.runs["second"].trials
    assert light.runs["second"].best.values == second.best.values
    with pytest.raises(UserError, match="stage 'third' is not a stage of it"):
        pick(record, "third")
    with pytest.raises(UserError, match="name one with --stage"):
        pick(record, None)


def test_a_foreign_file_is_told_from_a_damaged_one_by_its_type(folder, tmp_path):  # noqa: F811
    with pytest.raises(NotResultsFileError, match="not an evo-door results file"):
        read_results(folder / "trials.h5")
    damaged = tmp_path / "damaged.h5"
    with h5py.File(damaged, "w") as f:
        f.attrs["format"] = "evo-door run"  # a results file's root, nothing under it
    with pytest.raises(UserError, match="not a readable results file") as info:
        read_results(damaged)
    assert not isinstance(info.value, NotResultsFileError)


def _imports(module: str) -> set[str]:
    path = Path(evo_door.__file__).parent / (module.replace(".", "/") + ".py")
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return found


def test_the_store_imports_none_of_the_views_and_the_bound_is_defined_once():
    views = {
        "evo_door.experiment.results",
        "evo_door.reporting.format_text",
        "evo_door.reporting.format_json",
        "evo_door.reporting.format_tables",
        "evo_door.reporting.figures",
    }
    assert not _imports("experiment.store") & views
    assert not _imports("experiment.reader") & views
    from evo_door.optim import bounds, identifiability

    assert identifiability.BOUND_TOLERANCE is bounds.BOUND_TOLERANCE
