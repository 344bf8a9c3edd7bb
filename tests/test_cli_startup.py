"""Start-up of the command line: building the parser, ``--help`` and ``params haptic``
import none of the heavy libraries (numba, scipy, matplotlib, h5py, deap, aiohttp, and
numpy until a parameter vector is built).

Checked on ``sys.modules`` of a fresh interpreter, not on time (the time is
benchmarks/bench_startup.py's).
"""

import json
import subprocess
import sys

import pytest

from tests.helpers import ROOT

HEAVY = ("numba", "scipy", "matplotlib", "h5py", "deap", "aiohttp", "numpy")

# Runs CODE in a fresh interpreter, then prints (as the last line) the heavy modules
# it left in sys.modules, as JSON.
_PROBE = """
import contextlib, io, json, sys
out = io.StringIO()
with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
{code}
heavy = sorted({{m.split(".")[0] for m in sys.modules}} & set({heavy!r}))
print(out.getvalue())
print(json.dumps(heavy))
"""


def _probe(code: str) -> tuple[str, list[str]]:
    body = "\n".join("    " + line for line in code.strip().splitlines())
    script = _PROBE.format(code=body, heavy=HEAVY)
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    *printed, last = done.stdout.rstrip("\n").splitlines()
    return "\n".join(printed), json.loads(last)


def test_build_parser_imports_nothing_heavy():
    printed, heavy = _probe(
        """
import evo_door.cli
parser = evo_door.cli.build_parser()
print(sorted(parser._subparsers._group_actions[0].choices))
"""
    )
    assert heavy == []
    # every command was registered (the probe is not vacuous)
    for command in ("params", "simulate", "curve", "run", "report", "export-spec"):
        assert repr(command) in printed


def test_help_imports_nothing_heavy():
    printed, heavy = _probe(
        """
import evo_door.cli
try:
    evo_door.cli.main(["--help"])
except SystemExit as exc:
    assert exc.code == 0, exc.code
"""
    )
    assert heavy == []
    assert "usage: evo-door" in printed


def test_import_evo_door_imports_nothing_heavy_and_offers_the_api_lazily():
    """``import evo_door`` holds the version; the API's names (docs/api.md) are there,
    imported when first asked for (PEP 562), and only then."""
    printed, heavy = _probe(
        """
import sys
import evo_door
print(evo_door.__version__, "Experiment" in dir(evo_door), "evo_door.api" in sys.modules)
try:
    evo_door.Experimentt
except AttributeError as exc:
    print(exc)
"""
    )
    assert heavy == []
    assert printed.splitlines()[0].endswith(" True False")
    assert printed.splitlines()[1] == "module 'evo_door' has no attribute 'Experimentt'"
    _, heavy = _probe("import evo_door\nprint(evo_door.Experiment.__module__)")
    assert "numpy" in heavy  # the probe sees the API's import when it happens


def test_the_api_names_are_the_package_s():
    import evo_door
    import evo_door.api

    assert set(evo_door.API) == set(evo_door.api.__all__)
    assert evo_door.Experiment is evo_door.api.Experiment
    assert evo_door.load is evo_door.api.load


@pytest.mark.parametrize(
    "extra", [[], ["--json"], ["--params", "seed_trial", "--set", "inertia=2.5", "--json"]]
)
def test_params_haptic_imports_nothing_heavy(extra):
    printed, heavy = _probe(
        f"""
import evo_door.cli
assert evo_door.cli.main(["params", "haptic", *{extra!r}]) == 0
"""
    )
    # a loaded parameter set is a numpy vector; the declaration alone is not
    assert heavy == (["numpy"] if "--params" in extra else [])
    if "--json" in extra:
        rows = {r["name"]: r for r in json.loads(printed)["params"]}
        assert "inertia" in rows and "latch_gate_slope" in rows
        if "--set" in extra:
            assert rows["inertia"]["value"] == 2.5
    else:
        assert printed.startswith("Haptic model of the dishwasher door (haptic):")


def test_haptic_declaration_is_the_models():
    from evo_door.models import get_declaration, get_model, haptic, haptic_params

    model = get_model("haptic")
    declared = haptic_params.DECLARATION
    assert haptic.PARAMS is haptic_params.PARAMS is model.params is declared.params
    assert (declared.name, declared.title, declared.notes) == (
        model.name,
        model.title,
        model.notes,
    )
    assert declared.presets() == model.presets()
    assert (
        declared.load_params("seed_trial", {"inertia": 2.0}).as_dict()
        == model.load_params("seed_trial", {"inertia": 2.0}).as_dict()
    )
    # once the model is loaded, its declaration is the model itself
    assert get_declaration("haptic") is model


def test_door_declaration_is_the_models():
    """The door's declaration (no numba) is the model's: names, units, bounds, notes;
    once the model is loaded, its declaration is the model itself."""
    from evo_door.models import door_params, get_declaration, get_model

    model = get_model("door")
    declared = door_params.DECLARATION
    assert model.params is declared.params
    assert (declared.name, declared.title, declared.notes, declared.theta_unit) == (
        model.name,
        model.title,
        model.notes,
        model.theta_unit,
    )
    assert get_declaration("door") is model


