"""What may be written over: a table, a figure or a parameter file never replaces an
evo-door data file (trials, results, a log: HDF5), and a lock file is never written
through a symbolic link (part of issue 37).

Before, ``params door --write measured.h5`` replaced a trial file with YAML and said
"replaced"; ``curve``, ``simulate`` and ``export-spec --out`` did the same; and a
``.R.h5.lock`` that linked to another file had that file overwritten with a PID.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from tests.helpers import TINY_EXPERIMENT, cli_process
from tests.test_cli import cli

ROOT = Path(__file__).resolve().parents[1]


def _one_line(done) -> str:
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("evo-door: error:")
    return done.stderr


@pytest.fixture
def measured(tmp_path):
    """An HDF5 data file (what a trial, results or log file is) and its bytes."""
    path = tmp_path / "measured.h5"
    with h5py.File(path, "w") as f:
        f["t"] = np.linspace(0.0, 1.0, 11)
    return path, path.read_bytes()


@pytest.mark.parametrize(
    "command",
    [
        ("params", "door", "--write", "{out}"),
        ("curve", "door", "--out", "{out}"),
        ("simulate", "door", "--input", "{force}", "--out", "{out}"),
    ],
)
def test_a_derived_output_never_replaces_a_data_file(measured, tmp_path, command, capsys):
    path, before = measured
    force = tmp_path / "force.csv"
    force.write_text("t,force\n0,0\n0.1,1\n0.2,0\n")
    args = [a.format(out=path, force=force) for a in command]
    err = _one_line(cli(capsys, *args, cwd=tmp_path))
    assert "data file" in err and str(path.name) in err
    assert path.read_bytes() == before
    # another name works, and a derived file of its own is replaced as before
    other = [a.format(out=tmp_path / "table.out", force=force) for a in command]
    for _ in range(2):
        done = cli(capsys, *other, cwd=tmp_path)
        assert done.returncode == 0, done.stderr


@pytest.mark.slow
def test_export_spec_never_replaces_a_results_file(tmp_path, capsys):
    (tmp_path / "exp.yaml").write_text(TINY_EXPERIMENT)
    for out in ("a.h5", "b.h5"):
        assert cli(capsys, "run", "exp.yaml", "--out", out, "--quiet", cwd=tmp_path).returncode == 0
    before = (tmp_path / "b.h5").read_bytes()
    err = _one_line(cli(capsys, "export-spec", "a.h5", "--out", "b.h5", cwd=tmp_path))
    assert "data file" in err
    assert (tmp_path / "b.h5").read_bytes() == before


def test_a_lock_file_is_never_written_through_a_link(tmp_path):
    precious = tmp_path / "precious.txt"
    precious.write_text("a user's notes\n")
    (tmp_path / ".R.h5.lock").symlink_to(precious)
    (tmp_path / "exp.yaml").write_text(TINY_EXPERIMENT)
    err = _one_line(cli_process("run", "exp.yaml", "--out", "R.h5", "--quiet", cwd=tmp_path))
    assert "symbolic link" in err
    assert precious.read_text() == "a user's notes\n"
    assert not (tmp_path / "R.h5").exists()


@pytest.mark.slow
def test_twenty_imports_at_once_into_one_trial_file_keep_all_twenty(tmp_path):
    """Twenty ``data import --append`` at once into one new trial file: each waits for
    the file's lock, none is lost (before: one in three rounds lost a trial)."""
    rows = "".join(f"{i / 1024:.8f},1.0\n" for i in range(64))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = []
    for k in range(20):
        src = tmp_path / f"t{k}.csv"
        src.write_text("t,force\n" + rows)
        cmd = [sys.executable, "-m", "evo_door", "data", "import", str(src), "--id", f"T{k:02d}",
               "--out", str(tmp_path / "all.h5"), "--append"]  # fmt: skip
        procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env))
    errors = []
    for p in procs:
        out, err = p.communicate(timeout=300)
        if p.returncode != 0:
            errors.append(err.decode())
    assert not errors, errors
    from evo_door.data import read_trials

    held = sorted(t.trial_id for t in read_trials(tmp_path / "all.h5"))
    assert held == [f"T{k:02d}" for k in range(20)]
    assert not (tmp_path / ".all.h5.lock").exists()


