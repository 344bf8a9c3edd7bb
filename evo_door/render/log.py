"""The renderer's log in memory: device channels at a fixed rate (1 kHz default).

The servo loop runs at its own rate (2500 Hz) with a jittering clock on a real
device; :class:`RenderLog` resamples its cycles onto an exact uniform grid at the log
rate by linear interpolation between the two cycles around each tick, so a log is a
trial file (:mod:`evo_door.render.log_file` writes it). Besides the rows (the columns
of :data:`~evo_door.render.columns.COLUMNS`) it keeps the events (faults, clamps,
the watchdog, changes, the console's session: :mod:`evo_door.render.session`) and the
parameter sets in force, up to :data:`MAX_PARAM_SETS` (past it a change still comes
into force; the log counts it, and keeps the set in force at each choice and at the end).

Rows live in preallocated float64 blocks of :data:`BLOCK_ROWS` rows; a cycle writes
its rows in place (:func:`_resample`, compiled), so :meth:`RenderLog.add` allocates
nothing in the steady state. Once the side file (:mod:`evo_door.render.spill`,
:meth:`RenderLog.spill_to`) holds a block, the block is freed but the last
:data:`RETAIN_BLOCKS` (the control port's window): a session of a day holds a few
megabytes, not 430 MB an hour. :func:`recover` turns a side file left by a crash into
a log.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numba import njit

from evo_door import __version__
from evo_door.data.trial import Trial
from evo_door.errors import UserError, WriteError
from evo_door.files import check_folder, to_json
from evo_door.render.columns import COLUMNS, N_COLUMNS, ROW_DTYPE
from evo_door.render.log_file import trial_of, write_log
from evo_door.render.spill import (
    PARTIAL_SUFFIX,
    SPILL_ROWS,
    Spill,
    partial_path,
    scan_partial,
    side_rows,
)

#: rows of one preallocated block (8192 x 15 float64: 0.98 MB, 8.2 s at 1 kHz)
BLOCK_ROWS = 8192
#: blocks kept in memory once the side file holds them (16 s at 1 kHz: what the
#: control port hands a console that catches up)
RETAIN_BLOCKS = 2
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
#: parameter sets a log keeps at most, each with its "change" event. A participant's
#: session changes the set hundreds of times (keys, the console's sliders at 15 changes
#: a second while dragged, a JND session's switches); a client flooding valid changes
#: at the control port's 400 requests a second reached 24,001 sets in a minute. 5,000
#: sets of 48 float64 values are 1.9 MB, their change events about as much again.
#: Past the cap a change still comes into force: the log counts it in one event
#: "changes_dropped" and keeps the set in force at each choice (up to RECORD_RESERVE)
#: and at the end (:meth:`RenderLog.close`), so the set the session stands for is kept
MAX_PARAM_SETS = 5_000


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
        self._spill: Spill | None = None
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
        self.changes_dropped = 0  # parameter sets past MAX_PARAM_SETS
        self._changes_event: dict | None = None
        # the last set in force that was not kept (t, vector); choices kept (counted by
        # the control port's threads) and those the loop's thread has seen: a choice
        # since keeps the set it was made on
        self._unkept: tuple[float, np.ndarray] | None = None
        self._choices = 0
        self._choices_seen = 0
        self._kept_at_choices = 0
        self._names = list(table.names) if table is not None else []
        self._units = [p.unit for p in table] if table is not None else []
        # load the kernel now (numba's cache: milliseconds), not in a servo cycle
        _resample(0.0, self._prev, -1.0, self._prev.copy(), 0, 1.0, np.empty((0, N_COLUMNS)), 0)

    def _new_block(self) -> np.ndarray:
        block = np.empty((self.block_rows, N_COLUMNS), dtype=ROW_DTYPE)
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

    def params(self, t: float, vector) -> bool:
        """The parameter set in force from time ``t`` (s); returns whether it was kept.

        The log keeps :data:`MAX_PARAM_SETS` sets; past that it counts them (the event
        ``changes_dropped``: ``count``, from ``t`` to ``last_t``) and holds the last one
        back, to keep it if a choice is made on it or the log ends with it in force. The
        loop's thread only: the spill reads these lists from it.
        """
        vector = np.array(vector, dtype=np.float64)
        choices = self._choices
        if choices != self._choices_seen:  # a choice was made on the set in force until now
            self._choices_seen = choices
            self._keep_unkept(at_choice=True)
        if len(self.param_times) < MAX_PARAM_SETS:
            self.param_times.append(float(t))
            self.param_sets.append(vector)
            return True
        self._unkept = (float(t), vector)
        self.changes_dropped += 1
        if self._changes_event is None:  # said once; count and last_t follow in place
            self._changes_event = {
                "t": float(t),
                "kind": "changes_dropped",
                "message": f"parameter sets past the log's cap of {MAX_PARAM_SETS} came into "
                "force but are not kept, nor their change events; count: how many; the sets "
                "in force from t to last_t are not known but at a choice and at the end",
                "count": 0,
                "last_t": float(t),
            }
            self.events.append(self._changes_event)
        self._changes_event["count"] = self.changes_dropped
        self._changes_event["last_t"] = float(t)
        return False

    def _keep_unkept(self, at_choice: bool) -> None:
        """Keep the set in force that was held back (past the cap), if any: at a choice
        (up to :data:`RECORD_RESERVE` of them) or at the end."""
        if self._unkept is None or (at_choice and self._kept_at_choices >= RECORD_RESERVE):
            return
        t, vector = self._unkept
        self._unkept = None
        self._kept_at_choices += at_choice
        self.param_times.append(t)
        self.param_sets.append(vector)

    def tally(self) -> dict:
        """What the log changes in place rather than appends, for the side file: the
        events that count (``dropped``, ``changes_dropped``; copies) and the set in force
        held back ``[t, values]`` (or None)."""
        counting = [e for e in (self._dropped_event, self._changes_event) if e is not None]
        held = self._unkept
        return {
            "events": [dict(e) for e in counting],
            "in_force": None if held is None else [held[0], held[1].tolist()],
        }

    def tally_mark(self) -> tuple:
        """Changes whenever :meth:`tally` does (cheap: the spill asks every second)."""
        return (self.dropped, self.changes_dropped, self._unkept is None)

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
        it was kept. A choice kept (``chosen``) keeps the set in force it was made on
        too, past :data:`MAX_PARAM_SETS`.
        """
        if size is None:
            size = len(to_json(extra)) + len(message)
        if kind in RECORD_KINDS and self.record_events < RECORD_RESERVE:
            self.record_events += 1
        elif self.client_events >= MAX_CLIENT_EVENTS or self.client_bytes + size > MAX_CLIENT_BYTES:
            self._drop(t)
            return False
        else:
            self.client_events += 1
            self.client_bytes += size
        self.event(t, kind, message, **extra)
        if kind == "chosen":  # the set it was made on is kept, past the cap of sets too
            self._choices += 1
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
            yield from side_rows(self._spill.path, held)
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
        return trial_of(a, self.rate, device)

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
        self._spill = Spill(side, header)
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
        """The log ends: the set in force kept (held back past :data:`MAX_PARAM_SETS`);
        write the rows not yet spilled and stop the side file's writer (idempotent; the
        side file stays until :meth:`write` has written the log)."""
        self._keep_unkept(at_choice=False)
        if self._spill is not None:
            self._spill.close(self)

    # -- writing -----------------------------------------------------------------------
    def write(self, path, *, loop_rate: float, device: str, statistics: dict) -> None:
        """Write the log to ``path`` (HDF5, atomically); then remove the side file."""
        self.close()
        if self._recent_only and self._freed:
            raise UserError("render log: its early rows were not kept (keep_recent)")
        try:
            self._write(path, self.chunks(), self._k, loop_rate, device, statistics)
        except WriteError as exc:  # the side file (if any) holds the rows: say so
            spill = self._spill
            if spill is None or not spill.path.is_file():
                raise
            side = spill.path
            rows = "the rows up to the side file's own failure" if spill.error else "the rows"
            raise exc.leaving(
                f"{rows} are kept in {side}: `evo-door render --recover {side}` writes the "
                "log once there is room"
            ) from None
        if self._spill is not None:
            self._spill.path.unlink(missing_ok=True)

    def _write(self, path, chunks, n: int, loop_rate, device, statistics) -> None:
        """The log from ``chunks`` (arrays of rows, ``n`` rows in all), a chunk at a time."""
        write_log(
            path,
            chunks,
            n,
            rate=self.rate,
            names=self._names,
            units=self._units,
            events=self.events,
            param_times=self.param_times,
            param_sets=self.param_sets,
            loop_rate=loop_rate,
            device=device,
            statistics=statistics,
        )


# -- recovery --------------------------------------------------------------------------
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
    header, n, events, times, sets = scan_partial(side)
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
        side_rows(side, n),
        n,
        float("nan") if loop_rate is None else loop_rate,
        str(header.get("device", "")),
        {"recovered": True},
    )
    if out_path.resolve() != side.resolve():
        side.unlink(missing_ok=True)
    return out_path
