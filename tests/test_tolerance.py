"""Tolerances against a chosen feel: the bands alone and together, stored, exported, drawn.

One curve-target fit of a door's feel (K = 350 N/m, F_atD = 12 N; the example of
docs/experiments.md, "Tolerances a supplier can build to") is made once for the
module; the bands are then checked against the perceptual check itself
(``model_curve`` + ``perceptual_check`` + ``check_verdict``), not against the fast
grid the search uses.
"""

from __future__ import annotations

import csv
import io
import json
import subprocess
import sys

import numpy as np
import pytest

from evo_door.commands.curve import curve_csv
from evo_door.errors import UserError
from evo_door.experiment import Results, load_experiment, run_experiment
from evo_door.experiment.spec import render, spec_table
from evo_door.experiment.store import setup_from_tree
from evo_door.models import get_model
from evo_door.optim.tolerance import FeelCheck, allowed_failures, tolerances, wilson_lower
from evo_door.perception import check_verdict, model_curve, perceptual_check
from evo_door.sim.simulate import force_angle_curve

EXPERIMENT = """\
name: feelfit
model: door
params: default
target: {curve: feel.csv}
free: {K: [200, 800], F_load: [40, 160], M: [0.3, 3], F_atC: [0, 100], F_atD: [0, 100]}
algorithm: {population: 40, generations: 8, seed: 1, polish: slsqp}
"""


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A finished curve-target fit: its results file, setup and door."""
    folder = tmp_path_factory.mktemp("tol")
    door = get_model("door")
    params = door.load_params("default", {"K": 350.0, "F_atD": 12.0})
    (folder / "feel.csv").write_text(curve_csv(force_angle_curve(door, params)))
    (folder / "exp.yaml").write_text(EXPERIMENT)
    run = run_experiment(load_experiment(folder / "exp.yaml"), out=folder / "run.h5")
    res = Results(run.path)
    setup = setup_from_tree(res.tree)
    full = np.asarray(res.tree["best"]["full"], dtype=np.float64)
    return res, setup, full


def _passes(setup, p) -> bool:
    """The perceptual check itself, on the model's adaptive curve."""
    feel = setup.feel
    mech = model_curve(setup.model, p)
    return check_verdict(perceptual_check(mech, feel.curve, feel.jnd), feel.jnd)["passes"]


def _moved(setup, full, name, value):
    p = full.copy()
    i = setup.model.params.index(name)
    decl = setup.model.params[name]
    p[i] = min(max(value, decl.lower), decl.upper)
    return p


