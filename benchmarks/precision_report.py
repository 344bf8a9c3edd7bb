"""The trial section's output: metrics and targets, a table per trial, the figure.

What :mod:`benchmarks.precision` measured, as the suite records it: every point a
metric (seconds, and its three errors), the targets on the model's defaults, a
Markdown table per model and trial and the work-precision figure (max |dtheta error|
against seconds per trial, log-log, one line per way).
"""

from __future__ import annotations

import math
from typing import Any

from benchmarks.plain import RTOL
from benchmarks.precision import (
    DEFAULT_REPEATS,
    QUICK,
    REFERENCE_BOUNDS,
    REPEAT_BELOW,
    REPEATS,
    SCIPY,
    TIME_LIMIT,
    BenchTrial,
    Point,
)

#: Latch trials: the default within these of the reference (rad, rad/s) and at least
#: this many times faster than LSODA at rtol 1e-6 in the same run.
LATCH_THETA_TARGET = 1e-4
LATCH_DTHETA_TARGET = 1e-2
LSODA_RATIO_TARGET = 10.0
#: Smooth trials: (seconds, rad, rad/s) of the default. The door's are the earlier
#: suite's figures for this trial (benchmarks/suite.md of 2026-11-23, commit c34c99d);
#: the haptic model had no smooth trial there: its time is that suite's haptic trial's
#: and its accuracy the latch trials' targets (tighter than that trial's 1.22e-2 rad,
#: 1.25 rad/s).
SMOOTH_TARGETS = {"door": (2.68e-3, 2.52e-8, 1.28e-5), "haptic": (1.69e-3, 1e-4, 1e-2)}
#: Names the earlier suite gave: point key -> name after ``trial.<model>.``.
LEGACY = {
    "default": "workbench",
    "rk45.rtol1e-06": "rk45_compiled",
    "lsoda.rtol1e-06": "lsoda_compiled",
    "rk45_python.rtol1e-06": "rk45_python",
    "lsoda_python.rtol1e-06": "lsoda_python",
}


def metric_name(trial: BenchTrial, key: str) -> str:
    """The metric of point ``key`` on ``trial`` (the earlier suite's name where it had one)."""
    if trial.legacy and key in LEGACY:
        return f"trial.{trial.model}.{LEGACY[key]}"
    return f"trial.{trial.model}.{trial.key}.{key}"


def met_at_print(value: float, target: float) -> bool:
    """``value <= target`` as the tables print them (3 significant digits)."""
    return float(f"{value:.3g}") <= target


def record(suite, trial: BenchTrial, points: list[Point]) -> None:
    """Every point as metrics (seconds and three errors), and the trial's targets."""
    default = points[0]
    for point in points:
        name = metric_name(trial, point.key)
        label = f"{trial.model} {trial.key}: {point.way} {point.setting}"
        kw = {}
        if point.key != "default" and name != f"trial.{trial.model}.{trial.key}.{point.key}":
            # the earlier suite's plain ways keep their speed-up over its workbench figure
            if point.seconds is not None:
                kw = {
                    "ratio": point.seconds / (default.seconds or math.nan),
                    "ratio_to": metric_name(trial, "default"),
                }
        elif point.key == "default" and not trial.latch:
            target = SMOOTH_TARGETS[trial.model][0]
            kw = {
                "target": target,
                "target_text": f"<= {target * 1e3:g} ms (the earlier suite)",
                "met": met_at_print(point.seconds or math.nan, target),
            }
        suite.add(name, "trial", label, point.seconds, "s", note=point.stopped or None, **kw)
        errors = point.errors or (None, None, None)
        targets = error_targets(trial) if point.key == "default" else (None, None, None)
        for suffix, what, unit, value, target in zip(
            ("error_theta", "error_dtheta", "error_dtheta_rms"),
            ("max |theta error|", "max |dtheta error|", "RMS dtheta error"),
            ("rad", "rad/s", "rad/s"),
            errors,
            targets,
        ):
            kw = {}
            if target is not None:
                kw = {
                    "target": target,
                    "target_text": f"<= {target:.3g} {unit}",
                    "met": None if value is None else met_at_print(value, target),
                }
            suite.add(f"{name}.{suffix}", "trial", f"{label}, {what}", value, unit, **kw)
    if trial.latch:
        record_lsoda_ratio(suite, trial, points)


def error_targets(trial: BenchTrial) -> tuple:
    """Targets of the default's (max theta, max dtheta, RMS dtheta) errors (rad, rad/s)."""
    if trial.latch:
        return LATCH_THETA_TARGET, LATCH_DTHETA_TARGET, None
    return (*SMOOTH_TARGETS[trial.model][1:], None)


