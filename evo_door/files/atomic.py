"""Writing a file so that a crash leaves either the old file or the new one.

Every file evo-door writes goes through :func:`atomic_write`: the content is written
under a temporary name in the target's folder, flushed to the disk (``fsync``) and
renamed over the target (``os.replace``, atomic on POSIX and Windows). What the file
system refuses (a full disk, a read-only folder) is one line,
:class:`~evo_door.errors.WriteError`, that names the target and what is left: the
temporary is removed. Reading text (:func:`read_text`) is here too, with the one-line
errors of a file that is not text.
"""

from __future__ import annotations

import errno
import itertools
import os
import re
from contextlib import contextmanager
from pathlib import Path

from evo_door.errors import UserError, WriteError

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

    What the file system refuses (a full disk, a read-only folder, no permission: an
    ``OSError``, or the error text of HDF5 that carries its errno) is a
    :class:`~evo_door.errors.WriteError` naming ``path`` and the reason: the temporary
    is removed, and so are the folders ``make_folder`` made for it.

    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> with atomic_write(folder / "a.txt") as tmp:
    ...     _ = tmp.write_text("hello")
    >>> (folder / "a.txt").read_text(), sorted(p.name for p in folder.iterdir())
    ('hello', ['a.txt'])
    """
    path = Path(path)
    made: list[Path] = []
    if make_folder and not path.parent.exists():
        made = [p for p in (path.parent, *path.parent.parents) if not p.exists()]
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise WriteError(path, write_reason(exc) or str(exc)) from None
    path = check_folder(path)
    tmp = _temporary_name(path)
    try:
        yield tmp
        if not tmp.is_file():
            raise RuntimeError(f"atomic_write: nothing was written to {tmp}")
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        _publish(tmp, path)
        _fsync_folder(path.parent)
    except (OSError, RuntimeError) as exc:
        # a full or read-only file system, no permission...: say which file, not the
        # temporary's hidden name (a RuntimeError only when HDF5's text names an errno)
        reason = write_reason(exc)
        if reason is None:
            raise
        _remove(tmp)  # before the folders it is in
        _remove_folders(made)
        raise WriteError(path, reason) from None
    finally:
        _remove(tmp)


#: the files this process claimed as new (:func:`expect_new`): the first write of each
#: creates it, and never replaces a file another command made there meanwhile
_NEW: set[Path] = set()


def expect_new(path, new: bool = True) -> None:
    """Note that ``path`` did not exist when this command claimed it
    (:func:`~evo_door.files.claims.claim_outputs`): its first :func:`atomic_write`
    creates it, and refuses in one line if another command created it since.
    ``new=False``: the command may replace it (claimed with ``--force`` or ``--append``)."""
    if new:
        _NEW.add(Path(path).absolute())
    else:
        _NEW.discard(Path(path).absolute())


def _publish(tmp: Path, path: Path) -> None:
    """Rename the finished temporary onto ``path``: a new file by a hard link, which
    fails where a file is there already (two commands creating one file: the second
    is refused, nothing is lost); a file this command may replace by ``os.replace``."""
    key = path.absolute()
    if key not in _NEW:
        os.replace(tmp, path)
        return
    created_meanwhile = UserError(
        f"{path}: another command created this file while this one ran; it was not "
        "replaced: give another name, or --force to replace it"
    )
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise created_meanwhile from None
    except OSError as exc:  # a file system without hard links: the check, then the rename
        if exc.errno not in _NO_LINKS:
            raise
        if path.exists():
            raise created_meanwhile from None
        os.replace(tmp, path)
    _NEW.discard(key)


#: what ``os.link`` raises on a file system without hard links
_NO_LINKS = {errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.ENOSYS, errno.EXDEV}


#: errno -> what a refused write says (the rest: the system's own words)
WRITE_REASONS = {
    number: reason
    for name, reason in (
        ("ENOSPC", "no space left on device"),
        ("EDQUOT", "disk quota exceeded"),
        ("EROFS", "read-only file system"),
        ("EACCES", "permission denied"),
        ("EPERM", "permission denied"),
        ("EFBIG", "file too large"),
    )
    if (number := getattr(errno, name, None)) is not None
}


def write_reason(exc: BaseException) -> str | None:
    """Why a write failed, in a few words, or None when ``exc`` is no file system error.

    An ``OSError`` says it by its errno (:data:`WRITE_REASONS`), else by its text; h5py
    hides the errno in its message (``errno = 28, error message = '...'``), in an
    ``OSError`` or a ``RuntimeError``: that is read too. A ``RuntimeError`` without an
    errno is not a file system error (None).

    >>> write_reason(OSError(errno.ENOSPC, "No space left on device"))
    'no space left on device'
    >>> write_reason(RuntimeError("Can't close file (file write failed: errno = 30, "
    ...                           "error message = 'Read-only file system')"))
    'read-only file system'
    >>> write_reason(RuntimeError("not a file system error")) is None
    True
    """
    text = str(exc)
    number = exc.errno if isinstance(exc, OSError) else None
    if not number:
        found = re.search(r"errno = (\d+)", text)
        number = int(found.group(1)) if found else None
    if number in WRITE_REASONS:
        return WRITE_REASONS[number]
    said = re.search(r"error message = '([^']+)'", text)
    if said:
        words = said.group(1)
    elif isinstance(exc, OSError):
        words = exc.strerror or (text.splitlines() or [type(exc).__name__])[0][:120]
    else:
        return None
    return words[:1].lower() + words[1:]


def folder_reason(folder) -> str:
    """Why ``folder`` cannot be written in: a read-only file system, or no permission."""
    try:
        if os.statvfs(folder).f_flag & os.ST_RDONLY:
            return WRITE_REASONS[errno.EROFS]
    except (OSError, AttributeError):  # pragma: no cover - Windows: no statvfs
        pass
    return WRITE_REASONS[errno.EACCES]


def write_bytes(path, data) -> None:
    """Write ``data`` (bytes, or a buffer) as the new file ``path``, with plain writes.

    The room for it is claimed first where the system can (``posix_fallocate``), so a
    full disk says so before a byte is written; either way it is an ``OSError``
    (ENOSPC), which :func:`atomic_write` turns into one line.
    """
    view = memoryview(data).cast("B")
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    try:
        if len(view) and hasattr(os, "posix_fallocate"):
            try:
                os.posix_fallocate(fd, 0, len(view))
            except OSError as exc:
                if exc.errno in WRITE_REASONS:
                    raise
                # a file system that cannot preallocate (EOPNOTSUPP, EINVAL): the
                # writes themselves say whether there is room
        while view:
            view = view[os.write(fd, view) :]
    finally:
        os.close(fd)


def _remove(path: Path) -> None:
    try:
        path.unlink()
    except OSError:  # gone already (or never made: a read-only folder)
        pass


def _remove_folders(made: list[Path]) -> None:
    """Remove the folders in ``made`` (deepest first), each only if still empty."""
    for folder in made:
        try:
            folder.rmdir()
        except OSError:
            break


@contextmanager
def partial_output(folder):
    """A block that writes several files into ``folder`` (made if need be): when the
    file system refuses one (:class:`~evo_door.errors.WriteError`, or an ``OSError``
    such as a folder that cannot be made), the files the block added and the folder,
    if the block made it, are removed, and the error says so.

    Files that were there before and that the block had already replaced cannot be
    taken back: the error counts them.
    """
    folder = Path(folder)
    existed = folder.is_dir()
    before = {p: _stamp(p) for p in folder.iterdir()} if existed else {}
    try:
        yield folder
    except (WriteError, OSError) as exc:
        if not isinstance(exc, WriteError):
            exc = WriteError(exc.filename or folder, write_reason(exc) or str(exc))
        added = [p for p in folder.iterdir() if p not in before] if folder.is_dir() else []
        added = [p for p in added if p.is_file()]
        for p in added:
            _remove(p)
        if not existed:
            _remove_folders([folder])
        replaced = sum(_stamp(p) != stamp for p, stamp in before.items())
        parts = [f"its new files ({_files(len(added))}) were removed"] if added else []
        if replaced:
            parts.append(
                f"{_files(replaced)} in {folder} already replaced by new ones, the rest as "
                "they were"
            )
        raise exc.leaving("; ".join(parts) or exc.left) from None


def _files(n: int) -> str:
    return f"{n} file{'s' * (n != 1)}"


def _stamp(path: Path) -> tuple:
    """What changes when a file is replaced (an atomic write: a new inode)."""
    try:
        st = path.stat()
    except OSError:
        return ()
    return (st.st_ino, st.st_mtime_ns, st.st_size)


def read_text(path, what: str = "text file") -> str:
    """The text of ``path`` (UTF-8, a byte-order mark dropped), or a one-line error.

    A missing file, a folder, or binary content (an HDF5 file or a picture given where
    YAML or CSV is expected) each say so, naming the file and the ``what`` expected.
    """
    path = Path(path)
    a_what = f"{'an' if what[:1] in 'aeiou' else 'a'} {what}"
    if "\0" in str(path):  # a name from a file (YAML): no file has it
        raise UserError(f"{str(path)!r}: a file name with a NUL character; not {a_what}")
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
