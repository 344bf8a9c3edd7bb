"""The main job's estimates across GA seeds and CPUs: do they agree within what they state?

``python -m benchmarks --only seeds`` runs ``evo-door run experiments/case_study.yaml``
with every stage's GA seed 1, 2 and 3, and once more with seed 1 and numba compiling
for a generic x86-64 CPU (``NUMBA_CPU_NAME=generic``, a cache of its own: other vector
widths and FMA change the last bits, and a GA may then take another path). For every
stage and every estimate, it gives the spread over the runs against the interval the
run states for it (the identifiability check's half-width), and whether the verdicts
agree: an estimate called identifiable whose spread exceeds its interval is a claim
the runs do not bear out. A measured run writes ``benchmarks/seeds.md``.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

#: the runs: (label, --set overrides of every stage's algorithm, environment)
RUNS: tuple[tuple[str, tuple[str, ...], dict[str, str]], ...] = (
    ("seed 1", ("seed=1",), {}),
    ("seed 2", ("seed=2",), {}),
    ("seed 3", ("seed=3",), {}),
    ("seed 1, generic CPU", ("seed=1",), {"NUMBA_CPU_NAME": "generic"}),
)


def estimates(path: Path) -> dict:
    """stage -> parameter -> (value, relative half-width, verdict), from a results file."""
    from evo_door.experiment import Results
    from evo_door.experiment.pipeline_status import pipeline_summary

    out: dict = {}
    summary = pipeline_summary(path)
    assert summary is not None, path  # (a pipeline's results file: the run just made)
    for st in summary["stages"]:
        res = Results(path, st["name"])
        s = res.summary()
        ident = s.get("identifiability", {})
        out[st["name"]] = {
            n: (
                float(s["best"][n]),
                float(ident[n]["ci_rel"]) if n in ident else math.nan,
                ident[n]["verdict"] if n in ident else "-",
            )
            for n in res.free
        }
    return out


def measure(quick: bool) -> dict:
    """Every run of :data:`RUNS` (the first alone with ``quick``): label -> (wall s,
    :func:`estimates`)."""
    from benchmarks.bench_casestudy import run_pipeline

    done = {}
    runs = RUNS[:1] if quick else RUNS  # a smoke test: one run is enough
    with tempfile.TemporaryDirectory() as tmp:
        for k, (label, settings, env) in enumerate(runs):
            env = dict(env)
            if env:
                env["NUMBA_CACHE_DIR"] = str(Path(tmp) / f"cache-{k}")
            out = Path(tmp) / f"run-{k}.h5"
            wall = run_pipeline(out, quick, settings, env)
            done[label] = (wall, estimates(out))
    return done


def agreement(done: dict) -> list[dict]:
    """One row per stage and estimate: the values, their spread relative to their mean,
    the widest stated interval, the verdicts, and whether a claim fails."""
    runs = list(done.values())
    rows = []
    first = runs[0][1]
    for stage, params in first.items():
        for name in params:
            values = [r[1][stage][name][0] for r in runs if name in r[1].get(stage, {})]
            cis = [r[1][stage][name][1] for r in runs if name in r[1].get(stage, {})]
            verdicts = [r[1][stage][name][2] for r in runs if name in r[1].get(stage, {})]
            mean = sum(values) / len(values)
            spread = (max(values) - min(values)) / 2 / abs(mean) if mean else math.inf
            claimed = [c for c, v in zip(cis, verdicts) if v in ("identifiable", "correlated")]
            fails = bool(claimed) and spread > min(claimed)
            rows.append(
                {
                    "stage": stage,
                    "name": name,
                    "values": values,
                    "spread": spread,
                    "ci": max((c for c in cis if math.isfinite(c)), default=math.nan),
                    "verdicts": verdicts,
                    "fails": fails,
                }
            )
    return rows


def markdown(done: dict, rows: list[dict]) -> str:
    """The page's tables: the runs' wall times, then every estimate's agreement."""
    labels = list(done)
    lines = [
        "| run | wall time |",
        "|---|---:|",
        *[f"| {label} | {done[label][0]:.0f} s |" for label in labels],
        "",
        "Half the spread of each estimate over the runs, relative to its mean, against "
        "the widest relative half-width a run states for it (its identifiability "
        "interval). **claim fails**: a run calls the estimate identifiable (or correlated, "
        "still pinned) and the runs spread wider than it says.",
        "",
        "| stage | parameter | " + " | ".join(labels) + " | spread | stated | verdicts | |",
        "|---|---|" + "---:|" * len(labels) + "---:|---:|---|---|",
    ]
    for r in rows:
        vals = " | ".join(f"{v:.5g}" for v in r["values"])
        ci = "-" if not math.isfinite(r["ci"]) else f"+-{100 * r['ci']:.3g} %"
        verdicts = ", ".join(sorted(set(r["verdicts"])))
        lines.append(
            f"| {r['stage']} | {r['name']} | {vals} | +-{100 * r['spread']:.3g} % | {ci} | "
            f"{verdicts} | {'**claim fails**' if r['fails'] else ''} |"
        )
    failing = [f"{r['stage']}.{r['name']}" for r in rows if r["fails"]]
    lines += [
        "",
        f"Claims the runs do not bear out: {', '.join(failing)}."
        if failing
        else "Every estimate a run calls identifiable agrees over the runs within its "
        "stated interval.",
    ]
    return "\n".join(lines)
