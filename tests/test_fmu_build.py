"""The example door FMUs (examples/fmu): built from their C sources, checked with FMPy only.

Each FMU is compared with an independent scipy integration of the same equation of
motion, written again from the README's formula (``benchmarks/bench_fmu.py``'s
``door_accel``, which the benchmark's reference uses too). The force is a half-sine push
held constant over each 1/1024 s sample, given to FMPy as a staircase (a repeated time
at each step): FMPy then stops its model-exchange solver at every step and applies the
new value, so both interfaces and scipy see the same force. (With a linearly
interpolated signal FMPy's CVode holds the input between output points and overshoots
them; the README says by how much.)
"""

import fcntl
import shutil
import subprocess
import sys
import time
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from benchmarks.bench_fmu import door_accel as accel
from evo_door.errors import UserError
from tests.conftest import SharedFMUs
from tests.helpers import door_fmu_builder

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

# not numerics: FMPy and the C compiler make these numbers, not numba (CI's generic-CPU
# run repeats only what numba compiles)

ROOT = Path(__file__).resolve().parents[1]
BUILD_SCRIPT = ROOT / "examples" / "fmu" / "build.py"
build = door_fmu_builder()  # examples/fmu/build.py

needs_cmake = pytest.mark.skipif(shutil.which("cmake") is None, reason="cmake is not installed")

DT = 1 / 1024  # s: the force's sample time and the output interval
STOP = 1.0  # s


def push(t):
    """A 20 N half-sine push toward closing for 0.15 s (N)."""
    return np.where(t < 0.15, 20.0 * np.sin(np.pi * t / 0.15), 0.0)


T_SAMPLES = np.arange(0.0, STOP + DT / 2, DT)
F_SAMPLES = push(T_SAMPLES)


def staircase(name: str) -> np.ndarray:
    """The push held over each sample, as FMPy's input: F[i] on [t[i], t[i+1])."""
    t = np.repeat(T_SAMPLES, 2)[1:]
    f = np.repeat(F_SAMPLES, 2)[:-1]
    return np.array(list(zip(t, f)), dtype=[("time", float), (name, float)])


def reference(theta0=0.0, stop=STOP, **changed):
    """theta (rad) and omega (rad/s) at T_SAMPLES up to ``stop``: DOP853 at rtol 1e-10,
    restarted at each sample of the held force."""
    p = {q.name: q.start for q in build.PARAMETERS} | changed
    y = np.array([theta0, 0.0])
    out = [y]
    n = int(round(stop / DT))
    for i in range(n):
        f = F_SAMPLES[i]
        sol = solve_ivp(
            lambda t, y, f=f: [y[1], accel(y[0], y[1], f, p)],
            (T_SAMPLES[i], T_SAMPLES[i + 1]),
            y,
            method="DOP853",
            rtol=1e-10,
            atol=1e-12,
        )
        y = sol.y[:, -1]
        out.append(y)
    return T_SAMPLES[: n + 1], np.array(out)


def at_samples(result, name):
    """A recorded output at T_SAMPLES (model exchange records twice at each input step)."""
    t = result["time"]
    last = np.searchsorted(t, T_SAMPLES[: int(round(t[-1] / DT)) + 1], side="right") - 1
    return result[name][last]


@pytest.fixture(scope="module")
def fmus(shared_fmus):
    """The four FMUs, both interfaces each: {(fmi, layout): path}; ``build_fmu``'s, once
    per suite run (the tests that change how it builds build their own)."""
    return shared_fmus.doors()


