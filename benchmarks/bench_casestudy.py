"""The main job, measured: ``evo-door run experiments/case_study.yaml`` once, timed.

What the README and ``docs/case-study.md`` say about the main job (how long it takes,
how close the door's estimates come to the virtual door's truth, how well each stage
fits, what the perceptual check finds) is quoted from this benchmark's output, so that
a new run on another machine refreshes every figure at once:

    python -m benchmarks --only casestudy     # writes benchmarks/casestudy.md too

The run happens in a fresh process, as a user types it (start-up and numba's cache
loading included in the wall time); the figures are then read back from its results
file. ``quick=True`` shrinks every stage's GA (population 8, 1 generation, 2 SLSQP steps):
a smoke test of this code, not a measurement.
"""

from __future__ import annotations

import math
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
PIPELINE = ROOT / "experiments" / "case_study.yaml"

#: the main job's budget (s of wall time on 2 cores)
BUDGET_S = 120.0
#: every stage's GA in a --quick run: enough to exercise the code, nothing more (the
#: polish and the scans stay, each cut to two SLSQP iterations)
QUICK_SETTINGS = ("population=8", "generations=1", "max_iterations=2")
#: doors of the independent check of a specification's yield: measured, --quick
CHECK_DOORS, QUICK_CHECK_DOORS = 2000, 500


def stage_names(pipeline: Path) -> list[str]:
    """The stages the pipeline file declares, in order."""
    import yaml

    return list(yaml.safe_load(pipeline.read_text())["stages"])


def run_pipeline(out: Path, quick: bool, settings=(), env=None) -> float:
    """Run the main job (the pipeline :data:`PIPELINE` names when called; the tests put
    a small one in its place) into ``out`` in a fresh process; its wall time (s).

    ``settings`` are ``--set`` overrides of every stage's algorithm (``seed=3``), ``env``
    extra environment variables (``NUMBA_CPU_NAME``)."""
    from benchmarks._util import evo_door_command

    args = ["run", PIPELINE, "--out", out, "--quiet"]
    for stage in stage_names(PIPELINE):
        for setting in (*(QUICK_SETTINGS if quick else ()), *settings):
            args += ["--set", f"stages.{stage}.algorithm.{setting}"]
    return evo_door_command(args, env, cwd=ROOT)[0]


def stage_figures(path: Path, stage: str) -> dict:
    """One stage's time, evaluations, fitness, per-trial errors and parameters."""
    from evo_door.experiment import Results

    res = Results(path, stage)
    s = res.summary()
    errors = s.get("channel_errors", {})
    fit = [e for e in errors.values() if e["role"] == "fit"]
    val = [e for e in errors.values() if e["role"] != "fit"]
    ident = s.get("identifiability", {})
    params = []
    for name in res.free:
        value = s["best"][name]
        true = s["truth"].get(name)
        row = {
            "name": name,
            "unit": s["units"].get(name, ""),
            "value": value,
            "true": true,
            "error_pct": None if not true else 100.0 * (value - true) / true,
            "ci_pct": None,
            "verdict": "",
            "partner": "",
            "partner_r": None,
        }
        if name in s.get("table", {}):
            row["min"], row["max"] = s["table"][name]["min"], s["table"][name]["max"]
        if name in ident:
            i = ident[name]
            row["ci_pct"] = 100.0 * i["ci_rel"] if math.isfinite(i["ci_rel"]) else None
            row["verdict"] = i["verdict"]
            row["partner"], row["partner_r"] = i["partner"] or "", i["partner_r"]
        params.append(row)
    return {
        "stage": stage,
        "model": s["model"],
        "seconds": s["seconds"],
        "evaluations": s["evaluations"],
        "fitness": s["fitness"],
        "fitness_unit": s["fitness_unit"],
        "channel": (fit or val or [{"channel": "", "unit": ""}])[0]["channel"],
        "channel_unit": (fit or val or [{"channel": "", "unit": ""}])[0]["unit"],
        "rms_fit": [e["rms"] for e in fit],
        "rms_validation": [e["rms"] for e in val],
        "params": params,
    }


def perceptual(path: Path, stages: list[str]) -> list[dict]:
    """The perceptual check of every stage fitted to a chosen feel, as its results file
    holds it (the haptic model against the door, the specification and the redesign
    against the chosen feel), each at its own JND settings."""
    from evo_door.experiment import Results

    out = []
    for stage in stages:
        res = Results(path, stage)
        check = res.record.perceptual_check
        if check is None or not res.complete:
            continue
        judged = check.judged()
        row: dict = {
            "stage": stage,
            "chosen": judged["chosen"],
            "jnd": judged["jnd"],
            "worst_jnd": judged["worst_jnd"],
            "worst": judged["worst"],
            "passes": judged["passes"],
        }
        for d in ("opening", "closing"):
            c = judged[d]
            row[d] = {
                "worst_jnd": c["worst_jnd"],
                "worst_n": c["worst"]["difference_N"],
                "worst_deg": c["worst"]["angle_deg"],
                "jnd_n": c["worst"]["jnd_N"],
                "stroke_jnd": c["worst"]["jnd_units"],
                "peak_jnd": c["latch_peak"]["jnd_units"],
                "angle_jnd": c["peak_angle"]["jnd_units"],
                "verdict": c["verdict"],
            }
        out.append(row)
    return out


