"""A JND file for people: its summary as text (``evo-door show J.h5``) and its two
figures (``evo-door report J.h5``): the track of the session and the psychometric fit.
"""

from __future__ import annotations

import numpy as np

from evo_door.files import save_figure
from evo_door.perception.jnd_file import JndRecord, fitted_curve

#: the proportion correct at the Weber fraction (lapses aside): the 2IFC criterion
CRITERION = 0.75


def format_jnd(record: JndRecord) -> str:
    """The summary of a JND file: what was measured, how, by whom, and the estimate
    with its 95 % interval and the JND setting it informs."""
    r = record
    n = int(len(r.trials.get("step", ())))
    planned = r.attrs.get("trials_planned", n)
    lines = [
        f"JND session: {r.param} at {r.reference:g} {r.unit} (reference), {r.method}, "
        f"{n} of {planned} trials, {r.status}",
        f"  participant {r.participant}, device {r.device}, model {r.model}; asked which "
        f"interval felt {r.word}",
    ]
    fit = r.fit
    if fit is None:
        lines.append(f"  no estimate: {n} answers, too few to fit (10 at least)")
    else:
        lo, hi = fit.ci95
        lines.append(
            f"  Weber fraction {fit.weber:.3g} (1) = {100 * fit.weber:.3g} %, 95 % interval "
            f"[{lo:.3g}, {hi:.3g}] (1); JND {fit.weber * r.reference:.3g} {r.unit} at the "
            "reference"
        )
        lines.append(
            f"  psychometric fit: slope {fit.slope:.3g} (ln units), lapse {fit.lapse:.3g} (1), "
            f"{fit.trials} trials"
        )
        ends = [e for e, o in zip(("lower", "upper"), fit.open_ended, strict=True) if o]
        if ends:
            lines.append(
                f"  the answers do not bound its {' and '.join(ends)} end: run more trials"
            )
    if r.setting is None:
        lines.append(f"  informs no JND setting (a parameter in {r.unit} has none)")
    else:
        lines.append(
            f"  sets the JND setting {r.setting} (a Weber fraction) where it is used: "
            f"perception: {{files: [{r.path.name}]}} in an experiment, or report --jnd-file"
        )
    return "\n".join(lines)


def plot_track(record: JndRecord, path) -> None:
    """The session's track: the step of each trial (log axis), right answers filled,
    wrong ones open, the estimate as a line and its 95 % interval as a band."""
    from matplotlib.figure import Figure

    t = record.trials
    steps = np.asarray(t.get("step", []), dtype=float)
    correct = np.asarray(t.get("correct", []), dtype=bool)
    k = np.arange(1, steps.size + 1)
    fig = Figure(figsize=(7.5, 3.6), layout="constrained")
    ax = fig.subplots()
    ax.plot(k, 100 * steps, color="0.6", lw=0.8, zorder=1)
    ax.scatter(k[correct], 100 * steps[correct], color="tab:green", s=22, label="right", zorder=2)
    ax.scatter(
        k[~correct],
        100 * steps[~correct],
        facecolors="none",
        edgecolors="tab:red",
        s=26,
        label="wrong",
        zorder=2,
    )
    fit = record.fit
    if fit is not None:
        lo, hi = fit.ci95
        ax.axhspan(100 * lo, 100 * hi, color="tab:blue", alpha=0.12, label="95 % interval")
        ax.axhline(100 * fit.weber, color="tab:blue", lw=1.2, label=f"Weber {fit.weber:.3g}")
    ax.set_yscale("log")
    _plain_numbers(ax.yaxis)
    ax.set_xlabel("trial")
    ax.set_ylabel(f"step of {record.param} [%]")
    ax.set_title(f"{record.param} at {record.reference:g} {record.unit}: {record.method} track")
    ax.legend(fontsize=8, loc="upper right")
    save_figure(fig, path)


def _plain_numbers(axis) -> None:
    """A log axis labelled 5, 10, 20 rather than 5 x 10^0."""
    from matplotlib.ticker import FuncFormatter

    plain = FuncFormatter(lambda v, _: f"{v:g}")
    axis.set_major_formatter(plain)
    axis.set_minor_formatter(plain)


def step_bins(steps, correct, per_bin: int = 8):
    """The answers binned by step (log-spaced bins of about ``per_bin`` answers each):
    ``(geometric mean step, proportion correct, count)`` per non-empty bin."""
    steps = np.asarray(steps, dtype=float)
    correct = np.asarray(correct, dtype=bool)
    if steps.size == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)
    n_bins = max(1, min(12, steps.size // per_bin))
    lo, hi = np.log(steps.min()), np.log(steps.max())
    edges = np.linspace(lo, hi + 1e-12, n_bins + 1)
    which = np.clip(np.searchsorted(edges, np.log(steps), side="right") - 1, 0, n_bins - 1)
    x, p, n = [], [], []
    for b in range(n_bins):
        inside = which == b
        if inside.any():
            x.append(float(np.exp(np.log(steps[inside]).mean())))
            p.append(float(correct[inside].mean()))
            n.append(int(inside.sum()))
    return np.array(x), np.array(p), np.array(n, dtype=int)


def plot_psychometric(record: JndRecord, path) -> None:
    """The psychometric fit: the proportion right per step bin (marker area by count,
    the count written beside), the fitted function, its 75 % point at the Weber
    fraction and the fraction's 95 % interval."""
    from matplotlib.figure import Figure

    t = record.trials
    x, p, n = step_bins(t.get("step", []), t.get("correct", []))
    fig = Figure(figsize=(7.5, 4.0), layout="constrained")
    ax = fig.subplots()
    ax.scatter(100 * x, p, s=12 + 6 * n, color="0.35", alpha=0.7, label="answers (per bin)")
    for xi, pi, ni in zip(x, p, n, strict=True):
        ax.annotate(str(ni), (100 * xi, pi), textcoords="offset points", xytext=(6, 4), fontsize=7)
    fit = record.fit
    if fit is not None and x.size:
        cx, cp = fitted_curve(record)
        ax.plot(100 * cx, cp, color="tab:blue", lw=1.5, label="fitted function")
        lo, hi = fit.ci95
        ax.axvspan(100 * lo, 100 * hi, color="tab:blue", alpha=0.12, label="95 % interval")
        at = 0.5 + (0.5 - fit.lapse) * 0.5  # P at the Weber fraction: 75 % lapses aside
        ax.plot([100 * fit.weber] * 2, [0.45, at], color="tab:blue", ls="--", lw=1)
        ax.plot(
            [100 * fit.weber],
            [at],
            "o",
            color="tab:blue",
            label=f"Weber {fit.weber:.3g} ({100 * CRITERION:g} % point)",
        )
    ax.axhline(0.5, color="0.7", lw=0.8, ls=":")
    ax.set_xscale("log")
    _plain_numbers(ax.xaxis)
    ax.set_ylim(0.45, 1.02)
    ax.set_xlabel(f"step of {record.param} [%]")
    ax.set_ylabel("proportion right [1]")
    ax.set_title(f"psychometric fit: which interval felt {record.word}")
    ax.legend(fontsize=8, loc="lower right")
    save_figure(fig, path)