@pytest.mark.slow
@pytest.mark.parametrize("fmi", [2, 3])
@pytest.mark.parametrize("layout", build.LAYOUT_NAMES)
def test_the_model_description_is_valid_and_says_what_the_table_says(fmus, fmi, layout):
    path = fmus[fmi, layout]
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    assert md.fmiVersion == f"{fmi}.0"
    assert md.modelExchange.modelIdentifier == md.coSimulation.modelIdentifier == f"door{fmi}"
    assert (md.guid if fmi == 2 else md.instantiationToken) == build.token(
        fmi, layout, ("me", "cs")
    )
    assert md.numberOfContinuousStates == 2 and md.numberOfEventIndicators == 0
    by_name = {v.name: v for v in md.modelVariables}
    for i, p in enumerate(build.PARAMETERS):
        v = by_name[build.parameter_name(p, layout)]
        assert v.valueReference == build.FIRST_PARAMETER_VR + i
        assert (v.causality, v.variability, v.unit) == ("parameter", p.variability, p.unit)
        assert (float(v.start), float(v.min), float(v.max)) == (p.start, p.min, p.max)
        assert v.description == p.description
    states = [d.variable.derivative.name for d in md.derivatives]
    if layout == "tuned":
        assert states == ["theta", "dtheta"]
        assert [d.variable.name for d in md.derivatives] == ["dtheta", "ddtheta"]
        assert [o.variable.name for o in md.outputs] == ["theta", "dtheta", "ddtheta"]
        assert by_name["force"].causality == "input"
    else:
        assert states == ["door.phi", "door.w"]
        assert by_name["door.phi"].causality == by_name["door.w"].causality == "local"
        assert [o.variable.name for o in md.outputs] == ["angle", "speed"]
        assert by_name["angle"].unit == "deg" and by_name["speed"].unit == "deg/s"
        deg = {u.name: u for u in md.unitDefinitions}["deg"].baseUnit
        assert deg.rad == 1 and deg.factor == pytest.approx(np.pi / 180, rel=1e-15)


