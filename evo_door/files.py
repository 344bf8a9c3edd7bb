"""Writing files safely, and the one way metadata is stored in HDF5.

Every file evo-door writes (trials, results files, parameter sets, CSV tables,
figures) goes through :func:`atomic_write`: the content is written under a temporary
name in the target's folder, flushed to the disk (``fsync``) and renamed over the
target (``os.replace``, atomic on POSIX and Windows). A crash at any moment leaves
either the previous file or the new one, never half of one; HDF5 in particular is not
crash-safe while a file is open for writing.

:class:`FileLock` is an advisory lock on a file that one process owns while it works on
it (a run writing its results file), so that two processes never write one file.

:func:`claim_outputs` is the one rule of what a command may write over, which every
command that writes a file calls before it starts its work (see its docstring).

HDF5 files are written from a nested dict, the *tree* (:func:`write_h5`)::

    {"@attrs": {"format": "evo-door run", "seed": 1, "free": ["mass", "F_load"]},
     "best": {"@attrs": {...}, "x": np.array([...])},
     "trials": Keep(build)}          # copied unchanged from the file being replaced

A dict is a group and its ``"@attrs"`` entry the group's attributes; an array (or a
list of numbers) is a dataset, a :class:`Dataset` a dataset with attributes, a str a
scalar text dataset. Attributes hold str, int, float and bool as they are; anything
else (dict, list, None) is stored as JSON text behind the prefix ``json:``
(:func:`encode_attr`), and so is a str that itself starts with ``json:``, so that
reading is never ambiguous (:func:`decode_attr`). Files written by evo-door 0.1 with
the older encoding (a ``NAME.__json__`` flag beside the attribute) still read.
"""

from __future__ import annotations

import errno
import itertools
import json
import os
import re
import sys
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from evo_door.errors import UserError

ATTRS = "@attrs"
JSON_PREFIX = "json:"
#: flag attribute of the encoding used before this module (trial files, format 1)
_LEGACY_JSON_FLAG = ".__json__"
#: a counter that tells apart the temporaries of one process
_serial = itertools.count()


def h5py():
    """The h5py module, imported on first use (it costs ~0.1 s at start-up)."""
    import h5py as module

    return module


# -- JSON of metadata --------------------------------------------------------------
def jsonable(value):
    """``value`` with numpy scalars and arrays (and tuples, bytes) as plain Python.

    >>> import numpy as np
    >>> jsonable({"x": np.arange(2), "k": np.int64(3), "pair": (1.5, b"a")})
    {'x': [0, 1], 'k': 3, 'pair': [1.5, 'a']}
    """
    import numpy as np  # here, not at the top: commands that write no file start quicker

    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bytes):
        return value.decode()
    return value


def to_json(value, indent=None) -> str:
    """JSON text of ``value`` (numpy included; NaN and inf as JavaScript writes them)."""
    separators = None if indent is not None else (",", ":")
    return json.dumps(jsonable(value), separators=separators, indent=indent, allow_nan=True)


def encode_attr(value):
    """An HDF5 attribute value for ``value`` (see the module docstring).

    >>> encode_attr({"range": [-1, 1]}), encode_attr(None), encode_attr(2.5)
    ('json:{"range":[-1,1]}', 'json:null', 2.5)
    >>> decode_attr(encode_attr("json: is text here"))
    'json: is text here'
    """
    if value is None or isinstance(value, (dict, list, tuple)):
        return JSON_PREFIX + to_json(value)
    if isinstance(value, str) and value.startswith(JSON_PREFIX):
        return JSON_PREFIX + to_json(value)
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    return value


def decode_attr(value):
    """The Python value of an HDF5 attribute written by :func:`encode_attr`."""
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, str) and value.startswith(JSON_PREFIX):
        return json.loads(value[len(JSON_PREFIX) :])
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def write_attrs(obj, attrs: dict) -> None:
    """Set the attributes of an HDF5 group or dataset from ``attrs``."""
    for name, value in attrs.items():
        obj.attrs[str(name)] = encode_attr(value)


def read_attrs(obj) -> dict:
    """The attributes of an HDF5 group or dataset, decoded (both encodings)."""
    raw = obj.attrs
    out = {}
    for name, value in raw.items():
        if name.endswith(_LEGACY_JSON_FLAG):
            continue
        if name + _LEGACY_JSON_FLAG in raw:
            out[name] = json.loads(decode_attr(value))
        else:
            out[name] = decode_attr(value)
    return out


