"""Models on a state vector, end to end: a user's file with states of its own is
simulated (against scipy), its force-angle curve is its static equilibrium (against the
closed form), the rig makes trials of it and a fit recovers its truth, and bad
declarations are one line each.

The example is ``examples/cable_door/cable_door.py`` (a door whose spring pulls through
an elastic cable: angle, speed and the spring's carriage); a second model, written
here with names of its own (two bodies on a spring, a dry-friction contact on each), is
checked against scipy too.
"""

from __future__ import annotations

import json
import math
import shutil
import textwrap
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from evo_door.errors import UserError
from evo_door.models import get_model
from evo_door.sim import simulate
from evo_door.sim.simulate import force_angle_curve
from tests.test_cli import cli

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "cable_door"
DT = 1.0 / 1024.0


def cable_door():
    return get_model(f"{EXAMPLE / 'cable_door.py'}:MODEL")


def cable_reference(p: dict, force, theta0: float):
    """The cable door's equations written again, independently, for scipy."""
    r, kc, ks, pre, c = (
        p["drum_radius"], p["cable_stiffness"], p["spring_stiffness"], p["spring_preload"],
        p["carriage_damping"],
    )  # fmt: skip
    closed = 0.5 * math.pi

    def f_at(t):
        return np.interp(t, DT * np.arange(force.size), force)

    def rhs(t, y):
        a, w, car = y
        tension = max(kc * (r * (closed - a) - car), 0.0)
        stop = 0.0
        if a < 0.0:
            stop = max(-p["stop_stiffness"] * a - p["stop_damping"] * w, 0.0)
        elif a > closed:
            stop = min(-p["stop_stiffness"] * (a - closed) - p["stop_damping"] * w, 0.0)
        torque = (
            p["hand_lever"] * f_at(t) - p["weight_moment"] * math.cos(a) + r * tension
            - p["hinge_friction"] * math.tanh(p["friction_slope"] * w) + stop
        )  # fmt: skip
        return [w, torque / p["leaf_inertia"], (tension - pre - ks * car) / c]

    car0 = (kc * r * (closed - theta0) - pre) / (kc + ks)
    t = DT * np.arange(force.size)
    sol = solve_ivp(
        rhs, (0.0, t[-1]), [theta0, 0.0, car0], method="Radau", t_eval=t, rtol=1e-11,
        atol=1e-12, max_step=DT,
    )  # fmt: skip
    assert sol.success
    return sol.y


def push(n=2048, level=40.0, length=0.25):
    """A push toward closing from fully open: ``level`` N for ``length`` s, then let go."""
    t = DT * np.arange(n)
    return np.where(t < length, level * np.sin(np.pi * t / length) ** 2, 0.0)


def test_cable_door_matches_scipy_and_keeps_its_carriage_state():
    model = cable_door()
    assert model.plant.n_states == 3 and model.plant.state_names[2] == "carriage"
    ps = model.load_params()
    force = push()
    r = simulate(model, ps, force, DT, theta0=0.0, method="dopri5", tolerance=1e-10)
    assert r.ok and set(r.states) == {"carriage"}
    ref = cable_reference(ps.as_dict(), force, 0.0)
    assert np.max(np.abs(r.theta - ref[0])) < 1e-6  # rad
    assert np.max(np.abs(r.dtheta - ref[1])) < 1e-5  # rad/s
    assert np.max(np.abs(r.states["carriage"] - ref[2])) < 1e-7  # m
    assert r.theta.max() > 0.1  # the push lifted the door: the carriage moved
    assert np.ptp(r.states["carriage"]) > 1e-3
    # the default method (semi-implicit, 2 steps a sample) at its own accuracy
    d = simulate(model, ps, force, DT, theta0=0.0)
    assert d.ok and np.max(np.abs(d.theta - ref[0])) < 2e-3


def rows_per_call(monkeypatch, kernel: str, rows_at: int) -> list:
    """Count the calls of the compiled kernel ``kernel`` that the state plant makes: the
    list, filled as it is called, of the rows of each call (its argument ``rows_at``,
    the parameter matrix)."""
    from evo_door.sim import state_plant

    calls = []
    real = getattr(state_plant, kernel)

    def counted(*args):
        calls.append(args[rows_at].shape[0])
        return real(*args)

    monkeypatch.setattr(state_plant, kernel, counted)
    return calls