def specification(path: Path, stages: list[str], quick: bool = False) -> list[dict]:
    """What each stage with a specification a supplier builds states (its yield, the
    design, the allocation and the nearest feel where out of reach, the largest
    contributors to the yield loss) and the independent check of its yield on fresh
    doors (:mod:`benchmarks.yield_check`)."""
    from benchmarks.yield_check import check_file
    from evo_door.experiment import Results

    out = []
    for stage in stages:
        res = Results(path, stage)
        spec = res.record.tolerance
        if spec is None or not res.complete:
            continue
        got = check_file(path, stage, QUICK_CHECK_DOORS if quick else CHECK_DOORS, seed=7)
        loss = sorted(zip(spec.loss, spec.names), reverse=True)[:5]
        t = dict(zip(spec.names, spec.half_width))
        out.append(
            {
                "stage": stage,
                "yield": spec.yield_.as_dict(),
                "independent": got["independent"],
                "difference_points": got["difference_points"],
                "reachable": spec.reachable,
                "design": spec.design,
                "nominal_margin": spec.nominal_margin,
                "alternative": (
                    {
                        "design": spec.alternative["design"],
                        "yield": spec.alternative["yield"].as_dict(),
                    }
                    if spec.alternative
                    else None
                ),
                "worst": spec.worst,
                "losses": [(n, float(v)) for v, n in loss if v > 0.0],
                "allocation": {
                    n: {"process": float(t[n]), "tightened": w} for n, w in spec.allocation.items()
                },
                "allocation_yield": (
                    spec.allocation_yield.as_dict() if spec.allocation_yield else None
                ),
                "nearest": spec.nearest.as_dict() if spec.nearest is not None else None,
                "units": dict(zip(spec.names, spec.units)),
            }
        )
    return out


def figures(path: Path, wall: float, quick: bool = False) -> dict:
    """Everything the section reports, from the main job's results file."""
    from evo_door.experiment.pipeline_status import pipeline_summary

    summary = pipeline_summary(path)
    stages = [s["name"] for s in summary["stages"]]
    return {
        "wall": wall,
        "total": summary["total_s"],
        "stages": [stage_figures(path, s) for s in stages],
        "perceptual": perceptual(path, stages),
        "specification": specification(path, stages, quick),
    }


# -- text -------------------------------------------------------------------------------
def _g(v, digits: int = 4) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.{digits}g}"


def _range(values, digits: int = 3) -> str:
    if not values:
        return "-"
    lo, hi = min(values), max(values)
    return _g(lo, digits) if lo == hi else f"{_g(lo, digits)} .. {_g(hi, digits)}"


def _verdict(p: dict) -> str:
    if p["verdict"] == "correlated" and p["partner"]:
        return f"correlated with {p['partner']} (r = {p['partner_r']:+.2f})"
    return p["verdict"] or "-"