def record_lsoda_ratio(suite, trial: BenchTrial, points: list[Point]) -> None:
    """LSODA at rtol 1e-6 over the default's time, with its ``>= 10x`` target."""
    default = points[0]
    lsoda = next(pt for pt in points if pt.key == f"lsoda.rtol{RTOL:.0e}")
    value, note, met = None, None, None
    if lsoda.seconds is not None:
        value = lsoda.seconds / (default.seconds or math.nan)
        met = value >= LSODA_RATIO_TARGET
    elif "lower_bound" in lsoda.extra:
        value = lsoda.extra["lower_bound"] / default.seconds
        met = value >= LSODA_RATIO_TARGET
        note = f"at least: LSODA gave {lsoda.stopped}"
    else:
        note = f"LSODA gave no answer: {lsoda.stopped}"
    suite.add(
        f"trial.{trial.model}.{trial.key}.lsoda_over_default",
        "trial",
        f"{trial.model} {trial.key}: LSODA rtol 1e-6 time / the default's",
        value,
        "1",
        target_text=f">= {LSODA_RATIO_TARGET:g}x",
        met=met,
        note=note,
    )


def reference_text(resolution, quick: bool) -> str:
    """What the errors are judged against."""
    if quick:
        return "evo-door's own dopri5 x4 at tol 1e-12 (--quick: a smoke test, not a reference)"
    if resolution is None:
        return "`converged`, its two solutions more than 1e-7 apart (smaller errors unresolved)"
    return f"`converged`, its two solutions within {resolution:.0e}"


