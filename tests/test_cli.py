"""The command line as a user meets it: help, version, one-line errors with exit 2."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from evo_door import __version__
from evo_door.cli import main
from evo_door.sim import quasi_static_force
from tests.conftest import OSCILLATOR_MODEL

ROOT = Path(__file__).resolve().parents[1]
OSC = "tests.conftest:OSCILLATOR_MODEL"


def run(*args, cwd=ROOT):
    """``python -m evo_door ARGS`` from the repository root (so tests.* is importable)."""
    return subprocess.run([sys.executable, "-m", "evo_door", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def test_console_script_version_and_help():
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


def test_simulate_csv_round_trip(tmp_path):
    t = np.arange(1024) / 1024.0
    np.savetxt(tmp_path / "in.csv", np.column_stack([t, np.full_like(t, 5.0)]),
               delimiter=",", header="t,force", comments="")
    res = run("simulate", OSC, "--set", "k=100", "--set", "c=20", "--input",
              str(tmp_path / "in.csv"), "--out", str(tmp_path / "out.csv"))
    assert res.returncode == 0, res.stderr
    header = (tmp_path / "out.csv").read_text().splitlines()[0]
    assert header == "t,force,theta,dtheta,ddtheta"
    data = np.loadtxt(tmp_path / "out.csv", delimiter=",", skiprows=1)
    assert data.shape == (1024, 5)
    assert data[-1, 2] == pytest.approx(5.0 / 100.0, rel=1e-3)  # settles at F / k


@pytest.mark.parametrize("content, message", [
    ("", "empty file"),
    ("t,push\n0,1\n0.1,2\n", "missing column 'force'"),
    ("t,force\n0,1\n0,2\n", "not increasing at data row 2"),
    ("t,force\n0,1\n0.1,nan\n", "non-finite value on data row 2"),
    ("t,force\n0,1\n0.1,2\n0.3,2\n", "not uniformly sampled"),
])
def test_simulate_rejects_bad_input_file(tmp_path, content, message):
    (tmp_path / "in.csv").write_text(content)
    res = run("simulate", OSC, "--input", str(tmp_path / "in.csv"), "--out",
              str(tmp_path / "out.csv"))
    assert res.returncode == 2
    assert message in res.stderr and res.stderr.count("\n") == 1
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "out.csv").exists()


def test_quasi_static_force_of_a_spring_damper():
    p = OSCILLATOR_MODEL.params.vector({"k": 300.0, "c": 4.0, "theta_eq": 0.2})
    theta = np.linspace(0, 1.5, 7)
    f = quasi_static_force(OSCILLATOR_MODEL, p, theta, -0.5)
    np.testing.assert_allclose(f, 300.0 * (theta - 0.2) + 4.0 * -0.5, rtol=1e-12)


def test_curve_command_writes_both_directions(tmp_path):
    res = run("curve", OSC, "--points", "11", "--out", str(tmp_path / "c.csv"),
              "--plot", str(tmp_path / "c.png"))
    assert res.returncode == 0, res.stderr
    lines = (tmp_path / "c.csv").read_text().splitlines()
    assert lines[0] == "theta,force,direction" and len(lines) == 23
    assert {line.split(",")[2] for line in lines[1:]} == {"opening", "closing"}
    assert (tmp_path / "c.png").stat().st_size > 5000