def test_a_population_runs_in_one_parallel_call_each_from_its_own_start(monkeypatch):
    """The cable door's carriage starts where its cable and spring balance, which
    depends on the parameters (its ``start``): a population's errors are each
    individual's own (its start, its trials), from one call of the parallel kernel,
    not one call per individual."""
    from evo_door.sim_settings import DOPRI5, ISE

    model = cable_door()
    plant = model.plant
    assert model.start is not None
    base = model.load_params()
    names = [p.name for p in model.params]
    P = np.array([base.vector] * 3)
    P[1, names.index("spring_preload")] *= 1.3
    P[2, names.index("spring_stiffness")] *= 0.7
    force = np.concatenate([push(600), np.zeros(400)])
    settings = {"method": "dopri5", "substeps": 2, "tolerance": 1e-9}
    target = simulate(model, base, force, DT, theta0=0.0, **settings).dtheta
    calls = rows_per_call(monkeypatch, "population_errors_states", 2)
    err = np.empty((3, 1))
    ok = np.empty((3, 1), dtype=bool)
    plant.population_errors(
        P, force, target, np.ones(force.size, bool), np.array([0, force.size]),
        np.array([DT]), np.zeros(1), np.zeros(1), 2, DOPRI5, 1e-9, 1, ISE, err, ok,
    )  # fmt: skip
    assert calls == [3] and ok.all()
    assert err[0, 0] == 0.0  # the truth against its own simulation
    for i in (1, 2):
        starts = plant.initial_state(P[i], 0.0, 0.0)
        assert starts[2] != plant.initial_state(P[0], 0.0, 0.0)[2]  # a start of its own
        r = simulate(model, P[i], force, DT, theta0=0.0, **settings)
        e2 = (r.dtheta - target) ** 2
        own = DT * (e2.sum() - 0.5 * (e2[0] + e2[-1]))
        assert err[i, 0] == pytest.approx(own, rel=1e-12)


def test_a_populations_curves_and_inertia_come_from_one_parallel_call(monkeypatch):
    """The force-angle curves and felt inertia of several cable doors (each its own
    carriage start) in one call of the parallel equilibrium kernel, each row what the
    door alone gives, to the bit; no angle gives rows of no angle."""
    model = cable_door()
    plant = model.plant
    names = [p.name for p in model.params]
    P = np.array([model.load_params().vector] * 3)
    P[1, names.index("spring_preload")] *= 1.3
    P[2, names.index("cable_stiffness")] *= 0.5
    theta = np.linspace(0.0, 0.5 * math.pi, 91)
    calls = rows_per_call(monkeypatch, "hold_states_rows", 1)
    forces = plant.hold_forces_rows(P, theta, 1e-3)
    inertia = plant.inertia_rows(P, theta, -1e-3)
    assert calls == [3, 3] and forces.shape == inertia.shape == (3, 91)
    for r in range(3):
        assert np.array_equal(forces[r], plant.hold_forces(P[r], theta, 1e-3))
        assert np.array_equal(inertia[r], 1.0 / plant._hold(P[r], theta, -1e-3)[1])
    assert np.all(np.isfinite(forces)) and np.all(inertia > 0.0)
    assert np.ptp(forces[1] - forces[0]) > 0.0  # another pre-load: another curve
    assert plant.hold_forces_rows(P, theta[:0], 1e-3).shape == (3, 0)


def test_chunks_carry_the_whole_state():
    """Simulating in chunks from each chunk's ``final`` equals one call (the rig does)."""
    model = cable_door()
    ps = model.load_params()
    force = push(1024)
    whole = simulate(model, ps, force, DT, theta0=0.0)
    state, theta = None, [whole.theta[0]]
    for k in range(0, 1023, 8):
        r = simulate(model, ps, force[k : k + 9], DT, theta0=0.0, state=state)
        state = r.final
        theta += list(r.theta[1:])
    assert np.array_equal(np.array(theta), whole.theta)


