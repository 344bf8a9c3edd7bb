"""A page's Save: the set in force written as a parameter file of the rendered model
(``model:`` its name, every parameter of its declaration) in the save folder, under a
name of its own (never over another file), and recorded in the log: ``evo-door render
MODEL --params FILE`` renders it again."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

from evo_door.errors import UserError

if TYPE_CHECKING:
    from evo_door.render.console.page import Page
    from evo_door.render.console.session import Console

#: longest participant id and file stem (characters)
MAX_ID = 64
_STEM = re.compile(r"[^A-Za-z0-9_-]+")


def safe_stem(name) -> str:
    """A file stem of letters, digits, ``_`` and ``-`` only (``console`` if none is left).

    >>> safe_stem("../x"), safe_stem("P07 soft/door"), safe_stem("..")
    ('x', 'P07_soft_door', 'console')
    """
    stem = _STEM.sub("_", str(name)).strip("_-")[:MAX_ID]
    return stem or "console"


def unused_path(folder: Path, stem: str, suffix: str = ".yaml") -> Path:
    """``folder/stem.yaml``, or ``stem-2``, ``stem-3`` ... when taken, reserved by an
    empty file created exclusively (so two saves never pick one name)."""
    for k in range(1, 100000):
        path = folder / (f"{stem}{suffix}" if k == 1 else f"{stem}-{k}{suffix}")
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            continue
        os.close(fd)
        return path
    raise UserError(f"no free file name for {stem!r} in {folder}")


async def on_save(console: Console, page: Page, message: dict) -> None:
    from evo_door.files import check_folder
    from evo_door.params.sets import ParamSet

    stem = safe_stem(message.get("name") or console.participant or "console")
    folder = console.save_dir.resolve()
    check_folder(folder / "x.yaml")
    now = await console.refresh()
    note = "chosen in the evo-door console"
    if console.participant:
        note += f" by participant {console.participant}"
    ps = ParamSet.from_mapping(console.tunable.table, now, description=note)
    path = unused_path(folder, stem)
    try:
        ps.to_yaml(path)
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    await console.event("save", path=str(path))
    console.broadcast({"type": "saved", "path": str(path)})
