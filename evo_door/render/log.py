"""The renderer's log: device channels at a fixed rate (1 kHz default), in HDF5.

The servo loop runs at its own rate (2500 Hz) with a jittering clock on a real
device; :class:`RenderLog` resamples its cycles onto an exact uniform grid at the log
rate by linear interpolation between the two cycles around each tick, so a log is a
trial file: ``evo-door data show LOG.h5`` reads it and an experiment takes it as
``target: {data: LOG.h5}``. Layout::

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
    attributes of /render: rate, log_rate, device, statistics (loop period)
"""

from __future__ import annotations

import numpy as np

from evo_door import __version__
from evo_door.data.trial import Trial
from evo_door.errors import UserError
from evo_door.files import ATTRS, Dataset, write_h5

#: columns of a log row
COLUMNS = (
    "x",
    "y",
    "z",
    "vx",
    "vy",
    "vz",
    "fx",
    "fy",
    "fz",
    "cx",
    "cy",
    "cz",
    "theta",
    "dtheta",
    "force",
)
N_COLUMNS = len(COLUMNS)


class RenderLog:
    """Rows at ``rate`` (Hz) interpolated from the loop's cycles, plus events."""

    def __init__(self, rate: float = 1000.0, table=None):
        if not rate > 0:
            raise UserError(f"--log-rate {rate}: must be > 0 Hz")
        self.rate = float(rate)
        self.table = table
        self._rows: list[np.ndarray] = []
        self._prev_t: float | None = None
        self._prev = np.zeros(N_COLUMNS)
        self._k = 0  # next tick index
        self.param_times: list[float] = []
        self.param_sets: list[np.ndarray] = []
        self.events: list[dict] = []

    def add(self, t: float, row: np.ndarray) -> None:
        """One cycle at time ``t`` (s) with its ``row`` (see :data:`COLUMNS`)."""
        tick = self._k / self.rate
        if self._prev_t is None:
            if t >= tick:
                self._rows.append(row.copy())
                self._k += 1
        else:
            span = t - self._prev_t
            while tick <= t:
                w = (tick - self._prev_t) / span if span > 0 else 1.0
                self._rows.append(self._prev + w * (row - self._prev))
                self._k += 1
                tick = self._k / self.rate
        self._prev_t = t
        self._prev[:] = row

    def params(self, t: float, vector) -> None:
        """The parameter set in force from time ``t`` (s)."""
        self.param_times.append(float(t))
        self.param_sets.append(np.array(vector, dtype=np.float64))

    def event(self, t: float, kind: str, message: str, **extra) -> None:
        self.events.append({"t": float(t), "kind": kind, "message": message, **extra})

    @property
    def n(self) -> int:
        return len(self._rows)

    def array(self) -> np.ndarray:
        return np.array(self._rows).reshape(-1, N_COLUMNS)

    def trial(self, device: str = "") -> Trial:
        """The log as a trial (tangential user force, theta, dtheta)."""
        a = self.array()
        if a.shape[0] < 2:
            raise UserError("render log: fewer than two samples, nothing to write")
        t = np.arange(a.shape[0]) / self.rate
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
            meta={"device": device, "log_rate": self.rate},
        )

    def write(self, path, *, loop_rate: float, device: str, statistics: dict) -> None:
        """Write the log to ``path`` (HDF5, atomically)."""
        from evo_door.data.h5io import FORMAT, FORMAT_VERSION, _trial_tree

        tr = self.trial(device)
        a = self.array()
        col = COLUMNS.index
        names = list(self.table.names) if self.table is not None else []
        units = [p.unit for p in self.table] if self.table is not None else []
        render = {
            ATTRS: {
                "rate": float(loop_rate),
                "log_rate": self.rate,
                "device": device,
                "statistics": statistics,
                "events": self.events,
            },
            "t": Dataset(tr.t, {"unit": "s"}),
            "position": Dataset(a[:, col("x") : col("x") + 3], {"unit": "m"}),
            "velocity": Dataset(a[:, col("vx") : col("vx") + 3], {"unit": "m/s"}),
            "user_force": Dataset(a[:, col("fx") : col("fx") + 3], {"unit": "N"}),
            "command": Dataset(a[:, col("cx") : col("cx") + 3], {"unit": "N"}),
            "params": {
                ATTRS: {"names": names, "units": units},
                "t": Dataset(np.array(self.param_times), {"unit": "s"}),
                "values": np.array(self.param_sets).reshape(len(self.param_times), -1),
            },
        }
        tree = {
            ATTRS: {
                "format": FORMAT,
                "format_version": FORMAT_VERSION,
                "software": f"evo-door {__version__}",
                "description": f"haptic render log ({device})",
            },
            "trials": {"render": _trial_tree(tr)},
            "render": render,
        }
        write_h5(path, tree, compression=4, compress_above=1)
