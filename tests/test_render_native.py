"""What the device renders itself: the plane constraint as the HapticMaster's
own directional spring and damper, the emulator's spring settings, and the SimDevice's
native plane against the host-rendered one.

Everything network-facing runs over real TCP on 127.0.0.1 with an ephemeral port.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from evo_door.models.haptic import MODEL, PARAMS, device_force
from evo_door.params import param_vector
from evo_door.render.device import ForceScript, SimDevice
from evo_door.render.emulator_physics import advance_effects
from evo_door.render.hm_protocol import (
    NATIVE_PARAMS,
    PLANE_DAMPER,
    PLANE_SPRING,
    HapticMasterError,
    native_commands,
)
from tests.helpers import started

DT = 1.0 / 2500.0


def plane_set(k_plane: float, c_plane: float):
    return MODEL.load_params("seed_trial").replace({"k_plane": k_plane, "c_plane": c_plane})


def count_frames(emu) -> list[str]:
    """Record the frames the emulator answers (the instance attribute shadows the method)."""
    frames: list[str] = []
    answer = emu.answer_frame

    def counting(text):
        frames.append(text)
        return answer(text)

    emu.answer_frame = counting
    return frames


def damped_oscillator(t, x0, m, b, k):
    """x(t) of m x'' + b x' + k x = 0 from rest at x0, underdamped."""
    w0 = math.sqrt(k / m)
    zeta = b / (2.0 * math.sqrt(k * m))
    wd = w0 * math.sqrt(1.0 - zeta * zeta)
    decay = zeta * w0
    return x0 * np.exp(-decay * t) * (np.cos(wd * t) + decay / wd * np.sin(wd * t))


def one_step_force(pos, k, direction, deadband, maxforce, mass=2.0):
    """The springs' force (N) on a mass at rest at ``pos``: one undamped step's m a."""
    acc = advance_effects(
        np.array(pos, dtype=float),
        np.zeros(3),
        1,
        DT,
        mass,
        np.zeros(3),
        0.0,
        np.zeros(3),
        np.array([k]),
        np.zeros((1, 3)),
        np.zeros(1),
        np.array([direction], dtype=float),
        np.array([deadband]),
        np.array([maxforce]),
    )
    return mass * acc


# -- the commands ---------------------------------------------------------------------


def test_native_commands_are_exact():
    params = plane_set(1500.0, 12.5)
    expected = [
        "set evoDoorPlane stiffness 1500",
        "set evoDoorPlane dampfactor 0",
        "set evoDoorPlane direction [1,0,0]",
        "set evoDoorPlane pos [0,0,0]",
        "set evoDoorPlane deadband 0",
        "set evoDoorPlaneDamper dampcoef [12.5,0,0]",
    ]
    assert native_commands(params) == expected
    assert native_commands(param_vector(params, PARAMS)) == expected  # a kernel vector too
    capped = native_commands(params, max_force=200.0)
    assert capped == [*expected[:5], "set evoDoorPlane maxforce 200", expected[5]]
    assert NATIVE_PARAMS == ("k_plane", "c_plane")
    assert all(name in PARAMS.names for name in NATIVE_PARAMS)


def test_render_natively_creates_once_then_sets(emulator):
    device = started(emulator, max_force=150.0)
    frames = count_frames(emulator)
    n = len(emulator.received)
    assert device.render_natively(plane_set(2000.0, 10.0)) == ("k_plane", "c_plane")
    assert len(frames) == 1  # one frame
    first = emulator.received[n:]
    assert first[:2] == [f"create spring {PLANE_SPRING}", f"create damper {PLANE_DAMPER}"]
    assert first[-2:] == [f"set {PLANE_SPRING} enable", f"set {PLANE_DAMPER} enable"]
    spring, damper = emulator.effects[PLANE_SPRING], emulator.effects[PLANE_DAMPER]
    assert spring["type"] == "spring" and spring["enabled"]
    assert spring["stiffness"] == 2000.0 and spring["dampfactor"] == 0.0
    assert spring["direction"].tolist() == [1.0, 0.0, 0.0]
    assert spring["pos"].tolist() == [0.0, 0.0, 0.0]
    assert spring["deadband"] == 0.0 and spring["maxforce"] == 150.0
    assert damper["type"] == "damper" and damper["enabled"]
    assert damper["dampcoef"].tolist() == [10.0, 0.0, 0.0]

    # a parameter change: the same effects set anew in one frame, nothing created
    n = len(emulator.received)
    assert device.render_natively(plane_set(3500.0, 25.0)) == NATIVE_PARAMS
    assert len(frames) == 2
    again = emulator.received[n:]
    assert not any(c.startswith("create") for c in again)
    assert f"set {PLANE_SPRING} stiffness 3500" in again
    assert emulator.effects[PLANE_SPRING] is spring and spring["stiffness"] == 3500.0
    assert damper["dampcoef"].tolist() == [25.0, 0.0, 0.0]

    # a restart removes every effect: the next call creates them again
    device.stop()
    device.start()
    assert PLANE_SPRING not in emulator.effects
    device.render_natively(plane_set(3500.0, 25.0))
    assert emulator.effects[PLANE_SPRING]["enabled"]
    device.stop()


