"""The final render log: one HDF5 file, written a chunk at a time.

The log is a trial file: ``evo-door data show LOG.h5`` reads it and an experiment
takes it as ``target: {data: LOG.h5}``. Layout::

    /                      format = "evo-door trials" (a trial file), render = json
    /trials/render/        the trial: t (s), force (N, the measured user force on the
                           door's tangent, + toward closing), theta (rad), dtheta (rad/s)
    /render/
        t                  s, the log's time
        position           m, device frame, n x 3
        velocity           m/s, n x 3
        user_force         N, measured by the device's sensor, n x 3
        command            N, the force the host commanded, n x 3
        params/            names, units, t (s, when each set came into force),
                           values (n_sets x n_params, SI)
        events             json attribute: faults, clamps, watchdog, refused changes
    /session/              the participant's session, when there was one
                           (:func:`~evo_door.render.session.session_tree`)
    attributes of /render: rate, log_rate, device, statistics (loop period)

Storage: the final log is written from the side file (and the rows still in memory),
a chunk at a time, never the whole session in memory; its datasets are chunked
(:data:`CHUNK_ROWS`) and gzip-compressed after a byte shuffle. Time is float64 (at a
day, float32 would step by 8 ms); every other channel float32 (:data:`STORED`), whose
24-bit mantissa keeps 0.1 urad of theta, 0.06 um of position and 10 uN at 100 N, far
below any sensor's noise. ``benchmarks/suite.py`` (section device) measures the growth
per hour.
"""

from __future__ import annotations

import itertools

import numpy as np

from evo_door import __version__
from evo_door.data.trial import Trial
from evo_door.errors import UserError
from evo_door.files import ATTRS, Dataset
from evo_door.render.columns import COLUMNS, N_COLUMNS
from evo_door.render.session import session_tree

#: rows of an HDF5 chunk of the final log (16 s at 1 kHz)
CHUNK_ROWS = 16384
#: the final log's channel type but time's (see the module docstring)
STORED = np.float32


def trial_of(a: np.ndarray, rate: float, device: str) -> Trial:
    """The rows ``a`` of a log at ``rate`` (Hz) as a trial (tangential user force, theta,
    dtheta); a UserError for fewer than two."""
    if a.shape[0] < 2:
        raise UserError("render log: fewer than two samples, nothing to write")
    t = np.arange(a.shape[0]) / rate
    col = COLUMNS.index
    return Trial(
        t=t,
        force=a[:, col("force")],
        theta=a[:, col("theta")],
        dtheta=a[:, col("dtheta")],
        trial_id="render",
        kind="free",
        source=f"render on {device}" if device else "render",
        sensors={"force": {"model": "device force sensor, on the door's tangent"}},
        meta={"device": device, "log_rate": rate},
    )


def write_log(
    path,
    chunks,
    n: int,
    *,
    rate: float,
    names,
    units,
    events: list[dict],
    param_times: list[float],
    param_sets: list,
    loop_rate,
    device: str,
    statistics: dict,
) -> None:
    """The log from ``chunks`` (arrays of rows, ``n`` rows in all), a chunk at a time.

    ``rate`` (Hz) is the log's, ``loop_rate`` the loop's; ``names`` and ``units`` those
    of the parameter sets ``param_sets`` in force from ``param_times`` (s); ``events``
    the log's (the session record is gathered from them)."""
    from evo_door.data.h5io import FORMAT, FORMAT_VERSION, trial_tree
    from evo_door.files import atomic_write, new_h5, seal, write_group

    chunks = iter(chunks)
    lead: list[np.ndarray] = []  # the chunks up to the second row
    while sum(c.shape[0] for c in lead) < 2 and (c := next(chunks, None)) is not None:
        lead.append(c)
    two = np.concatenate(lead)[:2] if lead else np.zeros((0, N_COLUMNS))
    tr = trial_of(two, rate, device)  # the trial's attributes (and the two-row minimum)
    trial = trial_tree(tr)
    trial[ATTRS]["n_samples"] = n
    del trial[ATTRS]["data_digest"]  # of the two rows only: the file's checksums cover all
    channels = {name: trial.pop(name).attrs for name in ("t", "force", "theta", "dtheta")}
    render = {
        ATTRS: {
            "rate": float(loop_rate),
            "log_rate": rate,
            "device": device,
            "statistics": statistics,
            "events": events,
        },
        "params": {
            ATTRS: {"names": list(names), "units": list(units)},
            "t": Dataset(np.array(param_times), {"unit": "s"}),
            "values": np.array(param_sets).reshape(len(param_times), -1),
        },
    }
    tree = {
        ATTRS: {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "software": f"evo-door {__version__}",
            "description": f"haptic render log ({device})",
        },
        "trials": {"render": trial},
        "render": render,
    }
    session = session_tree(events, names, units)
    if session is not None:
        tree["session"] = session
    with atomic_write(path) as tmp, new_h5(tmp) as f:  # HDF5 writes in memory: see new_h5
        write_group(f, tree, compression=4, compress_above=1)
        sinks = _row_datasets(f, n, channels)
        k = 0
        for rows in itertools.chain(lead, chunks):
            m = rows.shape[0]
            for ds, cols in sinks:  # rows k..k+m; time: exact multiples of the period
                ds[k : k + m] = np.arange(k, k + m) / rate if cols is None else rows[:, cols]
            k += m
        if k != n:
            raise UserError(f"render log: {k} rows to write, expected {n}")
        f["render/t"] = f["trials/render/t"]  # the same times: one dataset, two names
        seal(f)


def _row_datasets(f, n: int, channels: dict) -> list:
    """The final log's row datasets in ``f`` (chunked, shuffled, gzip), each with the
    columns of a row it takes (None: the time): [(dataset, columns)]. ``channels``:
    the attributes of the trial's datasets."""
    from evo_door.files import write_attrs

    col = COLUMNS.index

    def dataset(group, name, dtype, attrs, width=0):
        shape = (n, width) if width else (n,)
        chunks = (min(n, CHUNK_ROWS), width) if width else (min(n, CHUNK_ROWS),)
        ds = group.create_dataset(
            name,
            shape,
            dtype,
            chunks=chunks,
            compression="gzip",
            compression_opts=4,
            shuffle=True,
            track_times=False,
        )
        write_attrs(ds, attrs)
        return ds

    trial = f["trials/render"]
    sinks = [(dataset(trial, "t", np.float64, channels["t"]), None)]
    for name in ("force", "theta", "dtheta"):
        sinks.append((dataset(trial, name, STORED, channels[name]), col(name)))
    for name, first, unit in _VECTORS:
        ds = dataset(f["render"], name, STORED, {"unit": unit}, width=3)
        sinks.append((ds, slice(col(first), col(first) + 3)))
    return sinks


#: the final log's 3-vector datasets of /render: (name, first column, unit)
_VECTORS = (
    ("position", "x", "m"),
    ("velocity", "vx", "m/s"),
    ("user_force", "fx", "N"),
    ("command", "cx", "N"),
)
