"""An FMU as a plant like the others (issue 38): it starts where it starts by itself, its
parameters are never taken for channels, and ``evo-door curve`` reads its force-angle
curve where its states allow it, or refuses in one line saying why.

The FMUs are built from the project's C once per suite run (conftest's ``shared_fmus``):
the hinge of ``tests/fmu_events`` in two variants (its angle starting at 0.3 rad; its
``latch_angle`` parameter renamed ``theta0``, as an export names a rest angle) and the
door of ``examples/fmu``.
"""

import csv
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from evo_door.cli import main
from evo_door.errors import UserError
from evo_door.models import get_model
from evo_door.sim import simulate
from tests.helpers import door_fmu_builder

fmpy = pytest.importorskip("fmpy")
pytestmark = pytest.mark.skipif(shutil.which("cmake") is None, reason="cmake is not installed")

build = door_fmu_builder()  # examples/fmu/build.py

DT = 1 / 1024  # s
T = np.arange(2049) * DT
#: a half-sine push of 20 N from 0.1 s for 0.15 s: from 0.3 rad the door reaches 1.2 rad,
#: short of the latch (1.45 rad), and comes back
PUSH = np.where((T >= 0.1) & (T < 0.25), 20.0 * np.sin(np.pi * (T - 0.1) / 0.15), 0.0)
START = 0.3  # rad: the start value of the hinge's angle in the first variant


@pytest.fixture(scope="module")
def fmus(shared_fmus):
    """The hinge's variants and the door's builds of the tests (once per suite run)."""
    return shared_fmus.many(
        {
            "start": shared_fmus.hinge_job(2, theta_start=START),
            "named": shared_fmus.hinge_job(3, rename={"latch_angle": "theta0"}),
            "plain": shared_fmus.hinge_job(3),
            "door": shared_fmus.door_job(3, "tuned"),
            "untuned": shared_fmus.door_job(2, "untuned"),
        }
    )


# -- 1. the FMU's own start -------------------------------------------------------------
def test_simulate_without_theta0_starts_the_fmu_at_its_own_start_as_fmpy_does(
    fmus, tmp_path, capsys
):
    np.savetxt(tmp_path / "in.csv", np.c_[T, PUSH], delimiter=",", header="t,force", comments="")
    out = tmp_path / "out.csv"
    assert main(["simulate", str(fmus["start"]), "--input", str(tmp_path / "in.csv"),
                 "--out", str(out)]) == 0  # fmt: skip
    ours = np.genfromtxt(out, delimiter=",", names=True)["theta"]
    # FMPy, its own start values (none given), CVode; the force linear between samples
    signal = np.array(list(zip(T, PUSH)), dtype=[("time", float), ("force", float)])
    r = fmpy.simulate_fmu(str(fmus["start"]), stop_time=T[-1], output_interval=DT, input=signal,
                          output=["theta"], solver="CVode", relative_tolerance=1e-8)  # fmt: skip
    theirs = np.interp(T, r["time"], r["theta"])
    assert theirs[0] == START and ours[0] == START
    assert np.abs(ours - theirs).max() < 2e-3  # measured 4.3e-4 rad
    assert np.ptp(theirs) > 0.5  # the push moves the door: the comparison is not of a rest
    # the model says where it starts, and a start given still wins over the FMU's
    model = get_model(str(fmus["start"]))
    assert model.theta0 == START
    given = simulate(model, model.params.defaults, PUSH, DT, theta0=0.2)
    assert given.ok and given.theta[0] == 0.2


def test_a_trial_that_gives_its_start_keeps_it_and_one_that_does_not_takes_the_fmus(fmus):
    model = get_model(str(fmus["start"]))
    p = model.params.defaults
    own = simulate(model, p, PUSH, DT)
    assert own.theta[0] == START and own.dtheta[0] == 0.0
    assert simulate(model, p, PUSH, DT, theta0=START, dtheta0=0.0).theta.tolist() == (
        own.theta.tolist()
    )
    moving = simulate(model, p, PUSH, DT, dtheta0=0.5)  # the speed given, the angle its own
    assert moving.theta[0] == START and moving.dtheta[0] == 0.5