def test_plane_spring_returns_x_like_the_damped_oscillator(emulator):
    """An x-displaced mass returns to x = 0 as m x'' + (b + c) x' + k x = 0 says, while
    its y-z motion only feels the device's damping (the spring is directional)."""
    m, k, c = 4.0, 2000.0, 10.0
    b = float(emulator.damping[0])  # the emulated device's own damping, 40 N s/m
    device = started(emulator)
    device.set_mass(m)
    device.render_natively(plane_set(k, c))
    x0, y0, z0, vy0 = 0.01, 0.05, -0.02, 0.04
    emulator.position[:] = (x0, y0, z0)
    emulator.velocity[:] = (0.0, vy0, 0.0)
    emulator.steps_per_query = 10  # 4 ms of device time per read
    pos = np.array([device.read()[0] for _ in range(250)])  # 1 s
    t = 10 * DT * np.arange(1, 251)

    x_exact = damped_oscillator(t, x0, m, b + c, k)
    assert np.abs(pos[:, 0] - x_exact).max() < 0.01 * x0
    # the period, from the zero crossings, and the decay, from the extremes
    crossings = t[:-1][np.diff(np.sign(pos[:, 0])) != 0]
    w0 = math.sqrt(k / m)
    zeta = (b + c) / (2.0 * math.sqrt(k * m))
    half_period = math.pi / (w0 * math.sqrt(1.0 - zeta * zeta))
    assert len(crossings) >= 4
    assert np.diff(crossings).mean() == pytest.approx(half_period, rel=0.03)
    # successive extremes, one between each pair of crossings, shrink by exp(-zeta w0 T/2)
    peaks = [np.abs(pos[(t > a) & (t < b_), 0]).max() for a, b_ in zip(crossings, crossings[1:])]
    ratios = np.array(peaks[1:]) / np.array(peaks[:-1])
    assert ratios[:2] == pytest.approx(math.exp(-zeta * w0 * half_period), rel=0.03)

    # y drifts as a free damped mass, z stays put: no pull back toward y = z = 0
    y_exact = y0 + vy0 * m / b * (1.0 - np.exp(-b * t / m))
    assert np.abs(pos[:, 1] - y_exact).max() < 1e-3 * abs(vy0 * m / b)
    np.testing.assert_array_equal(pos[:, 2], z0)
    device.stop()


# -- the emulator's spring settings -------------------------------------------------------


