"""A results file is data, never code: a file that names a model that is code (a Python
file, a module path) is refused by every command that reads it, in one line, without
running it; ``--allow-model`` runs it for a file the user trusts.

Before, ``show``, ``compare``, ``runs``, ``export-spec``, ``report`` and ``resume``
imported whatever the file's root ``model`` attribute named (a relative path looked up
in the current folder): a results file someone mailed you could run anything.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import pytest

from evo_door.errors import UserError
from evo_door.experiment import load_experiment, run_experiment
from evo_door.files import reseal
from evo_door.files.metadata import encode_attr
from evo_door.models import allow_model, is_code_spec, model_in_file
from tests.helpers import TINY_EXPERIMENT, cli_process

ROOT = Path(__file__).resolve().parents[1]

#: a "model" that, once imported, leaves a mark: the proof that reading ran it
EVIL = """\
from pathlib import Path
Path(__file__).with_name("ran.txt").write_text("this file was run")
MODEL = None
"""


@pytest.fixture(scope="module")
def hostile(tmp_path_factory):
    """A real results file whose model is renamed to a Python file that marks when run,
    and a folder with only that file (for ``runs``)."""
    folder = tmp_path_factory.mktemp("trust")
    (folder / "exp.yaml").write_text(TINY_EXPERIMENT)
    run = run_experiment(load_experiment(folder / "exp.yaml"), out=folder / "good.h5")
    (folder / "evil.py").write_text(EVIL)
    (folder / "evil_mod.py").write_text(EVIL)
    shown = folder / "shown"
    shown.mkdir()
    for name, spec in (("file", f"{folder / 'evil.py'}:MODEL"), ("module", "evil_mod:MODEL")):
        path = shown / f"{name}.h5"
        shutil.copy(run.path, path)
        with h5py.File(path, "r+") as f:
            f.attrs["model"] = encode_attr(spec)
            reseal(f)  # a hostile sender writes the checksums right
    return folder, shown


@pytest.mark.parametrize("which", ["file", "module"])
def test_every_reading_command_refuses_a_file_naming_code_without_running_it(hostile, which):
    folder, shown = hostile
    path = shown / f"{which}.h5"
    commands = [
        ("show", path),
        ("show", path, "--json"),
        ("compare", path, folder / "good.h5"),
        ("export-spec", path, "--format", "md"),
        ("report", path, "--out", folder / f"report-{which}"),
        ("resume", path),
    ]
    for args in commands:
        done = cli_process(*args, cwd=folder)
        assert done.returncode == 2, (args, done.stdout, done.stderr)
        err = done.stderr
        assert err.count("\n") == 1 and err.startswith("evo-door: error:"), (args, err)
        assert "names model" in err and "--allow-model" in err, (args, err)
        assert not (folder / "ran.txt").exists(), args
    # a folder of them: each one listed as unreadable, with the reason, none run
    listed = cli_process("runs", shown, "--json", cwd=folder)
    assert listed.returncode == 0, listed.stderr
    rows = {r["file"]: r for r in json.loads(listed.stdout)}
    assert rows[path.name]["status"] == "unreadable"
    assert "names model" in rows[path.name]["status_text"]
    assert not (folder / "ran.txt").exists()


def test_allow_model_runs_the_named_model_for_a_file_the_user_trusts(hostile):
    folder, shown = hostile
    spec = f"{folder / 'evil.py'}:MODEL"
    done = cli_process("show", shown / "file.h5", "--allow-model", spec, cwd=folder)
    assert (folder / "ran.txt").exists(), done.stderr  # the user said so: it ran
    (folder / "ran.txt").unlink()


def test_installed_models_and_the_users_own_need_no_flag(tmp_path):
    assert not is_code_spec("door") and not is_code_spec("haptic")
    assert is_code_spec("x.py:MODEL") and is_code_spec("pkg.mod:MODEL")
    assert model_in_file("door", "a file").name == "door"
    (tmp_path / "mine.py").write_text("MODEL = None\n")
    spec = f"{tmp_path / 'mine.py'}:MODEL"
    with pytest.raises(UserError, match="names model .*--allow-model"):
        model_in_file(spec, "run.h5")
    allow_model(spec)  # what --allow-model does (and an experiment the user runs)
    with pytest.raises(UserError) as got:  # now it is loaded: this one is no model
        model_in_file(spec, "run.h5")
    assert "names model" not in str(got.value)