@pytest.mark.slow
@pytest.mark.parametrize("fmi", [2, 3])
def test_model_exchange_and_co_simulation_agree_with_scipy(fmus, fmi):
    """Measured: model exchange (CVode, rtol 1e-10) 1.4e-7 rad, co-simulation (RK4 at
    h <= 1e-4 s) 2e-14 rad from scipy; CVode at FMPy's default rtol 1e-5 is 2.8e-3 rad
    off, the door creeping on its smoothed friction near 0.73 rad."""
    t, ref = reference()
    assert ref[:, 0].max() > 0.7  # the push moves the door most of the way
    common = dict(stop_time=STOP, output_interval=DT, input=staircase("force"))
    me = simulate_fmu(
        str(fmus[fmi, "tuned"]), fmi_type="ModelExchange", relative_tolerance=1e-10, **common
    )
    cs = simulate_fmu(str(fmus[fmi, "tuned"]), fmi_type="CoSimulation", **common)
    np.testing.assert_allclose(at_samples(me, "theta"), ref[:, 0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(at_samples(me, "dtheta"), ref[:, 1], rtol=0, atol=1e-5)
    np.testing.assert_allclose(cs["theta"], ref[:, 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(cs["dtheta"], ref[:, 1], rtol=0, atol=1e-8)
    # ddtheta is the right-hand side at the recorded state and the force the FMU holds
    # then: the one of the step that ended there (FMPy sets the next one before DoStep)
    held = np.concatenate([F_SAMPLES[:1], F_SAMPLES[:-1]])
    expected = [
        accel(th, om, f, {p.name: p.start for p in build.PARAMETERS})
        for th, om, f in zip(cs["theta"], cs["dtheta"], held)
    ]
    np.testing.assert_allclose(cs["ddtheta"], expected, rtol=1e-12, atol=1e-9)


@pytest.mark.slow
def test_start_values_change_the_response_as_the_physics_says(fmus):
    path, stop = str(fmus[3, "tuned"]), 0.25  # s, a whole number of samples
    common = dict(fmi_type="CoSimulation", stop_time=stop, output_interval=DT)
    common["input"] = staircase("force")

    def peak_speed(**start):
        return simulate_fmu(path, start_values=start, **common)["dtheta"].max()

    base = peak_speed()
    assert peak_speed(inertia=1.4) < 0.8 * base  # heavier door: slower
    assert peak_speed(lever_arm=0.9) > base  # a fixed parameter, set before initialization
    assert peak_speed(damping=5.0) < base
    # the initial state and a parameter at once, against scipy with the same values
    res = simulate_fmu(path, start_values={"theta": 0.5, "inertia": 1.4}, **common)
    t, ref = reference(theta0=0.5, stop=stop, inertia=1.4)
    assert res["theta"][0] == 0.5
    np.testing.assert_allclose(res["theta"], ref[:, 0], rtol=0, atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("fmi", [2, 3])
def test_the_untuned_layout_reports_degrees_of_the_same_motion(fmus, fmi):
    common = dict(fmi_type="CoSimulation", stop_time=0.5, output_interval=DT)
    tuned = simulate_fmu(
        str(fmus[fmi, "tuned"]),
        start_values={"theta": 0.2, "inertia": 0.9, "friction": 1.0},
        input=staircase("force"),
        **common,
    )
    untuned = simulate_fmu(
        str(fmus[fmi, "untuned"]),
        start_values={"door.phi": 0.2, "door.J": 0.9, "hinge.Tf": 1.0},
        input=staircase("F_hand"),
        **common,
    )
    assert untuned["angle"][0] == pytest.approx(0.2 * 180 / np.pi, rel=1e-15)
    np.testing.assert_allclose(untuned["angle"], tuned["theta"] * 180 / np.pi, rtol=1e-14)
    np.testing.assert_allclose(untuned["speed"], tuned["dtheta"] * 180 / np.pi, rtol=1e-14)


def _instance(path, fmi_type):
    md = read_model_description(str(path))
    fmu = fmpy.instantiate_fmu(fmpy.extract(str(path)), md, fmi_type)
    return md, fmu


@pytest.mark.slow
@pytest.mark.parametrize("fmi", [2, 3])
def test_the_c_side_holds_the_declared_starts_checks_sets_and_resets(fmus, fmi, capsys):
    md, fmu = _instance(fmus[fmi, "untuned"], "CoSimulation")
    get = fmu.getReal if fmi == 2 else fmu.getFloat64
    set_ = fmu.setReal if fmi == 2 else fmu.setFloat64
    vr = {v.name: v.valueReference for v in md.modelVariables}
    declared = [float(v.start) for v in md.modelVariables if v.causality == "parameter"]
    params = [v.valueReference for v in md.modelVariables if v.causality == "parameter"]
    assert get(params) == declared  # the C's table is the modelDescription's
    with pytest.raises(FMICallException):
        set_([vr["door.J"]], [99.0])  # above its max
    assert "door.J = 99 is outside [0.05, 5]" in capsys.readouterr().out
    set_([vr["door.J"], vr["door.r"], vr["door.phi"]], [1.5, 0.3, 0.4])
    if fmi == 2:
        fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    set_([vr["spring.k"]], [20.0])  # tunable: any time
    with pytest.raises(FMICallException):
        set_([vr["door.r"]], [0.5])
    assert "door.r is a fixed parameter" in capsys.readouterr().out
    with pytest.raises(FMICallException):
        set_([vr["angle"]], [1.0])
    state = fmu.getFMUState()
    fmu.doStep(0.0, 0.05)
    moved = get([vr["door.phi"], vr["door.w"]])
    fmu.setFMUState(state)
    fmu.doStep(0.0, 0.05)
    assert get([vr["door.phi"], vr["door.w"]]) == moved  # the state round trip
    fmu.freeFMUState(state)
    fmu.reset()
    assert get(params) == declared and get([vr["door.phi"], vr["time"]]) == [0.0, 0.0]
    fmu.freeInstance()


@pytest.mark.slow
@needs_cmake
def test_an_fmu_with_one_interface_refuses_the_other(tmp_path):
    path = build.build_fmu(tmp_path / "me.fmu", 3, "tuned", interfaces=("me",))
    md = read_model_description(str(path))
    assert md.modelExchange is not None and md.coSimulation is None
    assert validate_fmu(str(path)) == []
    result = simulate_fmu(str(path), stop_time=0.01, output_interval=DT)
    assert result["theta"][-1] > 0  # the door drifts shut on its own from fully open
    md.coSimulation = md.modelExchange  # pretend, to reach the binary's own check
    with pytest.raises(Exception, match="instantiate"):
        fmpy.instantiate_fmu(fmpy.extract(str(path)), md, "CoSimulation")


def test_the_command_line_builds_what_build_fmu_builds(shared_fmus, tmp_path, capsys):
    """Its flags reach ``build_fmu``: the faulty door of FMI 3.0 from the command line
    has the entries and the modelDescription of ``build_fmu(..., 3, faults=True)``'s."""
    out = tmp_path / "faulty3.fmu"
    assert build.main(["--fmi", "3", "--faults", "--out", str(out)]) == 0
    assert "(FMI 3.0, layout tuned, me,cs, faulty on purpose; " in capsys.readouterr().out
    with zipfile.ZipFile(out) as ours, zipfile.ZipFile(shared_fmus.door(3, faults=True)) as api:
        assert ours.namelist() == api.namelist()
        assert ours.read("modelDescription.xml") == api.read("modelDescription.xml")


def test_a_shared_fmu_is_made_once_and_waited_for_while_another_worker_makes_it(tmp_path):
    """conftest's ``shared_fmus``, which the FMU tests of every xdist worker share."""
    shared, made = SharedFMUs(tmp_path), []

    def make(out):
        made.append(out)
        out.write_bytes(b"ours")

    with ThreadPoolExecutor(1) as pool, open(tmp_path / ".x.fmu.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # another worker is making x.fmu
        asked = pool.submit(shared.once, "x.fmu", make)
        time.sleep(0.2)
        assert not asked.done()  # waiting for the lock
        (tmp_path / "x.fmu").write_bytes(b"theirs")
        lock.close()  # the other worker is done
        assert asked.result(timeout=10).read_bytes() == b"theirs" and made == []

    def broken(out):
        out.write_bytes(b"half")
        raise UserError("cmake --build failed")

    with pytest.raises(UserError):
        shared.once("y.fmu", broken)
    assert not (tmp_path / "y.fmu").exists()  # nothing half made to take
    assert shared.once("y.fmu", make).read_bytes() == b"ours"
    assert shared.once("y.fmu", broken).read_bytes() == b"ours" and len(made) == 1


def test_the_builder_refuses_bad_input_before_compiling(tmp_path):
    existing = tmp_path / "door.fmu"
    existing.write_bytes(b"keep me")
    with pytest.raises(UserError, match="exists: pass force=True"):
        build.build_fmu(existing)
    assert existing.read_bytes() == b"keep me"
    with pytest.raises(UserError, match="fmi must be 2 or 3"):
        build.build_fmu(tmp_path / "x.fmu", fmi=1)
    with pytest.raises(UserError, match="layout must be one of tuned, untuned"):
        build.build_fmu(tmp_path / "x.fmu", layout="tunde")
    with pytest.raises(UserError, match="interfaces must be"):
        build.build_fmu(tmp_path / "x.fmu", interfaces=("me", "se"))
    done = subprocess.run(
        [sys.executable, str(BUILD_SCRIPT), "--out", str(existing)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"build.py: error: {existing} exists: pass force=True (--force) to write over it"
    ]


def test_the_generated_header_numbers_what_the_model_description_names():
    sources = build.c_sources(2, "untuned", ("me", "cs"))
    header, table = sources["door_variables.h"], sources["door_variables.c"]
    for key, vr in build.VALUE_REFERENCES.items():
        assert f"DOOR_VR_{key.upper()} = {vr}," in header
    for i, p in enumerate(build.PARAMETERS):
        assert f"DOOR_P_{p.name.upper()} = {i}," in header
        assert f'{{"{p.untuned}", {p.start!r}, {p.min!r}, {p.max!r}, ' in table
    assert '"time", "door.phi", "door.w", "der(door.w)", "F_hand", "angle", "speed"' in table
    assert build.token(2, "tuned", ("me", "cs")) == build.token(2, "tuned", ("me", "cs"))
    assert build.token(2, "tuned", ("me",)) != build.token(2, "tuned", ("me", "cs"))
