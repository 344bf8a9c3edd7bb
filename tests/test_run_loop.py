"""One GA loop with hooks: the experiment runner drives GeneticAlgorithm.run, nothing else."""

import numpy as np
import pytest

from evo_door.experiment import (
    ExperimentRun,
    Interrupted,
    Results,
    resume_run,
    run_experiment,
)
from evo_door.experiment.config import AlgorithmSpec
from evo_door.optim import GASettings, GeneticAlgorithm
from evo_door.optim.hooks import EarlyStop
from tests import test_experiment

folder = test_experiment.folder  # the experiment folder fixture: oscillator trials, exp.yaml
load = test_experiment.load


def test_a_run_gives_exactly_what_the_library_loop_gives(folder):
    exp = load(folder, overrides=["algorithm.polish=none"])
    run = run_experiment(exp, out=folder / "r.h5")
    state = GeneticAlgorithm(exp.algorithm.ga).run(run.setup.problem())
    assert np.array_equal(run.result["best_x"], state.best_x)
    assert run.jobs[0].ga.logbook == state.logbook
    assert run.jobs[0].ga_stop == state.stop_reason == "6 generations done"


def test_patience_stops_early_and_a_resumed_run_stops_at_the_same_generation(folder):
    over = ["algorithm.polish=none", "algorithm.generations=60", "algorithm.patience=3"]
    full = run_experiment(load(folder, overrides=over), out=folder / "full.h5")
    stopped_at = full.jobs[0].ga.generation
    assert stopped_at < 60 and full.jobs[0].ga_stop.endswith("not improved for 3 generations")
    mins = full.jobs[0].ga.logbook.select("min")
    assert min(mins[-3:]) >= min(mins[:-3])  # the last three brought nothing

    def kill(run, job):
        if job.ga is not None and job.ga.generation == stopped_at - 2:
            raise Interrupted()

    with pytest.raises(Interrupted):
        run_experiment(load(folder, overrides=over), out=folder / "cut.h5", on_checkpoint=kill)
    resumed = resume_run(folder / "cut.h5")
    assert resumed.jobs[0].ga.generation == stopped_at
    assert np.array_equal(resumed.result["best_x"], full.result["best_x"])
    assert Results(folder / "cut.h5").summary()["algorithm"]["patience"] == 3


def test_patience_is_checked_like_every_setting(folder):
    from evo_door.errors import UserError

    with pytest.raises(UserError, match=r"algorithm\.patience: must be >= 1, got 0"):
        load(folder, overrides=["algorithm.patience=0"])
    with pytest.raises(ValueError, match="patience"):
        EarlyStop(0)


def test_settings_stay_typed_through_the_results_file(folder):
    exp = load(folder, overrides=["algorithm.seed=7", "algorithm.max_iterations=5"])
    assert AlgorithmSpec.from_resolved(exp.resolved()["algorithm"]) == exp.algorithm
    run = ExperimentRun.create(exp, folder / "r.h5")
    reopened = ExperimentRun.open(folder / "r.h5")
    assert reopened.algorithm == exp.algorithm == run.algorithm
    assert isinstance(reopened.algorithm.ga, GASettings) and reopened.algorithm.ga.seed == 7


def test_the_progress_end_line_flags_an_estimate_stopped_by_a_bound(folder, capsys):
    # the trials' true k is 100 N/rad (tests.test_optim.TRUE): a range ending at 60 stops it
    exp = load(folder, overrides=["free.k=[20, 60]", "algorithm.polish=slsqp"])
    run_experiment(exp, out=folder / "r.h5", progress=True)
    err = capsys.readouterr().err
    end = [line for line in err.splitlines() if "best fitness" in line][-1]
    assert "! k on its upper search bound (60 N/rad): widen free.k" in end
    assert "! c " not in end and "inertia on" not in end
