"""The perceptual check's rule: every point of both strokes within the force JND, each
latch peak's force and angle within theirs, the felt dynamics within theirs where the
chosen feel has them; the verdict names its worst point in JND units. Checked on
analytic curves, on the haptic model's latch, and against an independent statement of
the rule (tests/feel_reference.py) on random pairs of curves."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evo_door.errors import UserError
from evo_door.models import get_model
from evo_door.params import param_vector
from evo_door.perception import (
    JND,
    FeelCurve,
    FeelTarget,
    check_verdict,
    model_curve,
    perceptual_check,
    verdict_text,
)
from tests.feel_reference import reference_margins, reference_passes

CLOSED = 0.5 * math.pi
EDGE = CLOSED - math.radians(3.0)
#: width (rad) of the synthetic latch spikes
SPIKE = math.radians(0.15)


def _judge(mech, chosen, jnd=None, dynamics=None) -> dict:
    jnd = jnd or JND()
    return check_verdict(perceptual_check(mech, chosen, jnd), jnd, dynamics)


# -- the position JND -------------------------------------------------------------------
def test_the_position_jnd_is_an_angle_at_the_handle():
    assert JND().position == 0.005 and JND().handle_radius == 0.6
    assert JND().angle_threshold() == pytest.approx(0.005 / 0.6, rel=1e-15)
    assert math.degrees(JND().angle_threshold()) == pytest.approx(0.4775, abs=5e-5)
    assert JND(position=0.01, handle_radius=0.5).angle_threshold() == pytest.approx(0.02)
    jnd = JND.from_mapping({"position": 0.003, "handle_radius": 0.3})
    assert jnd.angle_threshold() == pytest.approx(0.01)


@pytest.mark.parametrize(
    "values, message",
    [
        ({"position": -1}, "perception.position -1.0: must be a number above 0"),
        ({"position": 0}, "perception.position 0.0: must be a number above 0"),
        ({"position": float("nan")}, "perception.position nan: must be a number above 0"),
        ({"handle_radius": 0.0}, "perception.handle_radius 0.0: must be a number above 0"),
        ({"positon": 0.005}, "unknown setting 'positon'"),
    ],
)
def test_bad_position_jnds_are_refused_in_one_line(values, message):
    with pytest.raises(UserError) as err:
        JND.from_mapping(values)
    assert message in str(err.value) and "\n" not in str(err.value)


# -- an analytic case ---------------------------------------------------------------------
def _constant(opening=-10.0, closing=2.0, n=181):
    th = np.linspace(0.0, CLOSED, n)
    return FeelCurve(th, opening + 0 * th, closing + 0 * th)


@pytest.mark.parametrize("sign", [-1.0, 1.0])
@pytest.mark.parametrize("direction", ["opening", "closing", "both"])
@pytest.mark.parametrize("size", [0.99, 1.01])
def test_a_constant_feel_shifted_by_a_share_of_its_jnd(sign, direction, size):
    # the JND is 1 N at -10 N (10 %) and 0.5 N at 2 N (the floor)
    chosen = _constant()
    shift_o = sign * size * 1.0 if direction in ("opening", "both") else 0.0
    shift_c = sign * size * 0.5 if direction in ("closing", "both") else 0.0
    v = _judge(_constant(-10.0 + shift_o, 2.0 + shift_c), chosen)
    assert v["worst_jnd"] == pytest.approx(size, rel=1e-12)
    assert v["passes"] is (size < 1.0)
    for d, shift in (("opening", shift_o), ("closing", shift_c)):
        noticeable = shift != 0.0 and size > 1.0
        assert v[d]["verdict"] == ("noticeable" if noticeable else "within the JND"), d
        assert v[d]["worst"]["jnd_units"] == pytest.approx(abs(shift) / (1.0, 0.5)[d == "closing"])
        # the whole latch zone moves with it: its peak by as much, at the same angle
        assert v[d]["latch_peak"]["jnd_units"] == pytest.approx(v[d]["worst"]["jnd_units"])
        assert v[d]["peak_angle"]["jnd_units"] == 0.0
    assert verdict_text(v).startswith("noticeable: " if size > 1.0 else "within the JND: ")


# -- synthetic feels with a latch -----------------------------------------------------------
def _grid(stroke_points=361, latch_points=601):
    return np.union1d(
        np.linspace(0.0, CLOSED, stroke_points), np.linspace(EDGE, CLOSED, latch_points)
    )


def _forces(theta, at_o=1.0, at_c=1.5, amp_o=15.0, amp_c=10.0, level_o=-8.0, level_c=3.0):
    """Opening and closing forces (N): a smooth stroke and a latch spike each, at
    ``at_o`` / ``at_c`` deg before closed."""
    g_o = np.exp(-0.5 * ((theta - (CLOSED - math.radians(at_o))) / SPIKE) ** 2)
    g_c = np.exp(-0.5 * ((theta - (CLOSED - math.radians(at_c))) / SPIKE) ** 2)
    opening = level_o * (1.0 + 0.3 * np.sin(theta)) - amp_o * g_o
    closing = level_c * (1.0 + 0.3 * np.cos(theta)) + amp_c * g_c
    return opening, closing


def _feel(theta=None, **kw) -> FeelCurve:
    theta = _grid() if theta is None else theta
    return FeelCurve(theta, *_forces(theta, **kw))


def test_one_stroke_point_beyond_its_jnd_is_noticeable_and_named():
    chosen = _feel()
    jnd = JND()
    k = int(np.searchsorted(chosen.theta, math.radians(40.0)))
    opening = chosen.opening.copy()
    opening[k] += 1.1 * jnd.force_threshold(opening[k])
    v = _judge(FeelCurve(chosen.theta, opening, chosen.closing), chosen)
    assert not v["passes"] and v["opening"]["verdict"] == "noticeable"
    assert v["worst_jnd"] == pytest.approx(1.1)
    assert v["worst"] == f"opening stroke at {math.degrees(chosen.theta[k]):.2f} deg"
    assert v["opening"]["worst"]["angle_deg"] == pytest.approx(math.degrees(chosen.theta[k]))
    # one point is no share of the stroke: the old rule would have let it pass
    assert v["opening"]["fraction_beyond_jnd"] == 0.0
    assert v["closing"]["verdict"] == "within the JND"
    assert verdict_text(v).startswith("noticeable: opening stroke at ")


def test_nine_tenths_of_the_jnd_everywhere_is_within():
    chosen = _feel()
    jnd = JND()
    mech = FeelCurve(
        chosen.theta,
        chosen.opening + 0.9 * jnd.force_threshold(chosen.opening),
        chosen.closing - 0.9 * jnd.force_threshold(chosen.closing),
    )
    v = _judge(mech, chosen)
    assert v["passes"] and v["worst_jnd"] == pytest.approx(0.9)
    for d in ("opening", "closing"):
        assert v[d]["verdict"] == "within the JND"
        assert v[d]["worst"]["jnd_units"] == pytest.approx(0.9)
        assert v[d]["latch_peak"]["jnd_units"] == pytest.approx(0.9)
        assert v[d]["peak_angle"]["jnd_units"] == 0.0
    assert verdict_text(v).startswith("within the JND: at most 0.9 JND")


@pytest.mark.parametrize("direction, words", [("opening", "unlock"), ("closing", "lock")])
def test_a_latch_peak_of_the_right_force_at_the_wrong_angle_is_noticeable(direction, words):
    chosen = _feel()
    moved = {"at_o": 1.6} if direction == "opening" else {"at_c": 2.1}  # 0.6 deg earlier
    v = _judge(_feel(**moved), chosen)
    units = 0.6 / math.degrees(JND().angle_threshold())  # 1.257 JND
    a = v[direction]["peak_angle"]
    assert a["jnd_units"] == pytest.approx(units, rel=0.01)
    assert a["jnd_deg"] == pytest.approx(0.4775, abs=5e-5)
    assert a["mechanism_deg"] - a["chosen_deg"] == pytest.approx(-0.6, abs=0.006)
    assert v[direction]["latch_peak"]["jnd_units"] < 0.01  # the force is right
    assert v[direction]["worst"]["jnd_units"] < 1e-6  # and so is the stroke
    assert not v["passes"] and v[direction]["verdict"] == "noticeable"
    assert v["worst"] == f"{words} peak's angle"
    assert verdict_text(v) == f"noticeable: {words} peak's angle off by {v['worst_jnd']:.3g} JND"
    # 0.4 deg is within (0.84 JND)
    near = {k: v - 0.2 for k, v in moved.items()}
    assert _judge(_feel(**near), chosen)["passes"]


def test_felt_inertia_beyond_its_jnd_is_noticeable_only_where_dynamics_are_judged():
    chosen = _feel()
    jnd = JND()
    limit = jnd.inertia_threshold(1.2)  # 15 %: 0.18 kg m
    assert limit == pytest.approx(0.18)
    heavy = {"inertia": (1.45, 1.2, limit), "damping": (2.0, 2.0, jnd.damping_threshold(2.0))}
    v = _judge(chosen, chosen, jnd, heavy)
    assert not v["passes"] and v["worst"] == "felt inertia"
    assert v["worst_jnd"] == pytest.approx(0.25 / 0.18)
    assert v["dynamics"]["inertia"]["verdict"] == "noticeable"
    assert v["dynamics"]["damping"]["verdict"] == "within the JND"
    assert v["dynamics"]["inertia"]["unit"] == "kg m"
    assert verdict_text(v).startswith("noticeable: felt inertia off by 1.39 JND")
    assert _judge(chosen, chosen, jnd)["passes"]  # the same curves without dynamics
    assert "dynamics" not in _judge(chosen, chosen, jnd)
    light = {"inertia": (1.35, 1.2, limit)}
    assert _judge(chosen, chosen, jnd, light)["passes"]


@pytest.mark.parametrize(
    "kind, mech, words, units",
    [
        ("stroke", dict(level_c=3.0 * 1.25), "closing stroke at", None),
        ("peak force", dict(amp_o=15.0 + 3.0), "unlock peak force", None),
        ("peak angle", dict(at_c=1.5 + 0.75), "lock peak's angle", 0.75 / 0.477465),
        ("dynamics", {}, "felt damping", 1.5),
    ],
)
def test_the_verdict_names_its_worst_point_in_jnd_units_for_each_kind(kind, mech, words, units):
    chosen = _feel()
    jnd = JND()
    dynamics = {"damping": (2.0 + 1.5 * 0.5, 2.0, jnd.damping_threshold(2.0))}
    v = _judge(_feel(**mech), chosen, jnd, dynamics if kind == "dynamics" else None)
    assert v["worst"].startswith(words) and not v["passes"]
    ref = reference_margins(_feel(**mech), chosen, jnd, dynamics if kind == "dynamics" else None)
    assert v["worst_jnd"] == pytest.approx(max(ref.values()), rel=1e-12)
    if units is not None:
        assert v["worst_jnd"] == pytest.approx(units, rel=0.01)
    text = verdict_text(v)
    assert text.startswith(f"noticeable: {words}") and text.endswith(
        f"off by {v['worst_jnd']:.3g} JND"
    )
    # the per-direction entries say the same in their own units
    if kind == "stroke":
        assert v["closing"]["worst"]["jnd_units"] == pytest.approx(v["worst_jnd"])
        assert v["closing"]["worst_at"] == v["worst"]
    elif kind == "peak force":
        assert v["opening"]["latch_peak"]["jnd_units"] == pytest.approx(v["worst_jnd"])
        assert v["opening"]["worst_at"] == "unlock peak force"
    elif kind == "peak angle":
        assert v["closing"]["peak_angle"]["jnd_units"] == pytest.approx(v["worst_jnd"])
    else:
        assert v["dynamics"]["damping"]["jnd_units"] == pytest.approx(1.5)
        assert v["opening"]["verdict"] == v["closing"]["verdict"] == "within the JND"


# -- the haptic model's latch ------------------------------------------------------------------
HAPTIC = get_model("haptic")


def _peak_angles(curve: FeelCurve) -> dict[str, float]:
    """The angle (rad) of each latch peak: the least opening force and the largest closing
    force in the last 3 deg of the curve."""
    zone = curve.theta >= curve.theta[-1] - math.radians(3.0)
    th = curve.theta[zone]
    return {
        "opening": float(th[np.argmin(curve.opening[zone])]),
        "closing": float(th[np.argmax(curve.closing[zone])]),
    }


@pytest.mark.numerics
def test_moving_the_haptic_latch_by_a_degree_is_noticeable_by_its_peaks_angles():
    base = HAPTIC.load_params("seed_trial")
    chosen = model_curve(HAPTIC, base)
    expected = _peak_angles(chosen)
    threshold = JND().angle_threshold()
    target = FeelTarget(chosen)
    values = {}
    for deg in (0.0, 0.1, 1.0):
        p = HAPTIC.load_params(
            "seed_trial", {"loose_angle": base["loose_angle"] + math.radians(deg)}
        )
        mech = model_curve(HAPTIC, p)
        got = _peak_angles(mech)
        v = _judge(mech, chosen)
        for d in ("opening", "closing"):
            units = abs(got[d] - expected[d]) / threshold
            assert v[d]["peak_angle"]["jnd_units"] == pytest.approx(units, rel=1e-9, abs=1e-12)
        if deg == 1.0:
            assert units > 2.0
            assert not v["passes"]
            assert v["worst"] in ("unlock peak's angle", "lock peak's angle")
            assert "peak's angle off by" in verdict_text(v)
        elif deg == 0.1:
            assert max(v[d]["peak_angle"]["jnd_units"] for d in ("opening", "closing")) < 0.25
        values[deg] = target.value(HAPTIC, param_vector(p, HAPTIC.params))
        r = target.residuals(HAPTIC, param_vector(p, HAPTIC.params))
        # the last four terms of a bare curve's target: each latch peak's force and angle
        # (to a step of the target's latch grid, 2e-5 rad: 0.0024 JND)
        assert abs(r[-3]) == pytest.approx(deg / math.degrees(threshold), abs=0.005)
        assert abs(r[-1]) == pytest.approx(deg / math.degrees(threshold), abs=0.005)
    assert values[0.0] < 1e-9 < values[0.1] < values[1.0]


@pytest.mark.numerics
def test_a_haptic_feel_with_dynamics_judges_the_latch_and_the_inertia():
    base = HAPTIC.load_params("seed_trial")
    target = FeelTarget.from_model(HAPTIC, base)
    moved = HAPTIC.load_params("seed_trial", {"loose_angle": base["loose_angle"] + math.radians(1)})
    v = target.verdict(HAPTIC, param_vector(moved, HAPTIC.params))
    assert not v["passes"] and v["worst"] in ("unlock peak's angle", "lock peak's angle")
    assert v["dynamics"]["inertia"]["jnd_units"] < 1e-6  # the latch moved, not the mass
    # a door 30 % heavier: its curve is the same, its felt inertia is not
    heavy = HAPTIC.load_params("seed_trial", {"inertia": 1.3 * base["inertia"]})
    v = target.verdict(HAPTIC, param_vector(heavy, HAPTIC.params))
    assert not v["passes"] and v["worst"] == "felt inertia"
    assert v["dynamics"]["inertia"]["verdict"] == "noticeable"
    for d in ("opening", "closing"):
        assert v[d]["verdict"] == "within the JND"
    assert target.verdict(HAPTIC, param_vector(base, HAPTIC.params))["passes"]


# -- against the independent statement of the rule --------------------------------------------
def _random_pair(rng):
    """A chosen feel and a mechanism near it: one or more of its stroke, its latch peaks'
    forces and angles, its felt dynamics moved by about one JND, on its own grid or the
    chosen one's."""
    jnd = JND()
    kw = dict(
        at_o=rng.uniform(0.5, 2.0),
        at_c=rng.uniform(0.8, 2.4),
        amp_o=rng.uniform(5.0, 30.0),
        amp_c=rng.uniform(3.0, 20.0),
        level_o=rng.uniform(-20.0, -2.0),
        level_c=rng.uniform(-2.0, 8.0),
    )
    chosen = _feel(**kw)
    if rng.random() < 0.5:
        theta = chosen.theta
    else:
        theta = _grid(int(rng.integers(150, 500)), int(rng.integers(200, 900)))
    kinds = set(rng.choice(["stroke", "peak force", "peak angle", "dynamics"], rng.integers(1, 4)))
    size = lambda: rng.uniform(0.85, 1.15) * rng.choice([-1.0, 1.0])  # noqa: E731
    mk = dict(kw)
    if "peak force" in kinds:
        mk["amp_o"] = kw["amp_o"] + size() * jnd.force_threshold(kw["level_o"] - kw["amp_o"])
        mk["amp_c"] = kw["amp_c"] + size() * 0.5 * jnd.force_threshold(kw["level_c"] + kw["amp_c"])
    if "peak angle" in kinds:
        step = math.degrees(jnd.angle_threshold())
        mk["at_o"] = kw["at_o"] + size() * step
        mk["at_c"] = kw["at_c"] + size() * 0.7 * step
    opening, closing = _forces(theta, **mk)
    if "stroke" in kinds:
        for forces, d in ((opening, "opening"), (closing, "closing")):
            at = rng.uniform(0.05, EDGE - 0.05)
            bump = np.exp(-0.5 * ((theta - at) / rng.uniform(0.01, 0.3)) ** 2) * (theta < EDGE)
            fc = np.interp(theta, chosen.theta, getattr(chosen, d))
            forces += size() * bump * jnd.force_threshold(fc)
    dynamics = None
    if "dynamics" in kinds:
        dynamics = {
            "inertia": (1.2 + size() * 0.18, 1.2, jnd.inertia_threshold(1.2)),
            "damping": (3.0 + 0.5 * size() * 0.75, 3.0, jnd.damping_threshold(3.0)),
        }
    return FeelCurve(theta, opening, closing), chosen, jnd, dynamics


