"""From named columns of numbers (a CSV table, a TDMS group, an HDF5 group) to a Trial.

Every importer reduces its file to :class:`Column` objects and calls
:func:`trial_from_columns`, so the mapping, the unit conversion and the checks (and
their messages: file, channel, row) are the same for every format.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from evo_door.data.trial import STEP_TOLERANCE, Trial, time_axis_problem
from evo_door.data.units import (
    CHANNELS,
    ChannelMap,
    UnitExpr,
    parse_unit,
    quote,
    quote_list,
    split_header,
)
from evo_door.errors import UserError
from evo_door.params.declaration import suggest

#: Column names recognised without a mapping (compared case-insensitively, without unit).
DEFAULT_NAMES = {
    "t": ("t", "time"),
    "force": ("force",),
    "theta": ("theta", "angle"),
    "dtheta": ("dtheta", "omega", "angular_speed"),
    "ddtheta": ("ddtheta", "angular_acceleration"),
}

__all__ = ["STEP_TOLERANCE", "Column", "trial_from_columns"]

#: Relative tolerance of an expected sampling rate.
RATE_TOLERANCE = 0.002


@dataclass
class Column:
    """One named column of a file: raw values plus the unit the file declares."""

    name: str
    values: np.ndarray
    unit: str | None = None
    #: Sample period the file declares for this column (TDMS waveforms), if any.
    dt: float | None = None
    t0: float = 0.0
    #: (row, text) of the first cell that is not a number (a text file's), if any:
    #: an error only if the column is used.
    bad: tuple[int, str] | None = None


def _at(row: int, line_of: Callable[[int], int] | None) -> str:
    return f"row {row}" + (f" (line {line_of(row)})" if line_of else "")


def _find(columns: dict[str, Column], name: str) -> Column | None:
    if name in columns:
        return columns[name]
    low = {k.lower(): c for k, c in columns.items()}
    if name.lower() in low:
        return low[name.lower()]
    # header with a unit: "force [kN]" matches the source name "force"
    for key, col in columns.items():
        base, _ = split_header(key)
        if base.lower() == name.lower():
            return col
    return None


def _default_column(columns: dict[str, Column], channel: str) -> Column | None:
    for name in DEFAULT_NAMES[channel]:
        col = _find(columns, name)
        if col is not None:
            return col
    return None


def _unit_of(col: Column, cmap: ChannelMap | None, channel: str, where: str) -> UnitExpr:
    if cmap is not None and cmap.unit is not None:
        return cmap.unit
    declared = col.unit
    if declared is None:
        declared = split_header(col.name)[1]
    if declared:
        return parse_unit(declared, channel, f"{where}: column {quote(col.name, 40)}")
    return UnitExpr(CHANNELS[channel][0])


def trial_from_columns(
    columns: dict[str, Column],
    where: str,
    mapping: dict[str, ChannelMap] | None = None,
    rate: float | None = None,
    fields: dict | None = None,
    line_of: Callable[[int], int] | None = None,
    record_import: bool = True,
    channels=tuple(CHANNELS),
) -> Trial:
    """Build and check one :class:`Trial`; raise a one-line :class:`UserError` on the first problem.

    Parameters
    ----------
    columns : dict
        The file's columns by name.
    where : str
        File (and group) for messages; becomes ``Trial.source``.
    mapping : dict of ChannelMap
        Channel -> source column and unit; unmapped channels are looked for under
        their own name (``t``/``time``, ``force``, ``theta``, ``dtheta``, ``ddtheta``,
        with an optional unit in the header: ``theta [deg]``).
    rate : float, optional
        Expected sampling rate (Hz); builds the time axis when the file has none.
    fields : dict
        Other Trial fields (trial_id, user_id, kind, theta0, ...).
    line_of : callable, optional
        Row (0-based data row) -> line of the file, for messages about text files.
    record_import : bool
        Note the file and the column mapping in ``meta["import"]``.
    channels : tuple of str
        The channels to take (``("t", "force")`` for a simulation's input); columns
        of the others are not read, so not checked either.

    Time stamps within :data:`~evo_door.data.trial.STEP_TOLERANCE` of a uniform grid
    become that grid (the Trial notes it in ``meta["time_axis"]``); beyond it the file
    is refused, naming the row (and line).
    """
    # long: the checks of one file's columns in the order they apply (pick the
    # columns, their lengths, the time axis, the units), each raising the first problem
    # with its column and line
    mapping = dict(mapping or {})
    fields = dict(fields or {})
    picked: dict[str, tuple[Column, UnitExpr]] = {}
    for channel in CHANNELS:
        if channel not in channels:
            continue
        cmap = mapping.get(channel)
        if cmap is not None:
            col = _find(columns, cmap.source)
            if col is None:
                raise UserError(
                    f"{where}: missing column {quote(cmap.source)} for channel "
                    f"{channel!r}"
                    + suggest(cmap.source, columns)
                    + f"; columns: {quote_list(columns)}"
                )
        else:
            col = _default_column(columns, channel)
            if col is None:
                continue
        picked[channel] = (col, _unit_of(col, cmap, channel, where))

    if "force" not in picked:
        raise UserError(
            f"{where}: missing column 'force' (the user force; map another "
            f"column with --map force=NAME:UNIT); columns: {quote_list(columns)}"
        )

    n = picked["force"][0].values.size
    if n == 0:
        raise UserError(f"{where}: empty: no data rows")
    for channel, (col, _) in picked.items():
        if col.values.ndim != 1:
            raise UserError(
                f"{where}: channel {channel!r} (column {quote(col.name)}) is not one-dimensional"
            )
        if col.values.size != n:
            raise UserError(
                f"{where}: channel {channel!r} (column {quote(col.name)}) has "
                f"{col.values.size} rows, channel 'force' has {n}"
            )
    if n < 2:
        raise UserError(f"{where}: only one data row; a trial needs at least two samples")

    signals: dict[str, np.ndarray] = {}
    for channel, (col, unit) in picked.items():
        if col.bad is not None:
            row, text = col.bad
            raise UserError(
                f"{where}: column {quote(col.name)} is not a number at "
                f"{_at(row, line_of)}: {quote(text)}"
            )
        raw = np.asarray(col.values, dtype=np.float64)
        bad = ~np.isfinite(raw)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise UserError(
                f"{where}: channel {channel!r} (column {quote(col.name)}) is not a "
                f"finite number at {_at(row, line_of)}: {float(raw[row])!r}"
            )
        signals[channel] = unit.apply(raw)

    signals["t"] = _time_axis(picked, signals, n, where, rate, line_of)
    trial_fields = {k: v for k, v in fields.items() if v is not None}
    trial_fields.setdefault("source", where)
    trial_fields.setdefault("meta", {})
    trial_fields["meta"] = dict(trial_fields["meta"])
    if record_import:
        trial_fields["meta"].setdefault(
            "import",
            {
                "file": where,
                "map": {ch: f"{col.name}:{unit}" for ch, (col, unit) in picked.items()},
            },
        )
    return Trial(
        t=signals["t"],
        force=signals["force"],
        theta=signals.get("theta"),
        dtheta=signals.get("dtheta"),
        ddtheta=signals.get("ddtheta"),
        **trial_fields,
    )


def _time_axis(picked, signals, n, where, rate, line_of) -> np.ndarray:
    """The time axis: built from ``rate`` or a waveform's step, or the file's, checked."""
    if "t" not in picked:
        dts = {c.dt for c, _ in picked.values() if c.dt}
        if dts:
            dt = min(dts)
            t0 = next(c.t0 for c, _ in picked.values() if c.dt == dt)
            if len(dts) > 1:
                raise UserError(
                    f"{where}: channels sampled at different rates "
                    f"({', '.join(f'{1 / d:g} Hz' for d in sorted(dts))})"
                )
        elif rate:
            dt, t0 = 1.0 / rate, 0.0
        else:
            raise UserError(
                f"{where}: missing column 't' (time in s); map one with "
                "--map t=NAME:UNIT or give the sampling rate (--rate HZ)"
            )
        _check_rate(1.0 / dt, rate, where, "t", line_of)
        return t0 + dt * np.arange(n)
    t = signals["t"]
    col = picked["t"][0]
    problem = time_axis_problem(t)
    if problem is not None:
        row, what, detail = problem
        hint = (
            ""
            if what == "is not increasing"
            else " (resample it first: evo_door.data.preprocess.to_uniform)"
        )
        raise UserError(
            f"{where}: channel 't' (column {quote(col.name)}) {what} at "
            f"{_at(row, line_of)}: {detail}{hint}"
        )
    _check_rate((t.size - 1) / (t[-1] - t[0]), rate, where, col.name, line_of)
    # the Trial puts stamps within STEP_TOLERANCE onto the exact grid and notes it
    return t


def _check_rate(actual, expected, where, name, line_of) -> None:
    if expected and abs(actual - expected) > RATE_TOLERANCE * expected:
        raise UserError(
            f"{where}: channel 't' (column {quote(name)}) is sampled at {actual:.6g} Hz, "
            f"expected {expected:g} Hz, at {_at(1, line_of)}"
        )
