"""Trial files: round trips (HDF5, CSV, TDMS), units and mappings, bad files, atomic writes."""

import math
import sys

import h5py
import numpy as np
import pytest

from evo_door.cli import main
from evo_door.data import Trial, read_trial, read_trials, write_trials
from evo_door.errors import UserError
from evo_door.files import h5tree, reseal
from evo_door.sim import simulate
from tests.conftest import OSCILLATOR_MODEL

RATE = 1024.0


def make_trial(tid="T01", n=300, seed=0, **kw):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    fields = dict(
        trial_id=tid,
        user_id="U2",
        kind="impulse",
        theta0=0.0,
        dtheta0=0.0,
        sensors={"force": {"sensor": "load cell", "range": [-445.0, 445.0]}},
        truth={
            "model": "toy",
            "params": {"k": 400.5, "mu": 0.75},
            "units": {"k": "N/m", "mu": "1"},
        },
        meta={"rig": {"seed": 3, "events": {"t_cut": None}}},
    )
    fields.update(kw)
    return Trial(
        t,
        30 * rng.standard_normal(n),
        dtheta=rng.standard_normal(n),
        theta=1.0 + 0.01 * rng.standard_normal(n),
        **fields,
    )


def same_signals(a: Trial, b: Trial, rtol=0.0, atol=0.0):
    for ch in ("t", "force", "theta", "dtheta", "ddtheta"):
        x, y = getattr(a, ch), getattr(b, ch)
        assert (x is None) == (y is None), ch
        if x is not None:
            np.testing.assert_allclose(y, x, rtol=rtol, atol=atol, err_msg=ch)


def test_hdf5_round_trip_keeps_everything_and_order(tmp_path):
    trials = [
        make_trial("zeta", seed=1),
        make_trial("alpha", seed=2, kind="unlock", theta0=None),
        make_trial("mid", seed=3, truth=None),
    ]
    path = tmp_path / "trials.h5"
    write_trials(path, trials)
    back = read_trials(path)
    assert [t.trial_id for t in back] == ["zeta", "alpha", "mid"]  # file order, not sorted
    for a, b in zip(trials, back):
        same_signals(a, b)
        for f in ("user_id", "kind", "theta0", "dtheta0", "sensors", "truth", "meta"):
            assert getattr(b, f) == getattr(a, f), f
    assert back[0].source.endswith(":/trials/zeta")
    # selection by id and by position; a wrong id gets a suggestion
    assert [t.trial_id for t in read_trials(path, ["mid", 0])] == ["mid", "zeta"]
    with pytest.raises(UserError, match=r"no trial 'alpah'.*did you mean 'alpha'"):
        read_trials(path, "alpah")
    # the layout of docs/data-format.md
    with h5py.File(path) as f:
        assert f.attrs["format"] == "evo-door trials" and f.attrs["format_version"] == 1
        g = f["trials/zeta"]
        assert g["dtheta"].attrs["unit"] == "rad/s" and g["t"].attrs["unit"] == "s"
        assert g.attrs["sample_rate"] == RATE and g.attrs["kind"] == "impulse"
        assert g["truth"].attrs["model"] == "toy" and g["truth/params"].attrs["k"] == 400.5
        assert g["truth/units"].attrs["k"] == "N/m"


def test_hdf5_append_and_duplicate_ids(tmp_path):
    path = tmp_path / "a.h5"
    write_trials(path, [make_trial("A")])
    write_trials(path, [make_trial("B")], append=True)
    assert [t.trial_id for t in read_trials(path)] == ["A", "B"]
    with pytest.raises(UserError, match="two trials named 'A'"):
        write_trials(path, [make_trial("A")], append=True)
    assert [t.trial_id for t in read_trials(path)] == ["A", "B"]


def test_hdf5_dataset_in_other_units_is_converted(tmp_path):
    path = tmp_path / "deg.h5"
    write_trials(path, [make_trial("A")])
    with h5py.File(path, "r+") as f:
        theta = f["trials/A/theta"][()]
        del f["trials/A/theta"]
        f["trials/A/theta"] = np.degrees(theta)
        f["trials/A/theta"].attrs["unit"] = "deg"
        reseal(f)  # as written so (its checksums right)
    np.testing.assert_allclose(read_trial(path).theta, theta, rtol=1e-14)