def test_params_door_and_the_readers_of_a_door_run_import_no_numba():
    """``params door``, ``show`` (text and JSON) and ``runs`` on a door run read the
    door's names, units and presets from its declaration, without the model's kernels."""
    from evo_door.models import get_model

    run = ROOT / "tests" / "data" / "run-0.1-interrupted.h5"
    printed, heavy = _probe(
        f"""
import contextlib, io, json
import evo_door.cli
from evo_door.models import get_declaration
with contextlib.redirect_stdout(io.StringIO()) as said:
    assert evo_door.cli.main(["params", "door"]) == 0
    assert evo_door.cli.main(["show", {str(run)!r}]) == 0
    assert evo_door.cli.main(["runs", {str(run.parent)!r}]) == 0
with contextlib.redirect_stdout(io.StringIO()) as shown:
    assert evo_door.cli.main(["show", {str(run)!r}, "--json"]) == 0
print(json.dumps(json.loads(shown.getvalue())["units"]))
print(json.dumps(get_declaration("door").presets()))
print("F_atD" in said.getvalue() and "N m" in said.getvalue())
"""
    )
    assert "numba" not in heavy, heavy
    units, presets, text = printed.strip().splitlines()
    assert json.loads(units) == {"F_load": "N", "M": "kg", "F_atD": "N"}
    assert json.loads(presets) == get_model("door").presets() and "table54_spec" in presets
    assert text == "True"


def test_a_mechanism_file_is_declared_from_the_file_alone():
    """``params`` on a mechanism file, and its declaration (what ``show`` reads of a
    mechanism's run), come from the file: its module is neither generated nor
    compiled, numba not imported; the coordinate's unit follows the handle's kind."""
    blocks = ROOT / "examples" / "blocks"
    printed, heavy = _probe(
        f"""
import json
import evo_door.cli
from evo_door.models import get_declaration
with contextlib.redirect_stdout(io.StringIO()) as said:
    assert evo_door.cli.main(["params", {str(blocks / "soft_close_drawer.yaml")!r}, "--json"]) == 0
units = {{r["name"]: r["unit"] for r in json.loads(said.getvalue())["params"]}}
print(json.dumps(units))
knob, drawer = (get_declaration(str({str(blocks)!r}) + f) for f in ("/knob.yaml", "/soft_close_drawer.yaml"))
print(knob.theta_unit, drawer.theta_unit, knob.name, len(knob.params))
"""
    )
    assert "numba" not in heavy, heavy
    units, declared = printed.strip().splitlines()
    assert json.loads(units)["box.mass"] == "kg" and json.loads(units)["runners.level"] == "N"
    assert declared.split()[:3] == ["rad", "m", "detent-knob"]


def test_declaration_of_other_models_is_the_model():
    from evo_door.models import get_declaration, get_model

    name = "tests.conftest:OSCILLATOR_MODEL"
    assert get_declaration(name) is get_model(name)


def test_declaration_of_unknown_model_is_a_user_error():
    from evo_door.errors import UserError
    from evo_door.models import get_declaration

    with pytest.raises(UserError, match="unknown model 'haptc'"):
        get_declaration("haptc")


def test_constants_written_out_for_the_parser_agree_with_the_library():
    """The commands spell out a few library constants so as not to import the library
    at start-up; they must not drift from it."""
    from evo_door.commands import export_spec, report, simulate
    from evo_door.experiment.spec import FORMATS
    from evo_door.reporting import report as report_lib
    from evo_door.sim import METHODS

    assert simulate.METHOD_NAMES == tuple(sorted(METHODS))
    assert export_spec.FORMAT_NAMES == tuple(FORMATS)
    assert report.DEFAULT_JND == report_lib.DEFAULT_JND
    assert report.FORCE_FLOOR == report_lib.FORCE_FLOOR


def test_reading_results_loads_no_integrator():
    """The results reader (``show``, ``export-spec``, ``runs``) and a refusal of a file
    that is not there import neither numba nor the runner: the settings a results file
    states are plain data (``evo_door.sim_settings``) and ``evo_door.experiment`` loads
    its names on first use. Asking for one of them loads it."""
    printed, heavy = _probe(
        """
import sys
import evo_door.cli, evo_door.experiment.reader
assert evo_door.cli.main(["show", "missing.h5"]) == 2
print("runner" if "evo_door.experiment.runner" in sys.modules else "no runner")
"""
    )
    assert "numba" not in heavy and printed.strip() == "no runner"
    printed, heavy = _probe(
        """
from evo_door.sim import simulate
from evo_door.experiment import ExperimentRun
print(simulate.__module__, ExperimentRun.__module__)
"""
    )
    assert (
        "numba" in heavy and printed.strip() == "evo_door.sim.simulate evo_door.experiment.runner"
    )
