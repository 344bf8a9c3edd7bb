"""Specification tables: a fit's parameters as the seed's tables 5.3 and 5.4 give them.

A product engineer takes one thing away from the method: a table of the mechanism's
technical specifications (or of the haptic model's sensations), each with its symbol,
unit and value, the range over the per-trial fits where there is one (seed table 5.3:
min .. max over ten trials) and whether the data pin it down at all (identifiability).
:func:`spec_table` builds it from a run (or a pipeline stage); :func:`render` writes it
as CSV, Markdown, LaTeX, HTML or a parameter file (YAML) that ``--params``, experiments
and the renderer read back.

Rows: every parameter of the model's ``specification`` and ``sensation`` groups, and
every free parameter whatever its group
(:func:`~evo_door.optim.specification.spec_names`); geometry and numerical settings stay
out of the table (the YAML file has them all). A run against a chosen
feel (the perceptual objective) on a mechanism a supplier builds adds what the
supplier needs (:mod:`evo_door.optim.tolerance`, one computation that ``show``,
``show --json``, every format here and the report all print): each specification's
**process tolerance** (``+-t``, the supplier's, as used: ``process:`` or its kind's
default) and distribution, whether the **feel determines** it, its **sensitivity**
(JND of the check per unit change; "not judged" where the check does not see it),
its **contribution to the yield loss** (the share of doors gained were it built
exactly) and whether it was **changed** from the AS-IS door; the caption gives the
yield with its interval and, where the target is out of reach, the allocation. Such a
table has no statistical interval: a feel-fitted value's 1-JND interval would
contradict its tolerance. ``status`` says where a value comes from:
``estimated`` (free in this fit), ``kept`` (free in a smallest-change fit, ``algorithm:
{kind: nsga2}``, and left at its AS-IS value because the chosen feel does not need it
changed), ``fixed`` (``fixed:`` of the experiment) or ``given`` (the base set: a preset,
a file or an earlier stage). A smallest-change fit whose feel is unreachable says so in
the caption (and the YAML's description): its table is the closest door's.
"""

from __future__ import annotations

import csv
import html
import io
import math
from collections.abc import Callable
from dataclasses import dataclass

from evo_door.errors import UserError
from evo_door.experiment.results import Results
from evo_door.optim.specification import spec_names

FORMATS = ("csv", "md", "tex", "html", "yaml")


@dataclass
class SpecRow:
    name: str
    symbol: str
    unit: str
    value: float
    status: str  # estimated, kept, fixed, given
    low: float = math.nan  # per-trial range (per_trial runs), else nan
    high: float = math.nan
    true: float = math.nan  # where the trials carry the truth
    verdict: str = ""  # identifiability of an estimated value
    se: float = math.nan  # standard error, unit of the value
    note: str = ""
    meaning: str = ""
    tolerance: float = math.nan  # the process's +- half-width (against a chosen feel), unit
    tolerance_text: str = ""  # as given: "+-10 %", "+-0.0002 rad"
    distribution: str = ""
    sensitivity: float = math.nan  # JND of the check per unit change; 0: not judged
    loss: float = math.nan  # share of doors gained were it built exactly
    change: str = ""  # "kept", "changed -8.4 %" (from the AS-IS door)

    @property
    def has_range(self) -> bool:
        return math.isfinite(self.low) and math.isfinite(self.high)


@dataclass
class SpecTable:
    title: str
    model: str  # how the run names its model (a name, an import path or a file)
    source: str  # the results file (and stage)
    rows: list[SpecRow]
    values: dict  # every parameter -> value (the YAML file)
    form: str  # "table 5.3" (a per-trial range) or "table 5.4" (one value)
    #: a smallest-change fit's outcome for the caption ("" for another fit)
    remark: str = ""
    #: the Monte-Carlo of the together bands and any note, for the caption ("" if none)
    tolerance_text: str = ""

    @property
    def has_range(self) -> bool:
        return any(r.has_range for r in self.rows)

    @property
    def has_tolerance(self) -> bool:
        return any(math.isfinite(r.tolerance) for r in self.rows)