def attrs_tree(data: dict) -> dict:
    """A nested dict as a tree of groups holding attributes (``truth/params/...``).

    >>> attrs_tree({"model": "door", "params": {"mass": 1.2}})
    {'@attrs': {'model': 'door'}, 'params': {'@attrs': {'mass': 1.2}}}
    """
    out = {ATTRS: {}}
    for key, value in data.items():
        if isinstance(value, dict):
            out[str(key)] = attrs_tree(value)
        else:
            out[ATTRS][str(key)] = value
    return out


def tree_attrs(tree: dict) -> dict:
    """The inverse of :func:`attrs_tree` (datasets, if any, are left out)."""
    out = dict(tree.get(ATTRS, {}))
    for key, value in tree.items():
        if key != ATTRS and isinstance(value, dict):
            out[key] = tree_attrs(value)
    return out


# -- atomic writes -----------------------------------------------------------------
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


# -- what a command may write over -------------------------------------------------
#: An output that holds trials (``data import``, ``rig generate``, a render's log): what
#: was measured or generated, a participant's session. Replaced only with ``--force``
#: (or extended with ``--append`` where the command has it).
TRIALS = "trials"
#: An output computed from the command's inputs (a CSV table, a figure, a report, a
#: parameter file written by ``params --write`` or ``export-spec``): running the command
#: again makes it again, so it is replaced, and the command says so on stderr.
DERIVED = "derived"
#: Results files (``run``) follow the same idea with more to say (complete or
#: interrupted, resume): :func:`evo_door.experiment.runner.claim_output`.


@dataclass(frozen=True)
class Output:
    """A file a command is about to write: its ``path``, the ``option`` that named it
    (for messages), its ``kind`` (:data:`TRIALS` or :data:`DERIVED`) and whether the
    command makes its folder (``report``) rather than needing it there."""

    path: object
    option: str = "--out"
    kind: str = DERIVED
    makes_folder: bool = False


@dataclass
class Claim:
    """What :func:`claim_outputs` allowed: the existing files the command will replace."""

    replaced: list = field(default_factory=list)

    def note(self) -> None:
        """Say on stderr, in one line, which existing files were replaced (call it once
        the outputs are written)."""
        if self.replaced:
            names = ", ".join(str(p) for p in self.replaced)
            print(f"evo-door: replaced {names}", file=sys.stderr)


def same_file(a, b) -> bool:
    """Whether the paths ``a`` and ``b`` name one file (links and ``..`` resolved)."""
    a, b = Path(a), Path(b)
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)  # hard links
    except OSError:  # one of them does not exist
        return False


def claim_outputs(outputs, inputs=(), *, force: bool = False, append=None) -> Claim:
    """The rule of every command that writes files: may it write ``outputs``?

    Called before the command does its work, so that a refusal leaves everything as
    it was. ``outputs`` are :class:`Output` (those whose path is None are not
    written); ``inputs`` the paths the command reads (None and names that are not
    files, such as a preset, are skipped). Raises a one-line
    :class:`~evo_door.errors.UserError` when

    * an output is one of the inputs: never, ``--force`` or not (``simulate --input X
      --out X`` would destroy its own input), nor one file named by two options;
    * its folder is missing, not a folder, or not writable, or the output is a folder;
    * a :data:`TRIALS` output exists, unless ``force`` (replace it) or ``append``
      (the command adds to it; None: the command has no ``--append``).

    An existing :data:`DERIVED` output is replaced: the returned :class:`Claim` lists
    it, and its :meth:`Claim.note` says so once the command has written. ``force``
    replacing a trial file is said the same way.
    """
    outputs = [o for o in outputs if o.path is not None]
    inputs = [Path(p) for p in inputs if p is not None and Path(p).is_file()]
    claim = Claim()
    for i, out in enumerate(outputs):
        path = Path(out.path)
        # the file itself, or (report) the folder to put it in, is an input
        for source in inputs:
            for target in (path, *path.parents):
                if target.is_file() and same_file(target, source):
                    raise UserError(
                        f"{out.option} {target}: is also an input of this command; evo-door "
                        f"never writes over its input (--force or not): give another "
                        f"{out.option}"
                    )
        for other in outputs[:i]:
            if same_file(path, other.path):
                raise UserError(f"{path}: given to both {other.option} and {out.option}")
        folder = _existing_folder(path) if out.makes_folder else check_folder(path).parent
        if not os.access(folder, os.W_OK):
            raise UserError(f"{path}: cannot write in {folder}")
        if not path.exists():
            continue
        if out.kind == TRIALS and not (force or append):
            extend = " or --append to add to its trials" if append is not None else ""
            raise UserError(
                f"{out.option} {path}: a file is there already; give --force to replace "
                f"it{extend}, or another {out.option}"
            )
        if not (out.kind == TRIALS and append):
            claim.replaced.append(path)
    return claim


