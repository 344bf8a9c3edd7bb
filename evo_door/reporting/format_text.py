"""What a person reads of one run: the text of ``show`` and a pipeline's header, each
built from the JSON-able documents the views make (:meth:`Results.summary`,
:func:`~evo_door.experiment.pipeline_status.pipeline_summary`), so that ``--json`` and the
text cannot disagree. The tables of several runs are :mod:`.format_tables`.
"""

from __future__ import annotations

import math

from evo_door.experiment.feel_check import jnd_value
from evo_door.experiment.results import (
    Results,
    declared_params,
    fmt_number,
)
from evo_door.perception import verdict_text


def _preprocess_text(pre: dict) -> str:
    """What was done to the target trials, as a tail for the objective line (or "")."""
    steps = []
    if pre.get("rate_bias", "none") != "none":
        steps.append(f"gyroscope bias removed ({pre['rate_bias']})")
    if pre.get("lowpass") is not None:
        steps.append(f"low-pass {pre['lowpass']:g} Hz")
    if pre.get("trim"):
        steps.append("trimmed to the motion")
    return f"; target preprocessed: {', '.join(steps)}" if steps else ""


def bound_advice(name: str, side: str, lo: float, hi: float, declared=None) -> str:
    """One line on an estimate stopped by a bound: which bound, and what to do.

    ``declared`` is the parameter's declaration (:class:`~evo_door.params.Param`), which
    says how far the range may be widened; None when the model cannot be loaded.

    >>> for part in bound_advice("k", "upper", 20.0, 90.0).split("; "):
    ...     print(part)
    k is on the upper bound of its search range, 90: the bound, not the data, decided it
    widen the range in free: (e.g. k: [20, 160])
    """
    bound = hi if side == "upper" else lo
    unit = f" {declared.unit}" if declared is not None and declared.unit != "1" else ""
    head = f"{name} is on the {side} bound of its search range, {bound:g}{unit}"
    limit = None if declared is None else (declared.upper if side == "upper" else declared.lower)
    if limit is not None and bound == limit:
        # nowhere to widen to: the model's own limit (a friction of 0, say) is the answer
        return (
            f"{head}, the model's declared limit: the data push {name} beyond what the "
            "model allows (a term the model lacks, or one the trials cannot see)"
        )
    # one more range's width on that side, inside what the model declares
    width = hi - lo
    new_lo, new_hi = (lo, hi + width) if side == "upper" else (lo - width, hi)
    if declared is not None:
        new_lo, new_hi = max(new_lo, declared.lower), min(new_hi, declared.upper)
    return (
        f"{head}: the bound, not the data, decided it; widen the range in free: "
        f"(e.g. {name}: [{new_lo:g}, {new_hi:g}])"
    )


#: the marker after an estimate on a bound
_MARK = {"lower": "<- lower bound", "upper": "<- upper bound"}


def format_show(res: Results) -> str:
    """The human-readable ``evo-door show``: head, per-trial table, answer, errors."""
    s = res.summary()
    lines = _show_head(res, s) + _show_per_trial(res, s) + _show_best(res, s)
    funit = s.get("trial_error_unit", s["fitness_unit"])
    if s.get("fit_errors"):
        lines.append(
            f"fit error per trial in {funit}: "
            + ", ".join(f"{k} {fmt_number(v)}" for k, v in s["fit_errors"].items())
        )
    if s.get("validation_errors"):
        lines.append(
            f"validation error in {funit}:    "
            + ", ".join(f"{k} {fmt_number(v)}" for k, v in s["validation_errors"].items())
        )
    lines += format_channel_errors(s.get("channel_errors") or {})
    if "integration_error" in s:  # a complete run: recorded or not
        lines += format_integration_error(s["integration_error"])
    if "perceptual_check" in s:
        lines += format_perceptual_check(s["perceptual_check"])
    if "jnds" in s:
        lines += format_jnds(s["jnds"])
    if "smallest_change" in s:
        lines += format_smallest_change(s)
    if s.get("identifiability_text") and not s.get("tolerance_text"):
        # (a specification a supplier builds: the table says whether the feel determines
        # each one; an interval beside its tolerance would contradict it)
        lines += ["", s["identifiability_text"]]
    if s.get("tolerance_text"):
        from evo_door.experiment.spec import render_text, spec_table

        lines += [
            "",
            "specification (what a supplier builds; export-spec writes the same table):",
            render_text(spec_table(res, tolerance=False)),
            s["tolerance_text"],
        ]
    return "\n".join(lines)