def test_spring_direction_deadband_and_maxforce_in_the_kernel():
    inf = math.inf
    # isotropic: the whole displacement; directional: only its component along it
    assert one_step_force([0.01, 0.02, 0.0], 1000.0, (0, 0, 0), 0.0, inf) == pytest.approx(
        [-10.0, -20.0, 0.0], rel=1e-12
    )
    assert one_step_force([0.01, 0.02, 0.03], 1000.0, (0, 0, 1), 0.0, inf) == pytest.approx(
        [0.0, 0.0, -30.0], rel=1e-12, abs=1e-12
    )
    s = 1.0 / math.sqrt(2.0)
    # along (1, 1, 0)/sqrt 2 the component of (0.03, 0.01, 0.05) is 0.04 / sqrt 2
    f = one_step_force([0.03, 0.01, 0.05], 1000.0, (s, s, 0.0), 0.0, inf)
    assert f == pytest.approx([-20.0, -20.0, 0.0], rel=1e-12, abs=1e-12)
    # deadband 0.01 m: nothing inside, k (d - 0.01) beyond, both sides
    for z, fz in [(0.009, 0.0), (-0.009, 0.0), (0.025, -15.0), (-0.025, 15.0)]:
        assert one_step_force([0.0, 0.0, z], 1000.0, (0, 0, 1), 0.01, inf)[2] == pytest.approx(
            fz, abs=1e-12
        )
    # isotropic deadband: a sphere
    f = one_step_force([0.03, 0.0, 0.04], 1000.0, (0, 0, 0), 0.01, inf)
    assert f == pytest.approx([-24.0, 0.0, -32.0], rel=1e-12, abs=1e-12)
    # maxforce caps the magnitude, keeps the direction
    f = one_step_force([0.03, 0.0, 0.04], 1000.0, (0, 0, 0), 0.0, 5.0)
    assert f == pytest.approx([-3.0, 0.0, -4.0], rel=1e-12, abs=1e-12)
    assert one_step_force([0.0, 0.0, 0.004], 1000.0, (0, 0, 1), 0.0, 5.0)[2] == pytest.approx(-4.0)


def test_spring_settings_over_the_protocol(emulator):
    answer = emulator.answer_frame
    emulator.damping[:] = 0.0
    emulator.inertia = 2.0
    answer("set state init;set state force")
    assert answer("create spring s") == "Effect spring with name s created"
    assert answer("set s direction [0,0,2];set s stiffness 1000;set s deadband 0.01") == (
        "Effect s direction set;Effect s stiffness set;Effect s deadband set"
    )
    assert answer("set s maxforce 5;set s enable") == "Effect s maxforce set;Effect s enabled"
    assert answer("get s direction;get s maxforce") == "[0,0,2];5.0"
    for bad in ["set s deadband -1", "set s maxforce 0", "set s direction [1,2]"]:
        assert answer(bad).startswith("--- ERROR"), bad
    emulator.steps_per_query = 1

    def force_at(position):
        emulator.position[:] = position
        emulator.velocity[:] = 0.0
        acc = [float(a) for a in answer("get modelacc")[1:-1].split(",")]
        return emulator.inertia * np.array(acc)

    # the direction [0,0,2] is used as a unit vector; x and y do not count
    assert force_at([0.5, -0.3, 0.005]) == pytest.approx([0, 0, 0], abs=1e-12)  # deadband
    assert force_at([0.5, -0.3, 0.014]) == pytest.approx([0, 0, -4.0], abs=1e-9)
    assert force_at([0.5, -0.3, 0.2]) == pytest.approx([0, 0, -5.0], abs=1e-9)  # capped

    # dampers: the device's spelling and the old one, per axis
    answer("create damper d;set d enable")
    assert answer("set d dampcoef [1,2,3];get d dampcoef") == "Effect d dampcoef set;[1,2,3]"
    assert answer("set d dampcoeff [4,5,6];get d dampcoeff") == "Effect d dampcoef set;[4,5,6]"