def spec_table(res: Results, tolerance: bool = True) -> SpecTable:
    """The specification table of a finished run or stage (see the module docstring);
    ``tolerance`` False leaves out tolerances that the file does not store (they would be
    computed, a few seconds)."""
    from evo_door.experiment.run_specification import tolerances_of

    if not res.complete:
        raise UserError(
            f"{res.path}: the run is not complete ({res.status().text}); a specification "
            "comes from a finished fit"
        )
    model = res.declaration  # names, units and bounds: no kernels
    if model is None:
        raise UserError(f"{res.path}: model {res.attrs['model']!r} cannot be loaded")
    summary = res.summary()
    values = res.values()
    fixed = res.config.get("fixed", {})
    table = summary.get("table", {})
    truth = summary.get("truth", {})
    ident = res.identifiability()
    front = res.smallest_change()
    kept = set(front.kept) if front is not None else set()
    verdicts = ident.as_dict() if ident is not None else {}
    rows = []
    tol = tolerances_of(res, compute=tolerance)
    if tol is not None and front is not None:  # the nominal stated: kept where unchanged
        kept = {n for n, c in zip(tol.names, tol.changed) if not c and n in res.free}
    listed = spec_names(model, res.free)
    for p in model.params:
        if p.name not in listed or p.name not in values:
            continue  # (a parameter declared since the run was made has no value in it)
        status = (
            ("kept" if p.name in kept else "estimated")
            if p.name in res.free
            else "fixed"
            if p.name in fixed
            else "given"
        )
        row = SpecRow(
            p.name,
            p.symbol or p.name,
            p.unit,
            float(values[p.name]),
            status,
            meaning=p.meaning,
        )
        if p.name in table:
            row.low, row.high = table[p.name]["min"], table[p.name]["max"]
        if p.name in truth:
            row.true = float(truth[p.name])
        if p.name in verdicts:
            v = verdicts[p.name]
            row.verdict, row.se = v["verdict"], v["se"]
            if v["verdict"] != "identifiable":
                row.note = v["reason"]
        if tol is not None and p.name in tol.names:
            _supply(row, tol, p)
        if p.name in kept:
            row.note = "kept at its AS-IS value: the chosen feel does not need it changed"
        elif front is not None and not front.reachable and p.name in res.free:
            row.note = "closest door: the chosen feel is unreachable; " + row.note
        elif p.name in summary.get("at_bound", {}):
            row.note = (row.note + "; " if row.note else "") + (
                f"on the {summary['at_bound'][p.name]} bound of its search range"
            )
        rows.append(row)
    where = f"{res.path}" + (f", stage {res.stage}" if res.stage else "")
    form = "table 5.3" if table else "table 5.4"
    kind = "Sensations" if any(p.group == "sensation" for p in model.params) else "Specification"
    return SpecTable(
        title=f"{kind}: {res.attrs.get('name')} ({model.name} model)",
        model=res.attrs["model"],
        source=where,
        rows=rows,
        values=values,
        form=form,
        remark=_remark(front, tol),
        tolerance_text=_tolerance_caption(tol, res) if tol is not None else "",
    )


def _supply(row: SpecRow, spec, param) -> None:
    """The supplier's columns of ``row`` from the stage's specification."""
    from evo_door.optim.process import format_tolerance

    d = spec.row(row.name)
    row.tolerance = d["half_width"]
    row.tolerance_text = format_tolerance(d["half_width"], row.unit) if d["half_width"] else "exact"
    row.distribution = d["distribution"]
    row.sensitivity = d["sensitivity_jnd_per_unit"]
    row.loss = d["yield_loss"]
    if d["changed"]:
        i = spec.names.index(row.name)
        asis = float(spec.asis[i])
        rel = f" {100 * (row.value - asis) / asis:+.3g} %" if asis else ""
        row.change = f"changed{rel} (AS-IS {asis:.6g})"
    else:
        row.change = "kept"
    if row.verdict:  # the feel's identifiability: does the feel determine it?
        row.verdict = "determined" if row.verdict == "identifiable" else "not determined"
        # neither the standard error nor a 1-JND interval: it would contradict the
        # supplier's tolerance (the sensitivity and the yield loss say what matters)
        row.se, row.note = math.nan, ""
    if not d["judged"]:
        row.note = "not judged by the perceptual check: the feel does not limit it"


def _remark(front, spec=None) -> str:
    """The caption's word on a smallest-change fit (module docstring); "" otherwise."""
    if front is None:
        return ""
    kept = f"; kept at AS-IS: {', '.join(front.kept)}" if front.kept else ""
    if front.reachable and spec is not None and spec.design == "centred":
        return (
            "the nominal centred for the yield; the smallest change within the JND (change "
            f"{front.change:.3g}{kept}) is its alternative"
        )
    if front.reachable:
        return f"smallest change within the JND (change {front.change:.3g}){kept}"
    return (
        "UNREACHABLE feel: no door passes the perceptual check; this is the closest door "
        f"(perceptual error {front.error:.3g} JND^2){kept}"
    )


