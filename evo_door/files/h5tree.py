"""A nested dict, the *tree*, written to HDF5 and read back (:func:`write_h5`).

A dict is a group and its ``"@attrs"`` entry the group's attributes
(:mod:`evo_door.files.metadata`); an array (or a list of numbers) is a dataset, a
:class:`Dataset` a dataset with attributes, a str a scalar text dataset, a
:class:`Keep` a group copied unchanged from the file being replaced.
"""

from __future__ import annotations

import io
import os
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from evo_door.errors import UserError
from evo_door.files.atomic import atomic_write, write_bytes
from evo_door.files.heaps import check_global_heaps
from evo_door.files.integrity import checked, seal, verify, vouch
from evo_door.files.metadata import ATTRS, read_attrs, write_attrs


def h5py():
    """The h5py module, imported on first use (it costs ~0.1 s at start-up)."""
    import h5py as module

    return module


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
    """An open HDF5 group as a tree: groups as dicts, datasets as arrays or str; each
    dict a :class:`~evo_door.files.fields.Node`, which names the file and the group."""
    from evo_door.files.fields import Node, as_text

    h5 = h5py()
    out = Node({ATTRS: read_attrs(group)}, place=f"{group.file.filename}: {group.name}")
    for key, item in group.items():
        if isinstance(item, h5.Group):
            out[key] = read_group(item)
        elif h5.check_string_dtype(item.dtype) is not None and item.shape == ():
            out[key] = as_text(item[()], out.name(key))
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
        with new_h5(tmp) as f:
            write_group(f, tree, compression, compress_above, keep)
            old, copied, checked_before = None, False, None
            if keep and path.is_file():
                checked_before = checked(path)
                try:
                    old = h5.File(path, "r")
                except OSError:
                    old = None
            try:
                for name, placeholder in keep:
                    parent, _, key = name.rpartition("/")
                    target = f[parent or "/"]
                    if old is not None and _copied(old, name, target, key):
                        copied = True
                        continue
                    write_group(
                        target.create_group(key, track_order=True),
                        placeholder.build(),
                        compression,
                        compress_above,
                    )
            finally:
                if old is not None:
                    old.close()
            seal(f)
            # copies keep the digests they came with: the new file is known good when
            # they came from a file checked (or written) by this process, unchanged since
            trusted = not copied or (checked_before is not None and checked(path) == checked_before)
        written = os.stat(tmp)
    if trusted:
        vouch(path, written)


def _copied(old, name: str, target, key: str) -> bool:
    """Copy ``old[name]`` into ``target`` as ``key``; False (nothing left behind) where
    the old file lacks it or HDF5 cannot copy it (damage a read does not meet): the
    caller then builds the group from what it holds in memory."""
    try:
        if name not in old:
            return False
        old.copy(old[name], target, name=key)
        return True
    except Exception:  # noqa: BLE001 - whatever HDF5 raises on a damaged object
        if key in target:
            del target[key]
        return False


@contextmanager
def new_h5(tmp):
    """A new HDF5 file to fill, made in memory and written to ``tmp`` when the block ends.

    HDF5 never writes to the disk itself: a write it cannot finish (a full disk) leaves
    the library in a state that crashes the process at exit (SIGSEGV, SIGBUS). The
    file's image is built in memory and written by :func:`~.atomic.write_bytes`,
    where a full disk is an ordinary ``OSError``; an error inside the block writes
    nothing. ``tmp`` is :func:`~.atomic.atomic_write`'s temporary.
    """
    image = io.BytesIO()
    with h5py().File(image, "w", track_order=True) as f:
        yield f
    with image.getbuffer() as data:
        write_bytes(tmp, data)


def open_h5(path, what: str = "HDF5 file"):
    """Open an HDF5 file for reading, its checksums checked
    (:func:`evo_door.files.integrity.verify`), or raise a one-line error naming it."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: {what} not found")
    if path.stat().st_size == 0:
        raise UserError(f"{path}: empty file")
    check_global_heaps(path)  # damage HDF5's reader would loop on for ever
    try:
        f = h5py().File(path, "r")
    except OSError as exc:
        raise UserError(f"{path}: not a readable HDF5 file ({exc})") from None
    try:
        verify(f, path)
    except BaseException:
        f.close()
        raise
    return f