def test_the_curve_is_the_static_equilibrium():
    """Coulomb curve of the cable door against the closed form: the carriage at rest,
    tension = k_c (P + k_s s) / (k_c + k_s) with s = r (pi/2 - angle)."""
    model = cable_door()
    ps = model.load_params()
    p = ps.as_dict()
    curve = force_angle_curve(model, ps, n=181)
    a = curve["theta"]
    s = p["drum_radius"] * (0.5 * math.pi - a)
    kc, ks = p["cable_stiffness"], p["spring_stiffness"]
    tension = kc * (p["spring_preload"] + ks * s) / (kc + ks)
    static = (p["weight_moment"] * np.cos(a) - p["drum_radius"] * tension) / p["hand_lever"]
    inside = (a > 1e-9) & (a < 0.5 * math.pi - 1e-9)
    friction = p["hinge_friction"] / p["hand_lever"]
    np.testing.assert_allclose(curve["closing"][inside], (static + friction)[inside], atol=1e-7)
    np.testing.assert_allclose(curve["opening"][inside], (static - friction)[inside], atol=1e-7)


TWO_BODIES = '''
"""Two carts on a rail: the hand pushes cart A, a spring couples it to cart B; each
slides on dry friction (a sign law: it sticks)."""
import math
from numba import njit
from evo_door.models import Model
from evo_door.params import Param, ParamTable

PARAMS = ParamTable("carts", [
    Param("mass_a", "kg", 2.0, 0.1, 20.0, "specification", "cart the hand pushes"),
    Param("mass_b", "kg", 3.0, 0.1, 20.0, "specification", "cart behind it"),
    Param("coupling", "N/m", 400.0, 1.0, 1e4, "specification", "spring between the carts"),
    Param("rub_a", "N", 1.5, 0.0, 20.0, "specification", "dry friction of cart A"),
    Param("rub_b", "N", 2.5, 0.0, 20.0, "specification", "dry friction of cart B"),
])

@njit(cache=True)
def sgn(v):
    return 0.0 if v == 0.0 else math.copysign(1.0, v)

@njit(cache=True)
def rhs(x, force, p, dx):
    spring = p[2] * (x[2] - x[0])
    dx[0] = x[1]
    dx[1] = (force + spring - p[3] * sgn(x[1])) / p[0]
    dx[2] = x[3]
    dx[3] = (-spring - p[4] * sgn(x[3])) / p[1]

SETTINGS = dict(states=("xa", "va", "xb", "vb"), handle=(0, 1), contacts=(1, 3))
# CHANGE
CARTS = Model(name="carts", title="two carts", params=PARAMS, rhs=rhs, method="dopri5",
              theta_range=(0.0, 0.5), theta_unit="m", tolerance=1e-10, **SETTINGS)
'''


def test_a_model_nobody_tuned_for_two_bodies_with_sticking_contacts(tmp_path):
    """Two carts: A is pushed for 0.3 s and stops dead (its contact sticks: speed exactly
    0); B follows, through the spring, and sticks too. Against scipy on the same law
    while both slide, and held exactly at rest once stuck."""
    (tmp_path / "carts.py").write_text(textwrap.dedent(TWO_BODIES))
    model = get_model(f"{tmp_path / 'carts.py'}:CARTS")
    ps = model.load_params()
    n = 2048
    t = DT * np.arange(n)
    force = np.where(t < 0.3, 8.0, 0.0)
    r = simulate(model, ps, force, DT, theta0=0.0)
    assert r.ok
    vb = r.states["vb"]
    # both carts end stuck: speed exactly zero, positions held
    assert r.dtheta[-1] == 0.0 and vb[-1] == 0.0
    assert r.theta[-1] == r.theta[-200] and r.states["xb"][-1] == r.states["xb"][-200]
    # while both slide forward (up to the first stop), scipy on the same equations
    p = ps.as_dict()

    def rhs(tt, y):
        f = np.interp(tt, t, force)
        spring = p["coupling"] * (y[2] - y[0])
        return [
            y[1],
            (f + spring - p["rub_a"] * np.sign(y[1])) / p["mass_a"],
            y[3],
            (-spring - p["rub_b"] * np.sign(y[3])) / p["mass_b"],
        ]

    moving = np.flatnonzero((r.dtheta[1:] > 0) & (vb[1:] > 0)) + 1
    assert moving.size > 50
    k0 = moving[0]
    stop = (
        k0 + np.argmax(np.diff(moving[moving >= k0]) > 1)
        if np.any(np.diff(moving) > 1)
        else moving[-1]
    )
    k1 = int(min(stop, moving[-1]))
    y0 = [r.theta[k0], r.dtheta[k0], r.states["xb"][k0], vb[k0]]
    sol = solve_ivp(rhs, (t[k0], t[k1]), y0, method="DOP853", t_eval=t[k0 : k1 + 1],
                    rtol=1e-12, atol=1e-13, max_step=DT)  # fmt: skip
    assert np.max(np.abs(sol.y[0] - r.theta[k0 : k1 + 1])) < 1e-8
    assert np.max(np.abs(sol.y[2] - r.states["xb"][k0 : k1 + 1])) < 1e-8


