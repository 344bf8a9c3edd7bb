"""HDF5 global heaps walked before HDF5 reads them: damage there must not hang a reader.

Every text attribute and text dataset evo-door writes (variable-length strings) lives
in a *global heap collection* of the file (``GCOL``). HDF5 reads a collection by walking
its objects, each header giving the object's size; a free-space object (index 0) of
size 0 sends that walk round the same place for ever (HDF5 1.14's
``H5HG__cache_heap_deserialize``): a few zeroed bytes in a file, and reading any text
attribute hangs the process in C, where no signal reaches. :func:`check_global_heaps`
walks every collection of a file the way HDF5 will, before it does, and refuses a file
whose walk would not end, in one line (:class:`~evo_door.files.integrity.DamagedFile`).

The layout (HDF5 file format specification, "Global Heap"): ``GCOL``, version 1, three
reserved bytes, the collection's size (8 bytes, the "size of lengths" h5py writes),
then objects of a 16-byte header (index 2, reference count 2, reserved 4, size 8) and
their data padded to 8 bytes; index 0 is the free space, whose size is its whole extent.
"""

from __future__ import annotations

import mmap
import os

from evo_door.files.integrity import DamagedFile

_MAGIC = b"GCOL\x01\x00\x00\x00"  # the signature, version 1 and its reserved bytes
_HEADER = 16  # the collection's header: signature 4, version 1, reserved 3, size 8
_OBJECT = 16  # an object's header: index 2, references 2, reserved 4, size 8


def check_global_heaps(path) -> None:
    """Refuse ``path`` (one line) if a global heap collection in it would make HDF5's
    reader loop for ever; any other file passes (its damage is HDF5's to find)."""
    try:
        with open(path, "rb") as fh:
            if os.fstat(fh.fileno()).st_size < _HEADER:
                return
            with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
                _check(data, path)
    except (OSError, ValueError):  # unreadable, or mmap refused: HDF5 says why
        return


def _check(data, path) -> None:
    end = len(data)
    at = data.find(_MAGIC)
    while at >= 0:
        size = int.from_bytes(data[at + 8 : at + 16], "little")
        if _HEADER <= size <= end - at and _walk_stalls(data, at, size):
            raise DamagedFile(
                f"{path}: damaged HDF5 file (the global heap at byte {at} holds an empty "
                "free-space entry: reading it would never end)"
            )
        at = data.find(_MAGIC, at + 1)


def _walk_stalls(data, at: int, size: int) -> bool:
    """Whether HDF5's walk over the collection at ``at`` of ``size`` bytes would stay
    at one place: an object of index 0 and size 0 before the collection's end."""
    p = _HEADER
    while p < size:
        if p + _OBJECT > size:  # too little left for a header: free space, the end
            return False
        head = at + p
        index = int.from_bytes(data[head : head + 2], "little")
        length = int.from_bytes(data[head + 8 : head + 16], "little")
        need = _OBJECT + (length + 7) // 8 * 8 if index > 0 else length
        if need == 0:
            return True
        p += need
    return False
