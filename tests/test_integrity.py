"""Every HDF5 file evo-door writes carries checksums, checked whenever it is read
(part of issue 37): a flipped bit in a value, an attribute or a name is one line naming
what does not match, and ``resume`` never continues from corrupt state.

Before, one flipped bit in a stored setup value (K 400.64 -> 200.32), a trial sample or
the stored random state let ``resume`` exit 0 with a different answer.
"""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from evo_door.cli import main
from evo_door.errors import UserError
from evo_door.experiment import load_experiment, run_experiment
from evo_door.files import DamagedFile, open_h5, reseal, seal, write_h5
from evo_door.files.integrity import DIGEST, MAX_DATASET_BYTES, group_digest
from tests.helpers import TINY_EXPERIMENT


class Interrupted(Exception):
    pass


def _one_line(err: str) -> str:
    assert err.count("\n") == 1 and err.startswith("evo-door: error:"), err
    assert "Traceback" not in err
    return err


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A tiny run killed after its first generation (cut.h5) and the same run whole."""
    folder = tmp_path_factory.mktemp("integrity")
    text = TINY_EXPERIMENT.replace("generations: 1", "generations: 3")
    (folder / "exp.yaml").write_text(text)
    whole = run_experiment(load_experiment(folder / "exp.yaml"), out=folder / "whole.h5")

    def kill_after_one(run, job):
        if job.ga is not None and job.ga.generation == 1:
            raise Interrupted()

    with pytest.raises(Interrupted):
        run_experiment(
            load_experiment(folder / "exp.yaml"), folder / "cut.h5", on_checkpoint=kill_after_one
        )
    return folder, whole


def _answer(shown: str) -> list[str]:
    """What ``show`` says of a run, less the file's name and when and how fast it ran."""
    return [
        line
        for line in shown.splitlines()[2:]
        if "created" not in line and " s\n" not in line + "\n"
    ]


def _flip(path, byte: int, bit: int) -> None:
    data = bytearray(path.read_bytes())
    data[byte] ^= 1 << bit
    path.write_bytes(bytes(data))


def test_every_group_is_sealed_and_the_seal_checks(tmp_path):
    path = tmp_path / "t.h5"
    write_h5(path, {"@attrs": {"k": 400.64}, "a": {"x": np.arange(5.0)}, "s": "text"})
    with h5py.File(path, "r") as f:
        assert all(DIGEST in g.attrs for g in (f, f["a"]))
        assert f.attrs[DIGEST] == group_digest(f)
    with open_h5(path) as f:  # reads
        assert "k" in f.attrs
    # a value, an attribute, a name: each changed after writing is one line naming it
    for change, where in (
        (lambda f: f["a/x"].write_direct(np.array([9.0]), np.s_[0:1], np.s_[1:2]), "/a"),
        (lambda f: f.attrs.modify("k", 200.32), "/ "),
        (lambda f: f.move("a", "b"), "/ "),
    ):
        copy = tmp_path / "c.h5"
        shutil.copy(path, copy)
        with h5py.File(copy, "r+") as f:
            change(f)
        with pytest.raises(DamagedFile, match="does not match its checksum") as err:
            open_h5(copy)
        assert f": damaged: {where.strip()} " in str(err.value) + " "


def test_a_dataset_is_digested_as_h5py_reads_it_whatever_its_type(tmp_path):
    """The digest reads plain numbers with one call into HDF5 (``integrity._whole``):
    the same bytes as h5py's own ``ds[()]`` for every type it reads whole, byte order,
    booleans and dimensions included, and so the same digests as files sealed before
    (variable-length strings and objects are digested element by element, not here)."""
    from evo_door.files.integrity import _whole

    rng = np.random.default_rng(3)
    values = {
        "f8": rng.normal(size=7),
        "big_endian": rng.normal(size=5).astype(">f8"),
        "f4_3d": rng.normal(size=(2, 3, 4)).astype(np.float32),
        "i2_2d": rng.integers(-300, 300, size=(3, 4)).astype(np.int16),
        "u1": rng.integers(0, 255, size=9).astype(np.uint8),
        "bool": rng.random(6) > 0.5,
        "complex": rng.normal(size=3) + 1j * rng.normal(size=3),
        "fixed_bytes": np.array([b"ab", b"cde"]),
        "pairs": np.array([(1, 2.5), (3, -1.0)], dtype=[("n", "<i4"), ("x", "<f8")]),
    }
    with h5py.File(tmp_path / "types.h5", "w") as f:
        for name, value in values.items():
            f[name] = value
    with h5py.File(tmp_path / "types.h5", "r") as f:
        for name in values:
            ds = f[name]
            want = np.ascontiguousarray(ds[()]).tobytes()
            assert _whole(ds, ds.shape, ds.dtype) == want, name


