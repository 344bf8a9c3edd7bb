"""``evo-door report RUN.h5``: one self-contained HTML page of a run or a pipeline.

The page needs no network to be read: the figures are PNG files written next to it and
embedded in it (base64), the styles are inline. For every run (every stage of a
pipeline) it shows the GA's convergence, the fit against the target per trial with each
trial's error in the channel's unit, the parameter table with the per-trial ranges and
the truth where the trials carry it (:mod:`evo_door.experiment.spec`), the
identifiability check and the correlation matrix of the estimates.

For a pipeline laid out like the case study (``docs/case-study.md``) it adds what the
seed's chapter 5 shows (:mod:`.report_case_study`). The page itself is built by
:class:`evo_door.reporting.page.ReportPage`.
"""

from __future__ import annotations

import html
import time
from pathlib import Path

import numpy as np

from evo_door.errors import UserError
from evo_door.experiment.reader import PipelineRecord, RunRecord, read_results
from evo_door.experiment.results import Results
from evo_door.experiment.run_specification import tolerances_of
from evo_door.experiment.spec import spec_table, table_html
from evo_door.files import save_figure, write_text
from evo_door.reporting.figures import plot_convergence, plot_fit, plot_tolerances
from evo_door.reporting.format_text import format_integration_error
from evo_door.reporting.page import ReportPage
from evo_door.reporting.report_case_study import _case_study
from evo_door.reporting.report_feel import (
    DEFAULT_JND,
    FORCE_FLOOR,
    JNDChanges,
    front_section,
    perceptual_section,
)
from evo_door.reporting.report_mechanism import mechanism_section

__all__ = ["DEFAULT_JND", "FORCE_FLOOR", "JNDChanges", "pipeline_settings", "write_report"]


def pipeline_settings(path, pipeline=None, jnd=None, force_floor=None, jnd_files=()) -> JNDChanges:
    """The report's changes to each run's JND (the run's ``perception:`` settings): the
    command line's (``--jnd``, ``--force-floor``, the JND files ``--jnd-file``), else the
    pipeline file's ``report:``, else none. ``path`` is the results file or its record
    (read once)."""
    stored = {}
    if pipeline is not None:
        record = path if isinstance(path, PipelineRecord) else read_results(path)
        stored = record.report
    report = "the pipeline file's report."
    return JNDChanges(
        jnd if jnd is not None else stored.get("jnd"),
        force_floor if force_floor is not None else stored.get("force_floor"),
        files=tuple(jnd_files or ()),
        jnd_from=report + "jnd" if jnd is None and "jnd" in stored else "--jnd",
        floor_from=(
            report + "force_floor"
            if force_floor is None and "force_floor" in stored
            else "--force-floor"
        ),
    )


def default_folder(path) -> Path:
    path = Path(path)
    return path.with_name(path.stem + "-report")


def write_report(path, out=None, settings: JNDChanges | None = None, log=None) -> Path:
    """Write the report of the results file ``path`` (or its record, read once by
    :func:`~evo_door.experiment.reader.read_results`) into the folder ``out`` (default
    ``<RUN>-report/`` next to it); returns the HTML file. ``settings`` changes the JND
    every perceptual check is judged by (default: the pipeline file's ``report:``, else
    the runs' own)."""
    from evo_door.experiment.pipeline_status import pipeline_summary

    t0 = time.perf_counter()
    record = path if isinstance(path, (PipelineRecord, RunRecord)) else read_results(path)
    path = record.path
    pipeline = pipeline_summary(record)
    settings = (settings or pipeline_settings(record, pipeline)).check()
    if pipeline is None:
        results = [Results.of(record)]
    else:
        results = [Results.of(run) for run in record.runs.values()]
    if not any(r.complete for r in results):
        raise UserError(f"{path}: nothing finished to report on yet ({results[0].status().text})")
    folder = _report_folder(path, out)
    page = ReportPage(folder)
    name = pipeline["name"] if pipeline else results[0].attrs.get("name", "run")
    _head(page, name, path, pipeline, results)
    for res in results:
        if log:
            log(f"report: {res.stage or name}")
        _run_section(page, res, settings)
    if pipeline:
        _case_study(page, results, settings)
    page.p(_made_by(results[0].record.provenance.versions, time.perf_counter() - t0), "small")
    text = page.document(f"{name}: evo-door report")
    target = folder / "report.html"
    write_text(target, text)
    return target


def _report_folder(path, out) -> Path:
    """The report's folder (default ``<RUN>-report/``), made if need be."""
    folder = Path(out) if out else default_folder(path)
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{folder}: exists and is not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _head(page: ReportPage, name: str, path, pipeline, results: list) -> None:
    """The page's title, its results file, and for a pipeline its summary and the links
    to its stages."""
    from evo_door.reporting.format_text import format_pipeline

    page.h(1, f"evo-door report: {name}")
    page.p(f"results file {Path(path).resolve()}")
    if pipeline:
        page.pre(format_pipeline(pipeline))
        page.raw(
            "<nav>"
            + "".join(
                f'<a href="#stage-{html.escape(r.stage)}">{html.escape(r.stage)}</a>'
                for r in results
            )
            + '<a href="#case-study">case study</a></nav>'
        )


def _made_by(v: dict, seconds: float) -> str:
    """The page's last line: the version that made it, in how long, with which libraries."""
    return (
        "made by evo-door "
        + str(v.get("evo_door", ""))
        + f" in {seconds:.1f} s; versions: "
        + ", ".join(
            f"{k} {v[k]}" for k in ("python", "numpy", "scipy", "numba", "deap", "h5py") if k in v
        )
    )


