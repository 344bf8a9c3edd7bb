"""A specification a supplier can build: process tolerances in, a centred nominal and a
yield out, checked on fresh doors by an independent implementation of the check.

One fit of a door to a feel that is not in the repository (a door with K = 350 N/m and
F_atD = 12 N, as a curve file) is made once for the module, with a process table of its
own; its stored specification is then held against doors drawn afresh from what it
states and judged by ``benchmarks.yield_check`` (its own grid, its own peak search, the
rule as the docs state it), not by the code that made it; and the fast check of many
doors the stage counts with is held against the perceptual check of one door.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import subprocess
import sys

import numpy as np
import pytest

from benchmarks.yield_check import check_file, draw_doors, judge_doors
from evo_door.commands.curve import curve_csv
from evo_door.errors import UserError
from evo_door.experiment import Results, load_experiment, run_experiment
from evo_door.experiment.spec import render, spec_table
from evo_door.experiment.stored import setup_from_tree
from evo_door.files import write_h5
from evo_door.models import get_model
from evo_door.optim.process import process_for
from evo_door.optim.tolerance import (
    BatchFeelCheck,
    NearestFeel,
    YieldEstimate,
    clopper_pearson,
    specify,
)
from evo_door.params import load_params
from evo_door.reporting.figures import plot_tolerances
from evo_door.sim.simulate import force_angle_curve
from tests.test_cli import cli

EXPERIMENT = """\
name: feelfit
model: door
params: default
target: {curve: feel.csv}
free: {K: [200, 800], F_load: [40, 160], M: [0.3, 3], F_atC: [0, 100], F_atD: [0, 100]}
algorithm: {population: 40, generations: 8, seed: 1, polish: slsqp}
# a supplier that holds everything to 1 %, its spring to 2 %
process: {kinds: {spring_rate: "2 %"}, mu: "1 %", F_atC: "1 %", F_atD: "1 %", F_load: "1 %",
          M: "1 %", unlock_force: "1 %", lock_force: "1 %", T_atO: "1 %", T_atA: "1 %",
          T_atB: "1 %", latch_seat_force: "1 %"}
"""


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A finished curve-target fit with its specification: results, setup, door."""
    folder = tmp_path_factory.mktemp("spec")
    door = get_model("door")
    params = door.load_params("default", {"K": 350.0, "F_atD": 12.0})
    (folder / "feel.csv").write_text(curve_csv(force_angle_curve(door, params)))
    (folder / "exp.yaml").write_text(EXPERIMENT)
    run = run_experiment(load_experiment(folder / "exp.yaml"), out=folder / "run.h5")
    res = Results(run.path)
    setup = setup_from_tree(res.tree)
    full = np.asarray(res.tree["best"]["full"], dtype=np.float64)
    return res, setup, full


@pytest.mark.slow
def test_a_reachable_yield_holds_on_fresh_doors_judged_independently(fitted):
    res, _, _ = fitted
    spec = res.record.tolerance
    assert spec is not None and spec.reachable
    assert spec.yield_.samples >= 2000 and spec.yield_.estimate >= 0.95
    lo, hi = spec.yield_.ci95
    assert lo <= spec.yield_.estimate <= hi
    got = check_file(res.path, None, 2000, seed=11)
    assert abs(got["difference_points"]) <= 3.0, got
    assert got["independent"]["estimate"] >= 0.92, got
    # the tolerances as stated: 1 % of mu's nominal, 2 % of K's
    row = spec.row("mu")
    assert row["half_width"] == pytest.approx(0.01 * row["nominal"])
    assert spec.row("K")["half_width"] == pytest.approx(0.02 * spec.row("K")["nominal"])


@pytest.mark.slow
def test_the_nominal_door_is_within_every_jnd(fitted):
    res, setup, full = fitted
    verdict = setup.feel.verdict(setup.model, full)
    assert verdict["passes"], verdict["worst"]
    for d in ("opening", "closing"):
        assert verdict[d]["latch_peak"]["jnd_units"] <= 1.0
        assert verdict[d]["peak_angle"]["jnd_units"] <= 1.0
        assert verdict[d]["worst"]["jnd_units"] <= 1.0
    assert res.summary()["perceptual_check"]["passes"]


