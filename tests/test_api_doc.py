"""docs/api.md is run, as a notebook would run it: its ``python`` blocks in order, in one
namespace, in a fresh folder holding the repository's ``experiments/``; the ``text``
block right after a ``python`` block is what that block prints, and must be exactly
that. A block that prints something and shows nothing fails too.

    EVO_DOOR_WRITE_DOCS=1 pytest tests/test_api_doc.py   # rewrite the shown output

(after a change that moves a number; the diff of the doc is then reviewed).
"""

from __future__ import annotations

import contextlib
import io
import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "api.md"

# a fenced block: its language and its text
_BLOCK = re.compile(r"^```(\w*)\n(.*?)^```\n", re.M | re.S)


def blocks(text: str) -> list[tuple[str, str, re.Match | None]]:
    """Each ``python`` block with the ``text`` block that follows it (only blank lines
    between), or None: (code, shown output, its match)."""
    found = list(_BLOCK.finditer(text))
    out = []
    for k, m in enumerate(found):
        if m.group(1) != "python":
            continue
        nxt = found[k + 1] if k + 1 < len(found) else None
        shown = None
        if nxt is not None and nxt.group(1) == "text" and not text[m.end() : nxt.start()].strip():
            shown = nxt
        out.append((m.group(2), shown.group(2) if shown else "", shown))
    return out


def run_blocks(text: str) -> list[str]:
    """What each python block of ``text`` prints, run in order in one namespace."""
    namespace: dict = {"__name__": "__api_doc__"}
    printed = []
    for k, (code, _, _) in enumerate(blocks(text)):
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            exec(compile(code, f"{DOC.name}, python block {k + 1}", "exec"), namespace)
        printed.append(out.getvalue())
    return printed


def _clean(text: str) -> str:
    return "\n".join(line.rstrip() for line in text.strip("\n").splitlines())


def test_the_api_walk_through_runs_and_prints_what_it_shows(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "experiments").symlink_to(ROOT / "experiments")
    text = DOC.read_text()
    found = blocks(text)
    assert len(found) >= 8, "docs/api.md lost its python blocks"
    printed = run_blocks(text)
    if os.environ.get("EVO_DOOR_WRITE_DOCS") == "1":
        _write(text, found, printed)
        return
    for k, ((code, shown, _), got) in enumerate(zip(found, printed)):
        assert _clean(got) == _clean(shown), (
            f"docs/api.md, python block {k + 1} printed something else than the doc shows "
            f"(EVO_DOOR_WRITE_DOCS=1 rewrites it):\n{code}\n--- printed:\n{got}"
        )


def _write(text: str, found, printed: list[str]) -> None:
    """The doc with each block's shown output replaced by what it printed."""
    for (_, _, shown), got in sorted(
        zip(found, printed), key=lambda p: -(p[0][2].start() if p[0][2] else -1)
    ):
        if shown is None:
            assert not got.strip(), f"a block prints but shows nothing:\n{got}"
            continue
        text = text[: shown.start(2)] + _clean(got) + "\n" + text[shown.end(2) :]
    DOC.write_text(text)


def test_the_reader_of_the_doc_pairs_code_and_output():
    """The pairing the test above relies on (a vacuous reader would pass it)."""
    text = (
        "a\n```python\nprint(1)\n```\n\n```text\n1\n```\n```python\nx = 2\n```\n```bash\nls\n```\n"
    )
    got = [(code, shown) for code, shown, _ in blocks(text)]
    assert got == [("print(1)\n", "1\n"), ("x = 2\n", "")]
    assert run_blocks(text) == ["1\n", ""]
