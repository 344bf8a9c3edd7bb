"""What a person reads of several runs at once: the tables of ``runs`` (a folder of
runs), ``compare`` (runs side by side) and ``batch`` (its experiments' summary), each
built from the JSON-able documents the views make (:func:`~.format_json.list_runs`,
:func:`~.format_json.compare`), so that ``--json`` and the text cannot disagree. One
run's text is :mod:`.format_text`.
"""

from __future__ import annotations

from pathlib import Path

from evo_door.experiment.results import fmt_number, objective_text


# -- a folder of runs ----------------------------------------------------------------
def _compact_values(row: dict) -> str:
    """``k=100 N/rad, c=2 N s/rad``; an estimate on a bound says so."""
    parts = []
    for n, v in row["values"].items():
        unit = row["units"].get(n, "")
        text = f"{n}={v:.4g}" + (f" {unit}" if unit and unit != "1" else "")
        if n in row["at_bound"]:
            text += f" ({row['at_bound'][n]} bound)"
        parts.append(text)
    return ", ".join(parts)


def text_table(header: list[str], rows: list[list[str]]) -> list[str]:
    widths = [
        max(len(h), *(len(row[i]) for row in rows)) if rows else len(h)
        for i, h in enumerate(header)
    ]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    out = [fmt.format(*header).rstrip(), fmt.format(*("-" * w for w in widths)).rstrip()]
    return out + [fmt.format(*row).rstrip() for row in rows]


def format_runs(rows: list[dict]) -> str:
    header = [
        "file",
        "name",
        "model",
        "status",
        "progress",
        "objective",
        "best fitness",
        "parameters",
        "seed",
        "created",
    ]
    table = [
        [
            r["file"],
            r["name"],
            r["model"],
            r["status"],
            r["progress"],
            "" if r["objective"] is None else objective_text(r["objective"]),
            "" if r["fitness"] is None else f"{r['fitness']:.4g} {r['fitness_unit']}",
            _compact_values(r),
            str(r["seed"]),
            r["created"],
        ]
        for r in rows
    ]
    out = text_table(header, table)
    stopped = [r["file"] for r in rows if r["status"] == "interrupted"]
    if stopped:
        out.append(
            f"\ninterrupted: {', '.join(stopped)}; `evo-door resume FILE` continues a run "
            "where it stopped"
        )
    if any(r["at_bound"] for r in rows):
        out.append("(lower / upper bound): an estimate on a bound of its search range; see show")
    return "\n".join(out)


# -- several runs side by side ---------------------------------------------------------
#: the widest cell of ``compare``'s table (a long description must not push the
#: other runs off the screen; --json has every value whole)
MAX_CELL = 40


def _cell(value, width: int = MAX_CELL) -> str:
    """A configuration value as text: ``ise``, ``0.6``, ``[20, 500]``, ``-`` for none."""
    text = _value_text(value)
    return text if len(text) <= width else text[: width - 3] + "..."


def _value_text(value) -> str:
    if value is None:
        return "-"
    if value == "":
        return '""'
    if isinstance(value, bool):
        return str(value).lower()  # as the experiment file writes it
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list):
        return "[" + ", ".join(_value_text(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_value_text(v)}" for k, v in value.items()) + "}"
    return str(value)


