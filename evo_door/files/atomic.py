"""Writing a file so that a crash leaves either the old file or the new one.

Every file evo-door writes goes through :func:`atomic_write`: the content is written
under a temporary name in the target's folder, flushed to the disk (``fsync``) and
renamed over the target (``os.replace``, atomic on POSIX and Windows). Reading text
(:func:`read_text`) is here too, with the one-line errors of a file that is not text.
"""

from __future__ import annotations

import itertools
import os
import re
from contextlib import contextmanager
from pathlib import Path

from evo_door.errors import UserError

#: a counter that tells apart the temporaries of one process (several writers of one
#: file in one process, threads included, each get their own name): a plain counter is
#: the state it needs, and it holds nothing else
_serial = itertools.count()


def check_folder(path) -> Path:
    """``path`` as a Path whose folder exists and is a folder (else one-line error)."""
    path = Path(path)
    parent = path.parent
    if not parent.exists():
        raise UserError(f"{path}: folder {parent} does not exist")
    if not parent.is_dir():
        raise UserError(f"{path}: {parent} is a file, not a folder")
    if path.is_dir():
        raise UserError(f"{path}: is a folder; give a file name")
    return path


def _temporary_name(path: Path) -> Path:
    return path.with_name(f".{path.name}.tmp-{os.getpid()}-{next(_serial)}")


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (POSIX; a no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # pragma: no cover - Windows
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - some file systems refuse fsync on folders
        pass
    finally:
        os.close(fd)


@contextmanager
def atomic_write(path, make_folder: bool = False):
    """Yield a temporary path next to ``path``; on success it replaces ``path``.

    Write the whole content to the yielded path (close it before the block ends). On
    leaving the block the temporary is flushed to the disk and renamed onto ``path``;
    an exception (or a kill) leaves ``path`` as it was and no temporary behind (a kill
    leaves one that :func:`remove_stale_temporaries` clears).

    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> with atomic_write(folder / "a.txt") as tmp:
    ...     _ = tmp.write_text("hello")
    >>> (folder / "a.txt").read_text(), sorted(p.name for p in folder.iterdir())
    ('hello', ['a.txt'])
    """
    path = Path(path)
    if make_folder and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    path = check_folder(path)
    tmp = _temporary_name(path)
    try:
        yield tmp
        if not tmp.is_file():
            raise RuntimeError(f"atomic_write: nothing was written to {tmp}")
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        _fsync_folder(path.parent)
    except OSError as exc:
        # a read-only or full file system, no permission...: say which file, not the
        # temporary's hidden name
        raise UserError(f"{path}: cannot write ({_reason(exc)})") from None
    finally:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass


def _reason(exc: OSError) -> str:
    """What an OSError says, in a few words (h5py's messages hide errno in the text)."""
    if exc.strerror:
        return exc.strerror
    text = str(exc)
    found = re.search(r"error message = '([^']+)'", text)
    return found.group(1) if found else text.splitlines()[0][:120]


def read_text(path, what: str = "text file") -> str:
    """The text of ``path`` (UTF-8, a byte-order mark dropped), or a one-line error.

    A missing file, a folder, or binary content (an HDF5 file or a picture given where
    YAML or CSV is expected) each say so, naming the file and the ``what`` expected.
    """
    path = Path(path)
    a_what = f"{'an' if what[:1] in 'aeiou' else 'a'} {what}"
    if path.is_dir():
        raise UserError(f"{path}: is a folder, not {a_what}")
    if not path.is_file():
        raise UserError(f"{path}: {what} not found")
    data = path.read_bytes()
    if b"\0" in data[:8192]:
        kind = " (an HDF5 file)" if data.startswith(b"\x89HDF") else ""
        raise UserError(f"{path}: binary data{kind}, not {a_what}")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise UserError(f"{path}: line {line} is not UTF-8 text; not {a_what}") from None


def write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_write(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def check_image_path(path) -> str:
    """The image format of ``path`` (its extension), or a one-line error.

    Commands that write a table and a figure call this first, so that a bad figure
    name leaves no table behind either.
    """
    from matplotlib.backend_bases import FigureCanvasBase

    path = check_folder(path)
    fmt = path.suffix.lower().lstrip(".")
    supported = FigureCanvasBase.get_supported_filetypes()
    if fmt not in supported:
        raise UserError(
            f"{path}: cannot write a {fmt or 'extension-less'} image; "
            f"use one of {', '.join('.' + k for k in sorted(supported))}"
        )
    return fmt


def save_figure(fig, path, dpi: int = 110) -> None:
    """Save a matplotlib figure atomically, the format from the file name's extension."""
    fmt = check_image_path(path)
    with atomic_write(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=fmt)


def remove_stale_temporaries(path) -> list[Path]:
    """Delete the temporaries that killed writers of ``path`` left behind.

    A temporary whose writer (by the process id in its name) is still alive is kept.
    """
    path = Path(path)
    removed = []
    for tmp in path.parent.glob(f".{path.name}.tmp-*"):
        pid = tmp.name.rsplit(".tmp-", 1)[1].split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and _alive(int(pid)):
            continue
        try:
            tmp.unlink()
            removed.append(tmp)
        except OSError:  # pragma: no cover - gone already, or not ours to remove
            pass
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # pragma: no cover - another user's process
        return True
    except OSError:  # pragma: no cover - Windows and the like: assume it is alive
        return True
    return True