def format_smallest_change(s: dict) -> list[str]:
    """``show``'s lines of an ``nsga2`` run: the front, the answer, the kept
    specifications, the check; for an unreachable feel, the closest door and its miss."""
    from evo_door.optim.smallest_change import miss_text

    c = s["smallest_change"]
    units = s["units"]
    lines = [
        "",
        f"smallest change within the JND: front of {len(c['front'])} points "
        f"(perceptual error JND^2, change {c['measure']}: mean |x - AS-IS| / search range)",
    ]
    if c.get("feel_reachable", s["reachable"]):
        start = f"front point {c['chosen']}" if c["chosen"] >= 0 else "the polished closest point"
        lines.append(
            f"  reachable: from {start}, error {c['error']:.4g} JND^2, change {c['change']:.4g}"
            + (", polished" if c["polished"] else "")
        )
    else:
        lines.append(
            f"  ! unreachable: no door of the front passes the check; the closest door "
            f"(least error, {c['error']:.4g} JND^2, change {c['change']:.4g}):"
        )
        lines += [f"    {n} = {v:.6g} {units.get(n, '')}".rstrip() for n, v in c["answer"].items()]
        lines.append("  where it misses:")
        lines += ["  " + line for line in miss_text(c["miss"])]
    w = max(len(n) for n in c["answer"])
    for n, v in c["answer"].items():
        asis = c["asis"][n]
        rel = f"{100 * (v - asis) / asis:+.2f} %" if asis else ""
        mark = "kept (AS-IS)" if n in s["kept"] else f"changed {rel}"
        lines.append(
            f"  {n:<{w}}  {v:>14.8g} {units.get(n, ''):<8} AS-IS {asis:.8g}  {mark}".rstrip()
        )
    lines.append(f"  check: {verdict_text(c['check'])}")
    return lines


def _show_head(res: Results, s: dict) -> list[str]:
    """``show``'s first lines: the run, its status, where a stage started, its settings."""
    cfg = res.config
    alg = cfg["algorithm"]
    obj = cfg["objective"]
    status = f"{s['status']} ({s['progress']})"
    if s["status"] == "running" and s["pid"]:
        status = f"running ({s['progress']}, process {s['pid']})"
    lines = [
        f"{s['name']}  ({res.path})",
        f"  model {s['model']}, status {status}, seed {s['seed']}, created {s['created']}",
    ]
    if s["status"] == "interrupted":
        lines.append(f"  {s['status_text']}; {s['resume']} continues it")
    if s["from"]:  # a pipeline's stage that started from earlier ones
        lines.append(f"  stage {s['stage']}: {format_sources(s['from'])}")
    return lines + [
        f"  objective {obj['kind']} on derivative {obj['derivative']}, {obj['combine']} "
        f"over trials" + _preprocess_text(cfg["target"].get("preprocess") or {}),
        (
            "  algorithm "
            + (
                f"{'GA' if alg['kind'] == 'ga' else 'NSGA-II'} population "
                f"{alg['population']} x {alg['generations']} "
                f"generations, reproduction {alg['reproduction_ratio']:g}, "
                f"mutation p {alg['mutation_probability']:g} amplitude "
                f"{alg['mutation_amplitude']:g}, polish {alg['polish']}"
                + (f", change {alg.get('change')}" if alg["kind"] == "nsga2" else "")
                if alg["kind"] in ("ga", "nsga2")
                else f"nlpql (SLSQP), max {alg['max_iterations']} iterations"
            )
            + (
                f", after a scan of {alg['scan']} points a parameter and "
                f"{alg.get('starts', 1)} starts"
                if alg.get("scan")
                else ""
            )
        ),
        "  simulation " + _simulation_text(s["simulation"]),
        f"  {s['evaluations']} evaluations, {s['blowups']} blow-ups, {(s['seconds'] or 0):.1f} s",
    ]


def _simulation_text(sim: dict) -> str:
    """``dopri5, 2 substeps per sample, tolerance 1e-07``: how the run integrated."""
    n = sim["substeps"]
    text = f"{sim['method']}, {n} substep{'s' if n != 1 else ''} per sample"
    if sim["method"] == "dopri5":
        tol = sim["tolerance"]
        text += f", tolerance {tol:.3g}" if tol is not None else ", the model's tolerance"
    return text


