"""How a comparison of objectives is shown: the printed table, Markdown, CSV and a figure.

From the rows of :func:`evo_door.experiment.comparison_summary.summarise`:
:func:`format_summary` (the table ``evo-door compare-objectives`` prints),
:func:`markdown`, :func:`summary_csv`, :func:`runs_csv` and :func:`figure`, written by
:func:`write_outputs` as ``compare.md``, ``compare.csv``, ``runs.csv`` and
``compare.png``. The yardstick is shown in degrees for a model whose angle is in
radians (SI in the CSV files, with a column in degrees beside it).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from evo_door.experiment.comparison import Comparison
from evo_door.experiment.comparison_summary import best_rows
from evo_door.experiment.objectives import KINDS
from evo_door.files import check_image_path, save_figure, write_text

#: the files a comparison writes next to its runs
OUTPUTS = ("compare.csv", "compare.md", "compare.png", "runs.csv")


# -- text ------------------------------------------------------------------------------
def _g(v, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "blew up"
    if isinstance(v, float) and math.isnan(v):
        return "-"
    return f"{v:.{digits}g}"


def _pct(v) -> str:
    """A percentage: two decimals, or two digits of a tiny one (``-1.4e-04``)."""
    if v is None or not math.isfinite(v):
        return "-"
    return f"{v:+.2f}" if abs(v) >= 0.01 or v == 0 else f"{v:+.1e}"


def _with_range(s: dict, fmt, unit_text: str = "") -> str:
    """``mean (min .. max)`` (only the mean for one seed)."""
    text = fmt(s["mean"])
    if s["n"] > 1 and math.isfinite(s["min"]):
        text += f" ({fmt(s['min'])} .. {fmt(s['max'])})"
    return text + unit_text


def _objective_label(row: dict) -> str:
    return f"{row['kind']} on {row['channel']} (d{row['derivative']})"


def _human_rms(row: dict) -> tuple[float, str]:
    """Factor and unit of the yardstick shown to people: degrees for an angle model."""
    if row["theta_unit"] == "rad":
        return 180.0 / math.pi, row["rms_unit"].replace("rad", "deg")
    return 1.0, row["rms_unit"]


def _scaled(s: dict | None, factor: float) -> dict | None:
    if s is None:
        return None
    return {k: (v * factor if k != "n" else v) for k, v in s.items()}


def verdict(rows: list[dict]) -> list[str]:
    """One line per measure: the objective that did best by it."""
    best = best_rows(rows)
    lines = []
    if best["truth"] is not None:
        row, value = best["truth"]
        lines.append(
            f"closest to the true values: {_objective_label(row)}, mean |error| "
            f"{value:.3g} % over the free parameters and seeds"
        )
    for measure in ("rms", "max"):
        if best[measure] is None:
            continue
        row, value = best[measure]
        factor, human = _human_rms(row)
        si = f" ({value:.3g} {row['rms_unit']})" if factor != 1.0 else ""
        what = (
            f"RMS {row['rms_channel']} error"
            if measure == "rms"
            else f"max |{row['rms_channel']} error|"
        )
        lines.append(
            f"smallest {what} on the {best['role']} trials: "
            f"{_objective_label(row)}, {value * factor:.3g} {human}{si}"
        )
    return lines


def markdown(comp: Comparison | None, rows: list[dict]) -> str:
    """``compare.md``: the table, the verdict, notes, and the command that made it."""
    names = list(rows[0]["params"])
    truth = any(p["true"] is not None for r in rows for p in r["params"].values())
    factor, human = _human_rms(rows[0])
    rms_units = human + (f"; {rows[0]['rms_unit']} in compare.csv" if factor != 1.0 else "")
    head = _markdown_head(rows[0], names, truth, human)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append("| " + " | ".join(_markdown_cells(r, names, truth, factor)) + " |")
    out = [
        f"# Objectives compared: {comp.name if comp else ''}".rstrip(),
        "",
        "Mean over the GA seeds, (min .. max) over them. Fitness and validation error are "
        "in each objective's own units and not comparable across rows; the RMS and the "
        f"largest absolute {rows[0]['rms_channel']} error of each run's answer, simulated "
        f"on the trials, are on one scale ({rms_units}).",
        "",
        *lines,
        "",
    ]
    if truth:
        out += [f"Error against the true values stored with the trials: {_truth_text(rows)}.", ""]
    out += [f"- {line}" for line in verdict(rows)]
    bound = [f"{_objective_label(r)} {note}" for r in rows for note in r["at_bound"]]
    if bound:
        out.append(
            "- on a bound of its search range (the bound, not the data, decided): "
            + "; ".join(bound)
        )
    if comp is not None:
        out += [f"- {note}" for note in comp.notes()]
        out += ["", "Made with:", "", "```", command_line(comp), "```"]
    return "\n".join(out) + "\n"


def _markdown_head(first: dict, names: list, truth: bool, human: str) -> list[str]:
    """The table's header: objective, seeds, each parameter (and its error), the
    measures with their units."""
    head = ["objective", "seeds"]
    for n in names:
        u = first["params"][n]["unit"]
        head.append(f"{n}" + (f" [{u}]" if u and u != "1" else ""))
        if truth:
            head.append(f"{n} error [%]")
    return head + [
        "fitness",
        "validation error",
        f"RMS {first['rms_channel']} error, fit [{human}]",
        f"RMS {first['rms_channel']} error, validation [{human}]",
        f"max abs {first['rms_channel']} error, validation [{human}]",
        "evaluations",
        "time per run [s]",
    ]


def _markdown_cells(r: dict, names: list, truth: bool, factor: float) -> list[str]:
    """One objective's cells, in the header's order."""
    cells = [_objective_label(r), str(len(r["seeds"]))]
    for n in names:
        p = r["params"][n]
        cells.append(_with_range(p["value"], lambda v: _g(v, 5)))
        if truth:
            cells.append("-" if p["error"] is None else _with_range(p["error"], _pct))
    cells.append(_with_range(r["fitness"], _g, f" {r['fitness_unit']}"))
    cells.append(
        "-"
        if r["validation_error"] is None
        else _with_range(r["validation_error"], _g, f" {r['fitness_unit']}")
    )
    cells.append(_with_range(_scaled(r["rms_fit"], factor), lambda v: _g(v, 3)))
    for key in ("rms_validation", "max_validation"):
        rv = _scaled(r[key], factor)
        cells.append("-" if rv is None else _with_range(rv, lambda v: _g(v, 3)))
    cells.append(_with_range(r["evaluations"], lambda v: f"{v:.0f}"))
    cells.append(_with_range(r["seconds"], lambda v: f"{v:.1f}"))
    return cells


def _truth_text(rows: list[dict]) -> str:
    p = rows[0]["params"]
    return ", ".join(
        f"{n} = {v['true']:.6g}" + (f" {v['unit']}" if v["unit"] not in ("", "1") else "")
        for n, v in p.items()
        if v["true"] is not None
    )


def command_line(comp: Comparison) -> str:
    """The command that makes this comparison again (into a new folder)."""
    parts = ["evo-door compare-objectives", comp.source]
    parts.append("--kinds " + ",".join(comp.kinds))
    parts.append("--derivatives " + ",".join(map(str, comp.derivatives)))
    parts.append(f"--seeds {len(comp.seeds)}")
    parts += [f"--set {a}" for a in comp.overrides]
    return " ".join(parts)


def format_summary(comp: Comparison | None, rows: list[dict]) -> str:
    """The table printed at the end of ``evo-door compare-objectives``."""
    names = list(rows[0]["params"])
    truth = any(p["true"] is not None for r in rows for p in r["params"].values())
    factor, human = _human_rms(rows[0])
    header = ["objective"]
    for n in names:
        u = rows[0]["params"][n]["unit"]
        header.append(
            f"{n}" + (f" [{u}]" if u and u != "1" else "") + (" (error %)" if truth else "")
        )
    role = "validation" if rows[0]["rms_validation"] is not None else "fit"
    ch = rows[0]["rms_channel"]
    header += [f"{ch} err, {role}: RMS | max [{human}]", "evals", "s/run"]
    table = []
    for r in rows:
        cells = [_objective_label(r)]
        for n in names:
            p = r["params"][n]
            text = _g(p["value"]["mean"], 5)
            if p["error"] is not None:
                e = p["error"]
                text += f" ({_pct(e['mean'])}"
                if e["n"] > 1 and math.isfinite(e["min"]):
                    text += f", {_pct(e['min'])}..{_pct(e['max'])}"
                text += ")"
            cells.append(text)
        rms = _scaled(r[f"rms_{role}"], factor)["mean"]
        cells.append(f"{_g(rms, 3)} | {_g(_scaled(r[f'max_{role}'], factor)['mean'], 3)}")
        cells.append(f"{r['evaluations']['mean']:.0f}")
        cells.append(f"{r['seconds']['mean']:.1f}")
        table.append(cells)
    widths = [max(len(h), *(len(row[i]) for row in table)) for i, h in enumerate(header)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    out = [fmt.format(*header).rstrip(), fmt.format(*("-" * w for w in widths)).rstrip()]
    out += [fmt.format(*row).rstrip() for row in table]
    n_seeds = len(rows[0]["seeds"])
    out.append(
        f"mean over {n_seeds} GA seed(s)" + (", (min..max) over them" if n_seeds > 1 else "")
    )
    out += verdict(rows)
    out += [
        f"on a search bound: {_objective_label(r)} {note}" for r in rows for note in r["at_bound"]
    ]
    if comp is not None:
        out += comp.notes()
    return "\n".join(out)


# -- files -----------------------------------------------------------------------------
def _csv_number(v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return f"{v:.10g}"


def _csv(header: list[str], rows: list[list]) -> str:
    lines = [",".join(header)]
    lines += [",".join(c if isinstance(c, str) else _csv_number(c) for c in row) for row in rows]
    return "\n".join(lines) + "\n"


def summary_csv(rows: list[dict]) -> str:
    """``compare.csv``: one line per (kind, derivative), SI units in the column names."""
    names = list(rows[0]["params"])
    ch, su = rows[0]["rms_channel"], rows[0]["rms_unit"]
    factor, human = _human_rms(rows[0])
    header = ["kind", "derivative", "channel", "seeds"]
    for n in names:
        u = rows[0]["params"][n]["unit"]
        header += [f"{n} {s} [{u}]" for s in ("mean", "min", "max", "std", "true")]
        header += [f"{n} error {s} [%]" for s in ("mean", "min", "max")]
        header.append(f"{n} abs error mean [%]")
    header += ["fitness mean", "fitness min", "fitness max", "fitness unit"]
    header += ["validation error mean", "validation error min", "validation error max"]
    for what in ("rms", "max abs"):
        for role in ("fit", "validation"):
            header += [f"{what} {ch} error {role} {s} [{su}]" for s in ("mean", "min", "max")]
            if factor != 1.0:
                header.append(f"{what} {ch} error {role} mean [{human}]")
    header += ["evaluations mean", "seconds mean", "seconds total", "on a bound"]
    table = []
    for r in rows:
        line = [r["kind"], str(r["derivative"]), r["channel"], " ".join(map(str, r["seeds"]))]
        for n in names:
            p = r["params"][n]
            v, e = p["value"], p["error"] or {}
            line += [v["mean"], v["min"], v["max"], v["std"], p["true"]]
            line += [e.get("mean"), e.get("min"), e.get("max"), p["abs_error"]]
        f = r["fitness"]
        line += [f["mean"], f["min"], f["max"], r["fitness_unit"]]
        ve = r["validation_error"] or {}
        line += [ve.get("mean"), ve.get("min"), ve.get("max")]
        for measure in ("rms", "max"):
            for role in ("fit", "validation"):
                s = r[f"{measure}_{role}"] or {}
                line += [s.get("mean"), s.get("min"), s.get("max")]
                if factor != 1.0:
                    line.append(None if not s else s["mean"] * factor)
        line += [r["evaluations"]["mean"], r["seconds"]["mean"], r["seconds_total"]]
        line.append("; ".join(r["at_bound"]))
        table.append(line)
    return _csv(header, table)


def runs_csv(records: list[dict]) -> str:
    """``runs.csv``: one line per run (file, objective, seed, estimates, errors, costs)."""
    first = records[0]
    ch, su = first["yardstick"]["channel"], first["yardstick"]["unit"]
    header = ["file", "kind", "derivative", "channel", "seed"]
    for n in first["free"]:
        header += [f"{n} [{first['units'][n]}]", f"{n} error [%]"]
    header += ["fitness", "fitness unit", "validation error"]
    header += [f"rms {ch} error {role} [{su}]" for role in ("fit", "validation")]
    header += [f"max abs {ch} error {role} [{su}]" for role in ("fit", "validation")]
    header += ["evaluations", "seconds", "on a bound"]
    table = []
    for r in records:
        line = [r["file"], r["kind"], str(r["derivative"]), r["channel"], str(r["seed"])]
        for n in r["free"]:
            line += [r["values"][n], r["errors"][n]]
        line += [r["fitness"], r["fitness_unit"], r["validation_error"]]
        y = r["yardstick"]
        line += [y["fit"], y["validation"], y["fit_max"], y["validation_max"]]
        line += [float(r["evaluations"]), r["seconds"]]
        line.append(" ".join(f"{n}:{s}" for n, s in r["at_bound"].items()))
        table.append(line)
    return _csv(header, table)


def figure(rows: list[dict], records: list[dict], title: str = ""):
    """Error against the truth (or the estimate) per free parameter and objective, the
    seeds as dots, their mean with a min..max bar; two last panels for the yardstick
    (RMS and largest error, :func:`yardstick`)."""
    from matplotlib.figure import Figure

    names = list(rows[0]["params"])
    factor, human = _human_rms(rows[0])
    panels = len(names) + 2
    ncols = min(panels, 3) if panels <= 6 else 4
    nrows = math.ceil(panels / ncols)
    fig = Figure(
        figsize=(max(3.3, 0.6 * len(rows) + 0.9) * ncols, 3.6 * nrows + 0.9), layout="constrained"
    )
    axes = list(fig.subplots(nrows, ncols, squeeze=False).flat)
    for ax, n in zip(axes, names):
        _parameter_panel(ax, rows, records, n)
    role = "validation" if rows[0]["rms_validation"] is not None else "fit"
    for ax, (measure, what) in zip(axes[len(names) :], (("rms", "RMS"), ("max", "largest"))):
        key = f"{role}_max" if measure == "max" else role
        per_row = [[rec["yardstick"][key] * factor for rec in _group(records, r)] for r in rows]
        spreads = [_scaled(r[f"{measure}_{role}"], factor) for r in rows]
        ylabel = f"{what} {rows[0]['rms_channel']} error [{human}]"
        _draw_seeds(ax, rows, per_row, spreads, ylabel, False)
        ax.set_ylim(bottom=0)
        ax.set_title(f"common yardstick: {what}, {role} trials", fontsize=9)
    for ax in axes[panels:]:
        ax.axis("off")
    n_seeds = len(rows[0]["seeds"])
    fig.suptitle(
        f"{title}: max-square (eq. 5.3) and ISE (eq. 5.4) on each derivative; "
        f"{n_seeds} GA seed(s): dots, mean with min..max bar",
        fontsize=10,
    )
    return fig


def _parameter_panel(ax, rows: list[dict], records: list[dict], n: str) -> None:
    """One free parameter: its error against the truth per objective, or its estimate
    where the trials carry no true value."""
    p0 = rows[0]["params"][n]
    if p0["true"] is not None:
        per_row = [[rec["errors"][n] for rec in _group(records, r)] for r in rows]
        spreads = [r["params"][n]["error"] for r in rows]
        _draw_seeds(ax, rows, per_row, spreads, f"error of {n} against the truth [%]", True)
        ax.set_title(f"{n} (true {p0['true']:.5g} {p0['unit']})", fontsize=9)
    else:
        per_row = [[rec["values"][n] for rec in _group(records, r)] for r in rows]
        spreads = [r["params"][n]["value"] for r in rows]
        _draw_seeds(ax, rows, per_row, spreads, f"{n} [{p0['unit']}]", False)
        ax.set_title(f"{n} (no true value in the trials)", fontsize=9)


def _draw_seeds(ax, rows, per_row, spreads, ylabel: str, zero_line: bool) -> None:
    """One panel: per objective (a column), the seeds' values as dots and their mean
    with a min..max bar, in the objective kind's colour."""
    short = {"max_square": "max-sq", "ise": "ISE"}
    labels = [f"{short.get(r['kind'], r['kind'])}\n{r['channel']}" for r in rows]
    colors = {k: f"C{i}" for i, k in enumerate(KINDS)}
    for i, (r, values, s) in enumerate(zip(rows, per_row, spreads)):
        color = colors.get(r["kind"], "0.3")
        finite = [v for v in values if v is not None and math.isfinite(v)]
        ax.plot([i] * len(finite), finite, "o", color=color, ms=3.5, alpha=0.45)
        if s is not None and math.isfinite(s["mean"]):
            lo = s["mean"] - s["min"] if math.isfinite(s["min"]) else 0.0
            hi = s["max"] - s["mean"] if math.isfinite(s["max"]) else 0.0
            ax.errorbar(
                [i],
                [s["mean"]],
                yerr=[[lo], [hi]],
                fmt="_",
                color=color,
                ms=14,
                mew=2,
                capsize=4,
                lw=1.2,
            )
    if zero_line:
        ax.axhline(0.0, color="0.4", lw=0.8)
    ax.set_xticks(np.arange(len(rows)), labels, fontsize=7.5)
    ax.set_xlim(-0.6, len(rows) - 0.4)
    ax.set_ylabel(ylabel, fontsize=9)
    ax.grid(alpha=0.3, axis="y")


def _group(records: list[dict], row: dict) -> list[dict]:
    return [r for r in records if (r["kind"], r["derivative"]) == (row["kind"], row["derivative"])]


def write_outputs(comp: Comparison, records: list[dict], rows: list[dict]) -> list[Path]:
    """``compare.csv``, ``compare.md``, ``compare.png`` and ``runs.csv`` in the folder."""
    folder = comp.folder
    check_image_path(folder / "compare.png")
    paths = [folder / name for name in OUTPUTS]
    write_text(paths[0], summary_csv(rows))
    write_text(paths[1], markdown(comp, rows))
    save_figure(figure(rows, records, comp.name), paths[2], dpi=110)
    write_text(paths[3], runs_csv(records))
    return paths