def test_csv_round_trip(tmp_path):
    tr = make_trial("C1")
    path = tmp_path / "c1.csv"
    write_trials(path, tr)
    back = read_trial(path)
    same_signals(tr, back, rtol=1e-11, atol=1e-12)
    for f in ("trial_id", "user_id", "kind", "theta0", "sensors", "truth", "meta"):
        assert getattr(back, f) == getattr(tr, f), f
    # without the metadata line the file is a plain table, the id is the file name
    bare = tmp_path / "bare.csv"
    bare.write_text("\n".join(path.read_text().splitlines()[1:]) + "\n")
    assert read_trial(bare).trial_id == "bare"


def test_tdms_fixture_with_group_and_channel_mapping(tmp_path):
    nptdms = pytest.importorskip("nptdms")
    n, dt = 512, 1 / RATE
    t = np.arange(n) * dt
    load_kn = 0.05 * np.sin(2 * np.pi * 3 * t)  # kN, as the DAQ scaled it
    gyro = 40.0 * np.cos(2 * np.pi * 3 * t)  # deg/s
    incl = 2.0 * t  # deg from closed, + opening
    wf = {"wf_increment": dt, "wf_start_offset": 0.0}
    path = tmp_path / "daq.tdms"
    with nptdms.TdmsWriter(str(path)) as w:
        w.write_segment(
            [
                nptdms.RootObject({"operator": "SignalExpress"}),
                nptdms.GroupObject("Voltage", properties={}),
                nptdms.ChannelObject(
                    "Voltage", "Load cell", load_kn, properties={"unit_string": "kN", **wf}
                ),
                nptdms.ChannelObject(
                    "Voltage", "Gyro", gyro, properties={"unit_string": "deg/s", **wf}
                ),
                nptdms.ChannelObject(
                    "Voltage", "Incl", incl, properties={"unit_string": "deg", **wf}
                ),
                nptdms.GroupObject("Other", properties={}),
                nptdms.ChannelObject(
                    "Other", "Load cell", load_kn[:100], properties={"unit_string": "kN", **wf}
                ),
            ]
        )
    maps = ["force=Load cell", "dtheta=Gyro", "theta=Incl:-1*deg+90"]
    (tr,) = read_trials(path, "Voltage", map=maps, rate=RATE, kind="unlock")
    assert tr.trial_id == "Voltage" and tr.kind == "unlock" and tr.rate == RATE
    np.testing.assert_allclose(tr.force, 1000 * load_kn)
    np.testing.assert_allclose(tr.dtheta, np.radians(gyro))
    np.testing.assert_allclose(tr.theta, np.radians(90.0 - incl))
    np.testing.assert_allclose(tr.t, t)
    # both groups are trials when none is chosen (Other has no Incl: a clear error)
    with pytest.raises(
        UserError, match=r"daq.tdms:Other: missing column 'Incl' for channel 'theta'"
    ):
        read_trials(path, map=maps)
    # and evo-door's own TDMS writer round-trips
    out = tmp_path / "rt.tdms"
    write_trials(out, [make_trial("A"), make_trial("B", seed=5)])
    back = read_trials(out)
    assert [b.trial_id for b in back] == ["A", "B"]
    same_signals(make_trial("B", seed=5), back[1])
    assert back[0].truth == make_trial("A").truth and back[0].user_id == "U2"


def test_tdms_without_nptdms_says_how_to_install(tmp_path, monkeypatch):
    path = tmp_path / "x.tdms"
    path.write_bytes(b"TDSm")
    monkeypatch.setitem(sys.modules, "nptdms", None)
    with pytest.raises(UserError, match=r"pip install 'evo-door\[tdms\]'"):
        read_trials(path)


def test_csv_units_and_mapping(tmp_path):
    path = tmp_path / "lab.csv"
    ms = np.arange(6) * 1000 / RATE
    rows = "\n".join(f"{float(m)!r};{0.1 * i};{2.0 * i};{10.0 * i}" for i, m in enumerate(ms))
    path.write_text("time [ms];Fz;angle [deg];Gyro\n" + rows + "\n")
    tr = read_trial(path, map=["force=Fz:kN", "dtheta=Gyro:deg/s"])
    np.testing.assert_allclose(tr.t, np.arange(6) / RATE, atol=1e-15)
    np.testing.assert_allclose(tr.force, 100.0 * np.arange(6))
    np.testing.assert_allclose(tr.theta, np.radians(2.0 * np.arange(6)))
    np.testing.assert_allclose(tr.dtheta, np.radians(10.0 * np.arange(6)))
    assert tr.meta["import"]["map"]["force"] == "Fz:kN"
    # a sign flip for a load cell mounted the other way round
    flipped = read_trial(path, map=["force=Fz:-1*N", "dtheta=Gyro:deg/s"])
    np.testing.assert_allclose(flipped.force, -0.1 * np.arange(6))
    # a unit of the wrong kind, an unknown unit
    with pytest.raises(UserError, match="unit 'deg' measures angle, channel 'force' needs force"):
        read_trial(path, map=["force=Fz:deg"])
    with pytest.raises(UserError, match="unknown unit 'kNN'.*did you mean 'kN'"):
        read_trial(path, map=["force=Fz:kNN"])


