import math

import numpy as np
import pytest

from evo_door.errors import ParameterError, UserError
from evo_door.params import Param, load_params, parse_assignments
from tests.conftest import OSCILLATOR_PARAMS as T


def test_vector_follows_declaration_order_and_defaults():
    vec = T.vector({"c": 2.5})
    assert vec.tolist() == [100.0, 2.5, 1.0, 0.0]
    assert T.as_dict(vec)["c"] == 2.5
    assert T.index("inertia") == 2


def test_unknown_name_suggests_closest():
    with pytest.raises(ParameterError, match=r"no parameter 'inertai'.*did you mean 'inertia'"):
        T.vector({"inertai": 1.0})


@pytest.mark.parametrize(
    "value, message",
    [
        (float("nan"), "must be finite"),
        (math.inf, "must be finite"),
        ("heavy", "must be a number"),
        (True, "must be a number"),
        (-1.0, r"outside its declared range \[0, 1e\+07\] N/rad"),
    ],
)
def test_bad_values_name_the_parameter(value, message):
    with pytest.raises(ParameterError, match=r"'k'.*" + message if "range" in message else message):
        T.vector({"k": value})


def test_declaration_rejects_default_outside_bounds():
    with pytest.raises(ValueError, match="outside"):
        Param("x", "m", 2.0, 0.0, 1.0, "geometry", "bad")
    with pytest.raises(ValueError, match="group"):
        Param("x", "m", 0.5, 0.0, 1.0, "colour", "bad")


def test_yaml_round_trip(tmp_path):
    ps = load_params(T, None).replace({"k": 250.0, "theta_eq": 0.125})
    path = tmp_path / "p.yaml"
    ps.to_yaml(path)
    again = load_params(T, path)
    np.testing.assert_array_equal(again.vector, ps.vector)
    assert again["k"] == 250.0


def test_yaml_errors_name_file_and_key(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("model: oscillator\nvalues:\n  k: [1, 2]\n")
    with pytest.raises(ParameterError, match=r"bad.yaml: parameter 'k' must be a number"):
        load_params(T, bad)
    bad.write_text("model: oscillator\nvalus: {k: 1}\n")
    with pytest.raises(UserError, match=r"unknown key 'valus'.*did you mean 'values'"):
        load_params(T, bad)
    bad.write_text("model: door\nvalues: {}\n")
    with pytest.raises(UserError, match="for model 'door', not 'oscillator'"):
        load_params(T, bad)
    bad.write_text("model: oscillator\nvalues: {k: 1\n")
    with pytest.raises(UserError, match=r"bad.yaml: line \d+ is not valid YAML"):
        load_params(T, bad)
    with pytest.raises(UserError, match="not found"):
        load_params(T, tmp_path / "missing.yaml")


def test_parse_assignments():
    assert parse_assignments(["k=3", " c = 0.5"]) == {"k": 3.0, "c": 0.5}
    with pytest.raises(UserError, match="NAME=VALUE"):
        parse_assignments(["k"])
    with pytest.raises(ParameterError, match="not a number"):
        parse_assignments(["k=soft"])


def test_table_text_lists_units_and_meaning():
    text = T.format_table()
    assert "N s/rad" in text and "viscous damping" in text
    assert text.splitlines()[0].split()[:3] == ["name", "unit", "default"]


def test_parameter_files_take_numbers_as_engineers_write_them(tmp_path):
    """PyYAML alone reads ``1e-3`` as text; parameter files accept it, and write 1.0e-03."""
    path = tmp_path / "p.yaml"
    path.write_text("model: oscillator\nvalues:\n  k: 2e2\n  c: 1e-3\n")
    ps = load_params(T, path)
    assert ps["k"] == 200.0 and ps["c"] == 1e-3
    text = ps.to_yaml()
    assert "1.0e-03" in text or "0.001" in text
    import yaml

    assert yaml.safe_load(text)["values"]["c"] == 1e-3  # any YAML 1.1 reader too


# -- parameter files of an upper layer's format (docs/architecture.md) ---------------------
def test_a_registered_reader_reads_its_hdf5_files_and_passes_the_others(tmp_path, monkeypatch):
    import h5py

    from evo_door.params import sets

    ours, other = tmp_path / "ours.h5", tmp_path / "other.h5"
    for path in (ours, other):
        with h5py.File(path, "w") as f:
            f.attrs["kind"] = path.stem
    seen = []

    def reader(table, path):
        seen.append(path.name)
        if path.name != "ours.h5":
            return None  # not its format: the next reader, then the YAML reader
        return sets.ParamSet.from_mapping(table, {"c": 3.0}, "from ours", str(path))

    monkeypatch.setattr(sets, "FILE_READERS", [])
    sets.register_file_reader(reader)
    sets.register_file_reader(reader)  # once per reader
    assert sets.FILE_READERS == [reader]
    ps = load_params(T, str(ours), {"k": 50.0})
    assert ps["c"] == 3.0 and ps["k"] == 50.0 and ps.description == "from ours"
    with pytest.raises(UserError, match="other.h5"):  # then read as YAML: refused
        load_params(T, str(other))
    assert seen == ["ours.h5", "other.h5"]


@pytest.mark.parametrize("way_in", ["evo_door.cli", "evo_door.experiment.batch"])
def test_every_way_in_reads_a_render_log_as_a_parameter_file(way_in):
    """The command line, and the experiment layer (as a batch's worker imports it),
    register the render-log reader; the parameter layer alone imports no renderer."""
    import subprocess
    import sys

    probe = (
        "import sys\n"
        "import evo_door.params\n"
        "assert 'evo_door.render' not in sys.modules\n"
        f"import {way_in}\n"
        "from evo_door.params.sets import FILE_READERS\n"
        "print([f'{r.__module__}.{r.__name__}' for r in FILE_READERS])\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == (
        "['evo_door.plugins.render_log_params', 'evo_door.plugins.nearest_feel_params']"
    )
