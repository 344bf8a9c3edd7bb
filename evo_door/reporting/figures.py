"""The figures of a run: its best response next to the target (``show --plot``), its
convergence (``show --convergence``) and its specification's yield loss and doors' band
(:func:`plot_tolerances`); the report embeds them.
"""

from __future__ import annotations

import math
import textwrap

import numpy as np

from evo_door.errors import UserError
from evo_door.experiment.results import Results, finite, fmt_number, theta_unit_of
from evo_door.files import save_figure
from evo_door.optim.problem import Objective
from evo_door.optim.specification import Specification


def plot_fit(res: Results, path, max_trials: int = 12) -> None:
    """Best response next to the target, one panel per trial (fitted, then validation).

    The target is drawn wide and light underneath, the model dashed on top, so that a
    perfect fit shows both; the applied force is a faint trace on its own axis.
    """
    # long: one figure's layout, top to bottom (a helper per panel would hide it)
    from matplotlib.figure import Figure

    from evo_door.channels import title, unit

    rows = res.responses()
    if not rows:
        raise UserError(
            f"{res.path}: the run is not complete, there is no best response yet "
            "(evo-door resume it first)"
        )
    rows = rows[:max_trials]
    n = len(rows)
    ncols = 1 if n == 1 else 2
    nrows = math.ceil(n / ncols)
    fig = Figure(
        figsize=(6.2 * ncols + (2.0 if n == 1 else 0.0), 2.6 * nrows + 1.0), layout="constrained"
    )
    axes = fig.subplots(nrows, ncols, squeeze=False)
    channel = rows[0].channel
    funit = res.fitness_unit
    handles = []
    for ax, r in zip(axes.flat, rows):
        t = np.asarray(r.t)
        axf = ax.twinx()
        # a twin axis is drawn over its host: lift the host (and clear its background)
        # so the responses lie over the force trace, not under it
        ax.set_zorder(axf.get_zorder() + 1)
        ax.patch.set_visible(False)
        (force,) = axf.plot(t, r.force, color="tab:blue", lw=0.6, alpha=0.35, label="force")
        axf.set_ylabel("force [N]", color="tab:blue", fontsize=8)
        axf.tick_params(axis="y", labelcolor="tab:blue", labelsize=7)
        (target,) = ax.plot(
            t, r.target, color="0.55", lw=3.2, alpha=0.6, solid_capstyle="round", label="target"
        )
        (model,) = ax.plot(t, r.model, color="tab:red", lw=1.1, ls="--", label="model (best)")
        handles = [target, model, force]
        ax.set_title(
            f"{r.trial_id} ({'fitted' if r.role == 'fit' else 'validation'}), "
            f"error {fmt_number(finite(r.error))} {funit}",
            fontsize=9,
        )
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"{channel} [{unit(channel, theta_unit_of(res.attrs['model']))}]")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    axes.flat[0].legend(handles=handles, loc="best", fontsize=8)
    obj = res.config["objective"]
    fig.suptitle(
        f"{res.attrs['name']}: {title(channel)}, best model vs target\n"
        f"model {res.attrs['model']}, objective {obj['kind']} (derivative "
        f"{obj['derivative']}, {obj['combine']}), fitness {fmt_number(finite(res.fitness()))} {funit}",
        fontsize=10,
    )
    save_figure(fig, path, dpi=110)


def _stop_text(res: Results, jobs: list) -> str:
    """Why the GA stopped (each job's ``ga_stop``), or where an unfinished run stands."""
    status = res.status()
    if status.state != "complete":
        return status.text if status.state == "interrupted" else f"running ({res.progress()})"
    stops = [(j.name, j.ga_stop) for j in jobs]
    reasons = list(dict.fromkeys(reason for _, reason in stops if reason))
    if len(reasons) <= 1:
        return f"stopped: {reasons[0]}" if reasons else ""
    return "stopped: " + "; ".join(f"{name}: {reason}" for name, reason in stops if reason)