def _existing_folder(path: Path) -> Path:
    """The deepest folder above ``path`` that exists (a file on the way: one-line error)."""
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise UserError(f"{path}: {parent} is a file, not a folder")
            return parent
    return Path(".")  # pragma: no cover - a relative path's parents end in "."


# -- locks -------------------------------------------------------------------------
#: lock file -> [descriptor, holders]: the locks this process holds (see FileLock)
_HELD: dict[str, list] = {}


class FileLock:
    """An advisory, exclusive lock on ``path`` for as long as this object holds it.

    The lock lives on a companion file ``.NAME.lock`` next to ``path`` (``path`` itself is
    replaced at every atomic write, so it cannot carry a lock), taken with ``flock``:
    the system releases it when the process dies, however it dies, so a killed run never
    leaves a file locked. :meth:`acquire` does not wait: a file locked by another
    process raises :class:`~evo_door.errors.UserError` saying which process holds it.
    Within one process the lock is shared (counted): a run that opens its own file
    again is not locked out by itself.

    >>> import tempfile
    >>> target = Path(tempfile.mkdtemp()) / "run.h5"
    >>> with FileLock(target) as lock:
    ...     FileLock.holder(target) == os.getpid()
    True
    >>> FileLock.holder(target) is None
    True
    """

    def __init__(self, path):
        self.path = Path(path)
        self.lock_path = self.path.with_name(f".{self.path.name}.lock")
        self._key: str | None = None

    @property
    def held(self) -> bool:
        return self._key is not None

    def acquire(self, what: str = "in use") -> FileLock:
        """Take the lock, or raise ``PATH: WHAT (process N); wait for it ...``."""
        import fcntl

        if self._key is not None:
            return self
        check_folder(self.path)
        key = str(self.lock_path.parent.resolve() / self.lock_path.name)
        if key in _HELD:
            _HELD[key][1] += 1
            self._key = key
            return self
        while True:
            try:
                fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o666)
            except OSError as exc:
                raise UserError(
                    f"{self.path}: cannot write in {self.path.parent} ({exc.strerror})"
                ) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                os.close(fd)
                if exc.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                    raise
                pid = self.holder(self.path)
                by = f"process {pid}" if pid and pid > 0 else "another process"
                raise UserError(
                    f"{self.path}: {what} ({by}); wait for it to finish or stop it first"
                ) from None
            # the holder before us may have removed the lock file after we opened it:
            # then we hold a lock on a file nobody else can see; take the new one
            try:
                same = os.stat(self.lock_path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        _HELD[key] = [fd, 1]
        self._key = key
        return self

    def release(self) -> None:
        """Let the lock go (the last holder in this process removes the lock file)."""
        if self._key is None:
            return
        entry = _HELD[self._key]
        entry[1] -= 1
        if entry[1] == 0:
            del _HELD[self._key]
            try:
                os.unlink(self.lock_path)
            except FileNotFoundError:  # pragma: no cover
                pass
            os.close(entry[0])  # closing releases the flock
        self._key = None

    @staticmethod
    def holder(path) -> int | None:
        """The process id holding the lock on ``path``, or None when it is free."""
        import fcntl

        path = Path(path)
        lock_path = path.with_name(f".{path.name}.lock")
        try:
            fd = os.open(lock_path, os.O_RDONLY)
        except OSError:
            return None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except OSError:
                text = os.pread(fd, 32, 0).decode(errors="replace").strip()
                return int(text) if text.isdigit() else -1
            fcntl.flock(fd, fcntl.LOCK_UN)
            return None
        finally:
            os.close(fd)

    def __enter__(self) -> FileLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()

    def __del__(self):  # a forgotten release
        try:
            self.release()
        except Exception:  # pragma: no cover - interpreter shutting down
            pass


# -- HDF5 trees --------------------------------------------------------------------
@dataclass
class Dataset:
    """A dataset with attributes, in a tree (plain arrays have none)."""

    data: object
    attrs: dict = field(default_factory=dict)


class Keep:
    """Placeholder in a tree: copy this group unchanged from the file being replaced.

    A results file is rewritten whole at every checkpoint; groups that never change
    (the trials) are copied from the previous version with HDF5's object copy, which
    moves the stored, compressed bytes instead of compressing them again. ``build()``
    gives the group when there is no previous version to copy from.
    """

    def __init__(self, build):
        self.build = build


def write_group(
    group, tree: dict, compression: int = 1, compress_above: int = 4096, keep=None
) -> None:
    """Write ``tree`` (see the module docstring) into an open HDF5 group.

    :class:`Keep` entries, at any depth, are appended to ``keep`` as (HDF5 path,
    placeholder) for :func:`write_h5` to copy; without ``keep`` they are built.
    """
    import numpy as np

    h5 = h5py()
    for key, value in tree.items():
        if key == ATTRS:
            write_attrs(group, value)
            continue
        if isinstance(value, Keep):
            if keep is not None:
                keep.append((f"{group.name.rstrip('/')}/{key}", value))
                continue
            value = value.build()
        if isinstance(value, dict):
            write_group(
                group.create_group(key, track_order=True), value, compression, compress_above, keep
            )
        elif isinstance(value, str):
            group.create_dataset(key, data=value, dtype=h5.string_dtype())
        else:
            attrs = {}
            if isinstance(value, Dataset):
                value, attrs = value.data, value.attrs
            data = np.asarray(value)
            if data.dtype == object:
                raise TypeError(f"cannot store {key!r}: object array")
            opts = (
                {"compression": "gzip", "compression_opts": compression, "shuffle": True}
                if data.ndim >= 1 and data.size >= compress_above
                else {}
            )
            ds = group.create_dataset(key, data=data, track_times=False, **opts)
            write_attrs(ds, attrs)


def read_group(group) -> dict:
    """An open HDF5 group as a tree: groups as dicts, datasets as arrays or str."""
    h5 = h5py()
    out = {ATTRS: read_attrs(group)}
    for key, item in group.items():
        if isinstance(item, h5.Group):
            out[key] = read_group(item)
        elif h5.check_string_dtype(item.dtype) is not None and item.shape == ():
            v = item[()]
            out[key] = v.decode() if isinstance(v, bytes) else str(v)
        else:
            out[key] = item[()]
    return out


def write_h5(
    path, tree: dict, compression: int = 1, compress_above: int = 4096, make_folder: bool = False
) -> None:
    """Write ``tree`` as the HDF5 file ``path``, atomically.

    :class:`Keep` entries (at any depth) are copied from the same place in the file
    being replaced when it has them, and built otherwise. ``compression`` is the gzip
    level of datasets of at least ``compress_above`` elements.
    """
    h5 = h5py()
    path = Path(path)
    keep: list = []
    with atomic_write(path, make_folder=make_folder) as tmp:
        with h5.File(tmp, "w", track_order=True) as f:
            write_group(f, tree, compression, compress_above, keep)
            old = None
            if keep and path.is_file():
                try:
                    old = h5.File(path, "r")
                except OSError:
                    old = None
            try:
                for name, placeholder in keep:
                    parent, _, key = name.rpartition("/")
                    target = f[parent or "/"]
                    if old is not None and name in old:
                        old.copy(old[name], target, name=key)
                    else:
                        write_group(
                            target.create_group(key, track_order=True),
                            placeholder.build(),
                            compression,
                            compress_above,
                        )
            finally:
                if old is not None:
                    old.close()


def open_h5(path, what: str = "HDF5 file"):
    """Open an HDF5 file for reading, or raise a one-line error naming it."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: {what} not found")
    if path.stat().st_size == 0:
        raise UserError(f"{path}: empty file")
    try:
        return h5py().File(path, "r")
    except OSError as exc:
        raise UserError(f"{path}: not a readable HDF5 file ({exc})") from None
