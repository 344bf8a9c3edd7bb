"""The rest of the component library of mechanisms from blocks (docs/blocks.md):
transmissions (slider-crank, four-bar, table) with their ratio against a finite
difference, a spring and a gas strut through a slider-crank against scipy on the
equations written here again, the static curve against the potential through the map,
detent, gas strut and table spring against their laws by hand, numbers with units, the
energy conserved by an undamped mechanism, and a transmission that folds refused in
one line naming it and where.
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
from scipy.interpolate import PchipInterpolator

from evo_door.errors import UserError
from evo_door.models import get_model
from evo_door.models.blocks import CACHE_ENV, mechanism_energy
from evo_door.models.blocks.kinematics import four_bar, pchip, pchip_integral, slider_crank
from evo_door.sim import simulate
from evo_door.sim.simulate import force_angle_curve
from tests.test_cli import cli

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "blocks"
DT = 1.0 / 1024.0


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    """Generated mechanisms in a tmp folder of the session (not the user's cache)."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path_factory.getbasetemp() / "mechanisms"))


def write(tmp_path, name, text):
    (tmp_path / name).write_text(textwrap.dedent(text))
    return str(tmp_path / name)


# -- the kinematic maps, written again here ---------------------------------------------
def crank_s(q, r=0.05, rod=0.15, e=0.02, phase=0.3):
    phi = q + phase
    return r * np.cos(phi) + np.sqrt(rod**2 - (r * np.sin(phi) - e) ** 2)


def rocker_angle(q, a, b, c, d, phase, branch):
    """The rocker's angle by intersecting two circles: the crank's end ``B`` and the
    rocker's pivot ``D``; the coupler ``b`` from B meets the rocker ``c`` from D."""
    bx, by = a * np.cos(q + phase), a * np.sin(q + phase)
    dist = math.hypot(d - bx, by)
    # the point C: distance b from B and c from D; along BD then across it
    along = (b**2 - c**2 + dist**2) / (2 * dist)
    across = math.sqrt(b**2 - along**2)
    ux, uy = (d - bx) / dist, (0 - by) / dist
    side = branch  # the open branch lies on the left of B -> D
    cx, cy = bx + along * ux - side * across * uy, by + along * uy + side * across * ux
    return math.atan2(cy, cx - d)


def test_every_ratio_is_the_derivative_of_its_map():
    h = 1e-6
    for q in np.linspace(0.2, 2.8, 27):
        s, r = slider_crank(q, 0.05, 0.15, 0.02, 0.3)
        assert s == pytest.approx(crank_s(q), abs=1e-15)
        fd = (
            slider_crank(q + h, 0.05, 0.15, 0.02, 0.3)[0]
            - slider_crank(q - h, 0.05, 0.15, 0.02, 0.3)[0]
        ) / (2 * h)
        assert r == pytest.approx(fd, abs=1e-7)
    for branch in (1.0, -1.0):
        for q in np.linspace(0.7, 3.4, 28):
            args = (0.04, 0.12, 0.08, 0.1, 0.0, branch)
            s, r = four_bar(q, *args)
            want = rocker_angle(q, 0.04, 0.12, 0.08, 0.1, 0.0, branch)
            assert math.remainder(s - want, 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
            fd = (four_bar(q + h, *args)[0] - four_bar(q - h, *args)[0]) / (2 * h)
            assert r == pytest.approx(fd, abs=1e-7)
    x, y = [0.0, 0.3, 1.0, 1.2, 2.0, 3.0], [0.0, 0.01, 0.015, 0.03, 0.05, 0.06]
    p = np.array([9.0] + x + y)  # the table from index 1
    ref = PchipInterpolator(x, y)
    for q in np.linspace(0.0, 3.0, 301):
        s, r = pchip(q, p, 1, 6)
        assert s == pytest.approx(float(ref(q)), abs=1e-15)
        assert r == pytest.approx(float(ref(q, 1)), rel=1e-12, abs=1e-14)
        if np.min(np.abs(q - np.array(x))) > 1e-4:  # C1 only: not across a knot
            fd = (pchip(q + h, p, 1, 6)[0] - pchip(q - h, p, 1, 6)[0]) / (2 * h)
            assert r == pytest.approx(fd, abs=1e-7)
    # beyond the points: a straight line with the end slope (a continuous ratio)
    # its integral from the first point (a table spring's potential), against scipy's
    for q in np.linspace(0.0, 3.0, 61):
        assert pchip_integral(q, p, 1, 6) == pytest.approx(
            ref.integrate(0.0, q), rel=1e-13, abs=1e-16
        )
    d0, d1 = float(ref(0.0, 1)), float(ref(3.0, 1))
    assert d0 > 0.0 and d1 > 0.0
    assert pchip(3.5, p, 1, 6) == pytest.approx((0.06 + 0.5 * d1, d1), rel=1e-14)
    assert pchip(-1.0, p, 1, 6) == pytest.approx((-d0, d0), rel=1e-14)
    assert pchip_integral(3.5, p, 1, 6) == pytest.approx(
        ref.integrate(0.0, 3.0) + 0.06 * 0.5 + 0.5 * d1 * 0.25, rel=1e-13
    )
    assert pchip_integral(-1.0, p, 1, 6) == pytest.approx(0.5 * d0, rel=1e-13)


def arm_potential(q, p):
    s = crank_s(q)
    d = s - p["spring.at"]
    u = p["strut.length"] - s
    return (p["spring.preload"] * d + 0.5 * p["spring.k"] * d * d
            + p["strut.preload"] * u + 0.5 * p["strut.slope"] * u * u)  # fmt: skip


def test_a_spring_and_a_strut_through_a_slider_crank_match_scipy():
    """examples/blocks/strut_arm.yaml pushed by the hand against scipy on the equations
    written here again (the map, its ratio, the virtual work); its static curve against
    -dV/dq of the spring's and the strut's potentials through the map."""
    model = get_model(str(EXAMPLES / "strut_arm.yaml"))
    ps = model.load_params()
    p = ps.as_dict()
    assert p["spring.k"] == 2000.0 and model.theta_range == pytest.approx(
        (math.pi / 6, 5 * math.pi / 6)
    )
    n = 1024
    t = DT * np.arange(n)
    force = np.where(t < 0.2, 30.0 * np.sin(np.pi * t / 0.2) ** 2, 0.0)
    q0 = 1.0
    r = simulate(model, ps, force, DT, theta0=q0, method="dopri5", tolerance=1e-11)
    assert r.ok

    def rhs(tt, y):
        q, w = y
        h = 1e-6  # the ratio of the map written here: a central difference is not
        # precise enough at 1e-8, so the closed form again
        phi = q + 0.3
        root = math.sqrt(0.15**2 - (0.05 * math.sin(phi) - 0.02) ** 2)
        ratio = -0.05 * math.sin(phi) - (0.05 * math.sin(phi) - 0.02) * 0.05 * math.cos(phi) / root
        assert abs(ratio - (crank_s(q + h) - crank_s(q - h)) / (2 * h)) < 1e-7
        s, v = crank_s(q), ratio * w
        tension = p["spring.preload"] + p["spring.k"] * (s - p["spring.at"])
        push = p["strut.preload"] + p["strut.slope"] * (p["strut.length"] - s)
        push -= (p["strut.c_extension"] if v > 0 else p["strut.c_compression"]) * v
        torque = 0.1 * np.interp(tt, t, force) + ratio * (push - tension) - p["oil.c"] * w
        return [w, torque / p["arm.inertia"]]

    sol = solve_ivp(rhs, (0.0, t[-1]), [q0, 0.0], method="DOP853", rtol=1e-12, atol=1e-13,
                    max_step=DT, dense_output=True)  # fmt: skip
    ref = sol.sol(t)
    assert np.ptp(r.theta) > 0.3 and np.ptp(r.dtheta) > 1.0  # it moved, both ways
    assert np.any(r.dtheta > 0.1) and np.any(r.dtheta < -0.1)
    np.testing.assert_allclose(r.theta, ref[0], atol=2e-8)
    np.testing.assert_allclose(r.dtheta, ref[1], atol=2e-7)

    # the static curve: the hand holds the arm against -dV/dq, the potential of the
    # spring and the strut through the map
    c = force_angle_curve(model, ps, n=121)
    q = c["theta"]
    h = 1e-6
    hold = (arm_potential(q + h, p) - arm_potential(q - h, p)) / (2 * h) / p["arm.hand_lever"]
    np.testing.assert_allclose(c["closing"], hold, rtol=1e-7, atol=1e-6)
    np.testing.assert_allclose(c["opening"], hold, rtol=1e-7, atol=1e-6)
    assert np.ptp(hold) > 10.0  # not a flat curve


EVERYTHING = """
mechanism:
  name: everything
  handle: arm
  bodies:
    arm: {kind: rotary, inertia: "0.01 kg m^2", range: ["40 deg", "160 deg"], hand_lever: "10 cm"}
    cart: {kind: linear, mass: "500 g", start: "20 mm"}
    sled: {kind: linear, mass: 1.0}
  transmissions:
    bar: {kind: four_bar, on: arm, crank: 0.04, coupler: 0.12, rocker: 0.08, ground: 0.1}
    cam: {kind: table, on: arm, output: linear, q: [0.0, 1.0, 2.0, 3.0],
          s: [0.0, 0.01, 0.03, 0.04]}
  elements:
    click: {kind: detent, on: bar, amplitude: 0.1, pitch: "30 deg", phase: 0.2}
    strut: {kind: gas_strut, on: cam, preload: 50.0, slope: 100, length: 0.05,
            c_extension: 3, c_compression: 30}
    table: {kind: spring_table, on: arm, deflection: [0.0, 1.0, 2.0, 3.0],
            force: [0.0, 0.2, 0.3, 0.35]}
    follower: {kind: spring, between: [cam, cart], k: "3 N/mm", at: 0.01}
    rub: {kind: detent, on: cart, amplitude: "2 N", pitch: "5 mm"}
    tie: {kind: detent, between: [sled, cart], amplitude: 1.0, pitch: 0.01}
    push: {kind: gas_strut, between: [cart, sled], preload: 10.0, length: 0.1,
           slope: 20.0, c_compression: 4.0}
    hill: {kind: bump, on: sled, amplitude: 3.0, at: 0.01, width: "4 cm"}
"""


def test_detent_strut_table_spring_and_maps_are_the_law_by_hand(tmp_path):
    """A rotary arm drives a rocker (four-bar) that clicks and a cam (table) with a gas
    strut, a table spring on it, a cart following the cam through a spring, a sled
    clicked and pushed from the cart: the rhs at random states against the laws by hand
    (the maps written again here, the tables by scipy's PchipInterpolator)."""
    model = get_model(write(tmp_path, "all.yaml", EVERYTHING))
    p = model.load_params().as_dict()
    assert p["cart.mass"] == 0.5 and p["click.pitch"] == pytest.approx(math.pi / 6, rel=1e-15)
    assert p["arm.hand_lever"] == pytest.approx(0.1) and p["rub.pitch"] == pytest.approx(0.005)
    assert p["follower.k"] == pytest.approx(3000.0) and model.x0[2] == pytest.approx(0.02)
    assert model.params["table.force_2"].unit == "N m" and model.params["cam.s_1"].unit == "m"
    assert model.params["click.amplitude"].unit == "N m" and model.params["cam.q_1"].unit == "rad"
    vec = model.params.defaults
    cam = PchipInterpolator([0.0, 1.0, 2.0, 3.0], [0.0, 0.01, 0.03, 0.04])
    spring = PchipInterpolator([0.0, 1.0, 2.0, 3.0], [0.0, 0.2, 0.3, 0.35])
    rng = np.random.default_rng(5)
    h = 1e-6
    for _ in range(40):
        q = rng.uniform(0.75, 2.75)
        x = np.array([q, rng.normal(), *rng.normal(scale=0.05, size=1), rng.normal(),
                      *rng.normal(scale=0.05, size=1), rng.normal()])  # fmt: skip
        f = float(rng.normal() * 5)
        dx = np.zeros(6)
        model.rhs(x, f, vec, dx)
        psi = rocker_angle(q, 0.04, 0.12, 0.08, 0.1, 0.0, 1.0)
        ratio = (rocker_angle(q + h, 0.04, 0.12, 0.08, 0.1, 0.0, 1.0)
                 - rocker_angle(q - h, 0.04, 0.12, 0.08, 0.1, 0.0, 1.0)) / (2 * h)  # fmt: skip
        click = -0.1 * math.sin(2 * math.pi * (psi - 0.2) / (math.pi / 6))
        s, rc = float(cam(q)), float(cam(q, 1))
        v = rc * x[1]
        strut = 50.0 + 100.0 * (0.05 - s) - (3.0 if v > 0 else 30.0) * v
        follow = 3000.0 * (x[2] - s - 0.01)  # tension: pulls the cam and the cart together
        torque = 0.1 * f + ratio * click + rc * (strut + follow) - float(spring(q))
        rub = -2.0 * math.sin(2 * math.pi * x[2] / 0.005)
        tie = -1.0 * math.sin(2 * math.pi * (x[2] - x[4]) / 0.01)
        w = x[5] - x[3]
        push = 10.0 + 20.0 * (0.1 - (x[4] - x[2])) - (4.0 * w if w < 0 else 0.0)
        assert dx[1] == pytest.approx(torque / 0.01, rel=1e-6)
        assert dx[3] == pytest.approx((-follow + rub + tie - push) / 0.5, rel=1e-12, abs=1e-9)
        u = x[4] - 0.01
        hill = 3.0 * math.sin(math.pi * u / 0.04) if abs(u) < 0.04 else 0.0
        assert dx[5] == pytest.approx((-tie + push + hill) / 1.0, rel=1e-12, abs=1e-9)
        g = np.zeros(model.n_switches)
        model.switches(x, f, vec, g)
        np.testing.assert_allclose(g, [u - 0.04, u + 0.04], rtol=0, atol=1e-16)
        assert (dx[0], dx[2], dx[4]) == (x[1], x[3], x[5])


def test_an_undamped_mechanism_conserves_its_energy(tmp_path):
    """Two carts, a spring, a table spring and a cable between them, a detent, a
    bump, end stops, a gas strut: no damper, no friction. Its energy
    stays within 1e-8 of its start along a simulation that crosses stops and clicks."""
    file = write(
        tmp_path,
        "free.yaml",
        """
        mechanism:
          name: free
          handle: a
          bodies:
            a: {kind: linear, mass: 1.0, range: [0.0, 0.5], start: 0.05}
            b: {kind: linear, mass: 2.0, start: 0.02}
          elements:
            coupling: {kind: spring, between: [a, b], k: 200.0, preload: 3.0, at: 0.01}
            rope: {kind: cable, between: [a, b], k: 800.0, length: 0.03}
            clicks: {kind: detent, on: a, amplitude: 4.0, pitch: 0.02, phase: 0.005}
            low: {kind: end_stop, on: a, at: 0.03, side: below, k: 5000.0, c: 0.0}
            high: {kind: end_stop, on: b, at: 0.08, k: 5000.0, c: 0.0}
            strut: {kind: gas_strut, on: b, preload: 5.0, slope: 50.0, length: 0.1}
            hill: {kind: bump, on: b, amplitude: 2.0, at: 0.05, width: 0.01}
            table: {kind: spring_table, between: [a, b], deflection: [-0.1, -0.02, 0.0, 0.06],
                    force: [-8.0, -2.0, 0.0, 5.0]}
    """,
    )
    model = get_model(file)
    energy = mechanism_energy(Path(file))
    ps = model.load_params()
    vec = model.params.vector(ps.as_dict())
    force = np.zeros(2048)
    r = simulate(model, ps, force, DT, theta0=0.05, method="dopri5", tolerance=1e-13)
    assert r.ok
    assert model.states == ("a", "a_speed", "b", "b_speed")
    x = np.column_stack([r.theta, r.dtheta, r.states["b"], r.states["b_speed"]])
    e = np.array([energy(np.ascontiguousarray(row), vec) for row in x])
    # at the start, by hand: the spring, the detent, the strut (the cable is slack)
    d = 0.02 - 0.05 - 0.01
    clicks = 4.0 * 0.02 / (2 * math.pi) * (1 - math.cos(2 * math.pi * (0.05 - 0.005) / 0.02))
    table = PchipInterpolator([-0.1, -0.02, 0.0, 0.06], [-8.0, -2.0, 0.0, 5.0]).integrate(
        -0.1, -0.03
    )
    hand = 3.0 * d + 100.0 * d * d + clicks + 5.0 * 0.08 + 25.0 * 0.08**2 + table
    assert e[0] == pytest.approx(hand, rel=1e-13)
    # it clicks, hits both stops, crosses the bump, and the cable comes taut
    assert np.ptp(x[:, 0]) > 0.1 and x[:, 0].min() < 0.03 and x[:, 2].max() > 0.08
    assert np.max(x[:, 2] - x[:, 0]) > 0.03
    assert np.max(np.abs(e / e[0] - 1.0)) < 1e-8, np.max(np.abs(e / e[0] - 1.0))


FOLDS = """
mechanism:
  name: folds
  handle: arm
  bodies:
    arm: {kind: rotary, inertia: 0.01, range: ["40 deg", "160 deg"]}
  transmissions:
    crank: {kind: slider_crank, on: arm, radius: 0.05, rod: 0.15, offset: 0.02, phase: 0.3}
    bar: {kind: four_bar, on: arm, crank: 0.04, coupler: 0.12, rocker: 0.08, ground: 0.1}
    cam: {kind: table, on: arm, output: linear, q: [0.0, 1.0, 2.0, 3.0], s: [0.0, 0.01, 0.03, 0.04]}
  elements:
    spring: {kind: spring, on: crank, k: 100.0}
    click: {kind: detent, on: bar, amplitude: 0.1, pitch: 0.5}
"""

BAD = [
    (("rod: 0.15", "rod: 0.027"), "transmission 'crank': it folds at q = 0.92263 rad: the rod cannot reach"),
    (("coupler: 0.12", "coupler: 0.3"),
     "transmission 'bar': it folds at q = 0.698132 rad: the four-bar cannot close"),
    (('"40 deg"', '"10 deg"'), "transmission 'bar': it passes a dead point at q = 0.42"),
    (("0.01, 0.03, 0.04]", "0.03, 0.02, 0.04]"),
     "transmission 'cam': it is not monotone: s turns at q = 1 rad (point 1)"),
    (("q: [0.0, 1.0,", "q: [0.0, 0.0,"),
     "transmission 'cam': its q points must rise; q_1 = 0 rad does not"),
    (("kind: slider_crank", "kind: slider_crnk"),
     "transmission 'crank': unknown kind 'slider_crnk' (did you mean 'slider_crank'?)"),
    (('arm: {kind: rotary, inertia: 0.01, range: ["40 deg", "160 deg"]}',
      "arm: {kind: linear, mass: 1.0}"),
     "transmission 'crank': a slider_crank is driven by a rotary body; 'arm' is linear"),
    (("spring: {kind: spring, on: crank", "spring: {kind: spring, on: bar"),
     "element 'spring': a spring acts on linear coordinates (its units); "
     "transmission 'bar' outputs a rotary one"),
    (("amplitude: 0.1", 'amplitude: "0.1 N"'),
     "element 'click': amplitude: the unit N does not fit N m"),
    (("    crank: {kind: slider_crank", "    arm: {kind: slider_crank"),
     "transmission 'arm': a body has that name"),
    (("click: {kind: detent, on: bar", "click: {kind: detent, between: [crank, bar]"),
     "element 'click': it connects a linear coordinate to a rotary one"),
    (("click: {kind: detent, on: bar", "click: {kind: detent, on: bra"),
     "element 'click': on: 'bra' is not a body (did you mean 'bar'"),
    (("s: [0.0, 0.01, 0.03, 0.04]", "s: [0.0, 0.01, 0.03]"),
     "transmission 'cam': q and s must hold as many points"),
    (("spring: {kind: spring, on: crank, k: 100.0}",
      "spring: {kind: spring_table, on: crank, deflection: [0, 1, 1], force: [0, 1, 2]}"),
     "element 'spring': its deflection points must rise; deflection[2] does not"),
    (("k: 100.0", 'k: "100 furlongs"'), "element 'spring': k: unknown unit 'furlongs'"),
    (("q: [0.0, 1.0,", 'q: [0.0, "100 turn",'), "transmission 'cam': q[1] = 628.319 rad is outside [-100, 100]"),
    (("s: [0.0, 0.01,", 's: [0.0, "3 cm",'), "transmission 'cam': it is not monotone: s turns at q = 1 rad"),
    (("s: [0.0, 0.01, 0.03, 0.04]", "s: 7"), "transmission 'cam': s must be a list of 2 to 64 numbers"),
]  # fmt: skip


@pytest.mark.parametrize("change, message", BAD, ids=[m[:40] for _, m in BAD])
def test_a_transmission_that_folds_is_one_line_naming_it(tmp_path, change, message):
    old, new = change
    text = textwrap.dedent(FOLDS)
    assert old in text
    (tmp_path / "bad.yaml").write_text(text.replace(old, new, 1))
    with pytest.raises(UserError) as err:
        get_model(str(tmp_path / "bad.yaml"))
    assert message in str(err.value) and "\n" not in str(err.value), str(err.value)


@pytest.mark.slow
def test_rig_fit_and_curve_of_the_knob_from_the_command_line(tmp_path, capsys):
    """The knob example through the real commands: impulse trials from the rig, the fit
    of knob_fit.yaml recovering the detent's amplitude, the bearing's friction and the
    grease within 2 %, and the Coulomb curve: the detent's sine plus the friction,
    through the finger's lever."""
    work = tmp_path / "blocks"
    shutil.copytree(EXAMPLES, work, ignore=shutil.ignore_patterns("*.h5", "*.csv"))
    made = cli(capsys, "rig", "generate", "--model", "knob.yaml", "--trials", "8",
               "--out", "knob_trials.h5", cwd=work)  # fmt: skip
    assert made.returncode == 0, made.stderr
    run = cli(capsys, "run", "knob_fit.yaml", "--out", "knob_fit.h5", cwd=work)
    assert run.returncode == 0, run.stderr
    shown = cli(capsys, "show", "knob_fit.h5", "--json", cwd=work)
    assert shown.returncode == 0, shown.stderr
    best = json.loads(shown.stdout)["best"]
    truth = get_model(str(EXAMPLES / "knob.yaml")).load_params().as_dict()
    for name in ("clicks.amplitude", "bearing.level", "grease.c"):
        assert abs(best[name] / truth[name] - 1.0) < 0.02, (name, best[name], truth[name])
    curve = cli(capsys, "curve", "knob.yaml", "--out", "knob_curve.csv", cwd=work)
    assert curve.returncode == 0, curve.stderr
    table = np.genfromtxt(work / "knob_curve.csv", delimiter=",", names=True, dtype=None,
                          encoding="utf-8")  # fmt: skip
    lever, amplitude = truth["knob.hand_lever"], truth["clicks.amplitude"]
    for direction, sign in (("closing", 1.0), ("opening", -1.0)):
        rows = table[table["direction"] == direction]
        q = rows["theta"]
        inside = (q > 0.01) & (q < truth["high.at"] - 0.01)
        want = (amplitude * np.sin(12.0 * q) + sign * truth["bearing.level"]) / lever
        np.testing.assert_allclose(rows["force"][inside], want[inside], atol=1e-6)


def test_energy_through_transmissions_is_conserved(tmp_path):
    """A rotary arm, undamped: a spring through a slider-crank, a detent on a four-bar's
    rocker, a gas strut on a cam table, a stop it swings into. The forces reach the arm
    as F ds/dq; its energy, the potentials through the maps, stays within 1e-8."""
    file = write(
        tmp_path,
        "free_arm.yaml",
        """
        mechanism:
          name: free-arm
          handle: arm
          bodies:
            arm: {kind: rotary, inertia: 0.002, range: ["40 deg", "160 deg"], start: 1.0}
          transmissions:
            crank: {kind: slider_crank, on: arm, radius: 0.05, rod: 0.15, offset: 0.02, phase: 0.3}
            bar: {kind: four_bar, on: arm, crank: 0.04, coupler: 0.12, rocker: 0.08, ground: 0.1}
            cam: {kind: table, on: arm, output: linear, q: [0.0, 1.0, 2.0, 3.0],
                  s: [0.0, 0.01, 0.03, 0.04]}
          elements:
            spring: {kind: spring, on: crank, k: 400.0, at: 0.15}
            click: {kind: detent, on: bar, amplitude: 0.05, pitch: 0.3}
            strut: {kind: gas_strut, on: cam, preload: 5.0, slope: 100.0, length: 0.05}
            low: {kind: end_stop, on: arm, at: "45 deg", side: below, k: 50.0, c: 0.0}
            high: {kind: end_stop, on: arm, at: "100 deg", k: 50.0, c: 0.0}
    """,
    )
    model = get_model(file)
    energy = mechanism_energy(Path(file))
    ps = model.load_params()
    vec = model.params.vector(ps.as_dict())
    r = simulate(model, ps, np.zeros(2048), DT, theta0=1.0, method="dopri5", tolerance=1e-13)
    assert r.ok
    x = np.column_stack([r.theta, r.dtheta])
    e = np.array([energy(np.ascontiguousarray(row), vec) for row in x])
    # it swings into the high stop and back
    assert np.ptp(r.theta) > 0.5 and r.theta.max() > math.radians(100) and r.theta.min() < 1.01
    assert np.max(np.abs(e / e[0] - 1.0)) < 1e-8, np.max(np.abs(e / e[0] - 1.0))


def test_free_text_in_transmissions_and_tables_never_becomes_code(tmp_path):
    """Code put where a transmission's name, word, table point or a unit goes is
    refused in one line; nothing of it runs (no marker file)."""
    marker = tmp_path / "ran"
    code = f"__import__('pathlib').Path({str(marker)!r}).touch()"
    text = textwrap.dedent(FOLDS)
    for old, new, says in [
        ("    cam: {kind: table", f"    {json.dumps(code)}: {{kind: table", "is not a name"),
        ("on: arm, crank: 0.04", f"on: arm, branch: {json.dumps(code)}, crank: 0.04",
         "'bar': branch must be one of open, crossed"),
        ("q: [0.0, 1.0,", f"q: [0.0, {json.dumps(code)},", "'cam': q[1] must be a number"),
        ("k: 100.0", f"k: {json.dumps('1 ' + code)}", "'spring': k: unknown unit"),
        ("on: crank, k", f"on: {json.dumps(code)}, k", "is not a body"),
    ]:  # fmt: skip
        assert old in text
        (tmp_path / "hostile.yaml").write_text(text.replace(old, new, 1))
        with pytest.raises(UserError) as err:
            get_model(str(tmp_path / "hostile.yaml"))
        assert says in str(err.value) and "\n" not in str(err.value), str(err.value)
    assert not marker.exists()


def test_a_friction_pad_through_a_slider_crank_sticks_and_slips(tmp_path):
    """Dry friction (sign law) on a slider-crank's output: the arm's speed is a
    stick-slip contact; it holds the arm against a hand torque below
    ``level |ds/dq|`` and slips above it, and the Coulomb curve is
    ``+-level |ds/dq| / hand_lever`` over the stroke."""
    file = write(
        tmp_path,
        "pad.yaml",
        """
        mechanism:
          name: pad
          handle: arm
          bodies:
            arm: {kind: rotary, inertia: 0.02, hand_lever: 0.1, range: ["30 deg", "150 deg"]}
          transmissions:
            crank: {kind: slider_crank, on: arm, radius: 0.05, rod: 0.15, offset: 0.02, phase: 0.3}
          elements:
            pad: {kind: friction, on: crank, level: 10.0}
    """,
    )
    model = get_model(file)
    assert model.contacts == (1,)
    ps = model.load_params()
    q0 = 1.0
    ratio = abs(slider_crank(q0, 0.05, 0.15, 0.02, 0.3)[1])
    hold = 10.0 * ratio / 0.1  # the hand force the pad holds at q0
    weak = simulate(model, ps, np.full(512, 0.9 * hold), DT, theta0=q0)
    assert weak.ok and np.all(weak.theta == q0) and np.all(weak.dtheta == 0.0)
    strong = simulate(model, ps, np.full(512, 1.1 * hold), DT, theta0=q0)
    assert strong.ok and strong.theta[-1] > q0 + 0.01
    c = force_angle_curve(model, ps, n=61)
    want = 10.0 * np.abs([slider_crank(q, 0.05, 0.15, 0.02, 0.3)[1] for q in c["theta"]]) / 0.1
    np.testing.assert_allclose(c["closing"], want, rtol=1e-9)
    np.testing.assert_allclose(c["opening"], -want, rtol=1e-9)


@pytest.mark.slow
def test_rig_fit_and_curve_of_the_cable_door_from_the_command_line(tmp_path, capsys):
    """The cable door as blocks (two bodies, a cable on a drum between them) through the
    real commands: impulse trials, the fit of cable_fit.yaml recovering the leaf's
    inertia, the spring's pre-load, the carriage's damper and the hinge friction within
    2 %, and the Coulomb curve against its closed form: the carriage at rest where the
    taut cable's tension is the spring's, ``c = (k_c s - P) / (k_c + k_s)``."""
    work = tmp_path / "blocks"
    shutil.copytree(EXAMPLES, work, ignore=shutil.ignore_patterns("*.h5", "*.csv"))
    made = cli(capsys, "rig", "generate", "--model", "cable_door.yaml", "--trials", "8",
               "--out", "cable_trials.h5", cwd=work)  # fmt: skip
    assert made.returncode == 0, made.stderr
    run = cli(capsys, "run", "cable_fit.yaml", "--out", "cable_fit.h5", cwd=work)
    assert run.returncode == 0, run.stderr
    shown = cli(capsys, "show", "cable_fit.h5", "--json", cwd=work)
    assert shown.returncode == 0, shown.stderr
    best = json.loads(shown.stdout)["best"]
    p = get_model(str(EXAMPLES / "cable_door.yaml")).load_params().as_dict()
    for name in ("door.inertia", "spring.preload", "dashpot.c", "hinge.level"):
        assert abs(best[name] / p[name] - 1.0) < 0.02, (name, best[name], p[name])
    curve = cli(capsys, "curve", "cable_door.yaml", "--out", "cable_curve.csv", cwd=work)
    assert curve.returncode == 0, curve.stderr
    table = np.genfromtxt(work / "cable_curve.csv", delimiter=",", names=True, dtype=None,
                          encoding="utf-8")  # fmt: skip
    radius = p["drum.s_0"] / p["drum.q_1"]
    k_c, k_s, preload = p["cable.k"], p["spring.k"], p["spring.preload"]
    for direction, sign in (("closing", 1.0), ("opening", -1.0)):
        rows = table[table["direction"] == direction]
        q = rows["theta"]
        inside = (q > 0.01) & (q < np.pi / 2 - 0.01)
        s = radius * (np.pi / 2 - q)
        carriage = (k_c * s - preload) / (k_c + k_s)
        tension = preload + k_s * carriage
        weight = p["door.mass"] * 9.80665 * p["door.arm"] * np.cos(q)
        want = (weight - radius * tension + sign * p["hinge.level"]) / p["door.hand_lever"]
        np.testing.assert_allclose(rows["force"][inside], want[inside], atol=1e-6)
