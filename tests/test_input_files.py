"""Input files as people write them, and the numbers people type.

``evo-door simulate --input`` reads a force record with the reader, mapping and units
of ``data import``; rounded time stamps become an exact uniform grid, real gaps are
refused with file, row and line; options outside their range are one-line errors;
a results file or a damaged chunk where trials are expected says so in one line.
"""

import hashlib
import math
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from evo_door.data import Trial, read_trial, read_trials, write_trials
from evo_door.data.forcecsv import read_force, read_force_csv
from evo_door.data.trial import STEP_TOLERANCE, check_theta0
from evo_door.errors import UserError
from evo_door.files import reseal
from evo_door.sim import simulate
from tests.conftest import OSCILLATOR_MODEL
from tests.test_cli import OSC, cli

RATE = 1024.0
N = 200
T = np.arange(N) / RATE
FORCE = np.where(T < 0.05, 5.0, 0.0) + 0.25 * np.sin(40 * T)
#: k, c of the oscillator used by every simulate run here
SET = ("--set", "k=100", "--set", "c=20")


def snapshot(folder: Path) -> dict:
    return {
        str(p.relative_to(folder)): hashlib.sha1(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def one_line_error(res, *names):
    """Exit 2, one line ``evo-door: error: ...`` naming every one of ``names``."""
    assert res.returncode == 2, (res.returncode, res.stdout, res.stderr)
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("evo-door: error: "), res.stderr
    assert "Traceback" not in res.stderr
    for name in names:
        assert str(name) in lines[0], (name, lines[0])
    return lines[0]


def reference_response():
    """What simulate gives on the exact input (the CSVs below all hold it)."""
    params = OSCILLATOR_MODEL.load_params(None, {"k": 100.0, "c": 20.0})
    return simulate(OSCILLATOR_MODEL, params, FORCE, 1 / RATE)


def _rows(fmt_t, fmt_f="{:.9f}", sep=","):
    return "".join(f"{fmt_t.format(t)}{sep}{fmt_f.format(f)}\n" for t, f in zip(T, FORCE))


#: name -> (file text, extra options): each file holds T and FORCE
HAND_WRITTEN = {
    "6 decimals at 1024 Hz": ("t,force\n" + _rows("{:.6f}"), []),
    "Time,Force": ("Time,Force\n" + _rows("{:.6f}"), []),
    "units in the header": ("t [s],force [N]\n" + _rows("{:.6f}"), []),
    "ms and kN in the header": (
        "time (ms);force (kN)\n"
        + "".join(f"{1000 * t:.3f};{f / 1000:.12f}\n" for t, f in zip(T, FORCE)),
        [],
    ),
    "byte-order mark": ("\ufefft,force\n" + _rows("{:.6f}"), []),
    "semicolons": ("t;force\n" + _rows("{:.6f}", sep=";"), []),
    "tabs and a mapped column": (
        "Zeit\tFz\n" + _rows("{:.6f}", sep="\t"),
        ["--map", "t=Zeit", "--map", "force=Fz:N"],
    ),
    "no time, --rate": ("force\n" + "".join(f"{f:.9f}\n" for f in FORCE), ["--rate", "1024"]),
    "response columns ignored, even bad ones": (
        "t,force,theta,dtheta\n" + "".join(f"{t:.6f},{f:.9f},nan,oops\n" for t, f in zip(T, FORCE)),
        [],
    ),
    "a notes column": (
        "t,force,note\n" + "".join(f"{t:.6f},{f:.9f},hand slipped\n" for t, f in zip(T, FORCE)),
        [],
    ),
}


@pytest.mark.parametrize("case", list(HAND_WRITTEN))
def test_simulate_reads_hand_written_force_files(case, tmp_path, capsys):
    text, extra = HAND_WRITTEN[case]
    src = tmp_path / "in.csv"
    src.write_bytes(text.encode("utf-8"))
    out = tmp_path / "out.csv"
    res = cli(capsys, "simulate", OSC, *SET, "--input", src, *extra, "--out", out)
    assert res.returncode == 0, res.stderr
    assert f"{N} samples at 1024 Hz" in res.stdout
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    ref = reference_response()
    # a uniform grid through the first and last stamps, not the rounded stamps
    steps = np.diff(data[:, 0])
    assert np.ptp(steps) < 1e-6 * steps.mean()  # uniform to the output's 10 digits
    inp = read_force(
        src, map=[e for e in extra if "=" in e], rate=1024 if "--rate" in extra else None
    )
    assert np.ptp(np.diff(inp.t)) < 1e-15 and inp.channels == ()
    np.testing.assert_allclose(data[:, 0], T, rtol=0, atol=1e-6)
    np.testing.assert_allclose(data[:, 1], FORCE, rtol=1e-8, atol=1e-9)
    # the step is 1/1024 s to the rounding of the last stamp: the same response
    np.testing.assert_allclose(data[:, 2], ref.theta, rtol=1e-5, atol=1e-9)


def test_simulate_reads_the_rigs_csv_and_starts_where_the_trial_did(tmp_path, capsys):
    """The rig's CSV (a 3 kB metadata line, then t, force, dtheta) is an input as it stands."""
    from evo_door.data.rig import Campaign, generate_trials
    from evo_door.models import get_model

    door = get_model("door")
    (trial,) = generate_trials(
        door, door.load_params("default"), Campaign(users=1, trials=1, seed=3)
    )
    src = tmp_path / "rig.csv"
    write_trials(src, trial)
    assert len(src.read_text().splitlines()[0]) > 2000  # the metadata line
    out = tmp_path / "out.csv"
    res = cli(capsys, "simulate", "door", "--params", "default", "--input", src, "--out", out)
    assert res.returncode == 0, res.stderr
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    assert data.shape == (trial.n, 5)
    # the file's theta0 (the trial's true start), not the model's rest angle
    assert trial.theta0 != door.theta0
    assert data[0, 2] == pytest.approx(trial.theta0, abs=1e-12)
    # with --theta0 the option wins
    res = cli(capsys, "simulate", "door", "--input", src, "--theta0", "0.5", "--out", out)
    assert res.returncode == 0 and np.loadtxt(out, delimiter=",", skiprows=1)[0, 2] == 0.5


def test_simulate_reads_one_trial_of_an_hdf5_file(tmp_path, capsys):
    trials = [Trial(T, FORCE, trial_id="A"), Trial(T, 2 * FORCE, trial_id="B")]
    write_trials(tmp_path / "two.h5", trials)
    out = tmp_path / "out.csv"
    res = cli(capsys, "simulate", OSC, *SET, "--input", tmp_path / "two.h5", "--out", out)
    one_line_error(res, "two.h5", "holds 2 trials")
    assert not out.exists()
    res = cli(
        capsys, "simulate", OSC, *SET, "--input", tmp_path / "two.h5", "--trial", "B", "--out", out
    )
    assert res.returncode == 0, res.stderr
    np.testing.assert_allclose(np.loadtxt(out, delimiter=",", skiprows=1)[:, 1], 2 * FORCE)


def test_read_force_csv_is_the_import_reader(tmp_path):
    """The wrapper the experiment setup calls: same grid as data import, t and force only."""
    src = tmp_path / "in.csv"
    src.write_text(
        "Time [ms],Force [kN],theta\n"
        + "".join(f"{1000 * t:.3f},{f / 1000:.12f},x\n" for t, f in zip(T, FORCE))
    )
    t, force = read_force_csv(src)
    np.testing.assert_allclose(t, T, atol=1e-6)  # ms with 3 decimals
    assert np.ptp(np.diff(t)) < 1e-15
    np.testing.assert_allclose(force, FORCE, rtol=0, atol=1e-9)
    assert read_force(src).channels == ()
    with pytest.raises(UserError, match=r"--map theta=Incl: a simulation's input is t and force"):
        read_force(src, map=["theta=Incl"])


def test_simulate_refuses_mapping_a_channel_it_does_not_read(tmp_path, capsys):
    src = tmp_path / "in.csv"
    src.write_text("t,force\n" + _rows("{:.6f}"))
    out = tmp_path / "out.csv"
    res = cli(capsys, "simulate", OSC, "--input", src, "--map", "dtheta=Gyro:deg/s", "--out", out)
    one_line_error(res, "--map dtheta=Gyro:deg/s")
    assert not out.exists()


# -- the time axis ----------------------------------------------------------------------
def test_rounded_stamps_become_the_grid_and_the_trial_says_so(tmp_path):
    rounded = np.round(T, 6)
    assert np.ptp(np.diff(rounded)) > 1e-6 * np.diff(rounded).mean()  # the old check failed
    tr = Trial(rounded, FORCE, trial_id="r")
    # t0 + k * mean step: exactly uniform, every stamp within the rounding of the file's
    step = (rounded[-1] - rounded[0]) / (N - 1)
    np.testing.assert_array_equal(tr.t, rounded[0] + step * np.arange(N))
    assert np.max(np.abs(tr.t - T)) <= 1e-6
    note = tr.meta["time_axis"]
    assert note["step"] == pytest.approx(1 / RATE, rel=1e-5) and note["t0"] == 0.0
    assert 0 < note["max_shift"] <= 1e-6
    # exact stamps are kept as they are, with no note
    assert "time_axis" not in Trial(T, FORCE).meta
    # through data import into HDF5, the note travels with the trial
    src = tmp_path / "rounded.csv"
    src.write_text("t,force\n" + _rows("{:.6f}"))
    write_trials(tmp_path / "r.h5", read_trials(src))
    assert read_trial(tmp_path / "r.h5").meta["time_axis"]["max_shift"] == note["max_shift"]


def test_jitter_within_the_tolerance_passes_beyond_it_fails():
    step = 1 / RATE
    jitter = np.zeros(N)
    jitter[50] = 0.4 * STEP_TOLERANCE * step  # moves two steps by 0.4 %
    assert Trial(T + jitter, FORCE).meta["time_axis"]["max_shift"] == pytest.approx(jitter[50])
    jitter[50] = 3 * STEP_TOLERANCE * step
    with pytest.raises(UserError, match=r"channel 't' is not uniformly sampled at row 50"):
        Trial(T + jitter, FORCE)
    # a clock that drifts: every step within 1 %, the stamps half a step off the grid
    drift = np.cumsum(np.r_[0, step * (1 + 0.009 * np.linspace(-1, 1, N - 1))])
    with pytest.raises(UserError, match=r"drifts from a uniform time grid at row \d+"):
        Trial(drift, FORCE)


BAD_TIME = {
    "gap": (
        "t,force\n" + "".join(f"{i / 1000 + (0.005 if i > 4 else 0)},1\n" for i in range(10)),
        r"bad\.csv: channel 't' \(column 't'\) is not uniformly sampled at row 5 \(line 7\): "
        r"step 0\.006 s, typical 0\.001 s",
    ),
    "jump back": (
        "t,force\n0,1\n0.001,1\n0.002,1\n0.0015,1\n0.003,1\n",
        r"bad\.csv: channel 't' \(column 't'\) is not increasing at row 3 \(line 5\): "
        r"0\.002 then 0\.0015 s",
    ),
    "rate change": (
        "t,force\n"
        + "".join(f"{i / 1000:.6f},1\n" for i in range(20))
        + "".join(f"{0.019 + i / 500:.6f},1\n" for i in range(1, 6)),
        r"bad\.csv: channel 't' \(column 't'\) is not uniformly sampled at row 20 \(line 22\)",
    ),
    "drifting clock": (
        "t,force\n"
        + "".join(
            f"{t:.9f},1\n"
            for t in np.cumsum(np.r_[0, 0.001 * (1 + 0.009 * np.linspace(-1, 1, 499))])
        ),
        r"bad\.csv: channel 't' \(column 't'\) drifts from a uniform time grid at row \d+ \(line \d+\)",
    ),
}


@pytest.mark.parametrize("command", ["simulate", "import"])
@pytest.mark.parametrize("case", list(BAD_TIME))
def test_real_non_uniform_sampling_is_refused_by_both_readers(case, command, tmp_path, capsys):
    text, pattern = BAD_TIME[case]
    (tmp_path / "bad.csv").write_text(text)
    before = snapshot(tmp_path)
    if command == "simulate":
        args = ["simulate", OSC, "--input", tmp_path / "bad.csv", "--out", tmp_path / "o.csv"]
    else:
        args = ["data", "import", tmp_path / "bad.csv", "--out", tmp_path / "o.h5"]
    line = one_line_error(cli(capsys, *args))
    assert re.search(pattern, line), line
    assert snapshot(tmp_path) == before


def test_errors_quote_little_of_a_file(tmp_path, capsys):
    """A 3 kB header, cell or unit is not printed back: ~80 characters of it at most."""
    header = ",".join(f"channel_{i}" for i in range(400))
    row = ",".join("1" for _ in range(400))
    (tmp_path / "wide.csv").write_text(f"{header}\n{row}\n{row}\n")
    (tmp_path / "cell.csv").write_text(f"t,force\n0,1\n0.001,{'x' * 3000}\n")
    (tmp_path / "unit.csv").write_text(f"t,force [{'N' * 3000}]\n0,1\n0.001,1\n")
    for name, what in (
        ("wide.csv", "missing column 'force'"),
        ("cell.csv", "is not a number at row 1 (line 3)"),
        ("unit.csv", "unknown unit"),
    ):
        path = tmp_path / name
        with pytest.raises(UserError) as err:
            read_force(path)
        message = str(err.value)
        assert what in message and "(3000 characters)" in message or name == "wide.csv"
        assert "x" * 81 not in message and "N" * 81 not in message
        assert len(message) < len(str(path)) + 300, message
        for args in (
            ["simulate", OSC, "--input", path, "--out", tmp_path / "o.csv"],
            ["data", "import", path, "--out", tmp_path / "o.h5"],
        ):
            line = one_line_error(cli(capsys, *args), name, what)
            assert line == f"evo-door: error: {message}"


# -- numbers people type ------------------------------------------------------------------
@pytest.mark.parametrize("points", ["0", "1", "-5"])
def test_curve_needs_two_points(points, tmp_path, capsys):
    res = cli(capsys, "curve", OSC, "--points", points, "--out", tmp_path / "c.csv")
    one_line_error(res, f"--points {points}", "from 2 (both ends of the range)")
    assert list(tmp_path.iterdir()) == []


def test_curve_checks_speed_and_plot_before_writing(tmp_path, capsys):
    for speed in ("0", "-0.1", "nan"):
        res = cli(capsys, "curve", OSC, "--speed", speed, "--out", tmp_path / "c.csv")
        one_line_error(res, "--speed", "above 0")
    res = cli(capsys, "curve", OSC, "--out", tmp_path / "c.csv", "--plot", tmp_path / "c.jpg2")
    one_line_error(res, "c.jpg2")
    assert list(tmp_path.iterdir()) == []  # no CSV left behind by the failed plot
    res = cli(capsys, "curve", OSC, "--points", "2", "--out", tmp_path / "c.csv")
    assert res.returncode == 0 and len((tmp_path / "c.csv").read_text().splitlines()) == 5


@pytest.mark.parametrize(
    "theta0, names",
    [
        ("10", ["--theta0 10", "0..1.5708 rad"]),
        ("-0.2", ["--theta0 -0.2", "0..1.5708 rad"]),
        ("90", ["--theta0 90", "in degrees? 90 deg is 1.5708 rad"]),
        ("nan", ["--theta0 nan"]),
    ],
)
def test_simulate_theta0_must_lie_in_the_models_range(theta0, names, tmp_path, capsys):
    (tmp_path / "in.csv").write_text("t,force\n" + _rows("{:.6f}"))
    before = snapshot(tmp_path)
    res = cli(
        capsys,
        "simulate",
        OSC,
        "--input",
        tmp_path / "in.csv",
        "--theta0",
        theta0,
        "--out",
        tmp_path / "o.csv",
    )
    one_line_error(res, *names)
    assert snapshot(tmp_path) == before


def test_theta0_range_follows_the_model_and_allows_a_typed_pi_half():
    assert check_theta0(1.5708) == 1.5708  # pi/2 typed with 4 decimals
    assert check_theta0(-2.9e-5) == -2.9e-5  # a door resting a hair past fully open
    assert check_theta0(0.3, (0.0, 0.45), "m") == 0.3
    with pytest.raises(UserError, match=r"--theta0 0.5: outside the coordinate range 0..0.45 m"):
        check_theta0(0.5, (0.0, 0.45), "m")
    # the drawer's stroke: no hint about degrees for a length
    with pytest.raises(UserError) as err:
        check_theta0(30, (0.0, 0.45), "m")
    assert "degrees" not in str(err.value)


def test_simulate_checks_the_files_theta0_too(tmp_path, capsys):
    src = tmp_path / "in.csv"
    write_trials(src, Trial(T, FORCE, trial_id="x", theta0=3.0))
    res = cli(capsys, "simulate", OSC, "--input", src, "--out", tmp_path / "o.csv")
    one_line_error(res, f"{src}: theta0 3", "0..1.5708")
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize(
    "option, value, names",
    [
        ("--theta0", "90", ["--theta0 90", "in degrees?"]),
        ("--theta0", "inf", ["--theta0 inf"]),
        ("--dtheta0", "nan", ["--dtheta0 nan", "finite"]),
        ("--rate", "0", ["--rate 0", "above 0"]),
        ("--rate", "-1024", ["--rate -1024", "above 0"]),
        ("--lowpass", "0", ["--lowpass 0", "above 0"]),
        ("--resample", "-5", ["--resample -5", "above 0"]),
    ],
)
def test_data_import_checks_its_numbers(option, value, names, tmp_path, capsys):
    (tmp_path / "in.csv").write_text("t,force\n" + _rows("{:.6f}"))
    before = snapshot(tmp_path)
    res = cli(
        capsys, "data", "import", tmp_path / "in.csv", option, value, "--out", tmp_path / "o.h5"
    )
    one_line_error(res, *names)
    assert snapshot(tmp_path) == before


def test_simulate_checks_rate_and_dtheta0(tmp_path, capsys):
    (tmp_path / "in.csv").write_text("force\n1\n2\n3\n")
    for args, name in ((["--rate", "0"], "--rate 0"), (["--dtheta0", "inf"], "--dtheta0 inf")):
        res = cli(
            capsys,
            "simulate",
            OSC,
            "--input",
            tmp_path / "in.csv",
            *args,
            "--out",
            tmp_path / "o.csv",
        )
        one_line_error(res, name)
    res = cli(
        capsys,
        "simulate",
        OSC,
        "--input",
        tmp_path / "in.csv",
        "--substeps",
        "0",
        "--out",
        tmp_path / "o.csv",
    )
    one_line_error(res, "--substeps 0")
    assert not (tmp_path / "o.csv").exists()


# -- a results file or a damaged file where trials are expected -------------------------------
def fake_run(path: Path) -> Path:
    """An HDF5 file laid out as a run's: root format "evo-door run", its trials in /trials."""
    write_trials(path, [Trial(T, FORCE, trial_id="A")])
    with h5py.File(path, "r+") as f:
        f.attrs["format"] = "evo-door run"
        reseal(f)  # made so on purpose: its checksums right
    return path


@pytest.mark.parametrize("command", ["show", "import", "simulate"])
def test_a_results_file_is_not_trials(command, tmp_path, capsys):
    run = fake_run(tmp_path / "run.h5")
    before = snapshot(tmp_path)
    args = {
        "show": ["data", "show", run],
        "import": ["data", "import", run, "--out", tmp_path / "x.h5"],
        "simulate": ["simulate", OSC, "--input", run, "--out", tmp_path / "o.csv"],
    }[command]
    line = one_line_error(cli(capsys, *args), f"{run}: is an evo-door results file (a run)")
    assert f"evo-door show {run}" in line and "/trials" in line
    assert snapshot(tmp_path) == before
    with pytest.raises(UserError, match="is an evo-door results file"):
        read_trials(run)


def test_an_experiment_whose_data_is_a_results_file(tmp_path, capsys):
    from tests.test_experiment import EXPERIMENT

    fake_run(tmp_path / "run.h5")
    (tmp_path / "exp.yaml").write_text(EXPERIMENT.replace("data: trials.h5", "data: run.h5"))
    before = snapshot(tmp_path)
    res = cli(capsys, "run", tmp_path / "exp.yaml", "--out", tmp_path / "r.h5", "--quiet")
    one_line_error(res, "run.h5", "is an evo-door results file")
    assert snapshot(tmp_path) == before


def corrupt_copy(tmp_path: Path) -> Path:
    path = tmp_path / "corrupt.h5"
    long = np.arange(20000) / RATE
    write_trials(path, [Trial(long, np.sin(long), dtheta=np.cos(long), trial_id="T01")])
    with h5py.File(path) as f:
        info = f["trials/T01/dtheta"].id.get_chunk_info(0)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + 16)
        fh.write(b"\xff" * 64)
    return path


@pytest.mark.parametrize("command", ["show", "import"])
def test_a_damaged_chunk_is_one_line_naming_file_and_dataset(command, tmp_path, capsys):
    path = corrupt_copy(tmp_path)
    before = snapshot(tmp_path)
    args = (
        ["data", "show", path]
        if command == "show"
        else ["data", "import", path, "--out", tmp_path / "x.h5"]
    )
    line = one_line_error(cli(capsys, *args), f"{path}: corrupt HDF5 data in /trials/T01/dtheta (")
    assert len(line) < len(str(path)) + 200
    assert snapshot(tmp_path) == before


def test_theta0_margin_is_a_thousandth_of_the_range():
    lo, hi = 0.0, 0.5 * math.pi
    check_theta0(hi + 0.9e-3 * (hi - lo))
    with pytest.raises(UserError):
        check_theta0(hi + 1.1e-3 * (hi - lo))