def _show_per_trial(res: Results, s: dict) -> list[str]:
    """A per_trial run's min / max / mean table (seed table 5.3), else nothing."""
    if "table" not in s:
        return []
    units = s["units"]
    lines = [f"\nper-trial fits ({len(s['per_trial_fits'])} trials), as seed table 5.3:"]
    w = max(len(n) for n in res.free)
    lines.append(f"  {'parameter':<{w}}  {'min':>12}  {'max':>12}  {'mean':>12}  unit")
    for n, row in s["table"].items():
        # which per-trial fits the bounds decided
        on = [f"{t} {hits[n]}" for t, hits in s["per_trial_at_bound"].items() if n in hits]
        note = f"  on a bound: {', '.join(on)}" if on else ""
        lines.append(
            f"  {n:<{w}}  {row['min']:>12.6g}  {row['max']:>12.6g}  "
            f"{row['mean']:>12.6g}  {units.get(n, '')}{note}".rstrip()
        )
    return lines


def _show_best(res: Results, s: dict) -> list[str]:
    """The answer: each value with its unit, range, truth and bound, then the fixed ones."""
    cfg = res.config
    units = s["units"]
    lines = [
        f"\nbest ({s.get('best_meaning') or 'best so far'}): fitness "
        f"{fmt_number(s['fitness'])} {s['fitness_unit']}"
    ]
    at_bound = s["at_bound"]
    if s["best"]:
        w = max(len(n) for n in s["best"])
        truth = s["truth"]
        for n, v in s["best"].items():
            lo, hi = cfg["free"][n]
            line = f"  {n:<{w}}  {v:>14.8g} {units.get(n, ''):<8} in [{lo:g}, {hi:g}]"
            if n in truth:
                true = truth[n]
                rel = f" ({100 * (v - true) / true:+.2f} %)" if true != 0 else ""
                line = f"{line:<{w + 48}} true {true:.8g}{rel}"
            if n in at_bound:
                line = f"{line:<{w + 48}} {_MARK[at_bound[n]]}"
            lines.append(line.rstrip())
        declared = declared_params(s["model"])
        for n, side in at_bound.items():
            lo, hi = cfg["free"][n]
            lines.append("! " + bound_advice(n, side, lo, hi, declared.get(n)))
    if s["fixed"]:
        lines.append(
            "fixed: "
            + ", ".join(f"{k} = {v:g} {units.get(k, '')}".rstrip() for k, v in s["fixed"].items())
        )
    return lines


def format_sources(sources: dict[str, str]) -> str:
    """Where a pipeline stage's ``{from: STAGE}`` came from, for a person.

    >>> format_sources({"params": "physical", "target.params": "latch"})
    'params from stage physical, target.params from stage latch'
    """
    return ", ".join(f"{key} from stage {stage}" for key, stage in sources.items())


def format_channel_errors(errors: dict) -> list[str]:
    """``show``'s lines of each trial's RMS and largest error in the channel's unit."""
    if not errors:
        return []
    first = next(iter(errors.values()))
    deg = "rms_deg" in first
    dunit = first["unit"].replace("rad", "deg")
    lines = [f"error of {first['channel']} per trial, model - target (RMS / largest, at t):"]
    for trial, e in errors.items():
        text = f"{e['rms']:.3g} / {e['max']:.3g} {e['unit']}"
        if deg:
            text += f" ({e['rms_deg']:.3g} / {e['max_deg']:.3g} {dunit})"
        role = "" if e["role"] == "fit" else "  (validation)"
        lines.append(f"  {trial:<8} {text}, largest at {e['at']:.3f} s{role}")
    return lines


def format_integration_error(entry: dict | None) -> list[str]:
    """``show``'s lines of the answer's integration error (``summary()``'s
    ``integration_error``): both settings, the objective at each, the largest changes,
    each trial's change of the fitted channel against its RMS fit error, and the
    warning (a line starting ``warning:``) when it is not small against the fit error."""
    if entry is None:
        return [
            "integration error: not recorded (the run was written before evo-door estimated it)"
        ]
    units, refined = entry["units"], entry["refined"]
    ch, unit = entry["channel"], units["channel_max"]

    def settings(e: dict) -> str:
        n = e["substeps"]
        text = f"{n} substep{'s' if n != 1 else ''}"
        return text + (f", tolerance {e['tolerance']:.3g}" if e["method"] == "dopri5" else "")

    change = entry["objective_change"]
    lines = [
        f"integration error of the answer, a posteriori ({entry['method']}, "
        f"{settings(entry)} per sample, against {settings(refined)}):",
        f"  objective {_number(entry['objective'])} {units['objective']} at the run's "
        f"settings, {_number(entry['objective_refined'])} {units['objective']} refined"
        + ("" if change is None else f" ({100 * change:+.3g} %)"),
        f"  largest change: theta {_number(entry['theta_max'])} {units['theta_max']}, "
        f"dtheta {_number(entry['dtheta_max'])} {units['dtheta_max']}"
        + ("" if ch in ("theta", "dtheta") else f", {ch} {_number(entry['channel_max'])} {unit}"),
        f"  change of {ch} per trial (largest, RMS) against its RMS fit error:",
    ]
    for trial, row in entry["trials"].items():
        d, r = row["channel_rms"], row["residual_rms"]
        share = f" ({100 * d / r:.3g} %)" if d is not None and r else ""
        role = "" if row["role"] == "fit" else "  (validation)"
        lines.append(
            f"    {trial:<8} {_number(row['channel_max'])}, {_number(d)} {unit} against "
            f"{_number(r)} {unit}{share}{role}"
        )
    if entry["warning"]:
        lines.append(f"warning: {entry['warning']}")
    return lines


