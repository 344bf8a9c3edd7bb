"""Work-precision of a trial: error against time, for every way and every setting.

What the suite's ``trial`` section measures (``benchmarks/suite.py``; its tables,
targets and figure: :mod:`benchmarks.precision_report`). Each model, ``door`` (preset
``default``) and ``haptic`` (preset ``seed_trial``), runs three trials sampled at 1024 Hz:

``smooth``
    no latch: the door pushed from fully open and pulled back
    (:func:`benchmarks.bench_door.force_profile`, the earlier suite's door trial); the
    haptic door swung short of the latch and back
    (:func:`benchmarks.bench_haptic.swing_profile`).
``latch``
    from latched shut, pulled open through the latch, swung, pushed shut
    (:func:`benchmarks.bench_door.latch_profile`;
    :func:`benchmarks.bench_haptic.force_profile`, the earlier suite's haptic trial).
``rig``
    an unlock trial of the virtual rig (one user, seed :data:`RIG_SEED`): a latch
    trial that nobody tuned an integrator on, its force measured with the rig's noise.

Every trial is run by every way at every setting:

- evo-door ``simulate``: the model's defaults; ``dopri5`` (one substep: steps of at
  most one sample, over several where the force is linear) at the tolerances
  :data:`TOLERANCES`; ``rk4`` and ``semi_implicit`` at the sub-steps :data:`SUBSTEPS`.
  Median of repeats, one numba thread.
- scipy ``solve_ivp`` RK45, LSODA, Radau and DOP853 around the compiled ``accel``, at
  the relative tolerances :data:`RTOLS` (atol = rtol / 1000, a step of at most 4
  samples, the force linear between samples: :func:`benchmarks.plain.run_plain`). A
  run is stopped after :data:`TIME_LIMIT` s of CPU time (a sign law's friction can make
  a solver chatter at rest for minutes); once one is, the method's tighter tolerances
  are skipped, all but the plain way's rtol 1e-6. Median of 3 runs when one takes
  less than a second, else one run.
- on the two trials of the earlier suite, also ``solve_ivp`` RK45 and LSODA at rtol
  1e-6 on the model run as pure Python (a fresh process, ``NUMBA_DISABLE_JIT=1``).

Errors are against :func:`tests.reference.converged` (DOP853 sample interval by
sample interval, its switching surfaces and stick-slip as events), whose two
solutions must agree within 1e-9 (or 1e-7: :data:`REFERENCE_BOUNDS`). ``--quick`` runs fewer
settings, fewer repeats, ``solve_ivp`` RK45 and LSODA at rtol 1e-6 only, stopped after
2 s, against the workbench's own ``dopri5`` at tol 1e-12 (a smoke test, not a
reference).

Metric names are ``trial.<model>.<trial>.<way>.<setting>`` (``...default`` for the
model's defaults), with ``.error_theta``, ``.error_dtheta`` and ``.error_dtheta_rms``;
the earlier suite's trials keep its names for the points it had
(:func:`benchmarks.precision_report.metric_name`).
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from benchmarks._util import median_time
from benchmarks.plain import RTOL, pure_python_runs, run_plain

#: Seed of the rig trial's user (any seed gives a trial of the same kind).
RIG_SEED = 2026
#: ``dopri5`` tolerances (per step, rad and rad/s).
TOLERANCES = (1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
#: ``rk4`` and ``semi_implicit`` sub-steps per sample.
SUBSTEPS = (1, 2, 4, 8, 16, 32, 64)
#: ``solve_ivp`` methods and relative tolerances (atol = rtol / 1000).
SCIPY = ("RK45", "LSODA", "Radau", "DOP853")
RTOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
#: CPU time (s) after which a ``solve_ivp`` run is stopped.
TIME_LIMIT = 20.0
#: The same in ``--quick`` (and only RK45 and LSODA).
QUICK: dict[str, Any] = {
    "tolerances": (1e-5, 1e-8),
    "substeps": (1, 8),
    "rtols": (1e-6,),
    "limit": 2.0,
}
#: Repeats of a workbench run (the default's carry the targets).
REPEATS, DEFAULT_REPEATS = 11, 31
#: A ``solve_ivp`` run shorter than this (s) is repeated 3 times.
REPEAT_BELOW = 1.0
#: The reference's two solutions agree within a tenth of the first of these they can
#: (rad and rad/s; :func:`tests.reference.converged`), else it is used as it is.
REFERENCE_BOUNDS = (1e-8, 1e-6)

CLOSED = 0.5 * math.pi


@dataclass(frozen=True)
class BenchTrial:
    """One trial of the section: a sampled force (N, + toward closing) every ``dt`` s
    from ``(theta0, dtheta0)`` (rad, rad/s)."""

    model: str
    key: str
    title: str
    preset: str
    force: np.ndarray
    dt: float
    theta0: float
    dtheta0: float
    latch: bool
    #: whether the earlier suite measured this trial (its metric names are kept)
    legacy: bool = False


@dataclass
class Point:
    """One way at one setting on one trial."""

    way: str
    setting: str
    key: str
    seconds: float | None = None
    repeats: int = 0
    #: (max |theta error| rad, max |dtheta error| rad/s, RMS dtheta error rad/s)
    errors: tuple | None = None
    #: why there is no answer ("" when there is one)
    stopped: str = ""
    extra: dict = field(default_factory=dict)


def bench_trials() -> list[BenchTrial]:
    """The six trials, two models by three kinds."""
    from benchmarks import bench_door, bench_haptic
    from evo_door.data.rig.loop import settle_model
    from evo_door.models import get_model

    door, haptic = get_model("door"), get_model("haptic")
    latched = settle_model(door, door.load_params("default"), CLOSED, bench_door.DT)
    out = []
    for model, preset, key, title, (_, force), start, latch in (
        (
            door,
            "default",
            "smooth",
            "pushed from fully open, pulled back (no latch)",
            bench_door.force_profile(),
            (0.0, 0.0),
            False,
        ),
        (
            door,
            "default",
            "latch",
            "pulled open through the latch, swung, pushed shut",
            bench_door.latch_profile(),
            latched,
            True,
        ),
        (
            haptic,
            "seed_trial",
            "smooth",
            "swung short of the latch and back",
            bench_haptic.swing_profile(),
            (bench_haptic.SWING_THETA0, 0.0),
            False,
        ),
        (
            haptic,
            "seed_trial",
            "latch",
            "pulled open through the latch, swung, pushed shut",
            bench_haptic.force_profile(),
            (haptic.theta0, 0.0),
            True,
        ),
    ):
        legacy = (model.name, key) in (("door", "smooth"), ("haptic", "latch"))
        out.append(
            BenchTrial(
                model.name,
                key,
                title,
                preset,
                force,
                bench_door.DT,
                float(start[0]),
                float(start[1]),
                latch,
                legacy,
            )
        )
    out.insert(2, rig_trial(door, "default"))
    out.append(rig_trial(haptic, "seed_trial"))
    return out


def rig_trial(model, preset) -> BenchTrial:
    """An unlock trial of the virtual rig (:data:`RIG_SEED`), its measured force."""
    from evo_door.data.rig import Campaign, generate_trials

    campaign = Campaign(users=1, trials=1, seed=RIG_SEED, kinds=("unlock",))
    (trial,) = generate_trials(model, model.load_params(preset), campaign, progress=False)
    return BenchTrial(
        model.name,
        "rig",
        f"the rig's unlock trial (seed {RIG_SEED}, noisy force)",
        preset,
        np.asarray(trial.force, dtype=float),
        float(trial.dt),
        float(trial.theta0 or 0.0),
        float(trial.dtheta0 or 0.0),
        True,
    )


def errors_of(theta, dtheta, ref) -> tuple[float, float, float]:
    """Max |theta error| (rad), max and RMS dtheta error (rad/s) against ``ref``."""
    dw = dtheta - ref[1]
    return (
        float(np.max(np.abs(theta - ref[0]))),
        float(np.max(np.abs(dw))),
        float(np.sqrt(np.mean(dw**2))),
    )


def reference(model, p, trial: BenchTrial, quick: bool):
    """``(theta, dtheta, resolution)`` on the samples' grid: the resolution (rad, rad/s)
    is what its two solutions agree within, None where unknown (``--quick``) or
    coarser than the last of :data:`REFERENCE_BOUNDS` / 10."""
    from evo_door.sim import simulate

    if quick:
        r = simulate(
            model,
            p,
            trial.force,
            trial.dt,
            theta0=trial.theta0,
            dtheta0=trial.dtheta0,
            method="dopri5",
            substeps=4,
            tolerance=1e-12,
        )
        return r.theta, r.dtheta, None
    from tests.reference import converged

    kw = {"stick": model.stick_slip, "switches": model.switches, "n_switches": model.n_switches}
    args = (model.accel, p, trial.force, trial.dt, trial.theta0, trial.dtheta0)
    for bound in REFERENCE_BOUNDS:
        try:
            theta, dtheta = converged(*args, bound=bound, **kw)
        except AssertionError:
            continue
        return theta, dtheta, bound / 10
    theta, dtheta = converged(*args, **kw)
    return theta, dtheta, None


def workbench_points(model, p, trial: BenchTrial, ref, quick: bool) -> list[Point]:
    """evo-door ``simulate`` at its defaults and at every setting of each method."""
    from evo_door.sim import simulate
    from evo_door.sim_settings import tolerance_of

    run = partial(
        simulate, model, p, trial.force, trial.dt, theta0=trial.theta0, dtheta0=trial.dtheta0
    )
    tolerances = QUICK["tolerances"] if quick else TOLERANCES
    substeps = QUICK["substeps"] if quick else SUBSTEPS
    default = f"{model.method} x{model.substeps}"
    if model.method == "dopri5":
        default += f", tol {tolerance_of(model):.0e}"
    specs: list[tuple[str, str, str, dict[str, Any]]] = [("default", default, "default", {})]
    specs += [
        (
            "dopri5",
            f"tol {tol:.0e}",
            f"dopri5.tol{tol:.0e}",
            {"method": "dopri5", "substeps": 1, "tolerance": tol},
        )
        for tol in tolerances
    ]
    specs += [
        (m, f"x{n}", f"{m}.x{n}", {"method": m, "substeps": n})
        for m in ("rk4", "semi_implicit")
        for n in substeps
    ]
    out = []
    for way, setting, key, kw in specs:
        r = run(**kw)  # compiles or loads the cache on the first call
        repeats = 3 if quick else (DEFAULT_REPEATS if key == "default" else REPEATS)
        point = Point(way, setting, key, median_time(partial(run, **kw), repeats), repeats)
        if r.ok:
            point.errors = errors_of(r.theta, r.dtheta, ref)
        else:
            point.stopped = "blew up"
        out.append(point)
    return out


def scipy_points(model, p, trial: BenchTrial, ref, quick: bool) -> list[Point]:
    """``solve_ivp`` around the compiled ``accel``, every method at every rtol."""
    limit = QUICK["limit"] if quick else TIME_LIMIT
    y0 = (trial.theta0, trial.dtheta0)
    out = []
    for method in SCIPY[:2] if quick else SCIPY:
        run = partial(
            run_plain, model.accel, p, trial.dt, trial.force, y0, method, time_limit=limit
        )
        run_plain(model.accel, p, trial.dt, trial.force[:64], y0, method, time_limit=limit)
        limited = False
        for rtol in QUICK["rtols"] if quick else RTOLS:
            point = Point(method, f"rtol {rtol:.0e}", f"{method.lower()}.rtol{rtol:.0e}")
            out.append(point)
            if limited and rtol != RTOL:
                point.stopped = "skipped (a looser rtol hit the time limit)"
                continue
            runs = [run(rtol=rtol)]
            if runs[0].complete and runs[0].seconds < REPEAT_BELOW and not quick:
                runs += [run(rtol=rtol) for _ in range(2)]
            finish(point, runs, ref, limit)
            limited = limited or runs[0].stopped == "time limit"
    return out


def finish(point: Point, runs, ref, limit: float) -> None:
    """Fill ``point`` from its ``solve_ivp`` runs (:class:`benchmarks.plain.PlainRun`)."""
    first = runs[0]
    point.repeats = len(runs)
    if first.complete:
        point.seconds = statistics.median(r.seconds for r in runs)
        point.errors = errors_of(first.theta, first.dtheta, ref)
    elif first.stopped == "time limit":
        point.stopped = f"no answer within {limit:g} s of CPU (at t = {first.reached:.3f} s)"
        point.extra["lower_bound"] = first.seconds
    else:
        point.stopped = f"stopped at t = {first.reached:.3f} s after {first.seconds:.3g} s: " + (
            first.stopped
        )


def pure_python_points(model, trial: BenchTrial, ref, quick: bool) -> list[Point]:
    """``solve_ivp`` RK45 and LSODA at rtol 1e-6 on the pure-Python model (one run each)."""
    limit = QUICK["limit"] if quick else TIME_LIMIT
    methods = ("RK45", "LSODA")
    points = [
        Point(f"{m}, pure Python", f"rtol {RTOL:.0e}", f"{m.lower()}_python.rtol{RTOL:.0e}")
        for m in methods
    ]
    try:
        runs = pure_python_runs(
            model.name,
            trial.preset,
            trial.force,
            trial.dt,
            (trial.theta0, trial.dtheta0),
            methods,
            time_limit=limit,
        )
    except RuntimeError as exc:
        for point in points:
            point.stopped = str(exc)
        return points
    for point, method in zip(points, methods):
        finish(point, [runs[method]], ref, limit)
    return points


def measure(trial: BenchTrial, quick: bool, say=lambda text: None):
    """Every point of ``trial`` and its reference's resolution (:func:`reference`)."""
    from evo_door.models import get_model
    from evo_door.sim.simulate import param_vector

    model = get_model(trial.model)
    p = param_vector(model.load_params(trial.preset))
    say(f"trial {trial.model} {trial.key}: reference")
    theta, dtheta, resolution = reference(model, p, trial, quick)
    ref = (theta, dtheta)
    assert model.accel is not None, "the precision benchmark runs models given by accel"
    model.accel(trial.theta0, 0.0, 0.0, p)  # the dispatcher's Python entry, compiled
    say(f"trial {trial.model} {trial.key}: evo-door")
    points = workbench_points(model, p, trial, ref, quick)
    say(f"trial {trial.model} {trial.key}: solve_ivp")
    points += scipy_points(model, p, trial, ref, quick)
    if trial.legacy:
        points += pure_python_points(model, trial, ref, quick)
    return points, resolution
