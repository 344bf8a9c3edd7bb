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

One module per question, all imported here (``from evo_door.files import ...``):

- :mod:`~evo_door.files.atomic`: how is a file written so that a crash leaves no half
  of it? (atomic writes, text, figures, the temporaries a killed writer left)
- :mod:`~evo_door.files.claims`: may this command write over that file?
- :mod:`~evo_door.files.locks`: who owns this file while a run writes it?
- :mod:`~evo_door.files.metadata`: how is metadata (attributes) stored in HDF5?
- :mod:`~evo_door.files.h5tree`: how is a nested dict written to and read from HDF5?
- :mod:`~evo_door.files.integrity`: is this HDF5 file as evo-door wrote it? (checksums)
- :mod:`~evo_door.files.heaps`: would HDF5's reader loop for ever on this file's damage?
- :mod:`~evo_door.files.fields`: does a value read from a file have the type a reader
  expects? (typed reading, each value named by its place)
"""

from evo_door.files import fields
from evo_door.files.atomic import (
    WRITE_REASONS,
    atomic_write,
    check_folder,
    check_image_path,
    folder_reason,
    partial_output,
    read_text,
    remove_stale_temporaries,
    save_figure,
    write_bytes,
    write_reason,
    write_text,
)
from evo_door.files.claims import DERIVED, TRIALS, Claim, Output, claim_outputs, same_file
from evo_door.files.fields import MissingInFile, Node
from evo_door.files.h5tree import (
    Dataset,
    Keep,
    h5py,
    new_h5,
    open_h5,
    read_group,
    write_group,
    write_h5,
)
from evo_door.files.integrity import DamagedFile, reseal, seal, verify
from evo_door.files.locks import FileLock
from evo_door.files.metadata import (
    ATTRS,
    JSON_PREFIX,
    attrs_tree,
    decode_attr,
    encode_attr,
    jsonable,
    read_attrs,
    to_json,
    tree_attrs,
    write_attrs,
)

__all__ = [
    "ATTRS",
    "DERIVED",
    "JSON_PREFIX",
    "TRIALS",
    "WRITE_REASONS",
    "Claim",
    "DamagedFile",
    "Dataset",
    "FileLock",
    "Keep",
    "MissingInFile",
    "Node",
    "Output",
    "atomic_write",
    "attrs_tree",
    "check_folder",
    "check_image_path",
    "claim_outputs",
    "decode_attr",
    "encode_attr",
    "folder_reason",
    "fields",
    "h5py",
    "jsonable",
    "new_h5",
    "open_h5",
    "partial_output",
    "read_attrs",
    "read_group",
    "read_text",
    "reseal",
    "remove_stale_temporaries",
    "same_file",
    "save_figure",
    "seal",
    "to_json",
    "tree_attrs",
    "verify",
    "write_attrs",
    "write_bytes",
    "write_group",
    "write_h5",
    "write_reason",
    "write_text",
]