BAD = [
    ("states=('x',)", "states must be a tuple of at least two names"),
    ("states=('x', 'x', 'y', 'w')", "name one state twice"),
    ("handle=(0, 9)", "handle's speed must be an index into states (0 to 3), got 9"),
    ("handle=(1, 1)", "the handle's position and speed must be two states"),
    ("contacts=(0,)", "contact 0 is the handle's position, not a speed"),
    ("x0=(0.0, 1.0)", "x0 has 2 values for 4 states"),
]


@pytest.mark.parametrize("change, message", BAD)
def test_a_bad_declaration_is_one_line(tmp_path, change, message):
    text = textwrap.dedent(TWO_BODIES).replace("# CHANGE", f"SETTINGS.update({change})")
    (tmp_path / "bad.py").write_text(text)
    with pytest.raises(UserError) as err:
        get_model(f"{tmp_path / 'bad.py'}:CARTS")
    assert message in str(err.value) and "\n" not in str(err.value)


def test_an_rhs_of_the_wrong_shape_is_one_line(tmp_path):
    text = (
        textwrap.dedent(TWO_BODIES)
        .replace("def rhs(x, force, p, dx):", "def rhs(x, force, p):")
        .replace("    spring = p[2]", "    dx = x.copy()\n    spring = p[2]")
    )
    (tmp_path / "bad.py").write_text(text)
    with pytest.raises(
        UserError, match=r"rhs must be a numba @njit function rhs\(x, force, p, dx\)"
    ):
        get_model(f"{tmp_path / 'bad.py'}:CARTS")


@pytest.mark.slow
def test_rig_fit_and_curve_from_the_command_line(tmp_path, capsys):
    """The real commands on the cable door: rig trials from its truth, a fit that
    recovers every free parameter within 2 %, a curve and a simulation; no Python."""
    work = tmp_path / "cable_door"
    shutil.copytree(EXAMPLE, work, ignore=shutil.ignore_patterns("__pycache__", "*.h5"))
    made = cli(capsys, "rig", "generate", "--model", "cable_door.py:MODEL", "--trials", "6",
               "--out", "trials.h5", cwd=work)  # fmt: skip
    assert made.returncode == 0, made.stderr
    run = cli(capsys, "run", "fit.yaml", "--out", "fit.h5", cwd=work)
    assert run.returncode == 0, run.stderr
    shown = cli(
        capsys, "show", "fit.h5", "--json", "--allow-model", "cable_door.py:MODEL", cwd=work
    )
    assert shown.returncode == 0, shown.stderr
    best = json.loads(shown.stdout)["best"]
    truth = cable_door().load_params().as_dict()
    for name in ("spring_stiffness", "spring_preload", "carriage_damping", "hinge_friction"):
        assert abs(best[name] / truth[name] - 1.0) < 0.02, (name, best[name], truth[name])
    curve = cli(capsys, "curve", "cable_door.py:MODEL", "--out", "curve.csv", cwd=work)
    assert curve.returncode == 0, curve.stderr
    table = np.genfromtxt(work / "curve.csv", delimiter=",", names=True, dtype=None,
                          encoding="utf-8")  # fmt: skip
    assert np.all(np.isfinite(table["force"])) and table.size >= 2 * 721
    assert set(table["direction"]) == {"opening", "closing"}
    (work / "push.csv").write_text(
        "t,force\n" + "".join(f"{k * DT},{f}\n" for k, f in enumerate(push(1024)))
    )
    sim = cli(capsys, "simulate", "cable_door.py:MODEL", "--input", "push.csv", "--out",
              "r.csv", cwd=work)  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    header = (work / "r.csv").read_text().splitlines()[0]
    assert header.endswith(",carriage")