def test_stiff_spring_is_stable():
    """1e5 N/m: no energy gain without damping, settles with it, also on a 1 g mass
    (substepped) and with a spring's own damping along an oblique direction."""
    x0 = 0.01
    for mass in (4.0, 0.05, 1e-3):
        pos, vel = np.array([x0, 0.0, 0.0]), np.zeros(3)
        args = (mass, np.zeros(3), 0.0, np.zeros(3), np.array([1e5]), np.zeros((1, 3)))
        dirs, cap = np.array([[1.0, 0.0, 0.0]]), np.array([math.inf])
        energy = np.empty(25000)
        for i in range(energy.size):  # 10 s, step by step
            advance_effects(pos, vel, 1, DT, *args, np.zeros(1), dirs, np.zeros(1), cap)
            energy[i] = 0.5 * mass * vel @ vel + 0.5 * 1e5 * pos[0] ** 2
        e0 = 0.5 * 1e5 * x0**2
        # symplectic Euler: the energy swings a little within a period, never grows,
        # and the scheme adds no damping of its own
        assert energy.max() < 1.12 * e0, mass
        assert energy[-2500:].max() > 0.98 * e0, mass
        assert energy[-2500:].max() == pytest.approx(energy[:2500].max(), rel=1e-3), mass
        # with damping and friction: to rest
        args = (mass, np.full(3, 40.0), 0.5, np.zeros(3), np.array([1e5]), np.zeros((1, 3)))
        pos, vel = np.array([x0, 0.02, 0.0]), np.zeros(3)
        advance_effects(pos, vel, 25000, DT, *args, np.zeros(1), dirs, np.zeros(1), cap)
        # it sticks where the spring no longer beats the friction: |x| <= 0.5 N / k
        assert abs(pos[0]) <= 0.5 / 1e5 * (1 + 1e-9) and np.abs(vel).max() < 1e-9, mass
    # a damping-only spring along (1, 1, 0)/sqrt 2 (the coupled implicit solve): speed
    # along it decays as implicit Euler of m v' = -(b + b_s) v says, across it as b
    s = 1.0 / math.sqrt(2.0)
    m, b, b_s, n = 2.0, 5.0, 1e5, 50
    for v0, beta in [((s, s, 0.0), b + b_s), ((s, -s, 0.0), b)]:
        pos, vel = np.zeros(3), np.array(v0)
        advance_effects(
            pos,
            vel,
            n,
            DT,
            m,
            np.full(3, b),
            0.0,
            np.zeros(3),
            np.zeros(1),
            np.zeros((1, 3)),
            np.array([b_s]),
            np.array([[s, s, 0.0]]),
            np.zeros(1),
            np.array([math.inf]),
        )
        assert vel == pytest.approx(np.array(v0) * (1.0 + DT * beta / m) ** -n, rel=1e-9)


def test_refused_native_setting_is_a_one_line_error(emulator):
    device = started(emulator)
    with pytest.raises(HapticMasterError, match="device refused") as info:
        device.render_natively(param_vector(plane_set(1.0, 1.0), PARAMS) * np.nan)
    assert "\n" not in str(info.value)
    device.stop()


# -- the simulated device ---------------------------------------------------------------


def x_return(native: bool, rate: float, k: float, c: float, duration: float = 2.0):
    """x(t) of a SimDevice released 1 cm off the plane, the loop's force each cycle.

    The device's own damping is 2 N s/m and its Coulomb friction 0.3 N.
    """
    params = plane_set(k, c)
    script = ForceScript("free", 0.8)  # no hand
    dev = SimDevice(script, radius=params["radius"], damping=2.0, coulomb=0.3, noise=0.0)
    dev.set_mass(params["inertia"] / params["radius"])
    p = param_vector(params, PARAMS)
    if native:
        for name in dev.render_natively(params):  # what the loop does with the answer
            p[PARAMS.index(name)] = 0.0
    dev.start()
    dev.pos[0] = 0.01
    out = np.empty(3)
    xs = np.empty(int(duration * rate))
    for i in range(xs.size):
        pos, vel, _ = dev.read()
        device_force(*pos.tolist(), *vel.tolist(), p, out)
        dev.command(out)
        dev.step(1.0 / rate)
        xs[i] = dev.pos[0]
    return xs


@pytest.mark.parametrize("k, c", [(2000.0, 10.0), (300.0, 100.0)])
def test_sim_device_native_plane_feels_like_the_host_rendered_one(k, c):
    host = x_return(False, 2500.0, k, c)
    native = x_return(True, 2500.0, k, c)
    assert np.abs(host[500:]).max() > 0.001  # it still moves after 0.2 s
    assert np.abs(native - host).max() < 0.02 * 0.01  # 2 % of the release offset
    assert np.abs(native[-250:]).max() < 0.05 * 0.01  # back at x = 0
    assert np.abs(host[-250:]).max() < 0.05 * 0.01


def test_sim_device_never_asked_renders_nothing_natively():
    dev = SimDevice(ForceScript("free", 0.8), noise=0.0)
    assert dev.k_plane == 0.0 and dev.c_plane == 0.0
    dev.start()
    dev.pos[0] = 0.01
    for _ in range(100):
        dev.step(DT)
    assert dev.pos[0] == pytest.approx(0.01, abs=1e-12)  # no plane spring of its own
    assert dev.render_natively(plane_set(2000.0, 10.0)) == NATIVE_PARAMS
    for _ in range(250):
        dev.step(DT)
    assert abs(dev.pos[0]) < 0.005  # now the device itself pulls it back
