"""The command line as a user meets it: help, version, one-line errors with exit 2."""

import contextlib
import subprocess
import warnings
from typing import NamedTuple

import numpy as np
import pytest

from evo_door import __version__
from evo_door.cli import main
from evo_door.sim import quasi_static_force
from tests.conftest import OSCILLATOR_MODEL

OSC = "tests.conftest:OSCILLATOR_MODEL"


class Ran(NamedTuple):
    returncode: int
    stdout: str
    stderr: str


@contextlib.contextmanager
def plain_warnings():
    """Record the warnings raised within, filtered as a plain ``python`` filters them
    (what a user would read on stderr): yields the list they are recorded into."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        for category in (
            DeprecationWarning,
            PendingDeprecationWarning,
            ImportWarning,
            ResourceWarning,
        ):
            warnings.simplefilter("ignore", category)
        yield caught


def cli(capsys, *args, cwd=None) -> Ran:
    """``evo-door ARGS`` in this process, read like a finished subprocess; with ``cwd``,
    run in that folder (its relative paths are the folder's).

    A subprocess costs 1-5 s of interpreter, numba and matplotlib start-up; keep one only
    where it is the point (the installed console script, a process killed and resumed,
    a fresh interpreter). stdout and stderr hold this command's output only. Warnings
    that a plain ``python`` would print are appended to stderr, so that assertions on
    stderr ("empty", "one line") mean what they meant for a subprocess. argparse errors
    raise SystemExit(2): catch them with ``pytest.raises(SystemExit)``.
    """
    capsys.readouterr()  # drop whatever the test printed before
    with plain_warnings() as caught:
        with contextlib.chdir(cwd) if cwd is not None else contextlib.nullcontext():
            code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    err += "".join(
        warnings.formatwarning(w.message, w.category, w.filename, w.lineno) for w in caught
    )
    return Ran(code, out, err)


def test_console_script_version_and_help():
    """The installed entry point itself: this one has to be a subprocess."""
    out = subprocess.run(["evo-door", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == f"evo-door {__version__}"
    out = subprocess.run(["evo-door", "--help"], capture_output=True, text=True)
    assert out.returncode == 0
    for command in ("params", "simulate", "curve"):
        assert command in out.stdout


def test_user_error_is_one_line_exit_2(capsys):
    assert main(["params", "hapic"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("evo-door: error: unknown model 'hapic'")
    assert "did you mean 'haptic'" in err


def test_params_table_and_overrides(capsys):
    assert main(["params", OSC, "--set", "k=250"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("k "))
    assert row.split()[:3] == ["k", "N/rad", "250"]
    assert main(["params", OSC, "--set", "k=-1"]) == 2
    assert "outside its declared range" in capsys.readouterr().err


def test_simulate_csv_round_trip(tmp_path, capsys):
    t = np.arange(1024) / 1024.0
    np.savetxt(
        tmp_path / "in.csv",
        np.column_stack([t, np.full_like(t, 5.0)]),
        delimiter=",",
        header="t,force",
        comments="",
    )
    res = cli(
        capsys,
        "simulate",
        OSC,
        "--set",
        "k=100",
        "--set",
        "c=20",
        "--input",
        tmp_path / "in.csv",
        "--out",
        tmp_path / "out.csv",
    )
    assert res.returncode == 0, res.stderr
    header = (tmp_path / "out.csv").read_text().splitlines()[0]
    assert header == "t,force,theta,dtheta,ddtheta"
    data = np.loadtxt(tmp_path / "out.csv", delimiter=",", skiprows=1)
    assert data.shape == (1024, 5)
    assert data[-1, 2] == pytest.approx(5.0 / 100.0, rel=1e-3)  # settles at F / k


@pytest.mark.parametrize(
    "content, message",
    [
        ("", "empty file"),
        ("t,push\n0,1\n0.1,2\n", "missing column 'force'"),
        ("t,force\n0,1\n0,2\n", "is not increasing at row 1 (line 3)"),
        ("t,force\n0,1\n0.1,nan\n", "is not a finite number at row 1 (line 3)"),
        ("t,force\n0,1\n0.1,2\n0.3,2\n", "not uniformly sampled"),
    ],
)
def test_simulate_rejects_bad_input_file(tmp_path, capsys, content, message):
    (tmp_path / "in.csv").write_text(content)
    res = cli(
        capsys, "simulate", OSC, "--input", tmp_path / "in.csv", "--out", tmp_path / "out.csv"
    )
    assert res.returncode == 2
    assert message in res.stderr and res.stderr.count("\n") == 1
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "out.csv").exists()


def test_quasi_static_force_of_a_spring_damper():
    p = OSCILLATOR_MODEL.params.vector({"k": 300.0, "c": 4.0, "theta_eq": 0.2})
    theta = np.linspace(0, 1.5, 7)
    f = quasi_static_force(OSCILLATOR_MODEL, p, theta, -0.5)
    np.testing.assert_allclose(f, 300.0 * (theta - 0.2) + 4.0 * -0.5, rtol=1e-12)


def test_curve_command_writes_both_directions(tmp_path, capsys):
    res = cli(
        capsys,
        "curve",
        OSC,
        "--points",
        "11",
        "--out",
        tmp_path / "c.csv",
        "--plot",
        tmp_path / "c.png",
    )
    assert res.returncode == 0, res.stderr
    lines = (tmp_path / "c.csv").read_text().splitlines()
    assert lines[0] == "theta,force,direction,speed" and len(lines) == 23
    assert {line.split(",")[2] for line in lines[1:]} == {"opening", "closing"}
    assert (tmp_path / "c.png").stat().st_size > 5000
