"""FMU models: declared from their description, simulated by the compiled kernels,
fitted from trials made by FMPy, refused in one line when broken (issue 28).

The FMUs are the project's own door (examples/fmu), built from its C sources for FMI
2.0 and 3.0 once per suite run (conftest's ``shared_fmus``). The "untuned" layout is the
FMU nobody tuned for evo-door: its input is ``F_hand``, its outputs ``angle`` and
``speed`` in degrees, its parameters named like a Modelica export (``door.J``); the tests
reach it only through a channel mapping.
"""

import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from evo_door.cli import main
from tests.helpers import door_fmu_builder

fmpy = pytest.importorskip("fmpy")

# numerics (run again on a generic CPU in CI): the comparisons of the kernels' numbers;
# the fits and the refusals are not about the last bits

build = door_fmu_builder()  # examples/fmu/build.py

DT = 1 / 1024  # s
UNTUNED = {"force": "F_hand", "theta": "angle", "dtheta": "speed"}
STATES = {"theta0": "door.phi", "dtheta0": "door.w"}


@pytest.fixture(scope="module")
def fmus(shared_fmus):
    """(fmi, layout) -> path of the built FMU (both interfaces in each; shared by the
    whole run: a test that changes one copies it)."""
    return shared_fmus.doors()


def push(amp=20.0, width=0.15, duration=2.0):
    """A half-sine push of ``amp`` N for ``width`` s, sampled at 1024 Hz."""
    t = np.arange(int(round(duration / DT)) + 1) * DT
    return t, np.where(t < width, amp * np.sin(np.pi * t / width), 0.0)