def test_a_file_without_checksums_reads_but_one_with_some_missing_is_damaged(tmp_path):
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:  # as another program writes it
        f["g/x"] = np.arange(3.0)
    open_h5(path).close()
    write_h5(path, {"g": {"x": np.arange(3.0)}})
    with h5py.File(path, "r+") as f:
        del f["g"].attrs[DIGEST]
    with pytest.raises(DamagedFile, match="/g has no checksum"):
        open_h5(path)


def test_a_link_to_another_file_and_an_oversized_dataset_are_refused(tmp_path):
    path = tmp_path / "link.h5"
    with h5py.File(path, "w") as f:
        f["x"] = h5py.ExternalLink("/etc/passwd", "/")
    with pytest.raises(DamagedFile, match="is a link"):
        open_h5(path)
    big = tmp_path / "big.h5"
    with h5py.File(big, "w") as f:  # a few KiB on disk, too many bytes once read
        n = MAX_DATASET_BYTES // 8 + 1
        f.create_dataset("x", shape=(n,), dtype="f8", chunks=(2**16,), compression="gzip")
    with pytest.raises(DamagedFile, match="MiB to read"):
        open_h5(big)


def test_a_flipped_bit_in_a_setup_value_is_refused_by_show_and_resume(runs, tmp_path, capsys):
    """The issue's case: the stored pre-load K halved by one bit."""
    folder, _ = runs
    path = tmp_path / "cut.h5"
    shutil.copy(folder / "cut.h5", path)
    with h5py.File(path, "r+") as f:
        base = f["setup/base"]
        values = base[()]
        values.view(np.uint64)[0] ^= np.uint64(1) << np.uint64(52)  # exponent: x2 or /2
        base[...] = values
    before = path.read_bytes()
    for command in (["show", str(path)], ["resume", str(path)]):
        assert main(command) == 2
        err = _one_line(capsys.readouterr().err)
        assert "/setup does not match its checksum" in err
    assert path.read_bytes() == before  # resume refused before writing anything


@pytest.mark.slow
def test_any_flipped_bit_is_refused_or_changes_nothing(runs, tmp_path, capsys):
    """40 seeded bits across a checkpoint: ``show`` and ``resume`` either refuse the
    file in one line or give the answer of the undamaged file."""
    folder, whole = runs
    assert main(["show", str(folder / "whole.h5")]) == 0
    shown = capsys.readouterr().out
    size = (folder / "cut.h5").stat().st_size
    rng = np.random.default_rng(37)
    refused = 0
    for byte in rng.integers(0, size, 40):
        bit = int(rng.integers(0, 8))
        path = tmp_path / "cut.h5"
        shutil.copy(folder / "cut.h5", path)
        _flip(path, int(byte), bit)
        code = main(["resume", str(path), "--quiet"])
        err = capsys.readouterr().err
        if code == 2:
            _one_line(err)
            refused += 1
            continue
        assert code == 0, err
        assert main(["show", str(path)]) == 0
        assert _answer(capsys.readouterr().out) == _answer(shown), (byte, bit)
    assert refused >= 30  # nearly all of a results file is checked data


def test_a_sealed_tree_rewritten_keeps_its_copied_groups_checked(tmp_path):
    """A checkpoint copies unchanged groups from the file it replaces (Keep): a copy of a
    damaged group is still noticed."""
    from evo_door.files import Keep

    path = tmp_path / "k.h5"
    tree = {"trials": Keep(lambda: {"x": np.arange(4.0)}), "n": np.array([1])}
    write_h5(path, tree)
    with h5py.File(path, "r+") as f:
        f["trials/x"][1] = 7.0
    write_h5(path, {**tree, "n": np.array([2])})
    with pytest.raises(DamagedFile, match="/trials does not match"):
        open_h5(path)


