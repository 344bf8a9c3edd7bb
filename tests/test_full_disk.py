"""A full disk or a read-only target is one line, never a crash (part of issue 37).

Each command runs in a fresh process against a real file system of its own: a tmpfs
of 8 KiB (too small for any HDF5 file evo-door writes), the same filled to the last
byte (too small even for a table), a read-only one, and, for a run, one just big
enough for its first checkpoints, so that a later one is refused with the earlier
ones on disk.

Before, HDF5 met the full disk while it wrote the temporary: a traceback, or an error
line followed by SIGSEGV or SIGBUS when the library closed its half-written objects at
exit, with the temporary and the lock file left behind. Now the HDF5 image is made in
memory and written with plain writes: one line ``evo-door: error: FILE: cannot write
(no space left on device); ...`` that says what is left, and exit status 2.

Mounting needs root (and a system that lets it mount): elsewhere these tests skip.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from tests.helpers import TINY_EXPERIMENT, cli_process

PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096

#: a force input for `data import` and `simulate`
FORCE_CSV = "t,force\n" + "".join(f"{k / 1024:.8f},1.0\n" for k in range(64))


def _mount(folder: Path, options: str) -> Path:
    """A tmpfs mounted on ``folder`` (made) with ``options``; skip where not allowed."""
    folder.mkdir(exist_ok=True)
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "evo-door-test", str(folder)],
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        pytest.skip(f"mount -t tmpfs is not permitted here: {done.stderr.strip()}")
    return folder


def _unmount(folder: Path) -> None:
    if subprocess.run(["umount", str(folder)], capture_output=True).returncode != 0:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True)


def _remount(folder: Path, options: str) -> None:
    subprocess.run(["mount", "-o", f"remount,{options}", str(folder)], check=True)


@pytest.fixture(scope="module")
def mountable(tmp_path_factory):
    """Skip the module, before any work, where a tmpfs cannot be mounted."""
    if not sys.platform.startswith("linux"):
        pytest.skip("a tmpfs of a given size needs Linux")
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root (these tests run as root)")
    _unmount(_mount(tmp_path_factory.mktemp("probe") / "disk", "size=8k"))


@pytest.fixture
def disk(mountable, tmp_path):
    """``mount(options) -> folder``: tmpfs file systems, unmounted after the test."""
    mounted: list[Path] = []

    def mount(options: str, name: str = "disk") -> Path:
        folder = _mount(tmp_path / name, options)
        mounted.append(folder)
        return folder

    yield mount
    for folder in mounted:
        _unmount(folder)


@pytest.fixture
def work(tmp_path):
    """The inputs: the tiny experiment and a force table."""
    (tmp_path / "exp.yaml").write_text(TINY_EXPERIMENT)
    (tmp_path / "force.csv").write_text(FORCE_CSV)
    return tmp_path


def _fill(folder: Path) -> None:
    """Take every free byte of ``folder``'s file system (a file the test leaves)."""
    st = os.statvfs(folder)
    fd = os.open(folder / "filler", os.O_WRONLY | os.O_CREAT)
    try:
        os.posix_fallocate(fd, 0, st.f_bavail * st.f_frsize)
    finally:
        os.close(fd)
    assert os.statvfs(folder).f_bavail == 0


def _one_line(done) -> str:
    """The one error line of a command that the file system refused, and exit 2."""
    assert done.returncode == 2, (done.returncode, done.stderr[-2000:])
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith("evo-door: error: "), done.stderr
    return done.stderr.strip()


def _left(folder: Path) -> list[str]:
    """What is in ``folder`` but the filler: no temporary, no lock, no folder."""
    return sorted(p.name for p in folder.iterdir() if p.name != "filler")


#: name -> (command line, output file, fill the disk first: the output would fit 8 KiB)
#: {d}: the small disk; {w}: the inputs' folder; {run}: a complete results file
COMMANDS = {
    "run": ("run {w}/exp.yaml --out {d}/R.h5 --quiet", "R.h5", False),
    "rig generate": ("rig generate --model door --trials 2 --out {d}/T.h5", "T.h5", False),
    "data import": ("data import {w}/force.csv --out {d}/I.h5", "I.h5", False),
    "simulate --out": ("simulate door --input {w}/force.csv --out {d}/S.csv", "S.csv", True),
    "curve --out": ("curve door --out {d}/C.csv", "C.csv", True),
    "export-spec --out": ("export-spec {run} --out {d}/spec.md", "spec.md", True),
    "report": ("report {run} --out {d}/rep", "rep", False),
}