def format_perceptual_check(entry: dict) -> list[str]:
    """``show``'s lines of the perceptual check (``summary()``'s ``perceptual_check``):
    the JNDs it is judged by and its verdict with the worst point in JND units, then per
    stroke the largest difference outside the latch zone (with the angles where it is
    beyond the JND), the latch peak and its angle, and the felt dynamics."""
    jnd = entry["jnd"]
    angle = math.degrees(jnd["position"] / jnd["handle_radius"])
    lines = [
        f"perceptual check: {entry['mechanism']} against the chosen feel, {entry['chosen']}"
        + ("" if entry.get("recorded", True) else " (computed on reading: not in the file)"),
        f"  force JND {100 * jnd['force']:.3g} % of the chosen force, at least "
        f"{jnd['force_floor']:g} N, at every angle outside the latch zone; position JND "
        f"{1000 * jnd['position']:.3g} mm at the handle ({angle:.2f} deg at "
        f"{jnd['handle_radius']:g} m)",
        f"  {verdict_text(entry)}",
    ]
    for d in ("opening", "closing"):
        c = entry[d]
        w, p, a = c["worst"], c["latch_peak"], c["peak_angle"]
        bands = ", ".join(f"{a:.1f}..{b:.1f}" for a, b in c["bands_deg"][:6])
        more = f" (+{len(c['bands_deg']) - 6} more)" if len(c["bands_deg"]) > 6 else ""
        lines.append(
            f"  {d:<8} {c['verdict']:<15} stroke: largest {w['difference_N']:+.2f} N at "
            f"{w['angle_deg']:.2f} deg (JND {w['jnd_N']:.2f} N, {w['jnd_units']:.2f} JND)"
            + (f", beyond at {bands}{more} deg" if bands else "")
        )
        if math.isfinite(p["chosen_N"]):
            lines.append(
                f"  {'':<8} {'':<15} latch peak {p['mechanism_N']:.2f} N against "
                f"{p['chosen_N']:.2f} N ({p['jnd_units']:.2f} JND) at {a['mechanism_deg']:.2f} "
                f"against {a['chosen_deg']:.2f} deg ({a['jnd_units']:.2f} JND)"
            )
    for name, e in (entry.get("dynamics") or {}).items():
        lines.append(
            f"  felt {name}: {e['mechanism']:.4g} against {e['chosen']:.4g} {e['unit']} "
            f"(JND {e['jnd']:.3g} {e['unit']}, {e['jnd_units']:.2f} JND), {e['verdict']}"
        )
    return lines


def format_jnds(jnds: dict) -> list[str]:
    """``show``'s lines of the JNDs a run judges its feel by (``summary()``'s ``jnds``):
    each setting, its value with its unit (a Weber fraction in %) and where it came from."""
    jnds = {k: e for k, e in jnds.items() if isinstance(e, dict)}  # (not position_m)
    w = max(len(k) for k in jnds)
    lines = ["JNDs used:"]
    for k, e in jnds.items():
        lines.append(f"  {k:<{w}}  {jnd_value(e):<9} {e['source']}")
    return lines


def _number(v) -> str:
    """A recorded number; None (not finite: a simulation that did not finish, or no
    sample counted) is ``-``."""
    return "-" if v is None else f"{v:.3g}"


def format_pipeline(summary: dict) -> str:
    """The pipeline's header for ``show``: status and each stage's state and sources."""
    # the time is a total for a finished pipeline, a running count for any other
    spent = f"{summary['total_s']:.0f} s" + ("" if summary["status"] == "complete" else " so far")
    lines = [
        f"pipeline {summary['name']}: {summary['status_text']}, {spent}, "
        f"created {summary['created']}"
    ]
    if summary["resume"]:
        lines.append(f"  {summary['resume']} continues it")
    for k, s in enumerate(summary["stages"], 1):
        sources = format_sources(s.get("from") or {})
        lines.append(f"  stage {k} {s['name']}: {s['text']}" + (f" ({sources})" if sources else ""))
    return "\n".join(lines)
