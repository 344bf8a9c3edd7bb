"""The one persistence layer: atomic writes, the lock, the metadata encoding, old files."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from evo_door import files
from evo_door.data import read_trials, write_trials
from evo_door.errors import UserError
from evo_door.experiment import Results, load_experiment, resume_run, run_experiment
from evo_door.files import ATTRS, Dataset, FileLock, Keep, atomic_write, read_attrs

DATA = Path(__file__).parent / "data"


# -- atomic writes --------------------------------------------------------------------
def test_atomic_write_replaces_only_on_success(tmp_path):
    path = tmp_path / "a.txt"
    files.write_text(path, "old")
    with pytest.raises(RuntimeError, match="disk full"):
        with atomic_write(path) as tmp:
            tmp.write_text("half of the new")
            raise RuntimeError("disk full")
    assert path.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]
    files.write_text(path, "new")
    assert path.read_text() == "new" and len(list(tmp_path.iterdir())) == 1


def test_atomic_write_gives_the_usual_file_mode(tmp_path):
    files.write_text(tmp_path / "a.txt", "x")
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o666 & ~umask


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p: p / "missing" / "x.h5", "folder .* does not exist"),
        (lambda p: (p / "afile").write_text("") or p / "afile" / "x.h5", "is a file, not a folder"),
        (lambda p: p, "is a folder; give a file name"),
    ],
)
def test_atomic_write_refuses_impossible_targets_in_one_line(tmp_path, make, message):
    with pytest.raises(UserError, match=message):
        files.write_text(make(tmp_path), "x")


def test_figures_are_written_atomically_and_bad_formats_refused(tmp_path):
    from matplotlib.figure import Figure

    fig = Figure()
    fig.subplots().plot([0, 1], [1, 0])
    files.save_figure(fig, tmp_path / "f.png")
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(UserError, match=r"f\.jpg2: cannot write a jpg2 image; use one of .*\.png"):
        files.save_figure(fig, tmp_path / "f.jpg2")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png"]


def test_stale_temporaries_of_dead_writers_go_those_of_live_ones_stay(tmp_path):
    path = tmp_path / "run.h5"
    dead = tmp_path / ".run.h5.tmp-999999-0"  # no such process
    live = tmp_path / f".run.h5.tmp-{os.getppid()}-3"  # our parent is alive
    for p in (dead, live):
        p.write_bytes(b"half a file")
    assert files.remove_stale_temporaries(path) == [dead]
    assert live.exists() and not dead.exists()


# -- the lock -------------------------------------------------------------------------
def test_a_lock_held_by_another_process_is_refused_naming_it(tmp_path):
    target = tmp_path / "run.h5"
    code = (
        "import sys, time; from evo_door.files import FileLock; "
        f"lock = FileLock({str(target)!r}).acquire(); print('held', flush=True); time.sleep(30)"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        assert FileLock.holder(target) == holder.pid
        with pytest.raises(
            UserError, match=rf"run\.h5: a run is writing it \(process {holder.pid}\); wait"
        ):
            FileLock(target).acquire("a run is writing it")
    finally:
        holder.kill()
        holder.wait()
    # the system dropped the dead holder's lock: no stale lock after a kill
    assert FileLock.holder(target) is None
    with FileLock(target) as lock:
        assert lock.held and FileLock.holder(target) == os.getpid()
        with FileLock(target) as again:  # the same process: shared, counted
            assert again.held
        assert lock.lock_path.exists() and FileLock.holder(target) == os.getpid()
    assert not lock.held and not lock.lock_path.exists()


# -- one metadata encoding ------------------------------------------------------------
def test_attributes_round_trip_every_kind_of_value(tmp_path):
    values = {
        "text": "door",
        "tricky": "json: not JSON",
        "n": 3,
        "x": 2.5,
        "flag": True,
        "none": None,
        "list": [1, 2.5, "a"],
        "nested": {"range": [-1.0, 1.0], "k": None},
        "numpy": np.float64(1.5),
        "array": np.arange(3),
    }
    with h5py.File(tmp_path / "a.h5", "w") as f:
        files.write_attrs(f, values)
        back = read_attrs(f)
    expect = dict(values, numpy=1.5, array=[0, 1, 2])
    assert back == expect
    assert type(back["n"]) is int and type(back["flag"]) is bool


def test_the_legacy_flag_encoding_still_reads(tmp_path):
    with h5py.File(tmp_path / "old.h5", "w") as f:
        f.attrs["range"] = json.dumps([0, 1])
        f.attrs.create("range.__json__", 1)
        f.attrs["nothing"] = "null"
        f.attrs.create("nothing.__json__", 1)
        f.attrs["plain"] = "[not decoded]"
        assert read_attrs(f) == {"range": [0, 1], "nothing": None, "plain": "[not decoded]"}


def test_trees_round_trip_and_keep_copies_the_old_group(tmp_path):
    path = tmp_path / "t.h5"
    tree = {
        ATTRS: {"format": "x"},
        "big": np.arange(10000.0),
        "text": "a\nb",
        "ds": Dataset(np.ones(3), {"unit": "N"}),
        "group": {ATTRS: {"a": [1]}, "y": [1, 2]},
    }
    files.write_h5(path, tree)
    with h5py.File(path) as f:
        back = files.read_group(f)
        assert f["big"].compression == "gzip" and f["ds"].attrs["unit"] == "N"
    assert back["text"] == "a\nb" and back["group"][ATTRS] == {"a": [1]}
    assert np.array_equal(back["big"], tree["big"]) and back["group"]["y"].tolist() == [1, 2]
    # Keep: copied from the file being replaced, built when there is none
    files.write_h5(path, {ATTRS: {}, "big": Keep(lambda: pytest.fail("must copy"))})
    with h5py.File(path) as f:
        assert np.array_equal(f["big"][()], tree["big"]) and set(f) == {"big"}
    files.write_h5(tmp_path / "new.h5", {"g": Keep(lambda: {"z": np.zeros(2)})})
    with h5py.File(tmp_path / "new.h5") as f:
        assert f["g/z"].shape == (2,)
    # at any depth: a stage of a pipeline keeps its trials while its sibling changes
    files.write_h5(path, {"s": {"a": {"t": np.arange(5.0)}, "b": {"x": 1.0}}})
    files.write_h5(
        path, {"s": {"a": {"t": Keep(lambda: pytest.fail("must copy"))}, "b": {"x": 2.0}}}
    )
    with h5py.File(path) as f:
        assert f["s/a/t"][()].tolist() == [0, 1, 2, 3, 4] and f["s/b/x"][()] == 2.0


# -- files written before the consolidation -------------------------------------------
def test_a_trial_file_of_evo_door_0_1_reads_and_rewrites_the_same(tmp_path):
    old = read_trials(DATA / "trials-0.1.h5")[0]
    assert old.trial_id == "T07" and old.kind == "impulse"
    assert old.truth["model"] == "door" and old.truth["params"]["M"] == pytest.approx(1.232)
    assert old.sensors["dtheta"]["range"] and isinstance(old.meta["rig"], dict)
    write_trials(tmp_path / "new.h5", [old])
    new = read_trials(tmp_path / "new.h5")[0]
    for name in ("sensors", "truth", "meta", "user_id", "kind", "theta0", "dtheta0"):
        assert getattr(new, name) == getattr(old, name), name
    assert np.array_equal(new.dtheta, old.dtheta) and np.array_equal(new.force, old.force)
    with h5py.File(tmp_path / "new.h5") as f:  # the one encoding, self-describing
        assert f["trials/T07"].attrs["sensors"].startswith("json:{")


def test_a_results_file_of_evo_door_0_1_shows_and_resumes_to_the_uninterrupted_result(tmp_path):
    old = tmp_path / "old.h5"
    shutil.copy(DATA / "run-0.1-interrupted.h5", old)
    res = Results(old)
    assert res.attrs["status"] == "running" and res.progress() == "1/2 gen"
    run = resume_run(old)
    assert run.status == "complete"
    exp = load_experiment(DATA / "old-format.yaml")
    fresh = run_experiment(exp, out=tmp_path / "fresh.h5")
    assert np.array_equal(run.result["best_x"], fresh.result["best_x"])
    assert Results(old).best() == Results(tmp_path / "fresh.h5").best()