def table(trial: BenchTrial, points: list[Point], resolution, quick: bool = False) -> str:
    """The trial's Markdown: what it is, then one row per point."""
    default = points[0]
    n = trial.force.size
    lines = [
        f"### {trial.model}, {trial.key}: {trial.title}",
        "",
        f"{n} samples ({n * trial.dt:.2f} s at {1 / trial.dt:g} Hz), preset `{trial.preset}`, "
        f"from {trial.theta0:.4f} rad at {trial.dtheta0:.3g} rad/s; reference: "
        f"{reference_text(resolution, quick)}.",
        "",
        "| way | setting | seconds per trial | / default | max abs theta error (rad) "
        "| max abs dtheta error (rad/s) | RMS dtheta error (rad/s) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for point in points:
        way = "**default**" if point.key == "default" else point.way
        if point.seconds is None:
            lines.append(f"| {way} | {point.setting} | {point.stopped} | | | | |")
            continue
        ratio = point.seconds / (default.seconds or math.nan)
        errors = point.errors or ("n/a",) * 3
        cells = " | ".join(e if isinstance(e, str) else f"{e:.2e}" for e in errors)
        note = f" ({point.stopped})" if point.stopped else ""
        lines.append(
            f"| {way} | {point.setting} | {fmt_seconds(point.seconds)}{note} | {ratio:.3g} "
            f"| {cells} |"
        )
    return "\n".join(lines)


def fmt_seconds(value: float) -> str:
    """Seconds as s / ms / us."""
    if value >= 1:
        return f"{value:.3g} s"
    if value >= 1e-3:
        return f"{value * 1e3:.3g} ms"
    return f"{value * 1e6:.3g} us"


#: Colour and style of each way in the figure.
STYLES = {
    "dopri5": ("tab:blue", "o-"),
    "rk4": ("tab:orange", "s-"),
    "semi_implicit": ("tab:green", "^-"),
    "RK45": ("tab:red", "v--"),
    "LSODA": ("tab:purple", "D--"),
    "Radau": ("tab:brown", "P--"),
    "DOP853": ("tab:pink", "X--"),
    "RK45, pure Python": ("tab:red", "v"),
    "LSODA, pure Python": ("tab:purple", "D"),
}
#: Smallest and largest error the figure shows (rad/s; an exact 0 is drawn at the first).
FLOOR, CEILING = 1e-14, 1e3


def figure(results, quick: bool):
    """Max |dtheta error| against seconds per trial, one panel per trial, one line per
    way (log-log), the default a star, the latch targets dotted; an error beyond
    :data:`CEILING` is drawn on it (the tables give its value)."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter

    def shown(error):
        return min(max(error, FLOOR), CEILING)

    fig = Figure(figsize=(16, 10), layout="constrained")
    axes = fig.subplots(2, 3, squeeze=False)
    handles: dict[str, Any] = {}
    for (trial, points, resolution), ax in zip(results, axes.flat):
        for way, (color, style) in STYLES.items():
            got = [pt for pt in points if pt.way == way and pt.key != "default" and pt.errors]
            if got:
                (line,) = ax.loglog(
                    [pt.seconds for pt in got],
                    [shown(pt.errors[1]) for pt in got],
                    style,
                    color=color,
                    ms=5,
                    mfc="none" if "pure" in way else color,
                    label=way,
                )
                handles.setdefault(way, line)
        default = points[0]
        if default.errors:
            at = (default.seconds, shown(default.errors[1]))
            (star,) = ax.loglog(*at, "*", ms=16, color="gold", mec="k", label="evo-door default")
            handles.setdefault("evo-door default", star)
            ax.annotate(f" {default.setting}", at, fontsize=7)
        if trial.latch:
            ax.axhline(LATCH_DTHETA_TARGET, color="k", ls=":", lw=0.8)
        if not quick:
            ax.axhspan(FLOOR / 10, resolution or REFERENCE_BOUNDS[-1] / 10, color="0.9", zorder=0)
        remarks = []
        missing = sorted({pt.way for pt in points if pt.errors is None})
        if missing:
            remarks.append("no answer at some settings: " + "; ".join(missing))
        off = [f"{pt.way} {pt.setting}" for pt in points if pt.errors and pt.errors[1] > CEILING]
        if off:
            remarks.append(f"drawn at {CEILING:g} rad/s, off scale: " + "; ".join(off))
        ax.text(0.02, 0.02, "\n".join(remarks), transform=ax.transAxes, fontsize=7, va="bottom")
        ax.set_title(f"{trial.model}, {trial.key}: {trial.title}", fontsize=9)
        ax.set_xlabel("seconds per trial (one thread)")
        ax.set_ylabel("max |dtheta error| (rad/s)")
        ax.grid(True, which="major", lw=0.3)
        low, high = ax.get_xlim()
        if high > 10 * low:  # labels on the decades only (else they crowd)
            ax.xaxis.set_minor_formatter(NullFormatter())
    fig.legend(list(handles.values()), list(handles), loc="outside lower center", ncol=10)  # type: ignore[call-overload]
    shade = "" if quick else "; grey: below the reference's resolution"
    fig.suptitle(
        "Work-precision: error against time per way and setting (dotted: the latch trials' "
        f"target{shade})" + (" --quick: a smoke run" if quick else ""),
        fontsize=11,
    )
    return fig


def intro(quick: bool, load: float) -> str:
    """What the section's tables hold, how they were measured."""
    limit = QUICK["limit"] if quick else TIME_LIMIT
    repeats = "3 runs" if quick else f"{REPEATS} runs, {DEFAULT_REPEATS} for the default"
    scipy = "RK45 and LSODA" if quick else ", ".join(SCIPY)
    reference = (
        "evo-door's own `dopri5` x4 at tol 1e-12 (--quick: a smoke test, not a reference)"
        if quick
        else "`tests.reference.converged` (DOP853 sample interval by sample interval, "
        "the model's switching surfaces and stick-slip as events, two tolerances that "
        "must agree; each table says within what)"
    )
    return (
        "Work-precision (`benchmarks/precision.py`): one smooth trial and two latch trials "
        "per model, each by every way at every setting; its time per trial on one numba "
        f"thread (evo-door: median of {repeats}; `solve_ivp`: median of 3 runs when one "
        f"takes under {REPEAT_BELOW:g} s, else one run) and its errors against {reference}. "
        f"Load average {load:.2f} when the section started. `solve_ivp` ({scipy}): around "
        "the compiled `accel`, atol = rtol / 1000, a step of at most 4 samples, the force "
        "linear between samples as the compiled integrators read it; a run is stopped after "
        f"{limit:g} s of CPU time, and then the method's tighter tolerances are skipped "
        "(but rtol 1e-6): the haptic model's dry friction is a sign law, on which "
        "`solve_ivp` chatters once the door comes to rest. Pure Python: the same, "
        "`NUMBA_DISABLE_JIT=1`, in a fresh process. evo-door `dopri5`: steps of at most "
        "one sample, over up to 16 where the force is linear over at least 4 "
        "(docs/integration.md). / default: the time over the model's default's. "
        "Targets: on the latch "
        f"trials, the default within {LATCH_THETA_TARGET:g} rad and "
        f"{LATCH_DTHETA_TARGET:g} rad/s of the reference and at least "
        f"{LSODA_RATIO_TARGET:g}x faster than LSODA at rtol 1e-6; on the smooth trials, "
        "the earlier suite's figures (2026-11-23); judged as printed, to 3 digits."
    )
