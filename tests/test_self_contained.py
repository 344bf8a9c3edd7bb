"""The repository stands alone: no tracked file sends the reader to a path outside it.

The project grew next to a folder of shared material (a specification and the thesis
it implements); its README and docstrings once pointed there, which a reader of a
clone cannot follow. What they need is in ``docs/conventions.md``.
"""

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Written in two parts so that this file does not match itself.
OUTSIDE = [b".." + b"/shared", b"shared" + b"/spec", b"shared" + b"/seeds"]


def tracked_files() -> list[Path]:
    try:
        done = subprocess.run(
            ["git", "ls-files", "-z"], capture_output=True, cwd=ROOT, timeout=60, check=True
        )
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [ROOT / name for name in done.stdout.decode().split("\0") if name]


def references_outside(files, root: Path = ROOT) -> list[str]:
    """``path: pattern`` for every file that names a path outside the repository."""
    found = []
    for path in files:
        try:
            data = path.read_bytes()
        except (FileNotFoundError, IsADirectoryError):
            continue  # deleted in the work tree, or a submodule
        found += [f"{path.relative_to(root)}: {p.decode()}" for p in OUTSIDE if p in data]
    return found


def test_no_tracked_file_refers_outside_the_repository():
    files = tracked_files()
    assert len(files) > 50  # the listing worked
    assert references_outside(files) == []


def test_the_check_finds_a_reference(tmp_path):
    bad = tmp_path / "notes.md"
    bad.write_text("see `" + "/".join(["..", "shared", "spec", "CASE_STUDY.md"]) + "`\n")
    good = tmp_path / "good.md"
    good.write_text("see `docs/conventions.md`\n")
    assert references_outside([bad, good], tmp_path) == [
        "notes.md: " + ".." + "/shared",
        "notes.md: " + "shared" + "/spec",
    ]


def test_the_readme_links_the_conventions_and_the_seed_is_defined_there():
    readme = (ROOT / "README.md").read_text()
    assert "(docs/conventions.md)" in readme
    page = (ROOT / "docs" / "conventions.md").read_text()
    assert "## The seed" in page and "seed table" in page