@pytest.mark.slow
def test_the_defaults_cannot_reach_it_and_the_allocation_does(fitted):
    """The kinds' default tolerances (+-10-30 %): not reachable, said so; the fewest
    tolerances tightened, about the most robust nominal, reach the target on a fresh
    sample judged independently."""
    _, setup, full = fitted
    model = setup.model
    names = [n for n in res_names(fitted)]
    spec = specify(
        model,
        full,
        setup.feel,
        names,
        process_for(model, names),
        list(setup.free),
        setup.lower,
        setup.upper,
        asis=setup.base,
    )
    assert not spec.reachable and spec.yield_.estimate < 0.95
    assert "NOT REACHABLE" in "\n".join(spec.summary_lines())
    assert spec.allocation, spec.summary_lines()
    assert spec.allocation_yield.estimate >= 0.95
    process = {n: float(t) for n, t in zip(spec.names, spec.half_width)}
    process.update(spec.allocation)  # the tightened half-widths
    nominal = full.copy()
    for n, v in zip(spec.names, spec.allocation_nominal):
        nominal[model.params.index(n)] = v
    stated = {"process": process, "distribution": dict(zip(spec.names, spec.distribution))}
    ok, _ = judge_doors(model, draw_doors(model, nominal, stated, 2000, 23), _feel_dict(setup))
    assert abs(ok.mean() - spec.allocation_yield.estimate) <= 0.03
    assert ok.mean() >= 0.92
    # every tightened tolerance is tighter than the process's, none is zero
    for n, w in spec.allocation.items():
        assert 0.0 < w < spec.half_width[spec.names.index(n)]


@pytest.mark.slow
def test_an_allocation_its_fresh_sample_does_not_verify_is_tightened_further(fitted, monkeypatch):
    """The allocation is searched first order on a thousand draws and verified on a
    fresh sample; where the sample misses the target (the main job once, by one door in
    2000), the search aims higher until it verifies. Here the first search is made to
    aim 5 points below the target: its allocation misses, the next one is kept."""
    from evo_door.optim import tolerance

    _, setup, full = fitted
    names = res_names(fitted)
    aims = []
    real = tolerance._allocate

    def first_too_loose(M, U, t, J, names, loss, swing, target, above):
        aims.append(above)
        return real(M, U, t, J, names, loss, swing, target, -0.05 if len(aims) == 1 else above)

    monkeypatch.setattr(tolerance, "_allocate", first_too_loose)
    spec = tolerance.specify(
        setup.model, full, setup.feel, names, process_for(setup.model, names),
        list(setup.free), setup.lower, setup.upper, asis=setup.base,
    )  # fmt: skip
    assert aims == list(tolerance.ALLOCATION_AIMS[:2]), aims
    assert spec.allocation and spec.allocation_yield.estimate >= spec.target


@pytest.mark.slow
def test_centring_never_gives_a_lower_yield_than_the_smallest_change(fitted):
    res, _, _ = fitted
    spec = res.record.tolerance
    if spec.design == "centred":
        assert spec.alternative["design"] == "smallest change"
        assert spec.alternative["yield"].estimate <= spec.yield_.estimate + 0.01
    else:
        assert not spec.alternative