# -- one run -----------------------------------------------------------------------------
def _run_section(page: ReportPage, res: Results, changes: JNDChanges) -> None:
    # long: a run's section in the order a reader meets it (fit, errors, the feel's
    # check, the front, the specification and its yield, identifiability)
    label = res.stage or res.attrs.get("name", "run")
    key = res.stage or "run"
    page.h(2, f"{'Stage ' if res.stage else 'Run '}{label}", f"stage-{key}")
    cfg = res.config
    if cfg.get("description"):
        page.p(cfg["description"])
    s = res.summary()
    obj = cfg["objective"]
    page.p(
        f"model {s['model']}, status {s['status_text']}, objective {obj['kind']} on "
        f"derivative {obj['derivative']}, {s['evaluations']} evaluations in "
        f"{(s['seconds'] or 0):.1f} s, seed {s['seed']}; best fitness "
        f"{s['fitness']:.4g} {s['fitness_unit']} ({s.get('best_meaning', '')})"
    )
    mechanism_section(page, res.attrs.get("model"), key, label)
    if not res.complete:
        page.p("not finished: the figures and tables below wait for its end", "fail")
        return
    if cfg["algorithm"]["kind"] in ("ga", "nsga2"):
        page.figure(
            f"{key}-convergence",
            lambda p: plot_convergence(res, p),
            f"{label}: best and mean fitness per generation",
        )
    else:  # SLSQP alone (after a scan, perhaps): no generations to draw
        page.p(f"{label}: {cfg['algorithm']['kind']} (SLSQP) without a genetic algorithm")
    if res.responses():  # a run fitted to a feel alone (a curve) has no trial to draw
        page.figure(
            f"{key}-fit", lambda p: plot_fit(res, p), f"{label}: best response against target"
        )
    else:  # fitted to a chosen feel alone: no trial to respond to
        page.p(f"{label}: no trials (fitted to a chosen feel's force-angle curve)")
    errors = s.get("channel_errors") or {}
    if errors:
        first = next(iter(errors.values()))
        deg = "rms_deg" in first
        dunit = first["unit"].replace("rad", "deg")
        header = ["trial", "role", f"RMS [{first['unit']}]", f"largest [{first['unit']}]"]
        header += [f"RMS [{dunit}]", f"largest [{dunit}]"] if deg else []
        rows = []
        for trial, e in errors.items():
            row = [trial, e["role"], f"{e['rms']:.3g}", f"{e['max']:.3g}"]
            row += [f"{e['rms_deg']:.3g}", f"{e['max_deg']:.3g}"] if deg else []
            rows.append(row)
        page.table(header, rows, f"{label}: error of {first['channel']} per trial, model - target")
    _integration_error(page, s.get("integration_error"))
    perceptual_section(page, res, changes, key)
    front_section(page, res, key)
    page.raw(table_html(spec_table(res)))
    tol = tolerances_of(res)
    if tol is not None:
        page.pre("\n".join(tol.summary_lines()))
        fc = res.record.perceptual_check
        if fc is not None and changes.apply(fc.jnd) != fc.jnd:
            page.p(
                f"{label}: the yield is the run's, found with its own JNDs when it ran, "
                "not with this report's changes",
                "small",
            )
        page.figure(
            f"{key}-tolerance",
            lambda p: plot_tolerances(tol, label, p),
            f"{label}: the yield each specification's process tolerance costs (the doors "
            "gained were it built exactly; red: changed from the AS-IS door); the "
            "force-angle curves of the doors built to the process (dashed: 95 % of them) "
            "against the chosen feel's JND band",
        )
    ident = res.identifiability()
    if ident is not None:
        if tol is None:
            page.pre(ident.format())
        else:  # the table's "feel determines it": no interval beside a tolerance
            page.p(
                f"{label}: whether the feel determines each specification is the table's "
                "column; the correlations of the estimates at the smallest change:",
                "small",
            )
        if len(ident.names) > 1:
            page.figure(
                f"{key}-correlation",
                lambda p: _correlation_figure(ident, label, p),
                f"{label}: correlation of the estimates at the optimum",
            )


def _integration_error(page: ReportPage, entry: dict | None) -> None:
    """The answer's integration error beside the fit error, as ``show`` prints it; its
    warning (not small against the fit error) in the page's warning style."""
    lines = format_integration_error(entry)
    warning = [line for line in lines if line.startswith("warning:")]
    page.pre("\n".join(line for line in lines if line not in warning))
    for line in warning:
        page.p(line, "fail")


def _correlation_figure(ident, label: str, path) -> None:
    from matplotlib.figure import Figure

    n = len(ident.names)
    size = 2.2 + 0.55 * n
    fig = Figure(figsize=(size + 1.2, size), layout="constrained")
    ax = fig.subplots()
    c = np.asarray(ident.correlation, dtype=float)
    # an undetermined parameter has no correlation: a grey cell and "-", not a 0
    im = ax.imshow(np.ma.masked_invalid(c), cmap="RdBu_r", vmin=-1, vmax=1)
    ax.set_facecolor("0.8")
    ax.set_xticks(range(n), ident.names, rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(n), ident.names, fontsize=8)
    for i in range(n):
        for j in range(n):
            v = c[i, j]
            text = f"{v:+.2f}" if np.isfinite(v) else "-"
            color = "white" if np.isfinite(v) and abs(v) > 0.6 else "black"
            ax.text(j, i, text, ha="center", va="center", fontsize=7, color=color)
    fig.colorbar(im, ax=ax, label="correlation")
    ax.set_title(f"{label}: correlation of the estimates", fontsize=10)
    save_figure(fig, path, dpi=110)