def markdown(fig: dict) -> str:
    """The section's tables (Markdown): stages, parameters, perceptual check."""
    lines = [
        f"Wall time of `evo-door run experiments/case_study.yaml` in a fresh process: "
        f"**{fig['wall']:.0f} s** (the pipeline's own time {fig['total']:.0f} s); its "
        f"budget, {BUDGET_S:.0f} s on 2 cores, is "
        + ("met." if fig["wall"] <= BUDGET_S else "**not met**."),
        "",
        "| stage | model | time | evaluations | fitness | RMS error per fit trial "
        "| RMS error, validation trial |",
        "|---|---|---:|---:|---|---|---|",
    ]
    for s in fig["stages"]:
        unit = f" {s['channel_unit']}" if s["channel_unit"] else ""
        lines.append(
            f"| {s['stage']} | {s['model']} | {s['seconds']:.1f} s | {s['evaluations']} | "
            f"{_g(s['fitness'], 3)} {s['fitness_unit']} | "
            f"{_range(s['rms_fit'])}{unit} ({s['channel']}) | "
            f"{_range(s['rms_validation'])}{unit if s['rms_validation'] else ''} |"
        )
    lines += [
        "",
        "Each stage's estimates; where the trials carry the virtual door's truth (the "
        "stages fitted to its trials), the error against it. 95 % CI: the half-width of "
        "the identifiability check's confidence interval, relative to the value (for the "
        "stages fitted to a feel: the change that moves the feel by one JND).",
        "",
        "| stage | parameter | per-trial min .. max | estimate | true | error | 95 % CI "
        "| verdict |",
        "|---|---|---|---|---|---:|---:|---|",
    ]
    for s in fig["stages"]:
        for p in s["params"]:
            unit = "" if p["unit"] in ("", "1") else f" {p['unit']}"
            span = f"{_g(p['min'])} .. {_g(p['max'])}{unit}" if "min" in p else "-"
            true = "-" if p["true"] is None else f"{_g(p['true'])}{unit}"
            err = "-" if p["error_pct"] is None else f"{p['error_pct']:+.2f} %"
            ci = "-" if p["ci_pct"] is None else f"+-{p['ci_pct']:.3g} %"
            lines.append(
                f"| {s['stage']} | {p['name']} | {span} | {_g(p['value'])}{unit} | {true} | "
                f"{err} | {ci} | {_verdict(p)} |"
            )
    errors = [
        abs(p["error_pct"])
        for s in fig["stages"]
        for p in s["params"]
        if p["error_pct"] is not None
    ]
    if errors:
        lines += ["", f"Largest error against the truth: {max(errors):.2f} %."]
    checks = fig["perceptual"]
    if checks:
        jnd = checks[0]["jnd"]
        lines += [
            "",
            "The perceptual check of every stage fitted to a chosen feel: its answer's "
            "force-angle curve against the feel it was fitted to, at every angle outside the "
            f"latch zone within the force JND ({100 * jnd['force']:g} % of the chosen force, "
            f"at least {jnd['force_floor']:g} N), each latch peak within its force JND and "
            f"its angle within {1000 * jnd['position']:g} mm at the handle "
            f"({math.degrees(jnd['position'] / jnd['handle_radius']):.2f} deg at "
            f"{jnd['handle_radius']:g} m), the felt inertia and damping within theirs; the "
            "largest of each in JND:",
            "",
            "| stage | fitted to | direction | stroke: largest difference | latch peak "
            "| peak's angle | verdict |",
            "|---|---|---|---|---:|---:|---|",
        ]
        for pc in checks:
            for d in ("opening", "closing"):
                c = pc[d]
                lines.append(
                    f"| {pc['stage']} | {pc['chosen']} | {d} | {c['worst_n']:+.2f} N at "
                    f"{c['worst_deg']:.2f} deg ({c['stroke_jnd']:.2f} JND) | "
                    f"{c['peak_jnd']:.2f} JND | {c['angle_jnd']:.2f} JND | {c['verdict']} |"
                )
    for sp in fig.get("specification", []):
        y, i = sp["yield"], sp["independent"]
        lines += [
            "",
            f"Stage {sp['stage']}, what the supplier builds (the default process of each "
            f"kind of specification, docs/experiments.md): the {sp['design']} nominal, its "
            f"own worst difference from the chosen feel {sp['nominal_margin']:.2f} JND. "
            f"Yield: **{100 * y['estimate']:.1f} %** of {y['samples']} doors built to the "
            f"process pass the check (95 % interval {100 * y['ci95'][0]:.1f}-"
            f"{100 * y['ci95'][1]:.1f} %, seed {y['seed']}); an independent check of "
            f"{i['samples']} other doors (`benchmarks/yield_check.py`, seed {i['seed']}): "
            f"{100 * i['estimate']:.1f} % ({sp['difference_points']:+.1f} points). "
            + ("Reachable." if sp["reachable"] else "**Not reachable** (target 95 %).")
            + (f" Most doors fail at: {sp['worst']}." if sp["worst"] else ""),
        ]
        if sp["alternative"]:
            a = sp["alternative"]
            lines.append(
                f"The {a['design']} nominal would give {100 * a['yield']['estimate']:.1f} %."
            )
        if sp["losses"]:
            lines.append(
                "The yield each tolerance costs (doors gained were it built exactly): "
                + ", ".join(f"{n} {100 * v:.1f} %" for n, v in sp["losses"])
                + "."
            )
        if sp["allocation"]:
            ay = sp["allocation_yield"]
            shares = [v["tightened"] / v["process"] for v in sp["allocation"].values()]
            lines.append(
                f"Allocation: {len(sp['allocation'])} tolerances tightened to "
                f"{100 * min(shares):.0f}-{100 * max(shares):.0f} % of the process's ("
                + ", ".join(
                    f"{n} +-{v['tightened']:.3g}"
                    + ("" if sp["units"][n] == "1" else f" {sp['units'][n]}")
                    for n, v in list(sp["allocation"].items())[:4]
                )
                + (", ..." if len(sp["allocation"]) > 4 else "")
                + f"): {100 * ay['estimate']:.1f} % of {ay['samples']} fresh doors pass "
                f"(seed {ay['seed']})."
            )
        elif not sp["reachable"]:
            lines.append("No tightening of the tolerances the check sees reaches the target.")
        if sp["nearest"]:
            n = sp["nearest"]
            lines.append(
                f"The nearest feel (the chosen feel's model, {len(n['moved'])} sensations "
                f"moved, {n['distance_jnd']:.2f} JND from the chosen feel): "
                f"{100 * n['yield']['estimate']:.1f} % of the doors pass it"
                + ("." if n["holds"] else ": the process holds no feel this near.")
            )
    return "\n".join(lines)
