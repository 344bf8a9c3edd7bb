"""The install is reproducible: constraints.txt pins what pyproject.toml allows, and the
README's Quickstart and CI install through it, in a virtual environment."""

import re
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[1]


def pins() -> dict:
    """``{canonical name: version}`` of constraints.txt (comments and blanks skipped)."""
    out = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"constraints.txt: {line!r} is not pinned with =="
            out[canonicalize_name(name)] = version
    return out


def requirements() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = [r for group in project["optional-dependencies"].values() for r in group]
    return [Requirement(r) for r in project["dependencies"] + extras]


def test_every_dependency_is_pinned_within_its_declared_range():
    pinned = pins()
    for req in requirements():
        name = canonicalize_name(req.name)
        assert name in pinned, f"{req.name} is not pinned in constraints.txt"
        assert req.specifier.contains(pinned[name], prereleases=True), (
            f"constraints.txt pins {req.name} {pinned[name]}, outside pyproject's {req}"
        )


def test_ruff_is_pinned_exactly_so_the_format_check_cannot_drift():
    (ruff,) = [r for r in requirements() if r.name == "ruff"]
    assert str(ruff.specifier).startswith("=="), ruff


def test_numpy_and_numba_have_upper_bounds():
    for req in requirements():
        if req.name in ("numpy", "numba"):
            assert any(s.operator == "<" for s in req.specifier), req


def test_the_license_is_an_spdx_expression_the_build_backend_reads():
    """A table (``{text = ...}``) is deprecated in setuptools 77 and refused by its
    releases from 2027-02-18: every install would then fail to build the package."""
    doc = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert doc["project"]["license"] == "MIT"
    (backend,) = [Requirement(r) for r in doc["build-system"]["requires"]]
    assert backend.name == "setuptools" and backend.specifier.contains("77.0"), backend
    assert not backend.specifier.contains("76.9"), backend


def test_quickstart_and_ci_install_through_the_constraints_in_a_virtual_environment():
    readme = (ROOT / "README.md").read_text()
    quick = readme[readme.index("## Quickstart") :]
    blocks = re.findall(r"```bash\n(.*?)```", quick, re.S)[:2]
    assert len(blocks) == 2
    for block in blocks:
        assert "python3 -m venv .venv && . .venv/bin/activate" in block, block
        assert "pip install --no-compile -c constraints.txt -e " in block, block
    ci = (ROOT / ".ci" / "run").read_text()
    for block in blocks:
        assert block.strip() in ci, f"CI does not run the README's command {block.strip()!r}"
