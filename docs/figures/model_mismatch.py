"""Figure and numbers of ``docs/model-mismatch.md``: residuals of door fits to rich trials.

Usage (after the commands of docs/model-mismatch.md, from the repository root)::

    python docs/figures/model_mismatch.py --model results/mismatch-model.h5 \\
        --rich results/mismatch-rich.h5 \\
        --effect Stribeck=results/mismatch-stribeck.h5 --effect handle=... \\
        --out docs/figures/model-mismatch.png

Prints, per run, the estimates against the true values, the fit and validation errors,
the RMS residual during the push and during the free decay, the mean residual over the
last third of the motion, and the quasi-static force of the fitted door next to the
true door's at mid-decay speed; draws the residuals over time.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from evo_door.experiment.results import Results
from evo_door.files import save_figure
from evo_door.sim import quasi_static_force

DEG = 180.0 / math.pi
#: force (N) above which the hand is pushing; the push starts at its first sample
PUSHING = 1.0
#: speed (rad/s) below which the door counts as stopped
STOPPED = 0.01


def phases(r: dict) -> tuple[float, float, float]:
    """(push start, push end, stop) in s of one stored response."""
    t, force, target = (np.asarray(r[k]) for k in ("t", "force", "target"))
    pushing = np.flatnonzero(force > PUSHING)
    start, end = t[pushing[0]], t[pushing[-1]]
    moving = np.flatnonzero((t > end) & (np.abs(target) > STOPPED))
    stop = t[moving[-1]] if moving.size else end
    return float(start), float(end), float(stop)


def residual_stats(res: Results) -> dict:
    """RMS residual (rad/s) in the push and the decay, mean residual late in the decay."""
    push, decay, late = [], [], []
    for r in res.responses():
        t = np.asarray(r["t"])
        e = np.asarray(r["model"]) - np.asarray(r["target"])
        start, end, stop = phases(r)
        push.append(e[(t >= start) & (t <= end)])
        decay.append(e[(t > end) & (t <= stop)])
        late.append(e[(t > stop - (stop - end) / 3) & (t <= stop)])
    return {
        "push_rms": math.sqrt(np.mean(np.concatenate(push) ** 2)),
        "decay_rms": math.sqrt(np.mean(np.concatenate(decay) ** 2)),
        "late_mean": float(np.mean(np.concatenate(late))),
    }


def feel(res: Results, speed: float = 0.5) -> dict[str, tuple[float, float]]:
    """Force (N) to move the fitted and the true door at ``speed`` rad/s toward closing
    (as in the trials) and toward opening (never in them), mean over 0.5..10 deg."""
    model = res.model
    fitted = res.values()
    true = dict(fitted, **res.truth())
    theta = np.radians(np.linspace(0.5, 10.0, 20))
    out = {}
    for way, v in (("closing", speed), ("opening", -speed)):
        out[way] = tuple(
            float(np.mean(quasi_static_force(model, model.load_params(None, x), theta, v)))
            for x in (fitted, true)
        )
    return out


def report(label: str, res: Results) -> None:
    truth, best = res.truth(), res.best()
    est = ", ".join(
        f"{n} {best[n]:.4g} ({100 * (best[n] / truth[n] - 1):+.1f} %)" for n in res.free
    )
    errors = {r["trial_id"]: (r["role"], float(r["error"])) for r in res.responses()}
    fit = [e for role, e in errors.values() if role == "fit"]
    val = [e for role, e in errors.values() if role != "fit"]
    s = residual_stats(res)
    f = feel(res)
    print(
        f"{label}: {est}; fitness {res.fitness():.3g} (rad/s)^2 s; fit errors "
        f"{min(fit):.2g}..{max(fit):.2g}, validation {', '.join(f'{v:.2g}' for v in val)} "
        f"(rad/s)^2 s; residual RMS push {s['push_rms'] * DEG:.2f} deg/s, decay "
        f"{s['decay_rms'] * DEG:.2f} deg/s, late mean {s['late_mean'] * DEG:+.2f} deg/s; "
        + "; ".join(
            f"force {way} at 0.5 rad/s, 0.5-10 deg: fitted {a:.2f} N, true {b:.2f} N"
            for way, (a, b) in f.items()
        )
    )


def draw(model_run: Results, rich_run: Results, effects: dict[str, Results], out, trial="T03"):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 9.0), layout="constrained")
    ax_fit, ax_res, ax_eff = fig.subplots(3, 1)

    def aligned(r):
        start, _, _ = phases(r)
        return np.asarray(r["t"]) - start

    rows = {r["trial_id"]: r for r in rich_run.responses()}
    r = rows[trial]
    t = aligned(r)
    ax_fit.plot(t, np.asarray(r["target"]) * DEG, color="0.55", lw=3, alpha=0.6,
                label="measured (rich truth, gyroscope)")  # fmt: skip
    ax_fit.plot(t, np.asarray(r["model"]) * DEG, color="tab:red", lw=1.1, ls="--",
                label="best door fit")  # fmt: skip
    axf = ax_fit.twinx()
    axf.plot(t, r["force"], color="tab:blue", lw=0.6, alpha=0.4)
    axf.set_ylabel("load cell [N]", color="tab:blue", fontsize=8)
    axf.tick_params(axis="y", labelcolor="tab:blue", labelsize=7)
    ax_fit.set_title(f"{trial} (fitted): angular speed, rich truth vs door model", fontsize=10)
    ax_fit.set_ylabel("angular speed [deg/s]")
    ax_fit.legend(fontsize=8, loc="upper right")

    colors = ["tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown"]
    for i, r in enumerate(model_run.responses()):
        e = (np.asarray(r["model"]) - np.asarray(r["target"])) * DEG
        ax_res.plot(aligned(r), e, color="0.6", lw=0.6,
                    label="model truth (inverse crime)" if i == 0 else None)  # fmt: skip
    for r, c in zip(rich_run.responses(), colors):
        e = (np.asarray(r["model"]) - np.asarray(r["target"])) * DEG
        role = "fitted" if r["role"] == "fit" else "validation"
        ax_res.plot(aligned(r), e, color=c, lw=1.0, label=f"{r['trial_id']} ({role})")
    ax_res.set_title("residual, fit - measured, every trial: rich truth (colours)", fontsize=10)
    ax_res.set_ylabel("residual [deg/s]")
    ax_res.legend(fontsize=7, ncol=3, loc="lower right")

    for (label, run), c in zip(effects.items(), colors):
        rr = {x["trial_id"]: x for x in run.responses()}[trial]
        e = (np.asarray(rr["model"]) - np.asarray(rr["target"])) * DEG
        ax_eff.plot(aligned(rr), e, color=c, lw=1.0, label=f"{label} only")
    ax_eff.set_title(f"{trial}: residual with one effect at a time", fontsize=10)
    ax_eff.set_ylabel("residual [deg/s]")
    ax_eff.legend(fontsize=8, ncol=2, loc="lower right")

    start, end, _ = phases(rows[trial])
    for ax in (ax_fit, ax_res, ax_eff):
        ax.set_xlim(-0.03, 0.3)
        ax.axvspan(0.0, end - start, color="0.9", zorder=0)
        ax.grid(alpha=0.3)
    ax_eff.set_xlabel(f"time from the start of the push [s] (shaded: the push of {trial})")
    save_figure(fig, out, dpi=100)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True, help="run on the model's own trials")
    ap.add_argument("--rich", required=True, help="run on the rich truth's trials")
    ap.add_argument("--also", action="append", default=[], metavar="LABEL=RUN.h5",
                    help="more runs to report (other seeds)")  # fmt: skip
    ap.add_argument("--effect", action="append", default=[], metavar="LABEL=RUN.h5",
                    help="run on trials with one effect only")  # fmt: skip
    ap.add_argument("--out", required=True, help="figure (.png)")
    args = ap.parse_args(argv)
    model_run, rich_run = Results(args.model), Results(args.rich)
    report("model truth", model_run)
    report("rich truth", rich_run)
    for item in args.also:
        label, _, path = item.partition("=")
        report(label, Results(path))
    effects = {}
    for item in args.effect:
        label, _, path = item.partition("=")
        effects[label] = Results(path)
        report(f"{label} only", effects[label])
    draw(model_run, rich_run, effects, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
