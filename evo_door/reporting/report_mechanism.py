"""A report's diagram of a run's mechanism file (``docs/blocks.md``, "Drawing").

A results file names its model; when that is a mechanism file, the run's section shows
the file's block diagram inline (SVG in the page, and ``<key>-mechanism.svg`` beside
it). The results file records the mechanism file's path, not its text: the diagram is
drawn from the file as it is now, read by the same checked reader as every command
(nothing in it runs, nothing is compiled). Where the file is not there (the results
file opened on another machine) or no longer reads, the page says so instead.
"""

from __future__ import annotations

import html
from pathlib import Path

from evo_door.errors import UserError
from evo_door.files import write_text
from evo_door.models.blocks import is_mechanism_spec
from evo_door.models.blocks.drawing import mechanism_svg
from evo_door.models.blocks.mechanism import read_mechanism
from evo_door.reporting.page import ReportPage


def mechanism_section(page: ReportPage, model: str | None, key: str, label: str) -> None:
    """The diagram of ``model`` (a results file's model name) if it is a mechanism
    file, a one-line note if that file cannot be read here, nothing for another model."""
    if not model or not is_mechanism_spec(model):
        return
    path = Path(model)
    if not path.is_file():
        page.p(
            f"{label}: no diagram of the mechanism: its file {path} is not on this machine "
            "(a results file names its mechanism file, it does not hold it); "
            "evo-door draw FILE.yaml draws it where it is",
            "small",
        )
        return
    try:
        mech = read_mechanism(path)
    except UserError as exc:
        page.p(f"{label}: no diagram of the mechanism: {exc}", "small")
        return
    svg = mechanism_svg(mech)
    write_text(page.folder / f"{key}-mechanism.svg", svg)
    caption = (
        f"{label}: the mechanism {mech.name} as its file {path.name} describes it now, "
        "with the file's values (not the fit's); evo-door draw draws it"
    )
    page.raw(
        f'<figure class="diagram">{svg.rstrip()}<figcaption>{html.escape(caption)}</figcaption></figure>'
    )