@pytest.mark.slow
def test_show_json_export_and_report_print_one_table(fitted, tmp_path, capsys):
    res, _, _ = fitted
    spec = res.record.tolerance
    shown = cli(capsys, "show", str(res.path), "--json")
    assert shown.returncode == 0, shown.stderr
    doc = json.loads(shown.stdout)
    assert doc["process"] == pytest.approx(
        {n: float(t) for n, t in zip(spec.names, spec.half_width)}
    )
    assert doc["yield"]["samples"] == spec.yield_.samples
    assert doc["yield"]["estimate"] == spec.yield_.estimate
    assert doc["reachable"] is True and doc["allocation"] == {}
    assert doc["jnds"]["position_m"] == pytest.approx(0.005)
    table = spec_table(res)
    rows = list(csv.DictReader(io.StringIO(render(table, "csv"))))
    for row in rows:
        if row["parameter"] in spec.names:
            assert float(row["process tolerance (+-)"]) == pytest.approx(
                doc["process"][row["parameter"]], rel=1e-5
            )
    assert "standard error" not in rows[0]  # no interval that contradicts a tolerance
    md = render(table, "md")
    assert spec.yield_.text() in md and "feel determines it" in md
    # the check does not see the door's inertia against a bare curve: it says so
    i_z = next(r for r in rows if r["parameter"] == "I_z")
    assert float(i_z["sensitivity (JND per unit)"]) == 0.0
    assert "not judged" in render(table, "md").split("| I_z |")[1].split("\n")[0]
    plot_tolerances(spec, "run", tmp_path / "spec.png")
    assert (tmp_path / "spec.png").stat().st_size > 1000


def test_clopper_pearson_against_scipy_beta():
    from scipy.stats import beta

    lo, hi = clopper_pearson(1880, 2000)
    assert lo == pytest.approx(beta.ppf(0.025, 1880, 121), rel=1e-12)
    assert hi == pytest.approx(beta.ppf(0.975, 1881, 120), rel=1e-12)
    assert clopper_pearson(2000, 2000)[1] == 1.0 and clopper_pearson(0, 2000)[0] == 0.0


def test_a_results_file_gives_its_nearest_feel_to_render_and_push(tmp_path, capsys):
    """The nearest feel a results file stores is a haptic parameter set, read as data;
    a results file without one, or a damaged one, is one line."""
    haptic = get_model("haptic")
    values = dict(zip(haptic.params.names, map(float, haptic.load_params("seed_trial").vector)))
    values["friction_opening"] = 7.5
    nearest = NearestFeel(
        "haptic", values, ["friction_opening"], 0.4, YieldEstimate(1900, 2000, 2), 0.95
    )
    path = tmp_path / "run.h5"
    write_h5(
        path,
        {
            "stages": {
                "specification": {
                    "setup": {"x": np.zeros(1)},
                    "tolerance": {"nearest_feel": nearest.to_tree()},
                }
            }
        },
    )
    ps = load_params(haptic.params, str(path))
    assert ps["friction_opening"] == 7.5
    assert "nearest feel" in ps.description and "specification" in ps.description
    bare = tmp_path / "bare.h5"
    write_h5(bare, {"setup": {"x": np.zeros(1)}, "tolerance": {"x": np.zeros(1)}})
    with pytest.raises(UserError, match="no nearest feel"):
        load_params(haptic.params, str(bare))
    door = get_model("door")
    with pytest.raises(UserError, match="not of 'door'"):
        load_params(door.params, str(path))
    out = cli(capsys, "params", "haptic", "--params", str(path), "--json")
    assert out.returncode == 0, out.stderr
    value = {p["name"]: p["value"] for p in json.loads(out.stdout)["params"]}
    assert value["friction_opening"] == 7.5
    # the renderer takes it as it takes a parameter file (push reads sets the same way)
    shown = subprocess.run(
        [sys.executable, "-m", "evo_door", "render", "--params", str(path), "--device", "sim",
         "--user", "hold", "--duration", "0.2"],
        capture_output=True,
        text=True,
    )  # fmt: skip
    assert shown.returncode == 0, shown.stderr
    assert "rendered" in shown.stdout


def _verdict(setup, p) -> dict:
    """The perceptual check itself of one door (FeelTarget.verdict)."""
    return setup.feel.verdict(setup.model, p)


def _moved(setup, full, name, value):
    p = full.copy()
    i = setup.model.params.index(name)
    decl = setup.model.params[name]
    p[i] = min(max(value, decl.lower), decl.upper)
    return p