def plot_convergence(res: Results, path) -> None:
    """Best and mean fitness of the population per generation, from the GA's logbook.

    One pair of lines per job (``per_trial``: per fitted trial), log scale; the fitness
    after the SLSQP polish, where there was one, is a star after the last generation. An
    unfinished run shows the generations it has.
    """
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    jobs = [j for j in res.record.jobs if j.ga is not None and np.size(j.ga.logbook["gen"])]
    if not jobs:
        kind = res.config["algorithm"]["kind"]
        why = (
            "it has no genetic algorithm"
            if kind not in ("ga", "nsga2")
            else "no generation is finished yet"
        )
        raise UserError(f"{res.path}: no convergence to plot: {why} (algorithm {kind})")
    fig = Figure(figsize=(7.5, 4.8), layout="constrained")
    ax = fig.subplots()
    several = len(jobs) > 1
    polished = False
    for i, job in enumerate(jobs):
        log = job.ga.logbook
        gen = np.asarray(log["gen"], dtype=float)
        color = f"C{i % 10}"
        label = f"{job.name}: " if several else ""
        # log scale: an exact fit (0) or a population that all blew up (inf) has no point
        best = _positive(log["min"])
        ax.plot(gen, best, color=color, lw=1.8, marker="o", ms=3, label=f"{label}best")
        ax.plot(gen, _positive(log["mean"]), color=color, lw=1.0, ls="--", label=f"{label}mean")
        if job.local_fitness is not None and job.done:
            f = _positive([job.local_fitness])[0]
            if math.isfinite(f):
                polished = True
                x_end = gen[-1] + 0.6
                ax.plot([gen[-1], x_end], [best[-1], f], color=color, lw=0.8, ls=":")
                ax.plot([x_end], [f], color=color, marker="*", ms=11, ls="none")
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("generation")
    ax.set_ylabel(f"fitness [{res.fitness_unit}]")
    ax.grid(alpha=0.3)
    ax.grid(alpha=0.1, which="minor", axis="y")
    handles, labels = ax.get_legend_handles_labels()
    if polished:
        handles.append(Line2D([], [], color="0.3", marker="*", ms=11, ls="none"))
        labels.append("after the SLSQP polish")
    ax.legend(handles, labels, fontsize=8, loc="best", ncols=2 if several else 1)
    obj = res.config["objective"]
    head = (
        f"{res.attrs.get('name', '')}: best and mean fitness of the population per "
        f"generation ({obj['kind']} on {Objective(obj['kind'], obj['derivative']).channel})"
    )
    stop = _stop_text(res, jobs)
    fig.suptitle(
        "\n".join(textwrap.wrap(head, 90) + textwrap.wrap(stop, 90)),
        fontsize=10,
    )
    save_figure(fig, path, dpi=110)


def _positive(values) -> np.ndarray:
    v = np.asarray(values, dtype=float)
    return np.where(np.isfinite(v) & (v > 0), v, np.nan)


def plot_tolerances(spec: Specification, label: str, path) -> None:
    """The report's figure: each specification's contribution to the yield loss (the
    yield gained were it built exactly), and the force-angle band of the yield's sampled
    doors (2.5-97.5 %) against the chosen feel's JND band, per stroke."""
    from matplotlib.figure import Figure

    n = len(spec.names)
    fig = Figure(figsize=(11.0, max(3.6, 0.9 + 0.24 * n)), layout="constrained")
    bars, curves = fig.subplots(1, 2, width_ratios=(1.0, 1.4))
    y = np.arange(n)[::-1]
    colours = ["tab:red" if c else "tab:blue" for c in spec.changed]
    bars.barh(y, 100.0 * spec.loss, color=colours, height=0.6)
    labels = [
        f"{name} +-{t:.3g}" + ("" if u == "1" else f" {u}")
        for name, t, u in zip(spec.names, spec.half_width, spec.units)
    ]
    bars.set_yticks(y, labels, fontsize=7)
    bars.set_xlabel("yield gained were it built exactly [% of doors]")
    y_text = spec.yield_.text().split(" (")[0]
    bars.set_title(f"{label}: yield {y_text}; red = changed from AS-IS", fontsize=10)
    c = spec.curves
    if c:
        deg = np.degrees(c["theta"])
        for d, colour in (("opening", "tab:blue"), ("closing", "tab:red")):
            chosen, jnd = c[f"{d}_chosen"], c[f"{d}_jnd"]
            curves.fill_between(deg, chosen - jnd, chosen + jnd, color=colour, alpha=0.18, lw=0)
            curves.plot(deg, chosen, color=colour, lw=1.0, label=f"{d}: chosen +- JND")
            curves.plot(deg, c[f"{d}_low"], color=colour, lw=0.6, ls="--")
            curves.plot(
                deg, c[f"{d}_high"], color=colour, lw=0.6, ls="--", label=f"{d}: 95 % of doors"
            )
        # the stroke sets the scale: the latch's peaks (the last 3 deg) would flatten it
        stroke = deg <= deg[-1] - 3.0
        parts = [c[f"{d}_{k}"][stroke] for d in ("opening", "closing") for k in ("low", "high")]
        parts += [
            c[f"{d}_chosen"][stroke] + s * c[f"{d}_jnd"][stroke]
            for d in ("opening", "closing")
            for s in (-1, 1)
        ]
        lo, hi = min(map(np.min, parts)), max(map(np.max, parts))
        pad = 0.15 * (hi - lo) + 0.5
        curves.set_ylim(lo - pad, hi + pad)
        curves.set_xlabel("theta [deg] (0 open, 90 closed; the latch's peaks are off scale)")
        curves.set_ylabel("force [N] (+ toward closing)")
        curves.legend(fontsize=7)
        curves.set_title(
            f"doors built to the process: {spec.yield_.samples} drawn, seed {spec.yield_.seed}",
            fontsize=10,
        )
    save_figure(fig, path, dpi=110)
