"""Planning a JND session: how many trials for an estimate within +-20 %?

``python -m benchmarks --only jnd`` runs many simulated sessions (no device: the
psychophysics alone, ``evo_door.perception.procedures.run_simulated``) of a simulated
participant of Weber fraction :data:`TRUTH` (slope 0.4, lapse 2 %), for each method
(staircase, QUEST) and number of trials in :data:`TRIALS`, each session with its own
seed. Per setting it gives the estimates' bias (median estimate over the truth, less
1), their spread (the central 90 % of estimate / truth), the share of sessions within
+-20 % of the truth, the share whose 95 % interval covers it, and the median interval
width. A measured run writes ``benchmarks/jnd.md`` and a figure of the share within
+-20 % against the number of trials.

The answer depends on the participant's slope and lapse rate, which a lab does not
know in advance; these defaults are a typical 2IFC observer, not a measurement.
"""

from __future__ import annotations

import time

import numpy as np

#: the simulated participant's Weber fraction (1) and the reference it is measured at
TRUTH = 0.15
REFERENCE = 10.0
#: numbers of trials per session compared
TRIALS = (20, 40, 80, 160)
METHODS = ("staircase", "quest")
#: sessions per setting (measured run, quick run)
SESSIONS = (200, 4)
#: the planning criterion: an estimate within this relative error
WITHIN = 0.20


def measure(quick: bool) -> list[dict]:
    """One row per (method, trials): the statistics over the sessions."""
    from evo_door.perception.procedures import JndSession, SimParticipant, run_simulated

    n = SESSIONS[1] if quick else SESSIONS[0]
    trials = TRIALS[1:2] if quick else TRIALS  # quick: a smoke run of 40 trials
    rows = []
    for method in METHODS:
        for k in trials:
            est, covered, width = [], 0, []
            tic = time.perf_counter()
            for seed in range(n):
                s = JndSession("p", "N", REFERENCE, method, trials=k, seed=seed, upper=1e3)
                fit = run_simulated(s, SimParticipant(TRUTH, seed=100_000 + seed))
                est.append(fit.weber / TRUTH)
                covered += fit.covers(TRUTH)
                width.append(fit.ci95[1] / fit.ci95[0])
            seconds = (time.perf_counter() - tic) / n
            ratio = np.array(est)
            rows.append(
                {
                    "method": method,
                    "trials": k,
                    "sessions": n,
                    "bias": float(np.median(ratio) - 1.0),
                    "p05": float(np.quantile(ratio, 0.05)),
                    "p95": float(np.quantile(ratio, 0.95)),
                    "within": float(np.mean(np.abs(ratio - 1.0) <= WITHIN)),
                    "coverage": float(covered / n),
                    "width": float(np.median(width)),
                    "seconds": seconds,
                }
            )
    return rows


def trials_needed(rows: list[dict], share: float = 0.9) -> dict:
    """method -> the fewest trials of :data:`TRIALS` with at least ``share`` of the
    sessions within +-20 %, or None."""
    out: dict = {}
    for method in METHODS:
        ok = [r["trials"] for r in rows if r["method"] == method and r["within"] >= share]
        out[method] = min(ok) if ok else None
    return out


def markdown(rows: list[dict], quick: bool) -> str:
    need = trials_needed(rows)
    lines = [
        f"Simulated participant: Weber fraction {TRUTH:g}, slope 0.4 (ln units), lapse 2 %; "
        f"{rows[0]['sessions']} sessions per setting"
        + (" (a quick run: not a measurement)." if quick else "."),
        "",
        "| method | trials | bias | 90 % of estimates within | within +-20 % | interval covers | "
        "median interval (hi/lo) | s per session |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['method']} | {r['trials']} | {100 * r['bias']:+.1f} % | "
            f"{100 * (r['p05'] - 1):+.0f} % to {100 * (r['p95'] - 1):+.0f} % | "
            f"{100 * r['within']:.0f} % | {100 * r['coverage']:.0f} % | "
            f"{r['width']:.2f} | {r['seconds']:.3f} |"
        )
    lines += [""]
    for method, k in need.items():
        lines.append(
            f"- {method}: "
            + (
                f"{k} trials put 90 % of the sessions within +-20 %."
                if k
                else f"no number of trials up to {max(r['trials'] for r in rows)} put 90 % "
                "of the sessions within +-20 %."
            )
        )
    return "\n".join(lines)


def figure(rows: list[dict]):
    """The share of sessions within +-20 % (and the coverage) against the trials."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 3.6))
    for method, style in zip(METHODS, ("o-", "s--")):
        rs = [r for r in rows if r["method"] == method]
        x = [r["trials"] for r in rs]
        ax.plot(x, [100 * r["within"] for r in rs], style, label=f"{method}: within +-20 %")
        ax.plot(x, [100 * r["coverage"] for r in rs], style, alpha=0.4, label=f"{method}: covers")
    ax.axhline(90, color="grey", lw=0.8, ls=":")
    ax.set_xscale("log")
    ax.set_xticks(
        sorted({r["trials"] for r in rows}), [str(t) for t in sorted({r["trials"] for r in rows})]
    )
    ax.set_xlabel("trials per session")
    ax.set_ylabel("sessions (%)")
    ax.set_ylim(0, 102)
    ax.set_title(f"JND sessions of a simulated participant (Weber {TRUTH:g})")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    return fig
