"""Checksums of HDF5 files: every group carries a digest of its content, checked on read.

A file evo-door writes is *sealed* (:func:`seal`) before it is renamed into place: each
group gets an attribute ``_digest``, a BLAKE2b digest of its attributes, the names of
its members, and the type, shape and bytes of each of its datasets (with their
attributes). A subgroup is covered by its own digest; its parent's covers its name, so
that a group that disappears or is renamed is noticed too. Groups copied unchanged from
the file being replaced (:class:`~evo_door.files.h5tree.Keep`) keep the digest they were
sealed with, so a damaged copy is still noticed.

:func:`verify` reads a whole file once and checks every digest, before any of its values
is used: a flipped bit in a value, an attribute or a name is one line that names the
object; damage to HDF5's own structures is one line too. It also bounds what a file may
make a reader allocate (:data:`MAX_DATASET_BYTES`, :data:`MAX_FILE_BYTES`) and refuses
links to other files. Files written before checksums existed have none anywhere and are
read as they are; a file with some digests but not all is damaged.
"""

from __future__ import annotations

import hashlib
import math

from evo_door.errors import UserError
from evo_door.files.metadata import DIGEST

#: how a digest is written: the algorithm, then the hex digest
_PREFIX = "blake2b:"
#: the largest dataset a file may hold, in bytes once read (512 MiB: a render log of
#: hours holds a few tens of MiB per column, results files a few MiB in all)
MAX_DATASET_BYTES = 512 * 2**20
#: the most a file may make a reader read in all, in bytes (1 GiB)
MAX_FILE_BYTES = 2**30
#: bytes hashed at a time, so that checking a file needs little memory
_SLICE_BYTES = 8 * 2**20


class DamagedFile(UserError):
    """An HDF5 file whose content does not match its checksums, or that HDF5 cannot read."""


def _h5py():
    import h5py

    return h5py


def _canon(value) -> bytes:
    """The bytes a value is digested as: its type, then its content."""
    import numpy as np

    if isinstance(value, str):
        return b"s" + value.encode("utf-8", "surrogatepass")
    if isinstance(value, bytes):
        return b"b" + value
    if isinstance(value, np.ndarray):
        head = f"a{value.dtype.str}{value.shape}".encode()
        if value.dtype.kind == "O":
            return head + b"".join(_canon(v) for v in value.ravel())
        return head + np.ascontiguousarray(value).tobytes()
    if isinstance(value, np.generic):
        return f"g{value.dtype.str}".encode() + value.tobytes()
    return b"r" + repr(value).encode()


def _attrs_digest(h, obj) -> None:
    attrs = obj.attrs
    for name in sorted(attrs):  # the names, then each value but the digest's own
        if name == DIGEST:
            continue
        h.update(b"@" + name.encode("utf-8", "surrogatepass") + b"\0")
        h.update(_canon(attrs[name]))
        h.update(b"\0")


