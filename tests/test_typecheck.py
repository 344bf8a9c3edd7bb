"""The type check's baseline only shrinks (.ci/typecheck.py): a new error fails it with
its line, a fixed one fails it until --shrink removes it, --shrink never adds.

mypy itself is not run here (CI and ``tox -e typecheck`` run it); its output is made up.
"""

import doctest
import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def typecheck(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("typecheck", ROOT / ".ci" / "typecheck.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "ROOT", tmp_path)
    monkeypatch.setattr(module, "BASELINE", tmp_path / "baseline.txt")
    return module


def _mypy(*errors: str) -> str:
    return "\n".join([*errors, "evo_door/x.py:5: note: a note"]) + "\n"


OLD = 'evo_door/a.py:10: error: "None" has no attribute "close"  [attr-defined]'
NEW = 'evo_door/b.py:3: error: Incompatible return value type (got "int", expected "str")  [return-value]'


def test_its_examples(typecheck):
    assert doctest.testmod(typecheck).failed == 0


def test_a_known_error_that_moved_passes_and_a_new_one_fails_with_its_line(typecheck, capsys):
    typecheck.BASELINE.write_text(
        'evo_door/a.py: error: "None" has no attribute "close"  [attr-defined]\n'
    )
    typecheck.run_mypy = lambda: _mypy(OLD.replace(":10:", ":42:"))
    assert typecheck.main([]) == 0
    typecheck.run_mypy = lambda: _mypy(OLD, NEW)
    assert typecheck.main([]) == 1
    out = capsys.readouterr().out
    assert NEW in out and "1 new type errors" in out
    assert typecheck.main(["--shrink"]) == 1  # never adds
    assert "b.py" not in typecheck.BASELINE.read_text()


def test_a_fixed_error_fails_until_shrink_removes_it(typecheck, capsys):
    typecheck.BASELINE.write_text(
        'evo_door/a.py: error: "None" has no attribute "close"  [attr-defined]\n' * 2
    )
    typecheck.run_mypy = lambda: _mypy(OLD)  # one of the two fixed
    assert typecheck.main([]) == 1
    assert "1 errors of the baseline are fixed" in capsys.readouterr().out
    assert typecheck.main(["--shrink"]) == 0
    assert typecheck.BASELINE.read_text().count("a.py") == 1
    assert typecheck.main([]) == 0


def test_the_baseline_is_in_the_repository_and_has_no_line_numbers():
    lines = (ROOT / ".ci" / "mypy-baseline.txt").read_text().splitlines()
    assert lines and all(": error: " in line for line in lines)
    assert not [line for line in lines if line.split(": error: ")[0].count(":")]
    assert lines == sorted(lines)
