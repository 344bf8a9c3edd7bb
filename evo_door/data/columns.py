"""From named columns of numbers (a CSV table, a TDMS group, an HDF5 group) to a Trial.

Every importer reduces its file to :class:`Column` objects and calls
:func:`trial_from_columns`, so the mapping, the unit conversion and the checks (and
their messages: file, channel, row) are the same for every format.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from evo_door.data.trial import Trial
from evo_door.data.units import CHANNELS, ChannelMap, UnitExpr, parse_unit, split_header
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

#: Successive time steps may differ by this fraction of the median step (text rounding
#: of time stamps) before a file counts as not uniformly sampled; within it the time
#: axis is replaced by the exact uniform grid.
STEP_TOLERANCE = 0.01
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
        return parse_unit(declared, channel, f"{where}: column {col.name!r}")
    return UnitExpr(CHANNELS[channel][0])


def trial_from_columns(
    columns: dict[str, Column],
    where: str,
    mapping: dict[str, ChannelMap] | None = None,
    rate: float | None = None,
    fields: dict | None = None,
    line_of: Callable[[int], int] | None = None,
    record_import: bool = True,
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
    """
    mapping = dict(mapping or {})
    fields = dict(fields or {})
    picked: dict[str, tuple[Column, UnitExpr]] = {}
    for channel in CHANNELS:
        cmap = mapping.get(channel)
        if cmap is not None:
            col = _find(columns, cmap.source)
            if col is None:
                raise UserError(
                    f"{where}: missing column {cmap.source!r} for channel "
                    f"{channel!r}"
                    + suggest(cmap.source, columns)
                    + f"; columns: {', '.join(columns) or 'none'}"
                )
        else:
            col = _default_column(columns, channel)
            if col is None:
                continue
        picked[channel] = (col, _unit_of(col, cmap, channel, where))

    if "force" not in picked:
        raise UserError(
            f"{where}: missing column 'force' (the user force; map another "
            f"column with --map force=NAME:UNIT); columns: {', '.join(columns) or 'none'}"
        )

    n = picked["force"][0].values.size
    if n == 0:
        raise UserError(f"{where}: empty: no data rows")
    for channel, (col, _) in picked.items():
        if col.values.ndim != 1:
            raise UserError(
                f"{where}: channel {channel!r} (column {col.name!r}) is not one-dimensional"
            )
        if col.values.size != n:
            raise UserError(
                f"{where}: channel {channel!r} (column {col.name!r}) has "
                f"{col.values.size} rows, channel 'force' has {n}"
            )
    if n < 2:
        raise UserError(f"{where}: only one data row; a trial needs at least two samples")

    signals: dict[str, np.ndarray] = {}
    for channel, (col, unit) in picked.items():
        raw = np.asarray(col.values, dtype=np.float64)
        bad = ~np.isfinite(raw)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise UserError(
                f"{where}: channel {channel!r} (column {col.name!r}) is not a "
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
    """The exact uniform time axis, after checking the file's one."""
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
    step = np.diff(t)
    if np.any(step <= 0):
        row = int(np.flatnonzero(step <= 0)[0]) + 1
        raise UserError(
            f"{where}: channel 't' (column {col.name!r}) is not increasing at "
            f"{_at(row, line_of)}: {float(t[row - 1])!r} then {float(t[row])!r} s"
        )
    median = float(np.median(step))
    off = np.abs(step - median) > STEP_TOLERANCE * median
    if off.any():
        row = int(np.flatnonzero(off)[0]) + 1
        raise UserError(
            f"{where}: channel 't' (column {col.name!r}) is not uniformly sampled "
            f"at {_at(row, line_of)}: step {step[row - 1]:.6g} s, typical "
            f"{median:.6g} s (resample it first: evo_door.data.preprocess.to_uniform)"
        )
    dt = (t[-1] - t[0]) / (n - 1)
    _check_rate(1.0 / dt, rate, where, col.name, line_of)
    return t[0] + dt * np.arange(n)


def _check_rate(actual, expected, where, name, line_of) -> None:
    if expected and abs(actual - expected) > RATE_TOLERANCE * expected:
        raise UserError(
            f"{where}: channel 't' (column {name!r}) is sampled at {actual:.6g} Hz, "
            f"expected {expected:g} Hz, at {_at(1, line_of)}"
        )