def test_seal_does_not_walk_into_a_copy_nor_vouch_for_what_came_without_its_digest(tmp_path):
    """A copied group (Keep) is copied whole, everything below it with its digest: seal
    looks at none of its subgroups (a results file's trials, copied at every checkpoint,
    are most of its groups). A subgroup of the copy that came without its digest (the
    file it came from damaged) is not given one: the new file is refused as the old one
    would be, where a digest made on the copy would vouch for what no one checked."""
    from evo_door.files import Keep, integrity

    path = tmp_path / "w.h5"
    trials = {f"T{k:02d}": {"t": np.arange(4.0) + k, "v": {"x": np.arange(2.0)}} for k in range(12)}
    tree = {"trials": Keep(lambda: trials), "n": np.array([1])}
    write_h5(path, tree)
    walked = []  # the groups seal looked into for their subgroups
    real = integrity._subgroups

    def counting(group):
        walked.append(group.name)
        return real(group)

    integrity._subgroups = counting
    try:
        write_h5(path, {**tree, "n": np.array([2])})
    finally:
        integrity._subgroups = real
    assert not [name for name in walked if name.startswith("/trials")], walked
    open_h5(path).close()  # the copy still checks
    with h5py.File(path, "r+") as f:  # damage: a digest below the copy lost
        del f["trials/T03/v"].attrs[DIGEST]
    write_h5(path, {**tree, "n": np.array([3])})
    with pytest.raises(DamagedFile):
        open_h5(path)


def test_seal_recomputes_nothing_it_already_sealed(tmp_path):
    path = tmp_path / "s.h5"
    write_h5(path, {"a": {"x": np.arange(3.0)}})
    with h5py.File(path, "r+") as f:
        stored = f["a"].attrs[DIGEST]
        f["a"].attrs[DIGEST] = "blake2b:" + "0" * 32
        seal(f)
        assert f["a"].attrs[DIGEST] != stored
    with pytest.raises(UserError):
        open_h5(path)


def test_a_stored_population_of_a_billion_is_refused_before_it_is_allocated(runs, tmp_path, capsys):
    """Sizes a file states are checked against a memory estimate on resume: a file made
    to ask for 1e9 individuals (its checksums right) is one line, not gigabytes."""
    import json

    folder, _ = runs
    path = tmp_path / "big.h5"
    shutil.copy(folder / "cut.h5", path)
    with h5py.File(path, "r+") as f:
        resolved = json.loads(f["experiment/resolved"][()])
        resolved["algorithm"]["population"] = 10**9
        del f["experiment/resolved"]
        f["experiment/resolved"] = json.dumps(resolved)
        reseal(f)
    assert main(["resume", str(path)]) == 2
    err = _one_line(capsys.readouterr().err)
    assert "population 1,000,000,000" in err and "of memory" in err


def test_a_file_this_process_wrote_is_read_back_unchecked_a_changed_one_checked(
    tmp_path, monkeypatch
):
    """A pipeline reads back its results file after every stage: the file it has just
    written (and the next one, whose copies came from it) is not checked again; once
    anything else changed it, it is."""
    from evo_door.files import Keep, integrity

    digests = []  # each group's digest computed, by seal or by a check
    digest = integrity._digest_and_subgroups
    monkeypatch.setattr(
        integrity, "_digest_and_subgroups", lambda *a: digests.append(1) or digest(*a)
    )
    path = tmp_path / "w.h5"
    tree = {"trials": Keep(lambda: {"x": np.arange(4.0)}), "n": np.array([1])}
    write_h5(path, tree)
    sealed = len(digests)
    open_h5(path).close()
    write_h5(path, {**tree, "n": np.array([2])})  # "trials" copied from the file above
    open_h5(path).close()
    assert len(digests) == 2 * sealed - 1  # the second seal skips the copied group only
    with h5py.File(path, "r+") as f:
        f["n"][0] = 3
    with pytest.raises(DamagedFile, match="does not match"):
        open_h5(path)
