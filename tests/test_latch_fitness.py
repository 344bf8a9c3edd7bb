"""The case study's latch stage: its fitness along the unlock force has no notch.

A fixed step that crosses a near-jump of the right-hand side (the latch's apex, a
stop's damper) makes the objective jagged: the GA and SLSQP then find minima of the
integration error rather than of the fit. Here the latch stage's own problem (built as
the pipeline builds it, from ``experiments/case_study.yaml`` and the bundled trials,
the physical stage's answer taken as the virtual door's truth) is evaluated on a fine
grid of the unlock force, +-3 % about the truth, the lock force at its truth, and
:func:`notches` holds the curve to one local minimum and a small jaggedness.
"""

import dataclasses

import numpy as np
import pytest

from evo_door.experiment.pipeline import fill, load_pipeline
from evo_door.experiment.setup import resolve
from evo_door.models import get_model
from evo_door.optim.ga import GeneticAlgorithm
from evo_door.optim.multistart import scan_and_polish
from evo_door.optim.problem import Problem

# the fitness checks are compared against references: run again on a generic CPU in CI
# (pyproject markers); the seeds test once (benchmarks --only seeds compares the CPUs)

#: Largest jaggedness (RMS of the second differences over the fitness's range) of a
#: smooth curve on the grid. A curve smooth but for one step of s (a fraction of its
#: range) has jaggedness s sqrt(2 / (n - 2)), 0.09 s on 241 points; noise of RMS a
#: (also over the range) has a sqrt(6). 1.5e-3 admits one step of 1.6 % (the converged
#: objective has one of 0.47 %: a fitted unlock trial stops unlocking when the unlock
#: force passes 40.145 N) or noise of 6e-4; a parabola alone gives 8 / n^2 = 1.4e-4.
JAGGED = 1.5e-3
GRID = 241
TRUE_UNLOCK, TRUE_LOCK = 40.0, 30.0  # N, the default door's (experiments/data/README.md)


def notches(u, f, bound=JAGGED) -> list[str]:
    """What is wrong with ``f`` sampled on the uniform grid ``u`` as the fitness near a
    minimum: more or fewer than one local minimum, jaggedness above ``bound``."""
    f = np.asarray(f, dtype=float)
    inside = (f[1:-1] < f[:-2]) & (f[1:-1] < f[2:])
    minima = np.asarray(u)[1:-1][inside]
    problems = []
    if minima.size != 1:
        where = ", ".join(f"{m:.3f}" for m in minima[:8])
        problems.append(f"{minima.size} local minima (at {where})")
    jag = np.sqrt(np.mean(np.diff(f, 2) ** 2)) / (f.max() - f.min())
    if jag > bound:
        problems.append(f"jaggedness {jag:.2e} above {bound:.1e}")
    return problems


@pytest.fixture(scope="module")
def latch_stage():
    """The latch stage's Problem, as the pipeline makes it (stage ``physical`` taken as
    the truth it lands within 2.3 % of)."""
    pipe = load_pipeline("experiments/case_study.yaml")
    truth = get_model("door").load_params("default").as_dict()
    problem = resolve(fill(pipe.stage("latch").experiment, {"physical": truth})).problem()
    assert problem.free == ("unlock_force", "lock_force")
    return problem


def along_unlock_force(problem):
    """``(u, fitness)``: the unlock force (N) on the grid, lock force at its truth."""
    u = np.linspace(0.97 * TRUE_UNLOCK, 1.03 * TRUE_UNLOCK, GRID)
    fitness, blown = problem.evaluate(np.column_stack([u, np.full(GRID, TRUE_LOCK)]))
    assert not blown.any()
    return u, fitness


def with_steps(problem, method, substeps):
    """The same problem integrated another way."""
    return Problem(
        problem.model,
        problem.free,
        problem.lower,
        problem.upper,
        problem.base,
        problem.fit.trials,
        problem.objective,
        (),
        method,
        substeps,
    )


@pytest.mark.slow
@pytest.mark.numerics
def test_latch_fitness_along_the_unlock_force_has_no_notch(latch_stage):
    u, f = along_unlock_force(latch_stage)
    assert abs(u[f.argmin()] - TRUE_UNLOCK) < 0.05  # N: the fit's answer is the truth
    problems = notches(u, f)
    print(f"{latch_stage.method} x{latch_stage.substeps}: {problems or 'smooth'}")
    assert not problems, f"latch stage ({latch_stage.method}): " + "; ".join(problems)


@pytest.mark.slow
@pytest.mark.numerics
def test_the_notch_check_flags_a_jagged_objective(latch_stage):
    """The same check on the same problem with one RK4 step per sample (jagged where
    the latch gives), and on made-up curves: a parabola passes it, the same with 0.2 %
    noise or a dip does not."""
    u, f = along_unlock_force(with_steps(latch_stage, "rk4", 1))
    problems = notches(u, f)
    assert problems and "jaggedness" in problems[-1], problems
    x = np.linspace(-1.0, 1.0, GRID)
    assert notches(x, x**2) == []
    noisy = x**2 + 2e-3 * np.random.default_rng(1).standard_normal(GRID)
    assert notches(x, noisy)[-1].startswith("jaggedness")
    dip = x**2 - 0.1 * np.exp(-(((x - 0.5) / 0.03) ** 2))
    assert notches(x, dip)[0].startswith("2 local minima")


@pytest.mark.slow
def test_latch_forces_are_the_same_whatever_the_ga_seed(latch_stage):
    """The stage's own algorithm (GA, then ``scan`` and a multi-start polish) over GA
    seeds 1 and 2 gives the unlock and lock forces within 1 % of each other and of the
    virtual door's truth, which the trials carry. Before the scan the unlock force
    ended +4.9, +5.0 % off for seeds 1, 2 (SLSQP started on the plateau beside the
    notch) and -0.03 % for seeds 3..5, which are no longer run: 1 and 2 are the ones
    that failed (``python -m benchmarks --only seeds`` runs the whole main job with
    seeds 1, 2 and 3)."""
    algorithm = load_pipeline("experiments/case_study.yaml").stage("latch").experiment.algorithm
    assert algorithm.scan.enabled
    truth = latch_stage.fit.trials[0].truth["params"]
    truth = np.array([truth[n] for n in latch_stage.free])
    assert truth.tolist() == [TRUE_UNLOCK, TRUE_LOCK]
    answers = []
    for seed in (1, 2):
        ga = GeneticAlgorithm(dataclasses.replace(algorithm.ga, seed=seed)).run(latch_stage)
        answers.append(scan_and_polish(latch_stage, ga.best_x, algorithm.scan, algorithm.local).x)
    answers = np.array(answers)
    print("unlock, lock (N) per seed:", answers.round(3).tolist())
    assert np.all(np.abs(answers / truth - 1.0) < 0.01), answers
    spread = (answers.max(axis=0) - answers.min(axis=0)) / answers.mean(axis=0)
    assert np.all(spread < 0.01), answers