@pytest.mark.slow
@pytest.mark.numerics
def test_fast_check_agrees_with_the_perceptual_check(fitted):
    """Doors with one specification moved to several values, on both sides of where the
    check's verdict turns: the fast check's margins give the slow check's verdict and its
    worst JND, door by door."""
    res, setup, full = fitted
    check = BatchFeelCheck(setup.model, setup.feel)
    assert check.columns == len(check.labels)
    moves = {
        "K": (-0.2, -0.1, -0.05, -0.02, 0.02, 0.05, 0.1, 0.3, 0.9),
        "F_load": (-0.1, -0.03, -0.01, 0.01, 0.03, 0.05, 0.2),
        "F_atD": (-0.3, -0.1, -0.03, 0.03, 0.1, 0.3),
        "M": (-0.2, 0.2),
    }
    doors = [full] + [
        _moved(setup, full, n, full[setup.model.params.index(n)] * (1 + s))
        for n, scales in moves.items()
        for s in scales
    ]
    margins = check.margins(np.array(doors))
    assert margins.shape == (len(doors), check.columns)
    judged = check.judge(np.array(doors))
    np.testing.assert_array_equal(judged, np.all(np.abs(margins) <= 1.0, axis=1))
    verdicts = [_verdict(setup, p) for p in doors]
    slow = np.array([v["passes"] for v in verdicts])
    worst = np.array([v["worst_jnd"] for v in verdicts])
    fast_worst = np.max(np.abs(margins), axis=1)
    # both verdicts, so that the agreement says something
    assert slow[0] and slow.sum() >= 3 and (~slow).sum() >= 3, worst
    assert np.all(judged == slow), list(zip(worst, fast_worst))
    np.testing.assert_allclose(fast_worst, worst, rtol=0.02, atol=0.02)
    # and the worst margin is the one the verdict names
    for v, row in zip(verdicts, margins):
        if v["worst_jnd"] > 0.05:
            assert check.labels[int(np.argmax(np.abs(row)))] == v["worst"], (v["worst"], row)
    assert check.passes(doors[0])


def res_names(fitted) -> list[str]:
    from evo_door.optim.specification import spec_names

    _, setup, _ = fitted
    return spec_names(setup.model, setup.free)


def _feel_dict(setup) -> dict:
    feel = setup.feel
    return {
        "theta": feel.curve.theta,
        "opening": feel.curve.opening,
        "closing": feel.curve.closing,
        "jnd": feel.jnd.as_dict(),
        "dynamics": feel.dynamics,
        "closed": feel.closed,
    }


def test_the_centrings_worst_margins_are_numpys_to_the_last_bit():
    """The centring's objective takes each design door's worst margin from a compiled
    loop (no temporaries of the design sample's size): the same numbers as numpy's
    ``max |v + D|`` row by row, NaN and infinities included, and the same smoothed yield."""
    from evo_door.optim.feel_doors import smoothed_share, soft_yield
    from evo_door.optim.yield_kernel import worst_shifted

    rng = np.random.default_rng(3)
    D = rng.standard_normal((400, 731)) * 0.7
    D[5, 100] = np.nan
    D[7, 3] = np.inf
    D[9, 730] = -np.inf
    v = rng.standard_normal(731) * 0.3
    got = worst_shifted(D, v)
    want = np.max(np.abs(v + D), axis=1)
    assert np.array_equal(got, want, equal_nan=True)
    assert np.isnan(got[5]) and got[7] == np.inf and got[9] == np.inf
    finite = np.delete(np.arange(400), [5])
    assert smoothed_share(got[finite]) == soft_yield(v + D[finite])