def _tolerance_caption(spec, res=None) -> str:
    """The caption's word on what the supplier builds: the yield, the design, reachable;
    and the latch peaks the hand feels (a latch force is the catch's alone: the hand
    also meets the door's friction and spring at the catch)."""
    text = "; ".join(line.strip() for line in spec.summary_lines())
    check = res.record.perceptual_check if res is not None else None
    if check is not None:
        judged = check.judged()
        felt = [
            f"{word} {abs(judged[d]['latch_peak']['mechanism_N']):.3g} N"
            for d, word in (("opening", "unlock"), ("closing", "lock"))
            if math.isfinite(judged[d]["latch_peak"]["mechanism_N"])
        ]
        if felt:
            text += "; at the handle the nominal door's latch peaks are " + " and ".join(felt)
    return text


# -- rendering ----------------------------------------------------------------------------
def _num(v: float, digits: int = 6) -> str:
    return "" if not math.isfinite(v) else f"{v:.{digits}g}"


def _band(r: SpecRow, band: float) -> str:
    from evo_door.optim.tolerance import band_text

    if not math.isfinite(band):
        return ""
    return band_text(band, r.unit, band / abs(r.value) if r.value != 0.0 else math.inf)


def _columns(t: SpecTable, fmt: str = "md") -> list[tuple[str, Callable[[SpecRow], str]]]:
    cols = [
        ("parameter", lambda r: r.name),
        ("symbol", lambda r: r.symbol),
        ("unit", lambda r: r.unit),
        ("value", lambda r: _num(r.value)),
    ]
    if t.has_range:
        cols += [("min", lambda r: _num(r.low)), ("max", lambda r: _num(r.high))]
    if any(math.isfinite(r.true) for r in t.rows):
        cols.append(("true", lambda r: _num(r.true)))
    if t.has_tolerance:
        if fmt == "csv":  # numbers, in the unit column's unit
            cols += [
                ("process tolerance (+-)", lambda r: _num(r.tolerance)),
                ("distribution", lambda r: r.distribution),
                ("feel determines it", lambda r: r.verdict),
                ("sensitivity (JND per unit)", lambda r: _num(r.sensitivity, 4)),
                ("yield loss", lambda r: _num(r.loss, 4)),
                ("change", lambda r: r.change),
            ]
        else:
            cols += [
                ("process tolerance", lambda r: _process_cell(r)),
                ("feel determines it", lambda r: r.verdict),
                ("sensitivity", lambda r: _sensitivity_cell(r)),
                ("yield loss", lambda r: _loss_cell(r)),
                ("change", lambda r: r.change),
            ]
        return cols + [("status", lambda r: r.status), ("note", lambda r: r.note)]
    cols += [
        ("status", lambda r: r.status),
        ("identifiability", lambda r: r.verdict),
        ("standard error", lambda r: _num(r.se, 3)),
        ("note", lambda r: r.note),
    ]
    return cols


def _process_cell(r: SpecRow) -> str:
    if not math.isfinite(r.tolerance):
        return ""
    band = _band(r, r.tolerance) if r.tolerance else "exact"
    return band + (" uniform" if r.distribution == "uniform" else "")


def _sensitivity_cell(r: SpecRow) -> str:
    if not math.isfinite(r.sensitivity):
        return ""
    if r.sensitivity == 0.0:
        return "not judged"
    unit = "" if r.unit == "1" else f" per {r.unit}"
    return f"{r.sensitivity:.3g} JND{unit}"


def _loss_cell(r: SpecRow) -> str:
    if not math.isfinite(r.loss):
        return ""
    return f"{100 * r.loss:.2g} %" if r.loss > 0 else "0"


def _caption(t: SpecTable) -> str:
    what = (
        "min and max over the per-trial fits, value of the fit of every trial at once"
        if t.has_range
        else "one value per parameter"
    )
    remark = f"; {t.remark}" if t.remark else ""
    tol = f"; {t.tolerance_text}" if t.tolerance_text else ""
    return f"{t.title}, in the form of seed {t.form} ({what}){remark}; from {t.source}{tol}"


def render(t: SpecTable, fmt: str) -> str:
    """The table as text in ``fmt`` (one of :data:`FORMATS`)."""
    if fmt not in FORMATS:
        raise UserError(f"--format {fmt!r}: choose one of {', '.join(FORMATS)}")
    if fmt == "yaml":
        return _yaml(t)
    cols = _columns(t, fmt)
    header = [c for c, _ in cols]
    body = [[f(r) for _, f in cols] for r in t.rows]
    if fmt == "csv":
        # Header and rows only: a comment line would be read as data by spreadsheets
        # and pandas.read_csv. The caption is in the other formats (and the YAML's
        # description); the columns say the rest.
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow(header)
        w.writerows(body)
        return out.getvalue()
    if fmt == "md":
        lines = [f"**{_md_cell(_caption(t))}**", "", _md_row(header)]
        lines.append("|" + "|".join("---" for _ in header) + "|")
        lines += [_md_row(row) for row in body]
        return "\n".join(lines) + "\n"
    if fmt == "tex":
        return _tex(t, header, body)
    return _html(t, header, body)


