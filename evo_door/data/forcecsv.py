"""Read a sampled input force (columns ``t`` in s and ``force`` in N) from CSV."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evo_door.errors import UserError


def read_force_csv(path) -> tuple[np.ndarray, np.ndarray]:
    """``(t, force)`` from a CSV with a header naming at least ``t`` and ``force``.

    Time must be uniformly sampled and increasing; every value finite.
    """
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: input file not found")
    with path.open() as fh:
        header = fh.readline().strip()
    if not header:
        raise UserError(f"{path}: empty file")
    names = [h.strip().strip('"') for h in header.split(",")]
    for col in ("t", "force"):
        if col not in names:
            raise UserError(f"{path}: missing column {col!r} (header: {header})")
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as exc:
        raise UserError(f"{path}: not a numeric CSV ({exc})") from None
    if data.shape[0] < 2:
        raise UserError(f"{path}: needs at least two rows of samples")
    t, force = data[:, names.index("t")], data[:, names.index("force")]
    bad = ~(np.isfinite(t) & np.isfinite(force))
    if bad.any():
        raise UserError(f"{path}: non-finite value on data row {int(np.flatnonzero(bad)[0]) + 1}")
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise UserError(
            f"{path}: time is not increasing at data row {int(np.flatnonzero(dt <= 0)[0]) + 2}"
        )
    if np.ptp(dt) > 1e-6 * dt.mean() + 1e-9:
        raise UserError(
            f"{path}: time is not uniformly sampled (step between "
            f"{dt.min():.6g} and {dt.max():.6g} s); resample it first"
        )
    return t, force
