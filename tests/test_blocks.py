"""Mechanisms from blocks (docs/blocks.md): a YAML file of bodies and components is a
model every command takes. The drawer example against scipy on equations written here
again; the generated rhs of the two carts against the same law by hand; the declared
parameters; the compiled module cached (a second process compiles nothing); a bad file
is one line naming the element; and, slow, the real commands: rig trials, a fit that
recovers every free parameter within 2 %, a curve.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from evo_door.errors import UserError
from evo_door.models import get_model, is_code_spec, resolve_model_name
from evo_door.models.base import check_named_in_file
from evo_door.models.blocks import CACHE_ENV
from evo_door.sim import simulate
from tests.test_cli import cli

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "blocks"
DT = 1.0 / 1024.0


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    """Generated mechanisms in a tmp folder of the session (not the user's cache)."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path_factory.getbasetemp() / "mechanisms"))


def drawer():
    return get_model(str(EXAMPLES / "soft_close_drawer.yaml"))


def push(n=2048, level=40.0, length=0.15):
    t = DT * np.arange(n)
    return np.where(t < length, level * np.sin(np.pi * t / length) ** 2, 0.0)


def drawer_reference(p: dict, force):
    """The drawer's law written again for scipy, while it slides forward (v > 0): from
    the break-away (the hand's force reaches the friction), the soft-close engagement
    split out as an event, up to where the drawer stops."""
    t = DT * np.arange(force.size)
    t_break = brentq(lambda tt: np.interp(tt, t, force) - p["runners.level"], 0.0, 0.07)

    def rhs(tt, y):
        x, v = y
        f = np.interp(tt, t, force) - p["runners.level"] - p["grease.c"] * v
        if x > p["softie.engage"]:
            f += p["softie.pull"] - p["softie.c_fluid"] * v
        if x > p["stop.at"]:
            f += min(-p["stop.k"] * (x - p["stop.at"]) - p["stop.c"] * v, 0.0)
        return [v, f / p["box.mass"]]

    def engage(tt, y):
        return y[0] - p["softie.engage"]

    def halt(tt, y):
        return y[1] - 1e-9 if tt > 0.05 else 1.0

    halt.terminal, halt.direction = True, -1
    kw = dict(method="DOP853", rtol=1e-12, atol=1e-13, max_step=DT)
    y0, t0, xs, ts = [0.0, 0.0], t_break, [], []
    for events in ([engage, halt], [halt]):
        sol = solve_ivp(rhs, (t0, t[-1]), y0, events=events, dense_output=True, **kw)
        assert sol.success
        t1 = sol.t[-1]
        keep = t[(t >= t0) & (t < t1)] if events[0] is engage else t[(t >= t0) & (t <= t1)]
        ts.append(keep)
        xs.append(sol.sol(keep))
        y0, t0 = sol.y[:, -1], t1
        if sol.status == 1 and events[0] is engage and sol.t_events[1].size:
            break
    return np.concatenate(ts), np.concatenate(xs, axis=1)


def test_the_drawer_matches_scipy_through_its_soft_close():
    model = drawer()
    assert model.states == ("box", "box_speed") and model.contacts == (1,)
    assert model.theta_unit == "m" and model.theta_range == (0.0, 0.45)
    ps = model.load_params()
    force = push()
    r = simulate(model, ps, force, DT, theta0=0.0, method="dopri5", tolerance=1e-11)
    assert r.ok
    t_ref, ref = drawer_reference(ps.as_dict(), force)
    k = np.rint(t_ref / DT).astype(int)
    assert r.theta.max() > ps["softie.engage"] + 0.005  # it went through the soft close
    assert k.size > 500
    np.testing.assert_allclose(r.theta[k], ref[0], atol=1e-8)
    np.testing.assert_allclose(r.dtheta[k], ref[1], atol=1e-7)
    # then it sticks: the sign law holds it exactly at rest
    assert r.dtheta[-1] == 0.0 and r.theta[-1] == r.theta[-100]


def test_the_two_carts_rhs_is_the_law_by_hand():
    model = get_model(str(EXAMPLES / "two_carts.yaml"))
    assert model.states == ("a", "a_speed", "b", "b_speed")
    assert model.handle == (0, 1) and model.contacts == (1, 3)
    p = model.load_params().as_dict()
    vec = model.params.vector(p)
    rng = np.random.default_rng(3)
    for _ in range(50):
        x = rng.normal(size=4)
        x[rng.integers(0, 4)] = 0.0 if rng.random() < 0.5 else x[0]
        f = float(rng.normal() * 10)
        dx = np.zeros(4)
        model.rhs(x, f, vec, dx)
        spring = p["coupling.k"] * (x[2] - x[0])
        want = [
            x[1],
            (f + spring - p["rub_a.level"] * np.sign(x[1])) / p["a.mass"],
            x[3],
            (-spring - p["rub_b.level"] * np.sign(x[3])) / p["b.mass"],
        ]
        np.testing.assert_allclose(dx, want, rtol=1e-14, atol=1e-14)


def test_every_parameter_is_declared_once_with_its_units():
    table = drawer().params
    assert table.names == (
        "box.mass", "runners.level", "grease.c", "stop.at", "stop.k", "stop.c",
        "softie.engage", "softie.c_fluid", "softie.pull",
    )  # fmt: skip
    assert [table[n].unit for n in ("box.mass", "runners.level", "grease.c", "stop.k")] == [
        "kg", "N", "N s/m", "N/m",
    ]  # fmt: skip
    assert table["softie.c_fluid"].default == 80.0 and table["stop.at"].group == "geometry"


def test_rotary_body_with_weight_and_asymmetric_tanh_friction(tmp_path):
    """A rotary lid: hand on a lever, weight m g d cos(theta), tanh friction with two
    levels, a stop; its rhs against the law by hand."""
    (tmp_path / "lid.yaml").write_text(textwrap.dedent("""
        mechanism:
          name: lid
          handle: leaf
          bodies:
            leaf: {kind: rotary, inertia: 0.4, mass: 2.0, arm: 0.2, hand_lever: 0.3}
          elements:
            hinge: {kind: friction, on: leaf, law: tanh, slope: 40.0,
                    level_opening: 0.2, level_closing: 0.5}
            shut: {kind: end_stop, on: leaf, at: 1.5707963, k: 2000.0, c: 5.0}
    """))  # fmt: skip
    model = get_model(str(tmp_path / "lid.yaml"))
    assert model.theta_unit == "rad" and model.params["hinge.level_closing"].unit == "N m"
    assert model.contacts == ()  # the tanh law does not stick
    vec = model.params.defaults
    for theta, w in [(0.3, 0.5), (0.3, -0.5), (1.6, 0.2)]:
        dx = np.zeros(2)
        model.rhs(np.array([theta, w]), 10.0, vec, dx)
        level = 0.5 if w > 0 else 0.2
        torque = 0.3 * 10.0 - 2.0 * 9.80665 * 0.2 * np.cos(theta) - level * np.tanh(40 * w)
        if theta > 1.5707963:
            torque += min(-2000.0 * (theta - 1.5707963) - 5.0 * w, 0.0)
        assert dx[1] == pytest.approx(torque / 0.4, rel=1e-14)


def test_a_mechanism_file_is_data_found_beside_an_experiment(tmp_path, monkeypatch):
    shutil.copy(EXAMPLES / "two_carts.yaml", tmp_path / "carts.yaml")
    monkeypatch.chdir(ROOT)
    resolved = resolve_model_name("carts.yaml", tmp_path)
    assert resolved == str((tmp_path / "carts.yaml").resolve())
    assert not is_code_spec(resolved)
    check_named_in_file(resolved, "a results file")  # not refused: no --allow-model
    assert get_model(resolved) is get_model(str(tmp_path / "." / "carts.yaml"))


_LOAD = """
import sys, time
from evo_door.models import get_model
t = time.perf_counter()
m = get_model(sys.argv[1])
s = [m.rhs.stats, m.switches.stats]
print(sum(x.cache_hits[k] for x in s for k in x.cache_hits),
      sum(x.cache_misses[k] for x in s for k in x.cache_misses), time.perf_counter() - t)
"""


def test_a_second_process_compiles_nothing(tmp_path):
    env = {**os.environ, CACHE_ENV: str(tmp_path / "cache"), "PYTHONPATH": str(ROOT)}
    file = str(EXAMPLES / "soft_close_drawer.yaml")

    def load():
        out = subprocess.run([sys.executable, "-c", _LOAD, file], env=env, check=True,
                             capture_output=True, text=True, timeout=600)  # fmt: skip
        hits, misses, _ = out.stdout.split()
        return int(hits), int(misses)

    assert load() == (0, 2)  # compiled: rhs and switches
    assert load() == (2, 0)  # loaded from numba's cache
    (source,) = (tmp_path / "cache").glob("*/mech.py")
    text = source.read_text()
    assert "# softie: soft-close damper" in text and "p[7] softie.c_fluid (N s/m)" in text
    assert list(source.parent.glob("__pycache__/mech.rhs-*.nbi"))


GOOD = """
mechanism:
  name: carts
  handle: a
  bodies:
    a: {kind: linear, mass: 2.0}
    b: {kind: linear, mass: 3.0}
  elements:
    coupling: {kind: spring, between: [a, b], k: 400.0}
    rub: {kind: friction, on: a, level: 1.5}
"""

BAD = [
    (("kind: spring,", "kind: sprung,"), "element 'coupling': unknown kind 'sprung' (did you mean 'spring'"),
    (("on: a,", "on: bxo,"), "element 'rub': on: 'bxo' is not a body"),
    (("handle: a", "handle: coupling"), "handle 'coupling' is not a body"),
    (("  handle: a\\n", ""), "missing handle:"),
    (("linear, mass: 2.0", "rotary, inertia: 2.0"), "'coupling': a spring acts on linear bodies"),
    (("level: 1.5", "level: lots"), "element 'rub': level must be a number or 'NUMBER UNIT', got 'lots'"),
    (("level: 1.5", "level: .nan"), "element 'rub': level must be a finite number"),
    (("level: 1.5", "levle: 1.5"), "element 'rub': unknown key 'levle' (did you mean 'level'?)"),
    (("between: [a, b]", "between: [a, a]"), "element 'coupling': between connects 'a' to itself"),
    (("between: [a, b]", "on: a"), "body 'b' is never connected to the handle 'a'"),
    (("rub:", "'rub; import os':"), "is not a name"),
    (("name: carts", "name: 'x\\\"\\\"\\\"; import os'"), "must be letters, digits, _ and -"),
    (("k: 400.0", "k: -4.0"), "element 'coupling': k = -4 N/m is outside [0, 1e+07]"),
    (("mass: 3.0", "mss: 3.0"), "body 'b': unknown key 'mss' (did you mean 'mass'?)"),
    (("level: 1.5", "level_opening: 1.5"), "element 'rub': give level, or level_opening and level_closing"),
    (("k: 400.0", 'k: "400 N m/rad"'), "element 'coupling': k: the unit N m/rad does not fit N/m"),
    (("mass: 3.0", 'mass: "3 m"'), "body 'b': mass: the unit m does not fit kg"),
    (("mass: 3.0", 'mass: "3 kgs"'), "body 'b': mass: unknown unit 'kgs'"),
    (("level: 1.5", 'level: "1.5 N N"'), "element 'rub': level: the unit N N does not fit N"),
    (("level: 1.5", 'level: "N 1.5"'), "element 'rub': level must be a number or 'NUMBER UNIT', got 'N 1.5'"),
]  # fmt: skip


@pytest.mark.parametrize("change, message", BAD, ids=[m[:40] for _, m in BAD])
def test_a_bad_mechanism_is_one_line_naming_the_element(tmp_path, change, message):
    old, new = (c.replace("\\n", "\n").replace('\\"', '"') for c in change)
    text = textwrap.dedent(GOOD)
    assert old in text
    (tmp_path / "bad.yaml").write_text(text.replace(old, new, 1))
    with pytest.raises(UserError) as err:
        get_model(str(tmp_path / "bad.yaml"))
    assert message in str(err.value) and "\n" not in str(err.value), str(err.value)


@pytest.mark.slow
def test_rig_fit_and_curve_of_the_drawer_from_the_command_line(tmp_path, capsys):
    work = tmp_path / "blocks"
    shutil.copytree(EXAMPLES, work, ignore=shutil.ignore_patterns("*.h5", "*.csv"))
    made = cli(capsys, "rig", "generate", "--model", "soft_close_drawer.yaml", "--trials", "8",
               "--out", "trials.h5", cwd=work)  # fmt: skip
    assert made.returncode == 0, made.stderr
    run = cli(capsys, "run", "fit.yaml", "--out", "fit.h5", cwd=work)
    assert run.returncode == 0, run.stderr
    # a mechanism is data: no --allow-model
    shown = cli(capsys, "show", "fit.h5", "--json", cwd=work)
    assert shown.returncode == 0, shown.stderr
    best = json.loads(shown.stdout)["best"]
    truth = drawer().load_params().as_dict()
    for name in ("box.mass", "runners.level", "grease.c", "softie.c_fluid"):
        assert abs(best[name] / truth[name] - 1.0) < 0.02, (name, best[name], truth[name])
    curve = cli(capsys, "curve", "soft_close_drawer.yaml", "--out", "curve.csv", cwd=work)
    assert curve.returncode == 0, curve.stderr
    table = np.genfromtxt(work / "curve.csv", delimiter=",", names=True, dtype=None,
                          encoding="utf-8")  # fmt: skip
    closing = table[table["direction"] == "closing"]
    inside = closing[(closing["theta"] > 0.01) & (closing["theta"] < 0.44)]
    np.testing.assert_allclose(inside["force"], truth["runners.level"], atol=1e-6)
    params = cli(capsys, "params", "two_carts.yaml", cwd=work)
    assert params.returncode == 0 and "coupling.k" in params.stdout, params.stderr


def test_cable_spring_and_damper_between_bodies_are_the_law_by_hand(tmp_path):
    """A door pulled shut through an elastic cable by a sprung carriage: the rhs and the
    switching functions at random states (slack and taut) against the law by hand."""
    (tmp_path / "pull.yaml").write_text(textwrap.dedent("""
        mechanism:
          name: pulled
          handle: door
          bodies:
            door: {kind: linear, mass: 1.5, range: [0.0, 0.6]}
            carriage: {kind: linear, mass: 0.2, start: 0.1}
          elements:
            rope: {kind: cable, between: [door, carriage], k: 5.0e4, length: 0.05}
            spring: {kind: spring, on: carriage, k: 300.0, preload: -20.0, at: 0.1}
            oil: {kind: damper, between: [door, carriage], c: 2.0}
            stop: {kind: end_stop, on: door, at: 0.0, side: below}
    """))  # fmt: skip
    model = get_model(str(tmp_path / "pull.yaml"))
    assert model.x0 == (0.0, 0.0, 0.1, 0.0) and model.n_switches == 2
    p = model.load_params().as_dict()
    vec = model.params.defaults
    rng = np.random.default_rng(7)
    for _ in range(50):
        x = rng.normal(scale=0.1, size=4)
        f = float(rng.normal() * 10)
        dx, g = np.zeros(4), np.zeros(2)
        model.rhs(x, f, vec, dx)
        model.switches(x, f, vec, g)
        stretch = x[2] - x[0] - p["rope.length"]
        tension = p["rope.k"] * max(stretch, 0.0)
        spring = p["spring.preload"] + p["spring.k"] * (x[2] - p["spring.at"])
        oil = -p["oil.c"] * (x[3] - x[1])
        stop = max(-p["stop.k"] * x[0] - p["stop.c"] * x[1], 0.0) if x[0] < 0.0 else 0.0
        want = [
            x[1],
            (f + tension - oil + stop) / p["door.mass"],
            x[3],
            (-tension - spring + oil) / p["carriage.mass"],
        ]
        np.testing.assert_allclose(dx, want, rtol=1e-13, atol=1e-10)
        np.testing.assert_allclose(g, [stretch, x[0]], rtol=0, atol=1e-15)


def test_a_soft_close_with_a_fluid_state_matches_scipy(tmp_path):
    """``tau`` gives the soft-close's fluid a state of its own (its force, lagging the
    viscous one): the drawer pushed through it against scipy on the law by hand, while
    it slides forward; then the fluid relaxes once the drawer rests against the stop."""
    text = (EXAMPLES / "soft_close_drawer.yaml").read_text()
    text = text.replace("c_fluid: 80.0}", "c_fluid: 80.0, tau: 0.02, pull: 0.5}")
    (tmp_path / "fluid.yaml").write_text(text)
    model = get_model(str(tmp_path / "fluid.yaml"))
    assert model.states == ("box", "box_speed", "softie_fluid")
    ps = model.load_params()
    p = ps.as_dict()
    force = push()
    r = simulate(model, ps, force, DT, theta0=0.0, method="dopri5", tolerance=1e-11)
    assert r.ok and r.theta.max() > p["softie.engage"] + 0.005
    t = DT * np.arange(force.size)
    t_break = brentq(lambda tt: np.interp(tt, t, force) - p["runners.level"], 0.0, 0.07)

    def rhs(tt, y):
        x, v, fluid = y
        f = np.interp(tt, t, force) - p["runners.level"] - p["grease.c"] * v
        if x > p["softie.engage"]:
            f += p["softie.pull"] + fluid
            rate = (-p["softie.c_fluid"] * v - fluid) / p["softie.tau"]
        else:
            rate = -fluid / p["softie.tau"]
        if x > p["stop.at"]:
            f += min(-p["stop.k"] * (x - p["stop.at"]) - p["stop.c"] * v, 0.0)
        return [v, f / p["box.mass"], rate]

    def engage(tt, y):
        return y[0] - p["softie.engage"]

    engage.terminal = True
    kw = dict(method="DOP853", rtol=1e-12, atol=1e-13, max_step=DT, dense_output=True)
    first = solve_ivp(rhs, (t_break, t[-1]), [0.0, 0.0, 0.0], events=engage, **kw)
    assert first.status == 1  # engaged
    t_in = first.t[-1]
    t_rest = t[np.flatnonzero((t > t_in) & (r.dtheta <= 0.0))[0]]  # where it stops
    second = solve_ivp(rhs, (t_in, t_rest - 2 * DT), first.y[:, -1], **kw)
    k1 = np.flatnonzero((t > t_break) & (t < t_in))
    k2 = np.flatnonzero((t > t_in) & (t <= t_rest - 2 * DT))
    assert k2.size > 20  # sliding in the soft close
    for k, sol in ((k1, first), (k2, second)):
        ref = sol.sol(t[k])
        np.testing.assert_allclose(r.theta[k], ref[0], atol=1e-8)
        np.testing.assert_allclose(r.dtheta[k], ref[1], atol=1e-7)
        np.testing.assert_allclose(r.states["softie_fluid"][k], ref[2], atol=1e-5)
    assert np.min(r.states["softie_fluid"]) < -1.0  # it braked


def test_an_override_names_a_mechanism_parameter_with_its_dot():
    """``--set free.box.mass=[2, 8]`` sets the parameter ``box.mass`` the file frees;
    ``free."grease.c"=...`` frees one it does not; a dangling quote is one line."""
    from evo_door.experiment.yamltree import apply_override, parse

    tree = parse("free:\n  box.mass: [1.0, 9.0]\nalgorithm: {seed: 1}\n", "fit.yaml")
    apply_override(tree, "free.box.mass=[2.0, 8.0]")
    apply_override(tree, 'free."grease.c"=[0.5, 12.0]')
    apply_override(tree, "algorithm.seed=3")
    assert dict(tree["free"]) == {"box.mass": [2.0, 8.0], "grease.c": [0.5, 12.0]}
    assert tree["algorithm"]["seed"] == 3
    with pytest.raises(UserError, match=r"expected KEY.PATH=VALUE") as err:
        apply_override(tree, 'free."box.mass=[2.0, 8.0]')
    assert "\n" not in str(err.value)


def test_free_text_of_the_file_never_becomes_code(tmp_path):
    """A title that closes the generated module's docstring and goes on as code stays
    text: no marker file is made, the model loads, its title is the file's."""
    marker = tmp_path / "ran"
    text = (EXAMPLES / "soft_close_drawer.yaml").read_text()
    hostile = f'''a drawer""" ; import pathlib ; pathlib.Path({str(marker)!r}).touch() ; """'''
    lines = [
        f"  title: {json.dumps(hostile)}" if line.strip().startswith("title:") else line
        for line in text.splitlines()
    ]
    (tmp_path / "hostile.yaml").write_text("\n".join(lines) + "\n")
    model = get_model(str(tmp_path / "hostile.yaml"))
    assert not marker.exists()
    assert model.title == hostile
    r = simulate(model, model.load_params(), push(256), DT)
    assert r.ok


def test_a_binary_or_bounded_mechanism_file_is_one_line(tmp_path):
    """Binary data, text that is not UTF-8 and an alias bomb: one line each, no
    traceback, nothing allocated beyond the YAML bounds."""
    cases = {
        "binary.yaml": b"\x89HDF\r\n\x1a\n\0\0\0",
        "latin.yaml": "mechanism: {name: caf\xe9}\n".encode("latin-1"),
        "bomb.yaml": (
            "a: &a [x, x, x, x, x, x, x, x, x]\n"
            + "".join(f"b{i}: &b{i} [*{'a' if i == 0 else f'b{i - 1}'}] \n" for i in range(200))
        ).encode(),
    }
    expect = {"binary.yaml": "binary data", "latin.yaml": "not UTF-8", "bomb.yaml": "aliases"}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(UserError) as err:
            get_model(str(tmp_path / name))
        assert expect[name] in str(err.value) and "\n" not in str(err.value), str(err.value)


def test_a_tanh_friction_between_two_bodies_is_the_law_by_hand(tmp_path, monkeypatch):
    """Friction on the relative speed (a sliding sleeve on a rod): on b, its reaction on
    a, asymmetric levels; the sign law between bodies is refused in one line."""
    text = textwrap.dedent("""
        mechanism:
          name: sleeve
          handle: rod
          bodies:
            rod: {kind: linear, mass: 2.0}
            sleeve: {kind: linear, mass: 0.5}
          elements:
            grip: {kind: friction, between: [rod, sleeve], law: tanh, level_opening: 3.0,
                   level_closing: 2.0, slope: 40.0}
    """)
    (tmp_path / "sleeve.yaml").write_text(text)
    model = get_model(str(tmp_path / "sleeve.yaml"))
    p = model.load_params().as_dict()
    vec = np.array([p[n] for n in model.params.names])
    for v_rod, v_sleeve in ((0.3, 0.1), (0.1, 0.3), (0.0, -0.02)):
        x, dx = np.array([0.1, v_rod, 0.05, v_sleeve]), np.empty(4)
        model.rhs(x, 5.0, vec, dx)
        rel = v_sleeve - v_rod
        level = 2.0 if rel > 0 else 3.0
        f = -level * np.tanh(40.0 * rel)  # on the sleeve
        assert dx[3] == pytest.approx(f / 0.5, rel=1e-14)
        assert dx[1] == pytest.approx((5.0 - f) / 2.0, rel=1e-14)
    (tmp_path / "bad.yaml").write_text(text.replace("law: tanh, ", "").replace(", slope: 40.0", ""))
    with pytest.raises(
        UserError, match="element 'grip': a friction between two bodies takes law: tanh"
    ):
        get_model(str(tmp_path / "bad.yaml"))


PIPELINE = """\
name: drawer-two-stages
stages:
  runners:
    model: soft_close_drawer.yaml
    target: {data: trials.h5, kinds: [impulse]}
    free: {runners.level: [0.2, 4.0], grease.c: [0.5, 12.0]}
    objective: {kind: ise, derivative: 1}
    algorithm: {population: 12, generations: 3, seed: 1, polish: slsqp}
  softie:
    model: soft_close_drawer.yaml
    params: {from: runners}
    target: {data: trials.h5, kinds: [impulse]}
    free: {softie.c_fluid: [20.0, 300.0]}
    objective: {kind: ise, derivative: 1}
    algorithm: {population: 12, generations: 3, seed: 1, polish: slsqp}
"""


def test_a_pipeline_takes_a_mechanism_file_stage_to_stage(tmp_path, capsys):
    """Two stages on the drawer, the second from the first's estimates (names with their
    dots through ``params: {from: ...}``): each recovers what it fits."""
    work = tmp_path / "blocks"
    shutil.copytree(EXAMPLES, work, ignore=shutil.ignore_patterns("*.h5", "*.csv"))
    (work / "pipeline.yaml").write_text(PIPELINE)
    made = cli(capsys, "rig", "generate", "--model", "soft_close_drawer.yaml", "--trials", "4",
               "--out", "trials.h5", cwd=work)  # fmt: skip
    assert made.returncode == 0, made.stderr
    run = cli(capsys, "run", "pipeline.yaml", "--out", "pipe.h5", "--quiet", cwd=work)
    assert run.returncode == 0, run.stderr
    from evo_door.api import load

    result = load(work / "pipe.h5")
    first, second = result.stages["runners"], result.stages["softie"]
    assert abs(first.estimates["runners.level"].value / 1.2 - 1.0) < 0.05
    assert abs(second.estimates["softie.c_fluid"].value / 80.0 - 1.0) < 0.05
    assert second.model == first.model and second.model.endswith("soft_close_drawer.yaml")
