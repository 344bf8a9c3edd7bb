"""How a report page is built: a self-contained HTML page of headings, paragraphs,
tables and figures (PNG files written next to it and embedded as base64; styles inline;
nothing else needed to read it). What goes on the page is :mod:`.report`'s and
:mod:`.report_case_study`'s.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

STYLE = (
    "body{font-family:sans-serif;margin:2em auto;max-width:72em;line-height:1.4;color:#222}"
    "table{border-collapse:collapse;margin:.8em 0}td,th{border:1px solid #bbb;"
    "padding:.15em .5em;text-align:left;font-size:.92em}caption{text-align:left;"
    "font-weight:bold;margin-bottom:.3em}tr.flag{background:#fde8e8}img{max-width:100%}"
    "figure{margin:1em 0}figcaption{font-size:.9em;color:#555}pre{background:#f6f6f6;"
    "padding:.6em;overflow-x:auto;font-size:.85em}.fail{color:#a00;font-weight:bold}"
    ".pass{color:#070;font-weight:bold}nav a{margin-right:1em}"
    "figure.diagram svg{max-width:100%;height:auto}"
)


class ReportPage:
    """The page being built: sections of HTML, figures written and embedded."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.parts: list[str] = []
        self.figures: list[Path] = []

    def h(self, level: int, text: str, anchor: str = "") -> None:
        a = f' id="{html.escape(anchor)}"' if anchor else ""
        self.parts.append(f"<h{level}{a}>{html.escape(text)}</h{level}>")

    def p(self, text: str, cls: str = "") -> None:
        c = f' class="{cls}"' if cls else ""
        self.parts.append(f"<p{c}>{html.escape(text)}</p>")

    def pre(self, text: str) -> None:
        self.parts.append(f"<pre>{html.escape(text)}</pre>")

    def raw(self, text: str) -> None:
        self.parts.append(text)

    def table(self, header: list[str], rows: list[list[str]], caption: str = "") -> None:
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
        body = "".join(
            "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
            for row in rows
        )
        self.parts.append(
            f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
        )

    def figure(self, name: str, draw, caption: str) -> None:
        """``draw(path)`` writes the PNG; it is kept in the folder and embedded."""
        path = self.folder / f"{name}.png"
        draw(path)
        self.figures.append(path)
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        self.parts.append(
            f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )

    def document(self, title: str) -> str:
        """The whole page: the sections in order, the styles inline."""
        body = "\n".join(self.parts)
        return (
            '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title><style>{STYLE}</style>"
            f"</head><body>\n{body}\n</body></html>\n"
        )