def format_compare(doc: dict) -> str:
    """The human-readable ``evo-door compare``: one column per run."""
    # long: the rows are written in the order the table shows them, each a line
    # or two, and splitting would scatter that order over helpers
    runs = doc["runs"]
    stages = doc.get("stages") or [None] * len(runs)
    names = [Path(f).name for f in doc["files"]]
    if len(set(zip(names, stages))) < len(names):  # one name in several folders: the paths
        names = list(doc["files"])
    # a pipeline's stage as runs lists it: FILE [stage]
    names = [name + (f" [{stage}]" if stage else "") for name, stage in zip(names, stages)]
    rows: list[list[str]] = []

    def row(label, cells):
        rows.append([label, *cells])

    def section(title):
        rows.append([title] + [""] * len(runs))

    row("name", [r["name"] or "" for r in runs])
    row("model", [r["model"] or "" for r in runs])
    row("status", [f"{r['status']} ({r['progress']})" for r in runs])
    row(
        "objective",
        [f"{objective_text(r['objective'])}, {r['objective']['combine']}" for r in runs],
    )
    units = {r["fitness_unit"] for r in runs}
    if len(units) == 1:
        row(f"fitness [{next(iter(units))}]", [fmt_number(r["fitness"]) for r in runs])
    else:
        row("fitness", [f"{fmt_number(r['fitness'])} {r['fitness_unit']}" for r in runs])
    row("answer", [r["best_meaning"] for r in runs])
    if doc["params"]:
        section("parameters")
    truth = any(r["params"][n]["true"] is not None for r in runs for n in doc["params"])
    for n in doc["params"]:
        unit = next((r["params"][n]["unit"] for r in runs if r["params"][n]["unit"]), "")
        cells = []
        for r in runs:
            p = r["params"][n]
            text = "-" if p["value"] is None else f"{p['value']:.8g}"
            if p["role"] != "free":
                text = f"{p['role']} {text}"
            elif p["at_bound"]:
                text += f" ({p['at_bound']} bound)"
            cells.append(text)
        row(f"  {n}" + (f" [{unit}]" if unit and unit != "1" else ""), cells)
        if truth:
            row("    true", [_cell(r["params"][n]["true"]) for r in runs])
            row(
                "    error",
                [
                    "-"
                    if r["params"][n]["error_percent"] is None
                    else f"{r['params'][n]['error_percent']:+.3f} %"
                    for r in runs
                ],
            )
    for key, title in (("fit_errors", "fit error"), ("validation_errors", "validation error")):
        trials = []
        for r in runs:
            trials += [t for t in r[key] if t not in trials]
        if trials:
            section(title + (f" [{next(iter(units))}]" if len(units) == 1 else ""))
            if len(units) > 1:
                row("  unit", [r["fitness_unit"] for r in runs])
            for t in trials:
                row(f"  {t}", [fmt_number(r[key][t]) if t in r[key] else "-" for r in runs])
    section("timings")
    row("  wall time [s]", [_cell(_round(r["timings"]["total_s"], 2)) for r in runs])
    row("  evaluations", [str(r["timings"]["evaluations"]) for r in runs])
    row("  GA evaluations/s", [f"{(r['timings']['evaluations_per_s'] or 0):,.0f}" for r in runs])
    row("  SLSQP [s]", [_cell(_round(r["timings"]["local_s"], 2)) for r in runs])
    if doc["differences"]:
        section("settings that differ")
        for key, values in doc["differences"].items():
            row(f"  {key}", [_cell(v) for v in values])
    else:
        section("settings: the same")
    out = text_table(["", *names], rows)
    notes = []
    if doc["models_differ"]:
        shared = ", ".join(doc["params"]) or "none"
        notes.append(
            f"runs of different models ({', '.join(dict.fromkeys(doc['models']))}): compared on "
            f"what they share; parameters declared by every model: {shared}"
            + (f"; not shared: {', '.join(doc['not_shared'])}" if doc["not_shared"] else "")
        )
    if doc["objectives_differ"]:
        notes.append("the objectives differ: fitness and errors are not on one scale across runs")
    for name, r in zip(names, runs):
        if r["status"] == "interrupted":
            notes.append(f"{name}: {r['status_text']}; {r['resume']} continues it")
    return "\n".join(out + ([""] + notes if notes else []))


def _round(v, digits):
    return None if v is None else round(float(v), digits)


def format_batch(tasks: list[dict], rows: dict) -> str:
    """The summary table: experiment, status, best fitness, parameters, time, file
    (a failed experiment's error under its row)."""
    body, errors = [], []
    for task in tasks:
        r = rows[task["name"]]
        seconds = f"{r['seconds']:.1f}" if "seconds" in r else ""
        body.append(
            [
                task["name"],
                r["status"],
                r.get("fitness", ""),
                r.get("params", ""),
                seconds,
                r.get("file", ""),
            ]
        )
        if r.get("error"):
            errors.append(f"  {task['name']}: {r['error']}")
    header = ["experiment", "status", "best fitness", "best parameters", "time (s)", "file"]
    lines = text_table(header, body)
    if errors:
        lines += ["failed:", *errors]
    return "\n".join(lines)
