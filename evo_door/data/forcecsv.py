"""The input of a simulation: a sampled force, read as ``evo-door data import`` reads trials.

A force input is a trial file of any format (CSV, HDF5, NI TDMS) read by the one
reader (:func:`evo_door.data.read_trials`: the same column names, ``--map``, units in
headers, delimiters, byte-order mark, checks and messages). It needs only the time
(a ``t`` column, or the sampling rate) and the ``force``; response channels, if the
file has any, are not used: a CSV's are not even read.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evo_door.data.trial import Trial
from evo_door.data.units import parse_maps
from evo_door.errors import UserError

#: The channels a simulation's input needs.
INPUT_CHANNELS = ("t", "force")


def read_force(path, *, map=None, rate=None, trial=None) -> Trial:
    """The force record of ``path`` as a :class:`Trial` with only ``t`` and ``force``.

    Parameters
    ----------
    path : str or Path
        A trial file: ``.csv`` (one trial), ``.h5`` or ``.tdms`` (choose with
        ``trial`` when the file holds several).
    map : list of str or dict, optional
        ``["force=Fz:kN", "t=Time:ms"]``: only ``t`` and ``force`` may be mapped.
    rate : float, optional
        Sampling rate in Hz: builds the time axis of a file without one, else must match.
    trial : str or int, optional
        Which trial of a file holding several (id or position).

    Returns
    -------
    Trial
        ``t`` (uniform, s), ``force`` (N) and the file's metadata (``theta0``...);
        no response channels.
    """
    mapping = map if isinstance(map, dict) else parse_maps(map)
    unused = sorted(set(mapping) - set(INPUT_CHANNELS))
    if unused:
        raise UserError(
            f"--map {mapping[unused[0]]}: a simulation's input is t and force only; "
            f"channel {unused[0]!r} is not read"
        )
    from evo_door.data.io import read_trial

    found = read_trial(path, trial, map=mapping, rate=rate, channels=INPUT_CHANNELS)
    return found.replace(theta=None, dtheta=None, ddtheta=None)


def read_force_csv(path, map=None, rate=None) -> tuple[np.ndarray, np.ndarray]:
    """``(t, force)`` in s and N from a trial file (see :func:`read_force`).

    Time stamps within :data:`~evo_door.data.trial.STEP_TOLERANCE` of a uniform grid
    come back as that grid.
    """
    found = read_force(Path(path), map=map, rate=rate)
    return found.t, found.force