def reference(t, force, theta0=0.0, **changes):
    """The door's equation of motion (examples/fmu/README.md), by scipy at rtol 1e-10,
    the force linearly interpolated between samples as evo-door's kernels take it."""
    p = {p.name: p.start for p in build.PARAMETERS}
    p.update(changes)

    def rhs(tt, y):
        th, w = y
        stop = 0.0
        if th < 0.0:
            stop = -p["stop_stiffness"] * th - p["stop_damping"] * w
        elif th > math.pi / 2:
            stop = -p["stop_stiffness"] * (th - math.pi / 2) - p["stop_damping"] * w
        torque = (
            p["lever_arm"] * np.interp(tt, t, force)
            + p["spring_preload"]
            + p["spring_stiffness"] * (math.pi / 2 - th)
            - p["weight_moment"] * math.cos(th)
            - p["damping"] * w
            - p["friction"] * math.tanh(w / p["friction_speed"])
            + stop
        )
        return [w, torque / p["inertia"]]

    sol = solve_ivp(rhs, (t[0], t[-1]), [theta0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12,
                    method="DOP853", max_step=DT)  # fmt: skip
    return sol.y[0]


def fmpy_run(path, t, force, interface, input_name="force", output="theta", **start):
    """FMPy's own simulation of the same trial (what a user of FMPy gets)."""
    sig = np.array(list(zip(t, force)), dtype=[("time", float), (input_name, float)])
    kind = "ModelExchange" if interface == "me" else "CoSimulation"
    extra = {"solver": "CVode", "relative_tolerance": 1e-10} if interface == "me" else {}
    r = fmpy.simulate_fmu(str(path), fmi_type=kind, stop_time=t[-1], output_interval=DT,
                          input=sig, output=[output], start_values=start, **extra)  # fmt: skip
    return np.interp(t, r["time"], r[output])


def write_csv(path, t, force):
    np.savetxt(path, np.c_[t, force], delimiter=",", header="t,force", comments="")


def read_csv(path):
    return np.genfromtxt(path, delimiter=",", names=True)


# -- the declaration --------------------------------------------------------------------
def test_params_lists_an_untuned_fmus_parameters_with_units_bounds_and_meaning(fmus, capsys):
    assert main(["params", str(fmus[3, "untuned"])]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in out.splitlines() if line.strip()}
    # name, unit, default (start), lower (min), upper (max), group, meaning
    assert rows["door.J"][1:5] == ["kg.m2", "0.7", "0.05", "5"]
    assert rows["spring.k"][1:5] == ["N.m/rad", "8", "0", "60"]
    assert "fixed: set before initialisation" in out.split("door.r", 1)[1].splitlines()[0]
    # nothing named force here: the channels are said, the parameters listed anyway
    assert "channels not matched" in out and "F_hand" in out


def test_params_and_set_are_checked_against_the_fmus_bounds(fmus, capsys):
    path = str(fmus[2, "tuned"])
    assert main(["params", path, "--set", "inertia=9"]) == 2
    assert "outside its declared range [0.05, 5]" in capsys.readouterr().err


# -- simulate -----------------------------------------------------------------------------
@pytest.mark.numerics
@pytest.mark.parametrize("fmi", [2, 3])
@pytest.mark.parametrize("interface", ["me", "cs"])
def test_simulate_agrees_with_fmpy_and_with_scipy(fmus, fmi, interface, tmp_path, capsys):
    t, force = push()
    write_csv(tmp_path / "in.csv", t, force)
    args = ["simulate", f"{fmus[fmi, 'untuned']}:{interface}", "--input", str(tmp_path / "in.csv")]
    args += [f"--channels={k}={v}" for k, v in UNTUNED.items()]
    assert main([*args, "--out", str(tmp_path / "out.csv")]) == 0
    ours = read_csv(tmp_path / "out.csv")["theta"]  # rad: converted from the FMU's deg
    theirs = np.radians(fmpy_run(fmus[fmi, "untuned"], t, force, interface, "F_hand", "angle"))
    assert np.abs(ours - theirs).max() < 2e-3
    if interface == "cs":  # the same steps inside the FMU, the same held input: exact
        assert np.abs(ours - theirs).max() < 1e-9
    else:  # the compiled RK4 against an independent integration of the same law
        assert np.abs(ours - reference(t, force)).max() < 1e-6


def test_evo_door_compile_compiles_the_types_an_fmus_runs_pass(fmus):
    """``evo-door compile`` compiles the FMU kernels without an FMU, for stub functions
    and a run's arrays (``runner_signatures``): the types real runs pass, model exchange
    and co-simulation, FMI 2 and 3, and the force that holds the door, are among them,
    so that an FMU's first run after it compiles nothing."""
    from evo_door.models import get_model
    from evo_door.models.fmu import kernels
    from evo_door.models.fmu.instance import runner_signatures

    _, force = push(duration=0.1)
    for fmi in (2, 3):
        for interface in ("me", "cs"):
            model = get_model(f"{fmus[fmi, 'tuned']}:{interface}")
            p = model.load_params().vector
            theta, _, _, ok = model.runner.simulate(p, force, DT)
            assert ok and np.isfinite(theta).all()
            if interface == "me":
                assert np.isfinite(model.runner.hold_force(p, np.array([0.3, 0.6]), 0.0)).all()
    ran = {(k, tuple(sig)) for k in (kernels.run_me, kernels.run_cs, kernels.hold_me)
           for sig in k.signatures}  # fmt: skip
    listed = set(runner_signatures())
    assert {k for k, _ in ran} == {kernels.run_me, kernels.run_cs, kernels.hold_me}
    assert ran <= listed, ran - listed
    assert len(listed) == 6  # three kernels, two FMI versions: the types differ


@pytest.mark.numerics
def test_the_trials_initial_state_and_parameters_reach_the_fmu(fmus):
    from evo_door.models import get_model
    from evo_door.sim import simulate

    t, force = push(amp=-10.0)
    name = "{}?{}".format(
        fmus[3, "untuned"], "&".join(f"{k}={v}" for k, v in {**UNTUNED, **STATES}.items())
    )
    model = get_model(name)
    params = model.load_params(None, {"door.J": 1.4, "hinge.d": 2.0})
    r = simulate(model, params, force, DT, theta0=1.2)
    assert r.ok and r.theta[0] == pytest.approx(1.2, abs=1e-12)
    ref = reference(t, force, theta0=1.2, inertia=1.4, damping=2.0)
    free = t < t[np.argmax(ref > math.pi / 2)]  # till it meets the closed stop: a kink
    assert free.sum() > 500 and np.abs(r.theta - ref)[free].max() < 1e-6
    assert np.abs(r.theta - ref).max() < 2e-4  # RK4 steps across the stop's kink
    # ddtheta, which this FMU does not output, is the difference quotient of dtheta
    assert np.abs(r.ddtheta[1:-1] - np.gradient(r.dtheta, DT)[1:-1]).max() < 1e-9


# -- the round trip ---------------------------------------------------------------------------
TRUE = {"door.J": 0.9, "spring.k": 11.0, "hinge.d": 1.3}


@pytest.mark.slow
def test_a_ga_recovers_three_parameters_of_an_untuned_fmu_from_fmpy_trials(fmus, tmp_path, capsys):
    from evo_door.data import Trial, write_trials

    fmu = tmp_path / "door.fmu"
    fmu.write_bytes(fmus[3, "untuned"].read_bytes())
    trials = []
    for i, (amp, width, theta0) in enumerate([(20, 0.15, 0.0), (-15, 0.2, 1.2), (30, 0.1, 0.3)]):
        t, force = push(amp, width)
        deg = fmpy_run(fmu, t, force, "cs", "F_hand", "speed", **TRUE, **{"door.phi": theta0})
        trials.append(Trial(t=t, force=force, dtheta=np.radians(deg), trial_id=f"T{i + 1}",
                            user_id="U1", kind="impulse", theta0=theta0, dtheta0=0.0))  # fmt: skip
    write_trials(tmp_path / "trials.h5", trials)
    (tmp_path / "fit.yaml").write_text(
        "model: door.fmu\n"
        "channels: {force: F_hand, theta: angle, dtheta: speed, theta0: door.phi, dtheta0: door.w}\n"
        "target: {data: trials.h5}\n"
        "free: {door.J: [0.3, 2.0], spring.k: [2.0, 20.0], hinge.d: [0.2, 3.0]}\n"
        "objective: {kind: ise, derivative: 1}\n"
        "algorithm: {kind: ga, population: 20, generations: 6, seed: 1, polish: slsqp}\n"
    )
    out = tmp_path / "fit.h5"
    assert main(["run", str(tmp_path / "fit.yaml"), "--out", str(out), "--quiet"]) == 0
    from evo_door.experiment.reader import read_results

    best = read_results(out).best.values
    for name, value in TRUE.items():
        assert best[name] == pytest.approx(value, rel=0.02), name


@pytest.mark.slow
def test_a_ga_recovers_three_parameters_of_a_co_simulation_fmi2_fmu(fmus, tmp_path):
    """The other version and interface: trials by FMPy, the fit stepping the FMU's own
    co-simulation (FMI 2.0, the tuned layout: nothing mapped)."""
    from evo_door.data import Trial, write_trials
    from evo_door.experiment.reader import read_results

    truth = {"inertia": 1.2, "spring_stiffness": 7.0, "damping": 0.5}
    fmu = tmp_path / "door2.fmu"
    fmu.write_bytes(fmus[2, "tuned"].read_bytes())
    trials = []
    for i, (amp, width) in enumerate([(25, 0.15), (18, 0.25)]):
        t, force = push(amp, width, duration=1.5)
        sig = np.array(list(zip(t, force)), dtype=[("time", float), ("force", float)])
        r = fmpy.simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=t[-1], output_interval=DT,
                              input=sig, output=["dtheta"], start_values=truth)  # fmt: skip
        trials.append(Trial(t=t, force=force, dtheta=np.interp(t, r["time"], r["dtheta"]),
                            trial_id=f"T{i + 1}", kind="impulse", theta0=0.0, dtheta0=0.0))  # fmt: skip
    write_trials(tmp_path / "trials.h5", trials)
    (tmp_path / "fit.yaml").write_text(
        "model: door2.fmu:cs\ntarget: {data: trials.h5}\n"
        "free: {inertia: [0.3, 3.0], spring_stiffness: [1.0, 20.0], damping: [0.1, 3.0]}\n"
        "objective: {kind: ise, derivative: 1}\n"
        "algorithm: {kind: ga, population: 16, generations: 4, seed: 2, polish: slsqp}\n"
    )
    out = tmp_path / "fit.h5"
    assert main(["run", str(tmp_path / "fit.yaml"), "--out", str(out), "--quiet"]) == 0
    best = read_results(out).best.values
    for name, value in truth.items():
        assert best[name] == pytest.approx(value, rel=0.02), name