def test_two_imports_creating_one_file_never_replace_each_other(tmp_path):
    """Two imports at once into one new file, without --force: one writes it, the other
    is refused in one line (before it claimed the file, or under the lock, after the
    first made it); the file holds the first one's trial alone."""
    rows = "".join(f"{i / 1024:.8f},1.0\n" for i in range(64))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = []
    for name in ("A", "B"):
        src = tmp_path / f"{name}.csv"
        src.write_text("t,force\n" + rows)
        cmd = [sys.executable, "-m", "evo_door", "data", "import", str(src), "--id", name,
               "--out", str(tmp_path / "new.h5")]  # fmt: skip
        procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env))
    done = [(p.wait(timeout=300), p.stderr.read().decode()) for p in procs]
    for p in procs:
        p.stdout.close()
        p.stderr.close()
    codes = sorted(code for code, _ in done)
    assert codes == [0, 2], done
    refused = next(err for code, err in done if code == 2)
    assert refused.count("\n") == 1 and "already" in refused
    from evo_door.data import read_trials

    held = [t.trial_id for t in read_trials(tmp_path / "new.h5")]
    winner = "AB"[[code for code, _ in done].index(0)]
    assert held == [winner]


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rpartition(")")[2].split()[1]) == pid:
                out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl is Linux's")
def test_a_runs_pool_workers_end_with_it_when_it_is_killed(tmp_path):
    """SIGKILL to a run on ``--executor processes:2``: nothing of it runs to stop its
    pool, and its workers end with it all the same (before: they ran on a minute)."""
    import signal
    import time

    (tmp_path / "exp.yaml").write_text(
        TINY_EXPERIMENT.replace("population: 6, generations: 1", "population: 60, generations: 30")
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "evo_door", "run", "exp.yaml", "--out", "r.h5", "--quiet",
           "--executor", "processes:2"]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=env, stderr=subprocess.DEVNULL)
    try:
        workers = []
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(workers) < 2 and proc.poll() is None:
            time.sleep(0.2)
            workers = [c for c in _children(proc.pid) if b"evo_door" not in _cmdline(c)]
        assert len(workers) >= 2, "the pool's workers did not start"
        time.sleep(1.0)  # they work
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_alive(w) for w in workers):
            time.sleep(0.1)
        assert not any(_alive(w) for w in workers), workers
    finally:
        if proc.poll() is None:
            proc.kill()


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


@pytest.mark.slow
def test_run_cleans_its_own_stale_temporary_files(tmp_path):
    """A killed run leaves ``.R.h5.tmp-PID-N`` behind (its process gone): a new run to
    ``R.h5`` cleans it, as resume does; a temporary of a live process stays."""
    (tmp_path / "exp.yaml").write_text(TINY_EXPERIMENT)
    stale = tmp_path / ".R.h5.tmp-999999999-0"
    stale.write_bytes(b"half a file")
    live = tmp_path / f".R.h5.tmp-{os.getpid()}-0"
    live.write_bytes(b"being written")
    done = cli_process("run", "exp.yaml", "--out", "R.h5", "--quiet", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert not stale.exists() and live.exists()


def test_a_file_another_command_creates_meanwhile_is_never_replaced(tmp_path):
    """A command claims a new file, another creates it while the first works: the
    first's write is refused in one line and the other's file stays (both at once:
    one lands, one is refused)."""
    from evo_door.errors import UserError
    from evo_door.files import Output, claim_outputs, write_text

    path = tmp_path / "p.yaml"
    claim_outputs([Output(path, "--write")])
    path.write_text("the other command's file\n")
    with pytest.raises(UserError, match="another command created this file"):
        write_text(path, "this command's file\n")
    assert path.read_text() == "the other command's file\n"
    assert [p.name for p in tmp_path.iterdir()] == ["p.yaml"]  # no temporary left
    # claimed with --force, or existing when claimed: replaced, as the claim said
    claim_outputs([Output(path, "--write")], force=True)
    write_text(path, "replaced\n")
    assert path.read_text() == "replaced\n"
    fresh = tmp_path / "q.yaml"
    claim_outputs([Output(fresh, "--write")])
    write_text(fresh, "first\n")
    write_text(fresh, "second\n")  # the command's own file, written again
    assert fresh.read_text() == "second\n"
