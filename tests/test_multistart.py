"""The scan before a multi-start polish: a notch beside a plateau is found on purpose.

A made-up fitness with the latch's shape (steep on one side, a plateau on the other,
the minimum in a notch a few thousandths of the range wide) defeats SLSQP started on
the plateau and is solved by :func:`scan_and_polish`; the experiment reader checks the
two keys (``scan``, ``starts``) and a run records them and uses them.
"""

import json

import h5py
import numpy as np
import pytest

from evo_door.data.io import write_trials
from evo_door.errors import UserError
from evo_door.experiment import Results
from evo_door.experiment.config_algorithm import AlgorithmSpec
from evo_door.experiment.runner import ExperimentRun
from evo_door.optim.local import polish
from evo_door.optim.multistart import ScanSettings, interval_bounds, scan_and_polish
from evo_door.optim.problem import Objective
from tests.test_experiment import EXPERIMENT, load
from tests.test_optim import make_trial

NOTCH, EDGE = 40.0, 40.15  # the minimum, and where the plateau starts


class Notched:
    """f(u, v) = the latch's shape in u plus a bowl in v; u in [20, 80], v in [10, 60]."""

    lower, upper = np.array([20.0, 10.0]), np.array([80.0, 60.0])
    n_var = 2
    objective = Objective("ise", 0, "sum")

    def evaluate(self, X):
        X = np.atleast_2d(X)
        u, v = X[:, 0], X[:, 1]
        g = np.where(u <= EDGE, 0.05 * (u - NOTCH) ** 2 + 0.001 * (EDGE - u), 0.2)
        return g + 1e-3 * (v - 30.0) ** 2, np.zeros(len(X), dtype=bool)


def test_interval_bounds_rank_the_drop_onto_a_plateau_first():
    u = np.linspace(20.0, 80.0, 21)  # a step of 3: no grid point in the notch
    f, _ = Notched().evaluate(np.column_stack([u, np.full(u.size, 30.0)]))
    assert f.min() == pytest.approx(0.2)  # the grid sees only the plateau's level
    k = int(np.argmin(interval_bounds(f)))
    assert u[k] < NOTCH < u[k + 1]


def test_scan_finds_the_notch_that_slsqp_on_the_plateau_cannot():
    problem, start = Notched(), np.array([60.0, 45.0])
    alone = polish(problem, start)
    assert alone.x[0] == pytest.approx(60.0)  # no slope on the plateau: stays put
    res = scan_and_polish(problem, start, ScanSettings(points=21, starts=2))
    assert res.x[0] == pytest.approx(NOTCH, abs=0.01) and res.x[1] == pytest.approx(30.0, abs=0.05)
    # the minimum of 0.05 (u - 40)^2 + 0.001 (40.15 - u): u = 40.01, 1.45e-4
    assert res.fitness == pytest.approx(1.45e-4, rel=1e-3) and res.fitness0 > 0.2
    assert res.x0.tolist() == start.tolist()
    assert res.message.startswith("scan: 295 evaluations (points 21, levels 4, starts 2)")
    assert res.evaluations > 295


def test_scan_settings_are_checked():
    with pytest.raises(ValueError, match="at least 3 points"):
        ScanSettings(points=2)
    with pytest.raises(ValueError, match="at least 1"):
        ScanSettings(points=5, starts=0)
    assert not ScanSettings().enabled and ScanSettings(points=3).enabled


@pytest.mark.parametrize(
    "change, message",
    [
        ("  polish: slsqp\n  scan: 2", "algorithm.scan: 2 points cannot bracket a minimum"),
        ("  polish: slsqp\n  scan: -1", "algorithm.scan: must be >= 0, got -1"),
        ("  polish: slsqp\n  scan: many", "algorithm.scan:"),
        ("  polish: slsqp\n  starts: 2", "algorithm.starts: polishes the scan's best points"),
        ("  polish: slsqp\n  scan: 21\n  starts: 0", "algorithm.starts: must be >= 1, got 0"),
        ("  polish: none\n  scan: 21", "algorithm.scan: hands its best points to SLSQP"),
        ("  polish: slsqp\n  scna: 21", "algorithm.scna: unknown key (did you mean 'scan'?)"),
    ],
)
def test_bad_scan_settings_are_one_line(tmp_path, change, message):
    (tmp_path / "trials.h5").touch()
    with pytest.raises(UserError) as info:
        load(tmp_path, EXPERIMENT.replace("  polish: slsqp", change))
    assert "\n" not in str(info.value) and message in str(info.value), str(info.value)


@pytest.fixture()
def folder(tmp_path):
    """The experiment of tests/test_experiment.py next to its trials."""
    trials = [make_trial(s, 0.75, tid=f"t{s}") for s in (1, 2, 3)] + [make_trial(4, 0.75, tid="v1")]
    write_trials(tmp_path / "trials.h5", trials)
    return tmp_path


def test_scan_round_trips_through_the_resolved_section(folder):
    exp = load(folder, EXPERIMENT.replace("  polish: slsqp", "  polish: slsqp\n  scan: 9"))
    assert exp.algorithm.scan == ScanSettings(points=9, starts=2)
    data = exp.algorithm.resolved()
    assert (data["scan"], data["starts"]) == (9, 2)
    assert AlgorithmSpec.from_resolved(data) == exp.algorithm
    old = {k: v for k, v in data.items() if k not in ("scan", "starts")}  # an older file
    assert not AlgorithmSpec.from_resolved(old).scan.enabled
    plain = load(folder, EXPERIMENT)
    assert plain.algorithm.scan == ScanSettings() and plain.algorithm.resolved()["scan"] == 0


def test_a_run_with_a_scan_records_it(folder):
    text = EXPERIMENT.replace("  polish: slsqp", "  polish: slsqp\n  scan: 7\n  starts: 1")
    run = ExperimentRun.create(load(folder, text), folder / "r.h5").run()
    with h5py.File(run.path) as f:
        assert f.attrs["scan"] == 7
        resolved = json.loads(f["experiment/resolved"][()])["algorithm"]
        assert (resolved["scan"], resolved["starts"]) == (7, 1)
    job = run.jobs[0]
    assert job.local.message.startswith("scan: 85 evaluations (points 7, levels 4, starts 1)")
    shown = Results(run.path).summary()
    assert shown["algorithm"]["scan"] == 7
