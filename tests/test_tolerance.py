"""The specification stage's fast check of many doors (``optim.tolerance.FeelCheck``)
against the perceptual check of one door.

One curve-target fit of a door's feel (K = 350 N/m, F_atD = 12 N) is made once for the
module; doors with one specification moved are judged by the fast check's margins and
by the perceptual check itself (``FeelTarget.verdict``). (The specification itself,
``specify``, is still being changed: its tests come with it.)
"""

from __future__ import annotations

import numpy as np
import pytest

from evo_door.commands.curve import curve_csv
from evo_door.experiment import Results, load_experiment, run_experiment
from evo_door.experiment.store import setup_from_tree
from evo_door.models import get_model
from evo_door.optim.tolerance import FeelCheck
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
    check = FeelCheck(setup.model, setup.feel)
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