def _dataset_digest(h, ds, budget: list, path) -> None:
    import numpy as np

    shape, dtype = ds.shape, ds.dtype  # each a call into HDF5: asked once
    nbytes = math.prod(shape) * dtype.itemsize if shape else 0
    if nbytes > MAX_DATASET_BYTES:
        raise DamagedFile(
            f"{path}: {ds.name} would take {nbytes / 2**20:.0f} MiB to read, "
            f"more than the {MAX_DATASET_BYTES / 2**20:.0f} MiB a dataset may hold"
        )
    budget[0] += nbytes
    if budget[0] > MAX_FILE_BYTES:
        raise DamagedFile(f"{path}: would take more than {MAX_FILE_BYTES / 2**30:.0f} GiB to read")
    h.update(f"d{dtype.str}{shape}".encode())
    _attrs_digest(h, ds)
    if shape is None:  # an empty dataspace
        return
    try:
        if not shape or dtype.kind == "O" or shape[0] == 0:
            h.update(_canon(ds[()]))
            return
        row = max(1, nbytes // shape[0])
        step = max(1, _SLICE_BYTES // row)
        if step >= shape[0]:  # the whole at once (most datasets): the same bytes
            h.update(_whole(ds, shape, dtype))
            return
        for i in range(0, shape[0], step):
            h.update(np.ascontiguousarray(ds[i : i + step]).tobytes())
    except Exception as exc:  # noqa: BLE001 - whatever HDF5 raises on a damaged chunk
        raise DamagedFile(f"{path}: corrupt HDF5 data in {ds.name} ({_first_line(exc)})") from None


def _whole(ds, shape, dtype) -> bytes:
    """The bytes of the whole dataset ``ds`` (of ``shape`` and ``dtype``, a shape of at
    least one dimension), as ``ds[()]`` reads them. Plain numbers (booleans, integers,
    floats) are read into an array of the dataset's own type with one call into HDF5,
    what h5py's indexing does after working out its selection, which costs more than
    the read for the small datasets of a results file; anything else through h5py."""
    import numpy as np

    if dtype.kind in "biuf" and dtype.subdtype is None:
        out = np.empty(shape, dtype=dtype)
        ds.id.read(_h5py().h5s.ALL, _h5py().h5s.ALL, out)
        return out.tobytes()
    return np.ascontiguousarray(ds[()]).tobytes()


def _encoded(name) -> bytes:
    """A member's name as HDF5 holds it: h5py lists a name that is not UTF-8 as bytes."""
    return name if isinstance(name, bytes) else name.encode("utf-8")


def group_digest(group, budget: list | None = None, path=None) -> str:
    """The digest of ``group`` (see the module docstring): its attributes, its members'
    names and kinds, and its datasets' content."""
    return _digest_and_subgroups(group, budget, path)[0]


def _digest_and_subgroups(group, budget: list | None = None, path=None) -> tuple[str, list]:
    """:func:`group_digest`, and the subgroups of ``group`` in the order HDF5 lists them
    (each member looked up once, for both)."""
    h5 = _h5py()
    budget = [0] if budget is None else budget
    path = group.file.filename if path is None else path
    h = hashlib.blake2b(digest_size=16)
    _attrs_digest(h, group)
    order = list(group.keys())
    subgroups = {}
    links = group.id.links  # each link's kind asked of HDF5 directly: group.get's objects cost more
    for name in sorted(order):
        if links.get_info(_encoded(name)).type != h5.h5l.TYPE_HARD:
            raise DamagedFile(
                f"{path}: {group.name.rstrip('/')}/{name} is a link "
                "(evo-door files hold none; a link could read another file)"
            )
        item = group[name]
        h.update(b"/" + name.encode("utf-8", "surrogatepass") + b"\0")
        if isinstance(item, h5.Group):
            h.update(b"g")
            subgroups[name] = item
        else:
            _dataset_digest(h, item, budget, path)
    return _PREFIX + h.hexdigest(), [subgroups[name] for name in order if name in subgroups]


def _subgroups(group) -> list:
    """The groups ``group`` holds by hard links, in the order HDF5 lists them."""
    h5 = _h5py()
    found = []
    for name in group.keys():
        if isinstance(group.get(name, getlink=True), h5.HardLink):
            item = group[name]
            if isinstance(item, h5.Group):
                found.append(item)
    return found


def _walk(group, visit, seen=None) -> None:
    """``visit(g)`` for ``group`` and every group below it, each once, a group before
    its subgroups; ``visit`` returns the subgroups of ``g`` (:func:`_subgroups`, or
    what :func:`_digest_and_subgroups` found while it digested ``g``)."""
    seen = set() if seen is None else seen
    key = hash(group.id)  # the file's and the object's numbers: one per object
    if key in seen:
        return
    seen.add(key)
    for item in visit(group):
        _walk(item, visit, seen)


def _groups(group) -> list:
    """``group`` and every group below it, each once."""
    found = []

    def visit(g):
        found.append(g)
        return _subgroups(g)

    _walk(group, visit)
    return found


def seal(f) -> None:
    """Give every group of the open file ``f`` that has none its digest (the last step
    of writing a file; groups copied from an earlier version keep theirs).

    A group that has a digest was copied whole from the file being replaced (a
    :class:`~evo_door.files.h5tree.Keep`: nothing is written into a copy), and so was
    every group below it: the walk does not go into it. (It did, for nothing: a
    results file's trials are most of its groups, copied at every checkpoint.) A group
    below a copy that came without its digest is left without: the file it came from
    was damaged, and the new one says so when read, where a digest made here would
    vouch for what no one checked."""

    def visit(group):
        if DIGEST in group.attrs:  # a copy with its digest: everything below it is
            return []
        digest, subgroups = _digest_and_subgroups(group)
        group.attrs[DIGEST] = digest
        return subgroups

    _walk(f, visit)


def reseal(f) -> None:
    """Seal the open file ``f`` afresh, every group's digest recomputed: for a file
    changed on purpose with h5py (tests make damaged or hostile files this way). Its
    checksums then vouch for the changed content, so use it only on a file you trust."""
    for group in _groups(f):
        if DIGEST in group.attrs:
            del group.attrs[DIGEST]
    seal(f)


def _damaged(path, exc: Exception) -> DamagedFile:
    return DamagedFile(f"{path}: damaged HDF5 file ({_first_line(exc)})")


def _first_line(exc: Exception) -> str:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return text if len(text) <= 80 else text[:77] + "..."


#: files this process checked already, by device, inode, size and change times: a
#: command that opens one file several times checks it once (a file replaced or
#: changed since has another inode or time)
_CHECKED: dict[tuple, None] = {}
_CHECKED_MAX = 256


def _identity(path) -> tuple | None:
    import os

    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


def verify(f, path) -> None:
    """Check every digest of the open file ``f`` (named ``path`` in messages), or raise
    one line (:class:`DamagedFile`) naming what does not match."""
    identity = _identity(path)
    if identity is not None and identity in _CHECKED:
        return
    _check(f, path)
    if identity is not None and identity == _identity(path):
        _remember(identity)


def _remember(identity: tuple) -> None:
    """Note the file of ``identity`` (:func:`_identity`) as checked."""
    if len(_CHECKED) >= _CHECKED_MAX:
        _CHECKED.clear()
    _CHECKED[identity] = None


def checked(path) -> tuple | None:
    """The identity of the file at ``path`` when this process checked it (or wrote it:
    :func:`vouch`) as it is now, else None."""
    identity = _identity(path)
    return identity if identity is not None and identity in _CHECKED else None


def vouch(path, written) -> None:
    """Count the file at ``path`` as checked when it is the file this process has just
    sealed and written (``written``: the ``os.stat`` of the temporary it was written as,
    before the rename onto ``path``): the same device, inode, size and modification
    time. A pipeline reads back the file it writes after every stage; its own file
    needs no second check, and a file another process put there meanwhile, or changed,
    is checked as any other."""
    identity = _identity(path)  # the rename changed its ctime only
    ours = (written.st_dev, written.st_ino, written.st_size, written.st_mtime_ns)
    if identity is not None and identity[:4] == ours:
        _remember(identity)


def _check(f, path) -> None:
    budget = [0]
    sealed, unsealed = [], []

    def visit(group):
        found, subgroups = _digest_and_subgroups(group, budget, path)  # all read: damage shows
        stored = group.attrs.get(DIGEST)
        if stored is None:
            unsealed.append(group.name)
            return subgroups
        if isinstance(stored, bytes):
            stored = stored.decode("utf-8", "replace")
        sealed.append(group.name)
        if found != stored:
            raise DamagedFile(
                f"{path}: damaged: {group.name} does not match its checksum "
                "(the file changed after evo-door wrote it)"
            )
        return subgroups

    try:
        _walk(f, visit)
    except UserError:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever HDF5 or numpy raise on damage
        raise _damaged(path, exc) from None
    if sealed and unsealed:
        raise DamagedFile(
            f"{path}: damaged: {unsealed[0]} has no checksum where the rest of the file has"
        )