# -- refused in one line --------------------------------------------------------------------
def _rezip(src: Path, dst: Path, edit) -> Path:
    """``src`` rewritten entry by entry: ``edit(name, data)`` returns the new
    ``(name, data)`` or None to leave the entry out."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.infolist():
            kept = edit(item.filename, zin.read(item.filename))
            if kept is not None:
                zout.writestr(kept[0], kept[1])
    return dst


BROKEN = {
    "not a zip": (
        lambda src, dst: dst.write_bytes(b"MZ not an archive") and dst,
        "not a zip archive",
    ),
    "no description": (
        lambda src, dst: _rezip(
            src, dst, lambda n, d: None if n == "modelDescription.xml" else (n, d)
        ),
        "has no modelDescription.xml",
    ),
    "malformed description": (
        lambda src, dst: _rezip(
            src, dst, lambda n, d: (n, d[: len(d) // 2]) if n.endswith(".xml") else (n, d)
        ),
        "modelDescription.xml is malformed",
    ),
    "FMI 1.0": (
        lambda src, dst: _rezip(
            src, dst, lambda n, d: (n, d.replace(b'fmiVersion="2.0"', b'fmiVersion="1.0"'))
        ),
        "is FMI 1.0; evo-door reads FMI 2.0 and 3.0",
    ),
    "no binary for this platform": (
        lambda src, dst: _rezip(
            src, dst, lambda n, d: (n.replace("linux64", "win64").replace(".so", ".dll"), d)
        ),
        "has no binary for this platform (linux64",
    ),
}


@pytest.mark.parametrize("case", list(BROKEN))
def test_a_broken_fmu_is_refused_in_one_line_with_exit_status_2(fmus, case, tmp_path, capsys):
    make, expected = BROKEN[case]
    bad = tmp_path / "bad.fmu"
    make(fmus[2, "tuned"], bad)
    assert main(["params", str(bad)]) == 2
    err = capsys.readouterr().err
    assert expected in err and len(err.strip().splitlines()) == 1, err
    if case == "no binary for this platform":
        assert "it has win64" in err


def _experiment(tmp_path, fmu, extra="", free="door.J: [0.3, 2.0]", theta0=None):
    from evo_door.data import Trial, write_trials

    t, force = push()
    write_trials(
        tmp_path / "trials.h5",
        [Trial(t=t, force=force, dtheta=0 * t, trial_id="T1", kind="impulse", theta0=theta0)],
    )
    (tmp_path / "x.fmu").write_bytes(Path(fmu).read_bytes())
    (tmp_path / "fit.yaml").write_text(
        f"model: x.fmu\n{extra}target: {{data: trials.h5}}\nfree: {{{free}}}\n"
        "objective: {kind: ise, derivative: 1}\n"
        "algorithm: {kind: ga, population: 4, generations: 1, seed: 1}\n"
    )
    return tmp_path / "fit.yaml"


@pytest.mark.parametrize(
    "extra, free, expected",
    [
        ("", "door.J: [0.3, 2.0]", "fit.yaml:1: model: FMU"),  # nothing named force
        ("channels: {force: F_hnd, theta: angle}\n", "door.J: [0.3, 2.0]",
         "the channel mapping names 'F_hnd', which it does not have (did you mean 'F_hand'"),
        ("channels: {force: angle, theta: angle}\n", "door.J: [0.3, 2.0]", "the force must be an input"),
        ("channels: {force: F_hand, theta: F_hand}\n", "door.J: [0.3, 2.0]", "cannot convert to the theta"),
        ("channels: {force: F_hand, theta: angle}\n", "angle: [0, 1]", "'angle' of FMU x.fmu cannot be set"),
    ],
)  # fmt: skip
def test_an_experiment_that_does_not_fit_its_fmu_is_refused_in_one_line(
    fmus, tmp_path, capsys, extra, free, expected
):
    exp = _experiment(tmp_path, fmus[3, "untuned"], extra, free)
    assert main(["run", str(exp), "--out", str(tmp_path / "r.h5")]) == 2
    err = capsys.readouterr().err
    assert expected in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "r.h5").exists()


def test_what_needs_the_state_set_at_will_refuses_a_co_simulation_fmu(fmus, tmp_path, capsys):
    # a model-exchange FMU gives its curve (tests/test_fmu_plant.py)
    assert main(["curve", f"{fmus[2, 'tuned']}:cs", "--out", str(tmp_path / "c.csv")]) == 2
    assert "is run by co-simulation: the force-angle curve needs" in capsys.readouterr().err


def test_a_trial_that_starts_where_the_fmu_cannot_be_put_is_refused(fmus, tmp_path, capsys):
    channels = "channels: {force: F_hand, theta: angle, dtheta: speed}\n"
    exp = _experiment(tmp_path, fmus[3, "untuned"], channels, theta0=1.0)
    assert main(["run", str(exp), "--out", str(tmp_path / "r.h5")]) == 2
    err = capsys.readouterr().err
    assert "trial T1: the run starts at theta = 1" in err and "channels: {theta0: VARIABLE}" in err
    # mapped to the state that sets it, the same experiment starts
    text = exp.read_text().replace(
        "dtheta: speed}", "dtheta: speed, theta0: door.phi, dtheta0: door.w}"
    )
    exp.write_text(text)
    assert main(["run", str(exp), "--out", str(tmp_path / "r.h5"), "--quiet"]) == 0


def test_channels_are_only_for_an_fmu(capsys, tmp_path):
    args = [
        "simulate",
        "haptic",
        "--channels",
        "force=F",
        "--input",
        "x.csv",
        "--out",
        str(tmp_path / "o.csv"),
    ]
    assert main(args) == 2
    assert "--channels: only for an FMU model" in capsys.readouterr().err


def test_a_preset_beside_the_fmu_is_found_by_name_and_checked(fmus, tmp_path, capsys):
    fmu = tmp_path / "door.fmu"
    fmu.write_bytes(fmus[2, "tuned"].read_bytes())
    (tmp_path / "presets").mkdir()
    (tmp_path / "presets" / "heavy.yaml").write_text(
        'model: door.fmu\ndescription: "a heavier door"\nvalues:\n  inertia: 1.5\n'
    )
    (tmp_path / "presets" / "other.yaml").write_text("model: door\nvalues:\n  L: 0.6\n")
    assert main(["params", str(fmu)]) == 0
    out = capsys.readouterr().out
    # the FMU's own preset; not the bundled door's, not one for another model
    assert "presets: heavy\n" in out and "table53" not in out
    assert main(["params", str(fmu), "--params", "heavy", "--set", "damping=2"]) == 0
    rows = {
        line.split()[0]: line.split()
        for line in capsys.readouterr().out.splitlines()
        if line.strip()
    }
    assert rows["inertia"][2] == "1.5" and rows["damping"][2] == "2"


def test_a_malformed_channel_mapping_is_one_line(fmus, tmp_path, capsys):
    out = tmp_path / "o.csv"
    args = [
        "simulate",
        str(fmus[2, "tuned"]),
        "--channels",
        "force",
        "--input",
        "x.csv",
        "--out",
        str(out),
    ]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert (
        "--channels 'force': expected CHANNEL=VARIABLE" in err
        and len(err.strip().splitlines()) == 1
    )
    assert not out.exists()