@pytest.fixture(scope="module")
def results(mountable, tmp_path_factory):
    """A complete results file of the tiny experiment (export-spec's and report's input)."""
    folder = tmp_path_factory.mktemp("results")
    (folder / "exp.yaml").write_text(TINY_EXPERIMENT)
    done = cli_process("run", "exp.yaml", "--out", "run.h5", "--quiet", cwd=folder)
    assert done.returncode == 0, done.stderr
    return folder / "run.h5"


def _args(command: str, d: Path, w: Path, run) -> list[str]:
    return command.format(d=d, w=w, run=run).split()


@pytest.mark.parametrize("name", list(COMMANDS))
def test_a_full_disk_is_one_line_and_leaves_nothing(name, disk, work, results):
    command, out, fill = COMMANDS[name]
    d = disk("size=8k")
    if fill:
        _fill(d)
    err = _one_line(cli_process(*_args(command, d, work, results), cwd=work))
    assert f"{d}/{out}" in err and "cannot write (no space left on device)" in err, err
    assert err.endswith("nothing was written"), err
    assert _left(d) == []  # the temporary, the lock, a report's folder: all gone


@pytest.mark.parametrize("name", ["run", "rig generate", "data import", "simulate --out", "report"])
def test_a_read_only_target_is_one_line(name, disk, work, results):
    command, out, _ = COMMANDS[name]
    d = disk("ro,size=64k")
    err = _one_line(cli_process(*_args(command, d, work, results), cwd=work))
    assert f"{d}/{out}" in err and "cannot write (read-only file system)" in err, err
    assert err.endswith("nothing was written"), err
    assert _left(d) == []


def test_a_report_that_fills_the_disk_removes_the_files_it_added(disk, work, results):
    d = disk("size=128k")  # room for the first figure, not for the next
    err = _one_line(cli_process("report", results, "--out", d / "rep", cwd=work))
    assert "cannot write (no space left on device)" in err, err
    assert re.search(r"; its new files \(\d+ files?\) were removed$", err), err
    assert _left(d) == []  # the folder it made, too


def _pages(size: int) -> int:
    return -(-size // PAGE)


def _best_x(path: Path) -> np.ndarray:
    with h5py.File(path, "r") as f:
        return np.array(f["jobs/0/best_x"])


@pytest.mark.slow
def test_a_refused_checkpoint_keeps_the_last_and_resume_ends_as_an_uninterrupted_run(disk, work):
    """A disk that fills during a run: the last checkpoint is kept, `resume` says so
    again while the disk is full, and, once there is room, ends with the numbers of an
    uninterrupted run."""
    from evo_door.experiment import load_experiment
    from evo_door.experiment.runner import ExperimentRun

    exp = work / "exp4.yaml"
    exp.write_text(TINY_EXPERIMENT.replace("generations: 1", "generations: 4"))
    d = disk("size=4m")
    out = d / "R.h5"
    # the uninterrupted run, on the same path (so the same sizes): each checkpoint's size
    run = ExperimentRun.create(load_experiment(exp), out)
    sizes = [out.stat().st_size]  # the first, written before the first generation
    run.run(on_checkpoint=lambda _run, _job: sizes.append(out.stat().st_size))
    best = run.result["best_x"]
    out.unlink()
    # pages a checkpoint needs: the lock's, the file before it and its own temporary
    pages = [_pages(size) for size in sizes]
    need = [1 + pages[0]] + [1 + a + b for a, b in zip(pages, pages[1:])]
    # the first checkpoint after generation 1 that needs more than every one before it
    k = next(i for i in range(3, len(need)) if need[i] > max(need[:i]))
    _remount(d, f"size={max(need[:k]) * PAGE}")

    every = ("--checkpoint-every", "0")  # every generation, as the sizes were measured
    err = _one_line(cli_process("run", exp, "--out", out, "--quiet", *every, cwd=work))
    kept = re.search(r"the last checkpoint \(generation (\d+)\) is kept: resume with `(.*)`$", err)
    assert kept and f"{out}: cannot write (no space left on device)" in err, err
    assert int(kept.group(1)) >= 1 and kept.group(2) == f"evo-door resume {out}"
    assert _left(d) == ["R.h5"]
    # the disk still full: resume says the same, and keeps the same checkpoint
    again = _one_line(cli_process("resume", out, "--quiet", *every, cwd=work))
    assert again == err, again
    assert _left(d) == ["R.h5"]
    # room again: resume ends as the uninterrupted run did
    _remount(d, "size=4m")
    done = cli_process("resume", out, "--quiet", *every, cwd=work)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert np.array_equal(_best_x(out), best)
    assert _left(d) == ["R.h5"]
