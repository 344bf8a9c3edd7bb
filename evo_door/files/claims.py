"""The one rule of what a command may write over (:func:`claim_outputs`)."""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

from evo_door.errors import UserError, WriteError
from evo_door.files.atomic import check_folder, expect_new, folder_reason

#: An output that holds trials (``data import``, ``rig generate``, a render's log): what
#: was measured or generated, a participant's session. Replaced only with ``--force``
#: (or extended with ``--append`` where the command has it).
TRIALS = "trials"
#: An output computed from the command's inputs (a CSV table, a figure, a report, a
#: parameter file written by ``params --write`` or ``export-spec``): running the command
#: again makes it again, so it is replaced, and the command says so on stderr.
DERIVED = "derived"
#: Results files (``run``) follow the same idea with more to say (complete or
#: interrupted, resume): :func:`evo_door.experiment.run_preflight.claim_output`.


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
    it, and its :meth:`Claim.note` says so once the command has written; never an
    HDF5 file there (a trial, results, log or JND file: :func:`is_data_file`), unless
    ``force``. ``force``
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
            raise WriteError(path, folder_reason(folder))
        # a new file is created, never replacing one another command makes meanwhile;
        # one the command may replace (--force, --append under the file's lock) is not
        expect_new(path, not (path.exists() or force or append or out.makes_folder))
        if not path.exists():
            continue
        if out.kind == TRIALS and not (force or append):
            extend = " or --append to add to its trials" if append is not None else ""
            raise UserError(
                f"{out.option} {path}: a file is there already; give --force to replace "
                f"it{extend}, or another {out.option}"
            )
        if out.kind == DERIVED and not force and is_data_file(path):
            raise UserError(
                f"{out.option} {path}: an evo-door data file is there (trials, a results "
                "file, a render log or a JND session: HDF5); a table, figure or parameter "
                f"file never replaces it: give another {out.option}"
            )
        if not (out.kind == TRIALS and append):
            claim.replaced.append(path)
    return claim


#: the first bytes of every HDF5 file: every file evo-door keeps data in (trials,
#: results, render logs, JND sessions) is one, and none of its derived outputs is
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def is_data_file(path) -> bool:
    """Whether ``path`` is an HDF5 file (what a derived output never replaces)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(len(HDF5_SIGNATURE)) == HDF5_SIGNATURE
    except OSError:
        return False


def _existing_folder(path: Path) -> Path:
    """The deepest folder above ``path`` that exists (a file on the way: one-line error)."""
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise UserError(f"{path}: {parent} is a file, not a folder")
            return parent
    return Path(".")  # pragma: no cover - a relative path's parents end in "."
