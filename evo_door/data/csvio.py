"""One trial per CSV file: a header of column names, then one row per sample.

Written by :func:`write_csv`::

    # evo-door trial: {"trial_id": "T01", "user_id": "U1", "kind": "impulse", ...}
    t,force,dtheta
    0,0.0137,-0.0012
    ...

The comment line carries the metadata as JSON (readers that skip ``#`` lines, e.g.
``numpy.loadtxt`` or pandas with ``comment="#"``, see a plain table). Without it the
trial id is the file name. Columns are SI unless the header says otherwise
(``theta [deg]``) or a mapping (``force=Fz:kN``) does; the delimiter (``,``, ``;`` or
tab) is taken from the header line. The CSV that ``evo-door simulate`` writes
(``t, force, theta, dtheta, ddtheta``) is a trial file as it stands.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from evo_door.channels import CHANNELS
from evo_door.data.columns import Column, trial_from_columns
from evo_door.data.trial import RESPONSE_CHANNELS, Trial
from evo_door.data.units import quote
from evo_door.errors import UserError
from evo_door.files import atomic_write, read_text, to_json

META_PREFIX = "# evo-door trial:"
METADATA_FIELDS = ("trial_id", "user_id", "kind", "theta0", "dtheta0", "sensors", "truth", "meta")


def read_csv(path, mapping=None, rate=None, fields=None, channels=tuple(CHANNELS)) -> Trial:
    """Read one trial from a CSV file (see the module docstring).

    ``mapping`` is ``{channel: ChannelMap}`` (:func:`evo_door.data.units.parse_maps`),
    ``rate`` the expected sampling rate in Hz, ``fields`` Trial fields overriding the
    file's metadata, ``channels`` the channels to take (the other columns are not
    read). UTF-8, a byte-order mark (as spreadsheets write it) allowed.
    """
    path = Path(path)
    # a missing file, a folder, a picture or an HDF5 file: one line saying which
    lines = read_text(path, "CSV file").splitlines()
    meta: dict = {}
    header_idx = None
    for i, line in enumerate(lines):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            if stripped.startswith(META_PREFIX):
                meta = _metadata(stripped[len(META_PREFIX) :], f"{path}: line {i + 1}")
            continue
        header_idx = i
        break
    if header_idx is None:
        raise UserError(f"{path}: empty file (no header line)")
    header_line = lines[header_idx]
    delimiter = max((",", ";", "\t"), key=header_line.count)
    names = [h.strip() for h in next(csv.reader([header_line], delimiter=delimiter))]
    if all(_is_number(h) for h in names):
        raise UserError(
            f"{path}: line {header_idx + 1}: no header line (first line holds "
            "numbers; name the columns, e.g. t,force,theta)"
        )
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise UserError(f"{path}: line {header_idx + 1}: column {quote(dup)} appears twice")

    body = [
        (i + 1, line)
        for i, line in enumerate(lines[header_idx + 1 :], start=header_idx + 1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    line_numbers = [ln for ln, _ in body]
    data, bad = _parse_body(path, body, names, delimiter)
    columns = {name: Column(name, data[:, j], bad=bad.get(name)) for j, name in enumerate(names)}
    merged = {k: meta[k] for k in METADATA_FIELDS if k in meta}
    merged.setdefault("trial_id", path.stem)
    merged.update({k: v for k, v in (fields or {}).items() if v is not None})
    return trial_from_columns(
        columns,
        str(path),
        mapping,
        rate,
        merged,
        line_of=lambda row: line_numbers[row],
        record_import=not meta or bool(mapping),
        channels=channels,
    )


def _metadata(text: str, where: str) -> dict:
    """The metadata line's JSON: a mapping whose ``meta``, ``sensors`` (and ``truth``,
    where given) are mappings too; else one line naming the file and line."""
    try:
        meta = json.loads(text)
    except RecursionError:
        raise UserError(f"{where}: metadata nested too deeply") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"{where}: metadata is not JSON ({exc.msg})") from None
    if not isinstance(meta, dict):
        raise UserError(f"{where}: metadata is not a JSON mapping")
    for key in ("meta", "sensors", "truth"):
        if (
            key in meta
            and not isinstance(meta[key], dict)
            and not (key == "truth" and meta[key] is None)
        ):
            raise UserError(f"{where}: metadata {key!r} is not a mapping")
    return meta


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _parse_body(path, body, names, delimiter) -> tuple[np.ndarray, dict[str, tuple[int, str]]]:
    """The numbers of the data lines, and per column its first cell that is not one.

    A cell that is not a number becomes NaN and is reported only if its column is
    used (a notes column, or a response channel a simulation ignores, may hold text).
    """
    if not body:
        return np.empty((0, len(names))), {}
    try:
        data = np.loadtxt(
            [line for _, line in body], delimiter=delimiter, ndmin=2, dtype=np.float64
        )
        if data.shape[1] == len(names):
            return data, {}
    except ValueError:
        pass
    # slow path: cell by cell, noting where each column first holds something else
    data = np.empty((len(body), len(names)))
    bad: dict[str, tuple[int, str]] = {}
    for row, (lineno, line) in enumerate(body):
        cells = next(csv.reader([line], delimiter=delimiter))
        if len(cells) != len(names):
            raise UserError(
                f"{path}: row {row} (line {lineno}) has {len(cells)} fields, "
                f"the header has {len(names)}"
            )
        for j, cell in enumerate(cells):
            try:
                data[row, j] = float(cell)
            except ValueError:
                data[row, j] = np.nan
                bad.setdefault(names[j], (row, cell.strip()))
    return data, bad


def write_csv(path, trial: Trial, metadata: bool = True) -> None:
    """Write one trial as CSV in SI (``t, force`` and the response channels present).

    Written to a temporary file and renamed, so a failure leaves nothing behind.
    """
    names = ["t", "force", *[c for c in RESPONSE_CHANNELS if getattr(trial, c) is not None]]
    table = np.column_stack([getattr(trial, c) for c in names])
    with atomic_write(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            if metadata:
                fh.write(
                    META_PREFIX
                    + " "
                    + to_json({k: getattr(trial, k) for k in METADATA_FIELDS})
                    + "\n"
                )
            fh.write(",".join(names) + "\n")
            np.savetxt(fh, table, delimiter=",", fmt="%.12g")
