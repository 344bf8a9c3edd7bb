"""Human-facing views of trials: a summary table and the seed-style figure (degrees, labelled)."""

from __future__ import annotations

import math

import numpy as np

from evo_door.data.preprocess import angle_from_rate, find_force_peak, lowpass
from evo_door.data.trial import Trial
from evo_door.errors import UserError

KIND_ORDER = ("unlock", "lock", "impulse", "slow", "free", "")


def _range(x, scale=1.0, fmt="{:.1f}") -> str:
    if x is None:
        return "-"
    return f"{fmt.format(scale * float(np.min(x)))}..{fmt.format(scale * float(np.max(x)))}"


def peak_or_none(trial: Trial):
    if trial.kind not in ("unlock", "lock"):
        return None
    try:
        return find_force_peak(trial)
    except UserError:
        return None


def summary_rows(trials: list[Trial], unit: str = "rad") -> list[dict]:
    """One row per trial; the coordinate in degrees where ``unit`` (the model's
    ``theta_unit``) is rad, else in ``unit`` (a drawer's metres)."""
    rows = []
    deg = 180.0 / math.pi if unit == "rad" else 1.0
    shown = "deg" if unit == "rad" else unit
    fmt = "{:.2f}" if unit == "rad" else "{:.4g}"
    for tr in trials:
        peak = peak_or_none(tr)
        sat = []
        for ch in tr.channels:
            k = int(np.sum(~tr.unsaturated(ch)))
            if k:
                sat.append(f"{ch}:{k}")
        rows.append(
            {
                "trial": tr.trial_id,
                "user": tr.user_id or "-",
                "kind": tr.kind or "-",
                "samples": str(tr.n),
                "duration [s]": f"{tr.duration:.3f}",
                "rate [Hz]": f"{tr.rate:g}",
                "force [N]": _range(tr.force),
                f"theta [{shown}]": _range(tr.theta, deg, fmt),
                f"dtheta [{shown}/s]": (
                    _range(tr.dtheta, deg) if unit == "rad" else _range(tr.dtheta, 1.0, "{:.3g}")
                ),
                "peak [N]": f"{peak.force:.1f}" if peak else "-",
                f"theta0 [{shown}]": ("-" if tr.theta0 is None else fmt.format(tr.theta0 * deg)),
                "saturated": ",".join(sat) or "-",
            }
        )
    return rows


def format_summary(trials: list[Trial], path="", unit: str = "rad") -> str:
    """A plain-text table, one trial per line, units in the header (degrees for people
    where the coordinate is an angle; ``unit``: the model's ``theta_unit``)."""
    rows = summary_rows(trials, unit)
    cols = list(rows[0])
    width = {c: max(len(c), *(len(r[c]) for r in rows)) for c in cols}
    lines = ["  ".join(c.ljust(width[c]) for c in cols)]
    lines.append("  ".join("-" * width[c] for c in cols))
    lines += ["  ".join(r[c].ljust(width[c]) for c in cols) for r in rows]
    users = sorted({t.user_id for t in trials if t.user_id})
    head = f"{path}: {len(trials)} trial(s)" + (f", users {', '.join(users)}" if users else "")
    truths = {t.truth["model"] for t in trials if t.truth and "model" in t.truth}
    if truths:
        src = {t.truth.get("params_source", "") for t in trials if t.truth} - {""}
        head += f"; generated from model {', '.join(sorted(truths))}"
        head += f" ({', '.join(sorted(src))})" if src else ""
    return head + "\n" + "\n".join(lines)


#: matplotlib's tab10 with black for its grey, which the sensor limits (dotted) use.
TRIAL_COLORS = [
    "tab:blue",
    "tab:orange",
    "tab:green",
    "tab:red",
    "tab:purple",
    "tab:brown",
    "tab:pink",
    "black",
    "tab:olive",
    "tab:cyan",
]


def trial_colors(trials: list[Trial], kinds: list[str]) -> dict:
    """A colour per trial id, distinct within each column of the figure.

    Up to ten trials in all: ten distinct colours over the whole figure; more: distinct
    within a column (one column per kind), so two trials side by side never share one.
    """
    import matplotlib

    def palette(n):
        if n <= 10:
            return TRIAL_COLORS[:n]
        if n <= 20:
            return [matplotlib.colormaps["tab20"](i) for i in range(n)]
        return [matplotlib.colormaps["viridis"](i / (n - 1)) for i in range(n)]

    if len(trials) <= 10:
        return dict(zip((t.trial_id for t in trials), palette(len(trials))))
    colors = {}
    for kind in kinds:
        ids = [t.trial_id for t in trials if t.kind == kind]
        colors.update(zip(ids, palette(len(ids))))
    return colors


#: What the line styles of :func:`plot_trials` mean, as its key says it.
STYLE_KEY = {
    "measured": "solid: measured by the trial's sensor",
    "derived": "dashed: derived (angle integrated from the gyroscope, "
    "speed differentiated from the inclinometer)",
    "limit": "dotted: sensor range limit",
    "peak": "triangle: unlock / lock force peak",
}


