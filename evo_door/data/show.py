"""Human-facing views of trials: a summary table and the seed-style figure (degrees, labelled)."""

from __future__ import annotations

import math

import numpy as np

from evo_door.data.preprocess import angle_from_rate, find_force_peak, lowpass
from evo_door.data.trial import Trial
from evo_door.errors import UserError

KIND_ORDER = ("unlock", "lock", "impulse", "free", "")


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


def summary_rows(trials: list[Trial]) -> list[dict]:
    rows = []
    deg = 180.0 / math.pi
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
                "theta [deg]": _range(tr.theta, deg, "{:.2f}"),
                "dtheta [deg/s]": _range(tr.dtheta, deg),
                "peak [N]": f"{peak.force:.1f}" if peak else "-",
                "theta0 [deg]": f"{tr.theta0 * deg:.2f}" if tr.theta0 is not None else "-",
                "saturated": ",".join(sat) or "-",
            }
        )
    return rows


def format_summary(trials: list[Trial], path="") -> str:
    """A plain-text table, one trial per line, units in the header (degrees for people)."""
    rows = summary_rows(trials)
    cols = list(rows[0])
    width = {c: max(len(c), *(len(r[c]) for r in rows)) for c in cols}
    lines = ["  ".join(c.ljust(width[c]) for c in cols)]
    lines.append("  ".join("-" * width[c] for c in cols))
    lines += ["  ".join(r[c].ljust(width[c]) for c in cols) for r in rows]
    users = sorted({t.user_id for t in trials if t.user_id})
    head = f"{path}: {len(trials)} trial(s)" + (f", users {', '.join(users)}" if users else "")
    truths = {t.truth.get("model") for t in trials if t.truth}
    if truths:
        src = {t.truth.get("params_source", "") for t in trials if t.truth} - {""}
        head += f"; generated from model {', '.join(sorted(truths))}"
        head += f" ({', '.join(sorted(src))})" if src else ""
    return head + "\n" + "\n".join(lines)


def plot_trials(trials: list[Trial], path, title: str = "") -> None:
    """Force, angle and speed against time, one column per kind, one colour per user.

    Angles and speeds in degrees (labelled). An angle integrated from the gyroscope
    (eq. 3.11) and a speed differentiated from the inclinometer are dashed; the
    sensors' range limits are dotted; unlock / lock force peaks are marked; the speed
    derived from a saturated inclinometer is left out.
    """
    import matplotlib
    from matplotlib.figure import Figure

    from evo_door.files import save_figure

    kinds = sorted(
        {t.kind for t in trials}, key=lambda k: KIND_ORDER.index(k) if k in KIND_ORDER else 99
    )
    users = sorted({t.user_id for t in trials})
    tab10 = matplotlib.colormaps["tab10"]
    colors = {u: tab10(i % 10) for i, u in enumerate(users)}
    fig = Figure(figsize=(4.6 * len(kinds) + 0.8, 8.0), layout="constrained")
    axes = fig.subplots(3, len(kinds), sharex="col", squeeze=False)
    deg = 180.0 / math.pi
    for j, kind in enumerate(kinds):
        ax_f, ax_a, ax_w = axes[:, j]
        limits_drawn = set()
        for tr in (t for t in trials if t.kind == kind):
            c = colors[tr.user_id]
            label = f"{tr.trial_id} ({tr.user_id})" if tr.user_id else tr.trial_id
            ax_f.plot(tr.t, tr.force, color=c, lw=0.9, label=label)
            peak = peak_or_none(tr)
            if peak:
                ax_f.plot(peak.t, peak.force, "v" if peak.force > 0 else "^", color=c, ms=7)
            if tr.theta is not None:
                ax_a.plot(tr.t, tr.theta * deg, color=c, lw=0.9)
            elif tr.dtheta is not None and tr.theta0 is not None:
                ax_a.plot(
                    tr.t, angle_from_rate(tr.t, tr.dtheta, tr.theta0) * deg, "--", color=c, lw=0.9
                )
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
        ax_f.legend(fontsize=7, loc="best")
    if title:
        fig.suptitle(title)
    save_figure(fig, path, dpi=110)