@pytest.mark.slow
def test_stored_with_the_run_and_shown(fitted):
    res, setup, full = fitted
    tol = res.record.tolerance
    assert tol is not None, "a perceptual run keeps its tolerances"
    rows = [r.name for r in spec_table(res, tolerance=False).rows]
    assert tol.names == rows
    assert tol.samples == 200 and tol.seed == 1 and tol.nominal_passes
    assert 0.0 < tol.factor <= 1.0
    np.testing.assert_allclose(tol.together, tol.factor * tol.alone)
    assert np.all(tol.alone <= tol.cap * (1 + 1e-12))
    # the estimated spring moves the whole stroke: bounded by the feel, not capped
    k = tol.names.index("K")
    assert not tol.capped[k] and 0.0 < tol.alone[k] < tol.cap[k]
    # the rate the file records is what the Monte-Carlo found, and meets its target
    assert tol.passed / tol.samples >= 0.95 and tol.lower_bound >= tol.target
    shown = json.loads(
        subprocess.run(
            [sys.executable, "-m", "evo_door", "show", str(res.path), "--json"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    )["tolerance"]
    assert shown["monte_carlo"]["samples"] == 200
    assert shown["specifications"]["K"]["alone"] == pytest.approx(tol.alone[k])
    assert shown["specifications"]["K"]["unit"] == "N/m"


@pytest.mark.slow
def test_together_bands_pass_with_an_independent_seed(fitted):
    """Doors drawn anywhere within the together bands with another seed pass at >= 95 %,
    judged by the full perceptual check (not the search's fast grid)."""
    res, setup, full = fitted
    tol = res.record.tolerance
    idx = [setup.model.params.index(n) for n in tol.names]
    lo = np.array([setup.model.params[n].lower for n in tol.names])
    hi = np.array([setup.model.params[n].upper for n in tol.names])
    rng = np.random.default_rng(20261126)  # not the run's seed
    n, passed = 60, 0
    for u in rng.uniform(-1.0, 1.0, (n, len(idx))):
        p = full.copy()
        p[idx] = np.clip(full[idx] + tol.together * u, lo, hi)
        passed += _passes(setup, p)
    assert passed / n >= 0.95, f"{passed}/{n} doors within the together bands pass"


@pytest.mark.slow
@pytest.mark.numerics
def test_just_outside_an_alone_band_fails(fitted):
    """The band's edge passes the full check; 10 % beyond it, on one side, fails."""
    res, setup, full = fitted
    tol = res.record.tolerance
    for name in ("K", "F_load", "mu"):
        row = tol.row(name)
        v, b = row["value"], row["alone"]
        assert not row["capped"]
        inside = [_moved(setup, full, name, v + s * 0.98 * b) for s in (-1, 1)]
        assert all(_passes(setup, p) for p in inside), name
        outside = [_moved(setup, full, name, v + s * 1.1 * b) for s in (-1, 1)]
        assert not all(_passes(setup, p) for p in outside), name


@pytest.mark.slow
@pytest.mark.numerics
def test_fast_check_agrees_with_the_perceptual_check(fitted):
    res, setup, full = fitted
    check = FeelCheck(setup.model, setup.feel)
    for name, scale in (("K", 0.3), ("K", 0.9), ("F_load", 0.05), ("F_load", 0.2), ("M", 0.2)):
        i = setup.model.params.index(name)
        p = _moved(setup, full, name, full[i] * (1 + scale))
        assert check.passes(p) == _passes(setup, p), (name, scale)


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["md", "csv", "tex", "html", "yaml"])
def test_export_has_the_column_in_each_format(fitted, fmt):
    res, _, _ = fitted
    tol = res.record.tolerance
    k = tol.names.index("K")
    text = render(spec_table(res), fmt)
    if fmt == "csv":
        rows = list(csv.DictReader(io.StringIO(text)))
        row = next(r for r in rows if r["parameter"] == "K")
        assert float(row["tolerance alone (+-)"]) == pytest.approx(tol.alone[k], rel=1e-5)
        assert float(row["tolerance together (+-)"]) == pytest.approx(tol.together[k], rel=1e-5)
        assert row["unit"] == "N/m"
        return
    band = f"+-{tol.alone[k]:.3g} N/m"
    assert band in text, fmt
    assert f"+-{tol.together[k]:.3g} N/m" in text, fmt
    if fmt != "yaml":
        assert "tolerance alone" in text.replace("\\_", "_")


@pytest.mark.slow
def test_computed_for_a_file_without_them(fitted, tmp_path):
    """A results file written before tolerances were kept: export-spec computes them and
    says so."""
    import shutil

    import h5py

    res, _, _ = fitted
    old = tmp_path / "old.h5"
    shutil.copy(res.path, old)
    with h5py.File(old, "a") as f:
        del f["tolerance"]
    out = subprocess.run(
        [sys.executable, "-m", "evo_door", "export-spec", str(old), "--format", "csv"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "tolerances computed now" in out.stderr
    rows = list(csv.DictReader(io.StringIO(out.stdout)))
    k = next(r for r in rows if r["parameter"] == "K")
    assert float(k["tolerance alone (+-)"]) == pytest.approx(
        res.record.tolerance.row("K")["alone"], rel=1e-5
    )


def test_wilson_bound_against_a_hand_computation():
    # 190 of 200, z = 1.6449: (0.95 + z^2/400 - z sqrt(0.95*0.05/200 + z^2/160000)) / (1 + z^2/200)
    z = 1.6448536269514722
    p = 0.95
    hand = (p + z * z / 400 - z * np.sqrt(p * (1 - p) / 200 + z * z / 160000)) / (1 + z * z / 200)
    assert wilson_lower(190, 200, 0.95) == pytest.approx(hand, rel=1e-12)
    k = allowed_failures(200, 0.95, 0.95)
    assert wilson_lower(200 - k, 200, 0.95) >= 0.95 > wilson_lower(199 - k, 200, 0.95)
    assert allowed_failures(20, 0.95, 0.95) == -1  # 20 doors cannot show 95 %


@pytest.mark.slow
def test_bad_inputs_are_one_line_errors(fitted):
    _, setup, full = fitted
    model, feel = setup.model, setup.feel
    cases = [
        (dict(names=["K"], feel=None), "need a chosen feel"),
        (dict(names=["K"], p0=full[:3]), "finite values"),
        (dict(names=[]), "no specification"),
        (dict(names=["Kk"]), "K"),
        (dict(names=["K", "K"]), "named twice"),
        (dict(names=["K"], samples=5), "at least 20"),
        (dict(names=["K"], target=1.5), "target"),
        (dict(names=["K"], samples=20), "sample more"),
    ]
    for kwargs, words in cases:
        args = {"p0": full, "feel": feel, **kwargs}
        with pytest.raises(UserError) as err:
            tolerances(model, args.pop("p0"), args.pop("feel"), **args)
        assert words in str(err.value) and "\n" not in str(err.value), kwargs