def plot_trials(trials: list[Trial], path, title: str = "") -> None:
    """Write :func:`trials_figure` to ``path`` (the format from its extension)."""
    from evo_door.files import save_figure

    save_figure(trials_figure(trials, title), path, dpi=110)


def trials_figure(trials: list[Trial], title: str = ""):
    """Force, angle and speed against time, one column per kind, one colour per trial.

    Angles and speeds in degrees (labelled). A key under the panels says what the line
    styles mean: solid is what a sensor measured; dashed is derived, an angle
    integrated from the gyroscope (eq. 3.11) or a speed differentiated from the
    inclinometer (left out where the inclinometer saturates); dotted is a sensor's
    range limit; triangles mark the unlock / lock force peaks. The legend names each
    trial and its user.
    """
    # long: one figure's layout, a column per kind and its three panels top to
    # bottom, with the key of what was drawn; helpers per panel would hide that order
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    kinds = sorted(
        {t.kind for t in trials}, key=lambda k: KIND_ORDER.index(k) if k in KIND_ORDER else 99
    )
    colors = trial_colors(trials, kinds)
    fig = Figure(figsize=(4.6 * len(kinds) + 0.8, 8.6), layout="constrained")
    axes = fig.subplots(3, len(kinds), sharex="col", squeeze=False)
    deg = 180.0 / math.pi
    drawn = set()  # the line styles used, for the key
    for j, kind in enumerate(kinds):
        ax_f, ax_a, ax_w = axes[:, j]
        limits_drawn = set()
        for tr in (t for t in trials if t.kind == kind):
            c = colors[tr.trial_id]
            label = f"{tr.trial_id} ({tr.user_id})" if tr.user_id else tr.trial_id
            ax_f.plot(tr.t, tr.force, color=c, lw=0.9, label=label)
            drawn.add("measured")
            peak = peak_or_none(tr)
            if peak:
                ax_f.plot(peak.t, peak.force, "v" if peak.force > 0 else "^", color=c, ms=7)
                drawn.add("peak")
            if tr.theta is not None:
                ax_a.plot(tr.t, tr.theta * deg, color=c, lw=0.9)
            elif tr.dtheta is not None and tr.theta0 is not None:
                ax_a.plot(
                    tr.t, angle_from_rate(tr.t, tr.dtheta, tr.theta0) * deg, "--", color=c, lw=0.9
                )
                drawn.add("derived")
            if tr.dtheta is not None:
                ax_w.plot(tr.t, tr.dtheta * deg, color=c, lw=0.9)
            elif tr.theta is not None and tr.n > 30:
                smooth = lowpass(tr.theta, tr.rate, min(20.0, 0.45 * tr.rate))
                speed = np.gradient(smooth, tr.t) * deg
                # a pinned inclinometer says nothing about the speed
                valid = tr.unsaturated("theta")
                valid = (
                    np.convolve(valid, np.ones(int(0.05 * tr.rate) | 1), "same")
                    >= int(0.05 * tr.rate) | 1
                )
                ax_w.plot(tr.t, np.where(valid, speed, np.nan), "--", color=c, lw=0.9)
                drawn.add("derived")
            for ch, ax, scale in (
                ("force", ax_f, 1.0),
                ("theta", ax_a, deg),
                ("dtheta", ax_w, deg),
            ):
                rng = tr.sensor(ch).get("range") if getattr(tr, ch) is not None else None
                if rng and ch not in limits_drawn:
                    lo, hi = rng
                    data = getattr(tr, ch)
                    # draw a limit only if the trace comes near it
                    for lim in (lo, hi):
                        if np.min(np.abs(data - lim)) < 0.05 * (hi - lo):
                            ax.axhline(lim * scale, color="0.4", ls=":", lw=1.0)
                            limits_drawn.add(ch)
                            drawn.add("limit")
        ax_f.set_title(
            {
                "unlock": "pull to unlock (from closed)",
                "lock": "push to lock (near closed)",
                "impulse": "impulse from fully open",
            }.get(kind, kind or "trials")
        )
        if j == 0:
            ax_f.set_ylabel("force at handle [N]\n(+ toward closing)")
            ax_a.set_ylabel("door angle [deg]\n(0 open, 90 closed)")
            ax_w.set_ylabel("angular speed [deg/s]\n(- opening)")
        ax_w.set_xlabel("time [s]")
        for ax in (ax_f, ax_a, ax_w):
            ax.grid(alpha=0.3)
        ax_f.legend(fontsize=7, loc="best", title="trial (user)", title_fontsize=7)
    proxies = {
        "measured": Line2D([], [], color="0.2", lw=1.2),
        "derived": Line2D([], [], color="0.2", lw=1.2, ls="--"),
        "limit": Line2D([], [], color="0.4", lw=1.0, ls=":"),
        "peak": Line2D([], [], color="0.2", marker="^", ls="none", ms=7),
    }
    used = [key for key in STYLE_KEY if key in drawn]
    fig.legend(
        [proxies[k] for k in used],
        [STYLE_KEY[k] for k in used],
        loc="outside lower center",
        ncols=min(len(used), 2),
        fontsize=8,
        frameon=False,
    )
    if title:
        fig.suptitle(title)
    return fig