def test_time_axis_from_rate_and_rounded_time_stamps(tmp_path):
    path = tmp_path / "norate.csv"
    path.write_text("force,theta\n" + "\n".join(f"{i},{0.1 * i}" for i in range(5)) + "\n")
    with pytest.raises(UserError, match="missing column 't'.*--rate"):
        read_trial(path)
    np.testing.assert_allclose(read_trial(path, rate=1000).t, np.arange(5) / 1000)
    # time stamps printed with 6 digits still make an exactly uniform axis
    rounded = tmp_path / "rounded.csv"
    rounded.write_text("t,force\n" + "\n".join(f"{i / RATE:.6f},1" for i in range(50)) + "\n")
    tr = read_trial(rounded)
    assert np.ptp(np.diff(tr.t)) < 1e-15 and abs(tr.rate - RATE) < 0.05


def test_simulate_csv_is_a_trial_file(tmp_path):
    model = OSCILLATOR_MODEL
    params = model.load_params(None, {"theta_eq": 1.0})
    force = np.where(np.arange(400) < 100, 5.0, 0.0)
    resp = simulate(model, params, force, 1 / RATE, theta0=0.5)
    path = tmp_path / "sim.csv"
    resp.to_csv(path)
    tr = read_trial(path)
    assert tr.channels == ("theta", "dtheta", "ddtheta") and tr.trial_id == "sim"
    assert tr.initial_state() == pytest.approx((0.5, 0.0))
    np.testing.assert_allclose(tr.dtheta, resp.dtheta, rtol=1e-9, atol=1e-12)
    # and the importer takes it as it stands
    assert main(["data", "import", str(path), "--out", str(tmp_path / "sim.h5")]) == 0
    assert read_trial(tmp_path / "sim.h5").n == 400


BAD_CSV = {
    "missing column": (
        "t,Fz,theta\n0,1,1\n0.001,1,1\n",
        ["--map", "force=Fy:N"],
        r"bad\.csv: missing column 'Fy' for channel 'force'.*did you mean 'Fz'",
    ),
    "missing force": ("t,theta\n0,1\n0.001,1\n", [], r"bad\.csv: missing column 'force'"),
    "non-monotonic time": (
        "t,force\n0,1\n0.001,1\n0.002,1\n0.0015,1\n0.003,1\n",
        [],
        r"bad\.csv: channel 't' \(column 't'\) is not increasing at row 3 \(line 5\)",
    ),
    "NaN": (
        "t,force,theta\n0,1,1\n0.001,1,nan\n0.002,1,1\n",
        [],
        r"bad\.csv: channel 'theta' \(column 'theta'\) is not a finite number at row 1 \(line 3\)",
    ),
    "text in a cell": (
        "t,force\n0,1\n0.001,abc\n",
        [],
        r"bad\.csv: column 'force' is not a number at row 1 \(line 3\): 'abc'",
    ),
    "wrong rate": (
        "t,force\n" + "".join(f"{i / 1000},1\n" for i in range(10)),
        ["--rate", "1024"],
        r"bad\.csv: channel 't' \(column 't'\) is sampled at 1000 Hz, expected 1024 Hz, at row 1 \(line 3\)",
    ),
    "gap": (
        "t,force\n" + "".join(f"{i / 1000 + (0.005 if i > 4 else 0)},1\n" for i in range(10)),
        [],
        r"bad\.csv: channel 't' \(column 't'\) is not uniformly sampled at row 5 \(line 7\)",
    ),
    "empty": ("", [], r"bad\.csv: empty file"),
    "header only": ("t,force\n", [], r"bad\.csv: empty: no data rows"),
    "ragged": ("t,force\n0,1\n0.001\n", [], r"bad\.csv: row 1 \(line 3\) has 1 fields"),
}