# -- 2. a parameter is never a channel --------------------------------------------------------
def test_a_parameter_named_theta0_stays_a_parameter_and_keeps_its_value(fmus, tmp_path, capsys):
    named, plain = get_model(str(fmus["named"])), get_model(str(fmus["plain"]))
    assert "theta0" in named.params.names and named.params["theta0"].default == 1.45
    # the initial angle goes to the state itself, not to the parameter of that name
    assert named.info.channels["theta0"].name == "theta"
    force = np.zeros(T.size)
    ours = simulate(named, named.params.defaults, force, DT, theta0=1.0)
    same = simulate(plain, plain.params.defaults, force, DT, theta0=1.0)
    assert ours.ok and np.array_equal(ours.theta, same.theta)
    # had 1.0 been written to the latch angle, the latch would hold the door from the start
    wrong = plain.params.defaults.copy()
    wrong[plain.params.index("latch_angle")] = 1.0
    assert np.abs(simulate(plain, wrong, force, DT, theta0=1.0).theta - same.theta).max() > 0.05
    # it is fitted as a parameter, and a mapping that names it for a channel is refused
    changed = named.params.defaults.copy()
    changed[named.params.index("theta0")] = 1.0
    assert np.abs(simulate(named, changed, force, DT, theta0=1.0).theta - same.theta).max() > 0.05
    with pytest.raises(UserError, match="'theta0' is a parameter of the FMU"):
        get_model(f"{fmus['named']}?theta0=theta0").runner.simulate(
            named.params.defaults, force, DT
        )
    np.savetxt(tmp_path / "in.csv", np.c_[T, force], delimiter=",", header="t,force", comments="")
    args = ["simulate", str(fmus["named"]), "--channels", "theta0=theta0"]
    args += ["--input", str(tmp_path / "in.csv"), "--out", str(tmp_path / "o.csv")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "'theta0' is a parameter of the FMU" in err and len(err.strip().splitlines()) == 1


# -- 5. the force-angle curve ---------------------------------------------------------------
def read_curve(path) -> dict:
    rows = list(csv.DictReader(open(path)))
    return {
        d: np.array([(float(r["theta"]), float(r["force"])) for r in rows if r["direction"] == d]).T
        for d in ("opening", "closing")
    }


def door_hold_force(theta, dtheta):
    """The door's force (N) that holds it still at (theta, dtheta), from the law of
    examples/fmu/README.md, independently of the FMU."""
    q = {p.name: p.start for p in build.PARAMETERS}
    stop = np.where(
        theta > math.pi / 2,
        -q["stop_stiffness"] * (theta - math.pi / 2) - q["stop_damping"] * dtheta,
        0.0,
    )
    torque = (
        q["spring_preload"]
        + q["spring_stiffness"] * (math.pi / 2 - theta)
        - q["weight_moment"] * np.cos(theta)
        - q["damping"] * dtheta
        - q["friction"] * np.tanh(dtheta / q["friction_speed"])
        + stop
    )
    return -torque / q["lever_arm"]


@pytest.mark.parametrize("speed", [None, 0.3])
def test_curve_of_a_model_exchange_fmu_is_its_hold_force(fmus, tmp_path, capsys, speed):
    out = tmp_path / "curve.csv"
    args = ["curve", str(fmus["door"]), "--out", str(out)]
    args += [] if speed is None else ["--speed", str(speed)]
    assert main(args) == 0
    curve = read_curve(out)
    for d, sign in (("opening", -1.0), ("closing", 1.0)):
        theta, force = curve[d]
        w = sign * (1e-15 if speed is None else speed)  # the Coulomb curve's vanishing speed
        assert theta.size >= 721 and theta[0] == 0.0 and theta[-1] == pytest.approx(math.pi / 2)
        # the CSV's 10 digits of theta, times the slope (3600 N/rad at the closed stop),
        # and the last angle, pi/2, rounded up in the CSV past the stop's kink
        inside = theta < math.pi / 2 - 1e-9
        assert np.abs(force - door_hold_force(theta, w))[inside].max() < 1e-5
    if speed is not None:  # damping and friction act: the two directions differ
        assert np.abs(curve["closing"][1] - curve["opening"][1]).min() > 1.0


def test_curve_refuses_an_fmu_that_cannot_be_put_at_any_angle_and_speed(fmus, tmp_path, capsys):
    out = str(tmp_path / "c.csv")
    # co-simulation: the FMU's states are its own
    assert main(["curve", f"{fmus['door']}:cs", "--out", out]) == 2
    err = capsys.readouterr().err
    assert "is run by co-simulation: the force-angle curve needs the derivatives" in err
    assert len(err.strip().splitlines()) == 1
    # states not named for the channels: which is the angle?
    untuned = f"{fmus['untuned']}?force=F_hand&theta=angle"
    assert main(["curve", untuned, "--out", out]) == 2
    err = capsys.readouterr().err
    assert "which of its states (door.phi, door.w) are the angle and the speed" in err
    assert len(err.strip().splitlines()) == 1 and not Path(out).exists()
    # mapped, it works, in the FMU's degrees converted to rad
    assert main(["curve", untuned + "&theta0=door.phi&dtheta0=door.w", "--out", out]) == 0
    theta, force = read_curve(out)["closing"]
    assert np.abs(force - door_hold_force(theta, 1e-15)).max() < 1e-5  # Coulomb: no kink
