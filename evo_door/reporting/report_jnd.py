"""The report page of a JND file (``evo-door report J.h5``): the session's summary, its
trials, the track and the psychometric fit as figures."""

from __future__ import annotations

from pathlib import Path

from evo_door.errors import UserError
from evo_door.files import write_text
from evo_door.perception.jnd_file import JndRecord
from evo_door.perception.jnd_show import format_jnd, plot_psychometric, plot_track
from evo_door.reporting.page import ReportPage


def default_jnd_folder(path) -> Path:
    path = Path(path)
    return path.with_name(path.stem + "-report")


def write_jnd_report(record: JndRecord, out=None) -> Path:
    """Write the page of ``record`` (and its two figures as PNG) into ``out`` (default
    ``<J>-report/`` next to the file); returns the HTML file."""
    folder = Path(out) if out else default_jnd_folder(record.path)
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{folder}: exists and is not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    page = ReportPage(folder)
    page.h(1, f"JND session: {record.param}")
    page.pre(format_jnd(record))
    n = int(len(record.trials.get("step", ())))
    if n:
        page.figure(
            "track",
            lambda p: plot_track(record, p),
            "The step of each trial (log axis; filled: right, open: wrong) and the "
            "estimated Weber fraction with its 95 % interval.",
        )
        page.figure(
            "psychometric",
            lambda p: plot_psychometric(record, p),
            "The proportion of right answers per step bin (the count beside each), the "
            "fitted psychometric function, its 75 % point at the Weber fraction and the "
            "fraction's 95 % interval.",
        )
    else:
        page.p("No trial was answered: nothing to draw.")
    rows = (
        [
            [
                str(i + 1),
                f"{100 * float(s):.3g}",
                f"{float(c):.4g}",
                str(int(o)),
                str(int(a)),
                "yes" if bool(ok) else "no",
                f"{float(t):.2f}",
            ]
            for i, (s, c, o, a, ok, t) in enumerate(
                zip(
                    *(
                        record.trials[k]
                        for k in ("step", "comparison", "order", "answer", "correct", "time")
                    )
                )
            )
        ]
        if n
        else []
    )
    page.table(
        [
            "trial",
            "step [%]",
            f"comparison [{record.unit}]",
            "comparison in",
            "answer",
            "right",
            "time [s]",
        ],
        rows,
        caption="Every answered trial",
    )
    target = folder / "report.html"
    write_text(target, page.document(f"{record.path.name}: evo-door JND report"))
    return target