def test_the_margins_written_in_place_are_the_plain_formulas_to_the_last_bit():
    """The batch check writes each door's margins (JND) into one array, the stroke's
    columns straight from its first angles: the same numbers as the formulas taken
    whole, a non-finite margin the blown-up door's, with and without felt dynamics."""
    from types import SimpleNamespace

    from evo_door.optim.feel_doors import BLOWN, DIRECTIONS, Reference

    rng = np.random.default_rng(5)
    rows, angles, n = 7, 40, 29
    check = SimpleNamespace(n_stroke=n, stroke=np.arange(angles) < n)
    got = {d: rng.normal(20.0, 5.0, (rows, angles)) for d in DIRECTIONS}
    got["opening"][2, 3] = np.nan
    got["peaks"] = {d: rng.normal(30.0, 3.0, rows) for d in DIRECTIONS}
    got["angles"] = {d: rng.normal(1.5, 0.01, rows) for d in DIRECTIONS}
    got["dynamics"] = rng.normal(1.0, 0.1, (rows, 2))
    got["dynamics"][4, 1] = np.inf
    chosen = {d: rng.normal(20.0, 5.0, angles) for d in DIRECTIONS}
    ref = Reference(
        chosen,
        {d: np.maximum(0.1 * np.abs(c), 0.5) for d, c in chosen.items()},
        {"opening": 31.0, "closing": 29.0},
        {"opening": 3.1, "closing": 2.9},
        {"opening": 1.49, "closing": 1.51},
        0.01,
        ((1.0, 0.2), (1.1, 0.3)),
    )
    for dynamics in (ref.dynamics, None):
        r = dataclasses.replace(ref, dynamics=dynamics)
        parts = [((got[d] - r.chosen[d]) / r.threshold[d])[:, check.stroke] for d in DIRECTIONS]
        parts.append(np.array([(got["peaks"][d] - r.peaks[d]) / r.peak_threshold[d]
                               for d in DIRECTIONS]).T)  # fmt: skip
        parts.append(np.array([(got["angles"][d] - r.peak_angles[d]) / r.angle_threshold
                               for d in DIRECTIONS]).T)  # fmt: skip
        if dynamics is not None:
            (ti, ji), (tc, jc) = dynamics
            parts.append(
                np.c_[(got["dynamics"][:, 0] - ti) / ji, (got["dynamics"][:, 1] - tc) / jc]
            )
        want = np.concatenate(parts, axis=1)
        want = np.where(np.isfinite(want), want, BLOWN)
        margins = BatchFeelCheck.against(check, got, r)
        assert margins.shape == want.shape == (rows, 2 * n + 4 + (2 if dynamics else 0))
        assert np.array_equal(margins, want)
        assert margins[2, 3] == BLOWN and (dynamics is None or margins[4, -1] == BLOWN)


def test_the_compiled_pass_verdicts_are_numpys_door_by_door():
    """Whether each door passes, from a compiled loop that stops at its first failing
    margin and moves the margins by an outer product without forming it: numpy's
    verdicts, with margins crowding +-1, NaN and infinities among them."""
    from evo_door.optim.feel_doors import passing, passing_moved

    rng = np.random.default_rng(11)
    M = rng.uniform(-0.99, 0.99, (3000, 40))
    rows, cols = np.arange(3000), rng.integers(0, 40, 3000)  # a margin at the edge each
    M[rows, cols] = rng.choice([-1.0, 1.0], 3000) * (1.0 + rng.uniform(-1e-3, 1e-3, 3000))
    M[:50, 0] = 1.0  # exactly on it: passes
    M[7, 5], M[9, 0], M[11, 39] = np.nan, np.inf, -np.inf
    a, b = rng.normal(0.0, 0.01, 3000), rng.normal(0.0, 1.0, 40)
    want = np.all(np.abs(M) <= 1.0, axis=-1)
    assert 0.2 < want.mean() < 0.8  # both verdicts, often
    assert np.array_equal(passing(M), want)
    assert not passing(M)[[7, 9, 11]].any()
    moved = np.all(np.abs(M - np.outer(a, b)) <= 1.0, axis=-1)
    assert np.array_equal(passing_moved(M, a, b), moved) and not np.array_equal(moved, want)
    assert np.array_equal(passing(M[:, ::2]), np.all(np.abs(M[:, ::2]) <= 1.0, axis=-1))
    assert np.array_equal(passing(M.astype(np.float32)), want)  # numpy's own, other types