def test_the_check_agrees_with_an_independent_statement_of_the_rule():
    rng = np.random.default_rng(20261128)
    results = []
    for case in range(50):
        mech, chosen, jnd, dynamics = _random_pair(rng)
        v = check_verdict(perceptual_check(mech, chosen, jnd), jnd, dynamics)
        passes, worst = reference_passes(mech, chosen, jnd, dynamics)
        assert v["passes"] is passes, (case, v["worst"], v["worst_jnd"], worst)
        assert v["worst_jnd"] == pytest.approx(worst, rel=1e-12), case
        results.append((passes, worst))
    passed = sum(p for p, _ in results)
    assert 10 <= passed <= 40, passed  # both verdicts, often
    assert sum(0.95 <= w <= 1.05 for _, w in results) >= 10  # many near the boundary


def test_the_reference_itself_sees_what_it_should():
    """The helper the yield tests will lean on: the rule's four kinds, each on its own."""
    chosen = _feel()
    jnd = JND()
    assert reference_passes(chosen, chosen, jnd) == (True, 0.0)
    for mech, name in (
        (_feel(level_o=-8.0 * 1.2), "opening stroke"),
        (_feel(amp_c=10.0 + 2.0), "closing peak force"),
        (_feel(at_o=1.0 + 0.6), "opening peak angle"),
    ):
        margins = reference_margins(mech, chosen, jnd)
        assert max(margins, key=margins.get) == name
        assert reference_passes(mech, chosen, jnd)[0] is False
    dyn = {"damping": (1.0, 2.0, jnd.damping_threshold(2.0))}
    assert reference_passes(chosen, chosen, jnd, dyn) == (False, 2.0)
