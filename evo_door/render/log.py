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

Rows live in preallocated float64 blocks of :data:`BLOCK_ROWS` rows; a cycle writes
its rows in place (:func:`_resample`, compiled), so :meth:`RenderLog.add` allocates
nothing in the steady state. Once the side file holds a block (below), the block is
freed but the last :data:`RETAIN_BLOCKS` (the control port's window): a session of a
day holds a few megabytes, not 430 MB an hour.

Storage: the final log is written from the side file (and the rows still in memory),
a chunk at a time, never the whole session in memory; its datasets are chunked
(:data:`CHUNK_ROWS`) and gzip-compressed after a byte shuffle. Time is float64 (at a
day, float32 would step by 8 ms); every other channel float32, whose 24-bit mantissa
keeps 0.1 urad of theta, 0.06 um of position and 10 uN at 100 N, far below any
sensor's noise. ``benchmarks/suite.py`` (section device) measures the growth per hour.

Crash safety: :meth:`RenderLog.spill_to` starts a background thread that appends the
finished rows (every :data:`SPILL_ROWS`, about a second at 1 kHz), the events and the
parameter sets to the side file ``LOG.h5.partial``; :meth:`RenderLog.write` removes it
once the log is written, and :func:`recover` turns one left by a crash into a log.
The side file is a sequence of records, each a 4-byte tag, its length (uint64,
little-endian) and its payload; a record cut short by a kill is ignored::

    magic    b"EVO-DOOR RENDER LOG PARTIAL 1\n"
    HEAD     JSON: columns, rate (log, Hz), loop_rate (Hz), device, names, units
    ROWS     float64 little-endian, m x N_COLUMNS, the next m rows of the log
    EVTS     JSON: a list of further events
    PARS     JSON: {"t": [...], "values": [[...], ...]}, further parameter sets
"""

from __future__ import annotations

import itertools
import json
import os
import queue
import struct
import threading
from pathlib import Path

import numpy as np
from numba import njit

from evo_door import __version__
from evo_door.data.trial import Trial
from evo_door.errors import UserError
from evo_door.files import ATTRS, Dataset, check_folder, to_json

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
#: rows of one preallocated block (8192 x 15 float64: 0.98 MB, 8.2 s at 1 kHz)
BLOCK_ROWS = 8192
#: finished rows that go to the side file at a time (1.02 s at 1 kHz)
SPILL_ROWS = 1024
#: blocks kept in memory once the side file holds them (16 s at 1 kHz: what the
#: control port hands a console that catches up)
RETAIN_BLOCKS = 2
#: rows of an HDF5 chunk of the final log (16 s at 1 kHz)
CHUNK_ROWS = 16384
#: the final log's channel type but time's (see the module docstring)
STORED = np.float32
#: suffix of the side file of a log being written
PARTIAL_SUFFIX = ".partial"
#: events a client causes (session events, refused changes) that a log keeps at most,
#: and their JSON text at most (bytes): a client flooding them must not grow the
#: renderer's memory and its log without bound (a participant's session is hundreds)
MAX_CLIENT_EVENTS = 10_000
MAX_CLIENT_BYTES = 4 * 2**20
#: what a session is for, the participant and the set they chose: kept past the cap of
#: the other client events (a flood must not cost the choice), up to an allowance of
#: its own (each event is at most 16 KiB: 1.6 MiB)
RECORD_KINDS = ("participant", "chosen")
RECORD_RESERVE = 100
_MAGIC = b"EVO-DOOR RENDER LOG PARTIAL 1\n"
_RECORD = struct.Struct("<4sQ")
_ROW_DTYPE = np.dtype("<f8")


@njit(cache=True)
def _resample(t, row, prev_t, prev, k, rate, block, fill):
    """Rows of the ticks ``k / rate, (k + 1) / rate, ...`` up to ``t`` (s), by linear
    interpolation between the previous cycle (``prev_t``, ``prev``) and this one
    (``t``, ``row``), into ``block[fill:]``, as many as fit. Returns how many it wrote;
    once every tick up to ``t`` is written, ``prev`` becomes ``row``."""
    cap = block.shape[0]
    span = t - prev_t
    m = 0
    tick = k / rate
    while tick <= t and fill + m < cap:
        w = (tick - prev_t) / span if span > 0 else 1.0
        for j in range(row.shape[0]):
            block[fill + m, j] = prev[j] + w * (row[j] - prev[j])
        m += 1
        tick = (k + m) / rate
    if tick > t:
        for j in range(row.shape[0]):
            prev[j] = row[j]
    return m


def partial_path(path) -> Path:
    """The side file of the log ``path``: ``path`` + ``.partial``."""
    return Path(str(path) + PARTIAL_SUFFIX)


class RenderLog:
    """Rows at ``rate`` (Hz) interpolated from the loop's cycles, plus events.

    ``table`` is the parameter declaration (names and units of the parameter sets);
    rows are kept in blocks of ``block_rows`` (tests use small ones).
    """

    def __init__(self, rate: float = 1000.0, table=None, block_rows: int = BLOCK_ROWS):
        if not (rate > 0 and np.isfinite(rate)):
            raise UserError(f"--log-rate {rate}: must be finite and > 0 Hz")
        self.rate = float(rate)
        self.table = table
        self.block_rows = int(block_rows)
        self._spill: _Spill | None = None
        self._freed = 0  # leading blocks freed (their rows are in the side file only)
        self._recent_only = False  # keep_recent(): free old blocks without a side file
        self._first: np.ndarray | None = None  # the first row, kept for summaries
        self._blocks: list[np.ndarray | None] = []
        self._block = self._new_block()
        self._fill = 0  # rows written in the current block
        self._prev_t: float | None = None
        self._prev = np.zeros(N_COLUMNS)
        self._k = 0  # next tick index: the number of rows
        self._next_tick = 0.0  # its time, k / rate (s)
        self.param_times: list[float] = []
        self.param_sets: list[np.ndarray] = []
        self.events: list[dict] = []
        self.client_events = 0  # kept (client_event)
        self.record_events = 0  # participants and choices kept (RECORD_KINDS)
        self.client_bytes = 0
        self.dropped = 0  # past the cap
        self._dropped_event: dict | None = None
        self._names = list(table.names) if table is not None else []
        self._units = [p.unit for p in table] if table is not None else []
        # load the kernel now (numba's cache: milliseconds), not in a servo cycle
        _resample(0.0, self._prev, -1.0, self._prev.copy(), 0, 1.0, np.empty((0, N_COLUMNS)), 0)

    def _new_block(self) -> np.ndarray:
        block = np.empty((self.block_rows, N_COLUMNS), dtype=_ROW_DTYPE)
        self._blocks.append(block)
        self._free_old()
        return block

    def _free_old(self) -> None:
        """Free the blocks the side file holds (synced to the disk), all but the last
        :data:`RETAIN_BLOCKS`; with :meth:`keep_recent`, those without a side file."""
        if self._spill is not None:
            safe = self._spill.written
        elif self._recent_only:
            safe = self._k
        else:
            return
        b = self.block_rows
        while self._freed < len(self._blocks) - RETAIN_BLOCKS and (self._freed + 1) * b <= safe:
            self._blocks[self._freed] = None
            self._freed += 1

    def keep_recent(self) -> None:
        """Keep only the recent rows (a render without a log: nothing reads the rest)."""
        self._recent_only = True

    @property
    def held_from(self) -> int:
        """The first row still in memory (earlier ones are in the side file only)."""
        return self._freed * self.block_rows

    def add(self, t: float, row: np.ndarray) -> None:
        """One cycle at time ``t`` (s) with its ``row`` (see :data:`COLUMNS`)."""
        if t < self._next_tick:  # no tick this cycle (most cycles at 2500 Hz)
            self._prev[:] = row
            self._prev_t = t
            return
        if self._prev_t is None:  # the first cycle: its row is the first tick's
            if t >= self._k / self.rate:
                self._block[self._fill] = row
                self._first = row.copy()
                self._advance(1)
            self._prev[:] = row
        else:
            while True:
                if self._fill == self.block_rows:
                    self._block = self._new_block()
                    self._fill = 0
                m = _resample(
                    t, row, self._prev_t, self._prev, self._k, self.rate, self._block, self._fill
                )
                if m:
                    self._advance(m)
                if self._fill < self.block_rows:
                    break
        self._prev_t = t
        self._next_tick = self._k / self.rate

    def _advance(self, m: int) -> None:
        self._fill += m
        self._k += m
        spill = self._spill
        if spill is not None and self._k - spill.rows >= SPILL_ROWS:
            spill.send_rows(self)

    def params(self, t: float, vector) -> None:
        """The parameter set in force from time ``t`` (s)."""
        self.param_times.append(float(t))
        self.param_sets.append(np.array(vector, dtype=np.float64))

    def event(self, t: float, kind: str, message: str, **extra) -> None:
        self.events.append({"t": float(t), "kind": kind, "message": message, **extra})

    def client_event(self, t: float, kind: str, message: str, size=None, **extra) -> bool:
        """An event a client caused (a session event, a refused change), kept while the
        log holds fewer than :data:`MAX_CLIENT_EVENTS` of them and
        :data:`MAX_CLIENT_BYTES` of their JSON (``size``, bytes; measured when not
        given). Past the cap it is dropped and counted: the first drop adds one event
        ``dropped`` that says so, whose ``count`` follows. The session's record
        (:data:`RECORD_KINDS`) has an allowance of its own, :data:`RECORD_RESERVE`
        events, so that a flood cannot cost the participant's choice. Returns whether
        it was kept.
        """
        if size is None:
            size = len(to_json(extra)) + len(message)
        if kind in RECORD_KINDS and self.record_events < RECORD_RESERVE:
            self.record_events += 1
            self.event(t, kind, message, **extra)
            return True
        if self.client_events >= MAX_CLIENT_EVENTS or self.client_bytes + size > MAX_CLIENT_BYTES:
            self._drop(t)
            return False
        self.client_events += 1
        self.client_bytes += size
        self.event(t, kind, message, **extra)
        return True

    def client_cap(self) -> str:
        """The cap of :meth:`client_event`, for people."""
        return f"{MAX_CLIENT_EVENTS} events or {MAX_CLIENT_BYTES / 2**20:g} MiB"

    def _drop(self, t: float) -> None:
        self.dropped += 1
        if self._dropped_event is None:  # said once; the count follows in place
            self._dropped_event = {
                "t": float(t),
                "kind": "dropped",
                "message": f"session events and refused changes past {self.client_cap()} "
                "are not kept; count: how many were dropped",
                "count": 0,
            }
            self.events.append(self._dropped_event)
        self._dropped_event["count"] = self.dropped

    @property
    def n(self) -> int:
        return self._k

    def first(self) -> np.ndarray | None:
        """A copy of the first row, or None."""
        return None if self._first is None else self._first.copy()

    def last(self) -> np.ndarray | None:
        """A copy of the last finished row, or None; safe from another thread."""
        n = self._k
        if n == 0:
            return None
        i = n - 1
        return self._blocks[i // self.block_rows][i % self.block_rows].copy()

    def rows(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Rows ``start:stop`` held in memory (a copy when they span blocks, else a
        view); rows before :attr:`held_from` are left out. Safe from another thread."""
        stop = self._k if stop is None else min(stop, self._k)
        b = self.block_rows
        while True:  # a block freed meanwhile (the loop's thread): start after it
            begin = max(start, self.held_from)
            if begin >= stop:
                return np.zeros((0, N_COLUMNS))
            first, last = begin // b, (stop - 1) // b
            blocks = self._blocks[first : last + 1]
            if all(block is not None for block in blocks):
                break
        if first == last:
            return blocks[0][begin - first * b : stop - first * b]
        parts = [blocks[0][begin - first * b :], *blocks[1:-1], blocks[-1][: stop - last * b]]
        return np.concatenate(parts)

    def chunks(self):
        """Every row in order, as arrays of rows: the side file's for the blocks freed,
        then memory's (the final log is written from these, a chunk at a time)."""
        held = self.held_from
        if held:
            yield from _side_rows(self._spill.path, held)
        b = self.block_rows
        for start in range(held, self._k, b):
            yield self.rows(start, min(start + b, self._k))

    def array(self) -> np.ndarray:
        """All the rows, n x :data:`N_COLUMNS` (a new array; read back from the side
        file where memory no longer holds them)."""
        parts = list(self.chunks())
        if not parts:
            return np.zeros((0, N_COLUMNS))
        return np.concatenate(parts) if len(parts) > 1 else parts[0].copy()

    def trial(self, device: str = "") -> Trial:
        """The log as a trial (tangential user force, theta, dtheta)."""
        a = self.array()
        return self._trial(a, device)

    def _trial(self, a: np.ndarray, device: str) -> Trial:
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

    # -- crash safety ------------------------------------------------------------------
    def spill_to(self, path, *, loop_rate: float | None = None, device: str = "") -> Path:
        """From now on, append the finished rows, the events and the parameter sets to
        the side file ``path.partial`` (a background thread writes it). ``loop_rate``
        (Hz) and ``device`` go into it for :func:`recover`. Returns the side file.

        A side file already there (a render that ended without a clean stop) is
        refused: recover it (:func:`recover`) or remove it first.
        """
        if self._spill is not None:
            raise UserError(f"render log: already spilling to {self._spill.path}")
        side = partial_path(path)
        check_folder(side)
        if side.exists():
            raise UserError(
                f"{side}: a render log left by a render that did not end cleanly; "
                "recover it (evo-door render --recover) or remove it"
            )
        header = {
            "format": "evo-door render log partial",
            "software": f"evo-door {__version__}",
            "columns": list(COLUMNS),
            "rate": self.rate,
            "loop_rate": None if loop_rate is None else float(loop_rate),
            "device": device,
            "names": self._names,
            "units": self._units,
            "log": str(path),
        }
        self._spill = _Spill(side, header)
        self._spill.send_rows(self)
        return side

    @property
    def spill_path(self) -> Path | None:
        """The side file being written, if any."""
        return self._spill.path if self._spill is not None else None

    @property
    def spill_error(self) -> str | None:
        """Why the side file could not be written (its writer then stops), if it failed."""
        return self._spill.error if self._spill is not None else None

    def close(self) -> None:
        """Write the rows not yet spilled and stop the side file's writer (idempotent;
        the side file stays until :meth:`write` has written the log)."""
        if self._spill is not None:
            self._spill.close(self)

    # -- writing -----------------------------------------------------------------------
    def write(self, path, *, loop_rate: float, device: str, statistics: dict) -> None:
        """Write the log to ``path`` (HDF5, atomically); then remove the side file."""
        self.close()
        if self._recent_only and self._freed:
            raise UserError("render log: its early rows were not kept (keep_recent)")
        self._write(path, self.chunks(), self._k, loop_rate, device, statistics)
        if self._spill is not None:
            self._spill.path.unlink(missing_ok=True)

    def _write(self, path, chunks, n: int, loop_rate, device, statistics) -> None:
        """The log from ``chunks`` (arrays of rows, ``n`` rows in all), a chunk at a time."""
        from evo_door.data.h5io import FORMAT, FORMAT_VERSION, trial_tree
        from evo_door.files import atomic_write, h5py, write_group

        chunks = iter(chunks)
        lead: list[np.ndarray] = []  # the chunks up to the second row
        while sum(c.shape[0] for c in lead) < 2 and (c := next(chunks, None)) is not None:
            lead.append(c)
        two = np.concatenate(lead)[:2] if lead else np.zeros((0, N_COLUMNS))
        tr = self._trial(two, device)  # the trial's attributes (and the two-row minimum)
        trial = trial_tree(tr)
        trial[ATTRS]["n_samples"] = n
        channels = {name: trial.pop(name).attrs for name in ("t", "force", "theta", "dtheta")}
        render = {
            ATTRS: {
                "rate": float(loop_rate),
                "log_rate": self.rate,
                "device": device,
                "statistics": statistics,
                "events": self.events,
            },
            "params": {
                ATTRS: {"names": list(self._names), "units": list(self._units)},
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
            "trials": {"render": trial},
            "render": render,
        }
        session = session_tree(self.events, self._names, self._units)
        if session is not None:
            tree["session"] = session
        with atomic_write(path) as tmp, h5py().File(tmp, "w", track_order=True) as f:
            write_group(f, tree, compression=4, compress_above=1)
            sinks = _row_datasets(f, n, channels)
            k = 0
            for rows in itertools.chain(lead, chunks):
                m = rows.shape[0]
                for ds, cols in sinks:  # rows k..k+m; time: exact multiples of the period
                    ds[k : k + m] = (
                        np.arange(k, k + m) / self.rate if cols is None else rows[:, cols]
                    )
                k += m
            if k != n:
                raise UserError(f"render log: {k} rows to write, expected {n}")
            f["render/t"] = f["trials/render/t"]  # the same times: one dataset, two names


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


# -- the session record (the web console's participant sessions, issue 15) ----------
#: the event kinds that belong to a participant's session
SESSION_KINDS = ("participant", "ab_store", "ab_switch", "ab_choice", "undo", "reset", "save")
SESSION_KINDS += ("chosen", "note")


def session_tree(events, names, units) -> dict | None:
    """The ``/session`` group of a log from its events; None without session events.

    Layout::

        /session               participant (str, the last one given), events (json:
                               every session event, time-stamped), choices (json: the
                               A/B preferences), chosen_t (s, -1 without a choice)
            chosen             the participant's final set (SI, in ``names`` order),
                               attributes names, units; absent without a choice
    """
    mine = [e for e in events if e.get("kind") in SESSION_KINDS]
    if not mine:
        return None
    participant = ""
    for e in mine:
        if e["kind"] == "participant":
            participant = str(e.get("id", ""))
    chosen = [e for e in mine if e["kind"] == "chosen"]
    tree = {
        ATTRS: {
            "participant": participant,
            "events": mine,
            "choices": [e for e in mine if e["kind"] == "ab_choice"],
            "chosen_t": chosen[-1]["t"] if chosen else -1.0,
        }
    }
    values = chosen[-1].get("params", {}) if chosen else {}
    if chosen and all(n in values for n in names):  # the control port completes it
        vector = np.array([values[n] for n in names], dtype=np.float64)
        tree["chosen"] = Dataset(vector, {"names": list(names), "units": list(units)})
    return tree


def read_session(path) -> dict:
    """A render log's session: participant, duration, parameter sets, the choice.

    Returns ``{"participant", "duration_s", "device", "sets": [(t, {name: value})],
    "changes", "choices", "chosen": {name: value} or None, "chosen_t", "events",
    "statistics", "stopped"}`` (``stopped``: who ended the render, as its ``stopped``
    event says, e.g. "stopped by the operator"; else ""); a log without a session
    record has an empty participant, no choice and the session events list empty. A file that is not a render log is a
    UserError.
    """
    from evo_door.files import open_h5, read_attrs

    with open_h5(path) as f:
        if "render" not in f:
            raise UserError(f"{path}: not a render log (no /render group)")
        render = read_attrs(f["render"])
        names = list(read_attrs(f["render/params"])["names"])
        times = f["render/params/t"][()]
        values = f["render/params/values"][()]
        duration = float(f["render/t"][-1]) if f["render/t"].shape[0] else 0.0
        session = read_attrs(f["session"]) if "session" in f else {}
        chosen = None
        if "session/chosen" in f:
            ds = f["session/chosen"]
            chosen = dict(zip(read_attrs(ds)["names"], ds[()].tolist(), strict=True))
    events = render.get("events", [])
    ended = [e.get("message", "") for e in events if e.get("kind") == "stopped"]
    return {
        "participant": session.get("participant", ""),
        "duration_s": duration,
        "device": render.get("device", ""),
        "sets": [
            (float(t), dict(zip(names, v.tolist(), strict=True)))
            for t, v in zip(times, values, strict=True)
        ],
        "changes": [e for e in events if e.get("kind") == "change"],
        "choices": session.get("choices", []),
        "chosen": chosen,
        "chosen_t": session.get("chosen_t", -1.0),
        "events": session.get("events", []),
        "statistics": render.get("statistics", {}),
        "stopped": ended[-1] if ended else "",
    }


def is_render_log(path) -> bool:
    """Whether ``path`` is an HDF5 file holding a render log (never raises)."""
    from evo_door.files import open_h5

    try:
        with open_h5(path) as f:
            return "render" in f and "render/params" in f
    except (UserError, OSError):  # not a file, not HDF5: the caller's own reader says why
        return False


def format_session(s: dict, path="") -> str:
    """:func:`read_session`'s summary for people (angles in degrees, units)."""
    from evo_door.models.haptic import PARAMS
    from evo_door.render.keys import shown as shown_unit

    def shown(name, value):
        return shown_unit(value, PARAMS[name].unit).strip()

    stats = s["statistics"]
    lines = [f"render log {path}".rstrip()]
    who = s["participant"] or "(no participant id)"
    lines.append(
        f"  participant {who}, {s['duration_s']:.1f} s on {s['device'] or '?'}, "
        f"{len(s['changes'])} parameter changes, {len(s['choices'])} A/B choices"
    )
    status = s.get("stopped") or stats.get("status", "?")
    if stats.get("realtime") is False:  # simulated time: it kept no clock to be on time for
        lines.append(
            f"  loop {stats.get('rate_hz', 0):g} Hz unpaced (simulated time), "
            f"{stats.get('faults', 0)} faults, status {status}"
        )
    elif "on_time_fraction" in stats:
        lines.append(
            f"  loop {stats.get('rate_hz', 0):g} Hz, {100 * stats['on_time_fraction']:.3f} % of "
            f"cycles on time, {stats.get('faults', 0)} faults, status {status}"
        )
    for e in s["choices"]:
        lines.append(f"  at {e['t']:7.1f} s: prefers {e.get('slot', '?')}")
    start = s["sets"][0][1] if s["sets"] else {}
    final = s["chosen"] if s["chosen"] is not None else (s["sets"][-1][1] if s["sets"] else {})
    title = f"chosen at {s['chosen_t']:.1f} s" if s["chosen"] is not None else "last set in force"
    differs = [n for n in final if final[n] != start.get(n)]
    lines.append(f"  {title} (differs from the starting set in {len(differs)} parameters):")
    for name in differs:
        lines.append(
            f"    {name:24s} {shown(name, start[name]):>14s} -> {shown(name, final[name])}"
        )
    if s["chosen"] is None:
        lines.append("  no final choice recorded: --params LOG.h5 takes the last set in force")
    return "\n".join(lines)


def session_params(path) -> tuple[dict, str]:
    """The parameter set a render log stands for, and what it is.

    The participant's chosen set when the session has one, else the last set in
    force. Returns ``({name: value}, description)``.
    """
    s = read_session(path)
    if s["chosen"] is not None:
        who = f" of participant {s['participant']}" if s["participant"] else ""
        return s["chosen"], f"{path}: the set chosen{who} at {s['chosen_t']:.1f} s"
    if not s["sets"]:
        raise UserError(f"{path}: the log holds no parameter set")
    t, values = s["sets"][-1]
    return values, f"{path}: the last set in force (from {t:.1f} s; no choice recorded)"


class _Spill:
    """The side file of a log and the thread that appends to it.

    The loop's thread only puts views of finished rows (never written again) and
    slices of the event and parameter lists (append-only) on a queue; this thread
    encodes and writes them, flushes, and syncs the rows to the disk.
    """

    def __init__(self, path: Path, header: dict):
        self.path = path
        self.rows = 0  # rows sent
        self.written = 0  # rows written and synced to the disk (the writer's count)
        self._events = 0  # events sent
        self._params = 0  # parameter sets sent
        self.error: str | None = None
        self._closed = False
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        try:
            self._file = open(path, "xb")  # noqa: SIM115 (the writer thread closes it)
            self._file.write(_MAGIC)
            self._record(b"HEAD", json.dumps(header).encode())
            self._file.flush()
        except OSError as exc:
            raise UserError(f"{path}: cannot write ({exc.strerror or exc})") from None
        self._thread = threading.Thread(target=self._work, name="evo-door-log-spill", daemon=True)
        self._thread.start()

    def send_rows(self, log: RenderLog) -> None:
        """Queue what the side file lacks: finished rows, events, parameter sets."""
        if self._closed:
            return
        n_ev, n_par = len(log.events), len(log.param_times)
        if n_ev > self._events:
            self._queue.put((b"EVTS", log.events[self._events : n_ev]))
            self._events = n_ev
        if n_par > self._params:
            sets = (log.param_times[self._params : n_par], log.param_sets[self._params : n_par])
            self._queue.put((b"PARS", sets))
            self._params = n_par
        b = log.block_rows
        while self.rows < log.n:  # one view per block touched
            start = self.rows
            stop = min(log.n, (start // b + 1) * b)
            self._queue.put(
                (b"ROWS", log._blocks[start // b][start % b : start % b + stop - start])
            )
            self.rows = stop

    def close(self, log: RenderLog) -> None:
        if self._closed:
            return
        self.send_rows(log)
        self._closed = True
        self._queue.put(None)
        self._thread.join()

    def _record(self, tag: bytes, payload) -> None:
        data = memoryview(payload).cast("B")
        self._file.write(_RECORD.pack(tag, data.nbytes))
        self._file.write(data)

    def _work(self) -> None:
        try:
            while True:
                item = self._queue.get()
                if item is None:
                    return
                if self.error is not None:
                    continue  # drain: the file is unusable
                tag, payload = item
                try:
                    if tag == b"ROWS":
                        self._record(tag, np.ascontiguousarray(payload, dtype=_ROW_DTYPE))
                    elif tag == b"PARS":
                        times, sets = payload
                        text = to_json({"t": times, "values": [list(v) for v in sets]})
                        self._record(tag, text.encode())
                    else:  # events one by one: one json.dumps of a list of many
                        # session events (16 kB each) held the interpreter lock, which
                        # the servo loop waits for, for milliseconds
                        text = "[" + ",".join(to_json(e) for e in payload) + "]"
                        self._record(tag, text.encode())
                    self._file.flush()
                    if tag == b"ROWS":
                        os.fsync(self._file.fileno())
                        self.written += len(payload)  # the loop may free these rows now
                except OSError as exc:
                    self.error = f"{self.path}: cannot write ({exc.strerror or exc})"
        finally:
            self._file.close()


# -- recovery --------------------------------------------------------------------------
def read_partial(path) -> tuple[dict, np.ndarray, list[dict], list[float], list[list[float]]]:
    """The header, rows, events, parameter times and sets of a side file.

    Records cut short (a kill while writing) and anything after them are ignored.
    """
    header, n, events, times, sets = _scan_partial(path)
    parts = list(_side_rows(path, n))
    a = np.concatenate(parts) if parts else np.zeros((0, N_COLUMNS))
    return header, a, events, times, sets


def _records(fh):
    """The whole records of an open side file after its magic: (tag, offset of the
    payload, size), up to the first one cut short or damaged."""
    fh.seek(0, os.SEEK_END)
    end = fh.tell()
    pos = len(_MAGIC)
    while pos + _RECORD.size <= end:
        fh.seek(pos)
        tag, size = _RECORD.unpack(fh.read(_RECORD.size))
        body = pos + _RECORD.size
        if body + size > end or tag not in (b"HEAD", b"ROWS", b"EVTS", b"PARS"):
            return  # cut short by the crash, or not a record
        yield tag, body, size
        pos = body + size


def _open_partial(path):
    path = Path(path)
    try:
        fh = open(path, "rb")  # noqa: SIM115 (the callers close it)
    except FileNotFoundError:
        raise UserError(f"{path}: render log side file not found") from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if fh.read(len(_MAGIC)) != _MAGIC:
        fh.close()
        raise UserError(f"{path}: not the side file of a render log")
    return fh


_ROW_BYTES = N_COLUMNS * _ROW_DTYPE.itemsize


def _scan_partial(path) -> tuple[dict, int, list[dict], list[float], list[list[float]]]:
    """A side file's header, number of whole rows, events, parameter times and sets,
    read without its rows."""
    header = None
    n = 0
    events: list[dict] = []
    times: list[float] = []
    sets: list[list[float]] = []
    with _open_partial(path) as fh:
        for tag, offset, size in _records(fh):
            if tag == b"ROWS":
                if size % _ROW_BYTES:
                    break
                n += size // _ROW_BYTES
                continue
            fh.seek(offset)
            try:
                item = json.loads(fh.read(size))
                if tag == b"HEAD":
                    header = item
                elif tag == b"EVTS":
                    events.extend(item)
                else:
                    times.extend(item["t"])
                    sets.extend(item["values"])
            except (ValueError, KeyError, TypeError):
                break
    if header is None:
        raise UserError(f"{path}: render log side file without its header")
    return header, n, events, times, sets


def _side_rows(path, limit: int):
    """The side file's first ``limit`` rows, a record (about a second) at a time."""
    left = limit
    with _open_partial(path) as fh:
        for tag, offset, size in _records(fh):
            if left <= 0:
                return
            if tag != b"ROWS":
                continue
            fh.seek(offset)
            rows = np.frombuffer(fh.read(size), dtype=_ROW_DTYPE).reshape(-1, N_COLUMNS)
            yield rows[:left].astype(np.float64, copy=False)
            left -= rows.shape[0]
    if left > 0:
        raise UserError(f"{path}: {left} rows of the render log missing from its side file")


def recover(partial_path, out_path=None) -> Path:
    """Turn the side file of a render that ended without a clean stop into a log.

    ``out_path`` defaults to the side file's name without ``.partial``. The log has
    the layout of :meth:`RenderLog.write`, statistics ``{"recovered": true}`` and a
    last event (kind ``"recovered"``) that says so; the side file is removed once the
    log is written. Returns the log's path.
    """
    side = Path(partial_path)
    if out_path is None:
        if not side.name.endswith(PARTIAL_SUFFIX):
            raise UserError(f"{side}: give the log to write (the name lacks {PARTIAL_SUFFIX})")
        out_path = side.with_name(side.name[: -len(PARTIAL_SUFFIX)])
    out_path = Path(out_path)
    header, n, events, times, sets = _scan_partial(side)
    log = RenderLog(float(header["rate"]))
    log._names = list(header.get("names", []))
    log._units = list(header.get("units", []))
    log.events = events
    log.param_times = [float(t) for t in times]
    log.param_sets = [np.array(v, dtype=np.float64) for v in sets]
    if n < 2:
        raise UserError(f"{side}: fewer than two rows of the render were saved; nothing to recover")
    end = (n - 1) / log.rate
    log.event(
        end,
        "recovered",
        f"the session ended without a clean stop; rows up to {end:.3f} s recovered from {side.name}",
    )
    loop_rate = header.get("loop_rate")
    log._write(
        out_path,
        _side_rows(side, n),
        n,
        float("nan") if loop_rate is None else loop_rate,
        str(header.get("device", "")),
        {"recovered": True},
    )
    if out_path.resolve() != side.resolve():
        side.unlink(missing_ok=True)
    return out_path