@pytest.mark.parametrize("case", sorted(BAD_CSV))
def test_bad_csv_one_line_error_and_no_output(tmp_path, capsys, case):
    text, extra, pattern = BAD_CSV[case]
    good = tmp_path / "good.csv"
    write_trials(good, make_trial("G"))
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    out = tmp_path / "out.h5"
    # a good file first (when the options fit it): nothing of it may be written either
    inputs = [str(bad)] if extra else [str(good), str(bad)]
    assert main(["data", "import", *inputs, "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("evo-door: error: ")
    assert __import__("re").search(pattern, err), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv", "good.csv"]


def test_bad_hdf5_trial_names_group_channel_row(tmp_path, capsys):
    src = tmp_path / "in.h5"
    write_trials(src, [make_trial("A"), make_trial("B")])
    with h5py.File(src, "r+") as f:
        f["trials/B/dtheta"][7] = np.nan
        reseal(f)  # a NaN as written (its checksums right)
    assert main(["data", "import", str(src), "--out", str(tmp_path / "out.h5")]) == 2
    err = capsys.readouterr().err
    assert "in.h5:/trials/B: channel 'dtheta'" in err and "row 7" in err
    assert not (tmp_path / "out.h5").exists()
    (tmp_path / "junk.h5").write_bytes(b"not hdf5 at all")
    with pytest.raises(UserError, match="junk.h5: not a readable HDF5 file"):
        read_trials(tmp_path / "junk.h5")


def test_foreign_hdf5_is_read_as_tables(tmp_path):
    path = tmp_path / "logger.h5"
    with h5py.File(path, "w") as f:
        g = f.create_group("run3")
        g["time"] = np.arange(20) / 500.0
        g["Fz"] = np.ones(20)
        g["Fz"].attrs["units"] = "kN"
        g["rate"] = np.full(20, 5.0)
    with pytest.raises(UserError, match=r"logger.h5:/run3: missing column 'force'"):
        read_trials(path)
    (tr,) = read_trials(path, map=["force=Fz", "dtheta=rate:deg/s"])
    assert tr.trial_id == "run3" and tr.rate == pytest.approx(500.0)
    np.testing.assert_allclose(tr.force, 1000.0)
    np.testing.assert_allclose(tr.dtheta, math.radians(5.0))


def test_crash_while_writing_leaves_old_file(tmp_path, monkeypatch):
    path = tmp_path / "keep.h5"
    write_trials(path, [make_trial("OLD")])
    before = path.read_bytes()

    def boom(*args, **kwargs):
        raise RuntimeError("disk full")

    # the HDF5 content fails half-way, after the temporary file was created (write_h5
    # writes the tree with its module's write_group)
    monkeypatch.setattr(h5tree, "write_group", boom)
    with pytest.raises(RuntimeError):
        write_trials(path, [make_trial("NEW")])
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["keep.h5"]


def test_unsaturated_mask_follows_sensor_range():
    t = np.arange(5) / RATE
    tr = Trial(
        t,
        np.zeros(5),
        dtheta=np.array([-1.0, 0.0, 1.0, 1.0, 0.5]),
        sensors={"dtheta": {"range": [-1.0, 1.0]}},
    )
    assert tr.unsaturated("dtheta").tolist() == [False, True, False, False, True]
    assert tr.unsaturated("force").all()


def test_import_removes_the_gyroscope_bias_of_rig_trials(tmp_path):
    """--rate-bias start: the rest before the push reads zero afterwards, and it is noted."""
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "experiments" / "data" / "default.h5"
    out = tmp_path / "debiased.h5"
    assert (
        main(
            [
                "data",
                "import",
                str(src),
                "--trial",
                "T03",
                "--rate-bias",
                "start",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    raw, fixed = read_trial(src, "T03"), read_trial(out)
    still = slice(0, 300)  # the door rests fully open before the push
    assert abs(np.mean(raw.dtheta[still])) > 1e-3  # about -0.15 deg/s of bias
    assert abs(np.mean(fixed.dtheta[still])) < 2e-4
    step = fixed.meta["preprocess"][-1]["remove_rate_bias"]
    assert step["bias_rad_s"] == pytest.approx(np.mean(raw.dtheta[still]), abs=2e-4)
    assert step["where"] == "start"