def render_text(t: SpecTable) -> str:
    """The table for a terminal (``show``): the columns of :func:`render`'s, aligned;
    the caption is ``show``'s own lines."""
    cols = _columns(t)
    rows = [[c for c, _ in cols]] + [[f(r) for _, f in cols] for r in t.rows]
    keep = [j for j in range(len(cols)) if any(row[j] for row in rows[1:])]
    width = [max(len(row[j]) for row in rows) for j in keep]
    lines = ["  ".join(row[j].ljust(w) for j, w in zip(keep, width)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * w for w in width))
    return "\n".join(lines)


def _md_cell(text: str) -> str:
    """A Markdown table cell: a pipe inside it (``|r| > 0.95``) escaped, so that it
    does not split the cell, and read as a pipe."""
    return text.replace("|", "\\|")


def _md_row(cells) -> str:
    return "| " + " | ".join(_md_cell(c) for c in cells) + " |"


def _tex_escape(text: str) -> str:
    for a, b in (("\\", r"\textbackslash{}"), ("_", r"\_"), ("%", r"\%"), ("&", r"\&")):
        text = text.replace(a, b)
    for a, b in (("#", r"\#"), ("^", r"\^{}"), ("$", r"\$")):
        text = text.replace(a, b)
    return text


def _tex(t: SpecTable, header, body) -> str:
    align = "l" * 3 + "r" * (len(header) - 7) + "l" * 4
    lines = [
        r"% needs \usepackage{booktabs}",
        r"\begin{table}[htbp]",
        r"\centering",
        rf"\caption{{{_tex_escape(_caption(t))}}}",
        rf"\begin{{tabular}}{{{align}}}",
        r"\toprule",
        " & ".join(_tex_escape(h) for h in header) + r" \\",
        r"\midrule",
    ]
    lines += [" & ".join(_tex_escape(c) for c in row) + r" \\" for row in body]
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def table_html(t: SpecTable) -> str:
    """The table as an HTML ``<table>`` (the report embeds it)."""
    cols = _columns(t)
    head = "".join(f"<th>{html.escape(c)}</th>" for c, _ in cols)
    rows = []
    for r in t.rows:
        cls = "" if r.verdict in ("", "identifiable") else ' class="flag"'
        cells = "".join(f"<td>{html.escape(f(r))}</td>" for _, f in cols)
        rows.append(f"<tr{cls}>{cells}</tr>")
    return (
        f"<table><caption>{html.escape(_caption(t))}</caption>"
        f"<thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"
    )


def _html(t: SpecTable, header, body) -> str:
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(t.title)}</title><style>"
        "body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
        "td,th{border:1px solid #bbb;padding:.2em .5em;text-align:left}"
        "tr.flag{background:#fde8e8}caption{font-weight:bold;margin-bottom:.5em}"
        f"</style></head><body>{table_html(t)}</body></html>\n"
    )


def _yaml(t: SpecTable) -> str:
    from evo_door.models import get_model
    from evo_door.params.sets import ParamSet

    model = get_model(t.model)
    description = f"{t.title}, from {t.source}" + (f"; {t.remark}" if t.remark else "")
    values = {n: v for n, v in t.values.items() if n in model.params}
    notes = {
        r.name: f"process tolerance {_process_cell(r)}; sensitivity {_sensitivity_cell(r)}; "
        f"yield loss {_loss_cell(r)}; {r.change}"
        for r in t.rows
        if math.isfinite(r.tolerance)
    }
    if notes:
        description += f"; {t.tolerance_text}"
    return ParamSet.from_mapping(model.params, values, description).to_yaml(notes=notes)


def export(res: Results, fmt: str, out=None, log=None) -> str:
    """Render ``res``'s table in ``fmt``; write it to ``out`` when given (atomically).
    ``log(line)`` hears that tolerances were computed because the file had none."""
    from evo_door.experiment.run_specification import COMPUTED_NOTE
    from evo_door.files import write_text

    table = spec_table(res)
    if log is not None and COMPUTED_NOTE in table.tolerance_text:
        log(f"note: tolerances {COMPUTED_NOTE}")
    text = render(table, fmt)
    if out is not None:
        write_text(out, text)
    return text
