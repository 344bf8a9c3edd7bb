"""The side file of a render log: written while rendering, read back after a crash.

Crash safety: :meth:`~evo_door.render.log.RenderLog.spill_to` starts a
:class:`Spill`, a background thread that appends the finished rows (every
:data:`SPILL_ROWS`, about a second at 1 kHz), the events and the parameter sets to the
side file ``LOG.h5.partial``; :meth:`~evo_door.render.log.RenderLog.write` removes it
once the log is written, and :func:`~evo_door.render.log.recover` turns one left
by a crash into a log. The side file is a sequence of records, each a 4-byte tag, its
length (uint64, little-endian) and its payload; a record cut short by a kill is
ignored::

    magic    b"EVO-DOOR RENDER LOG PARTIAL 1\n"
    HEAD     JSON: columns, rate (log, Hz), loop_rate (Hz), device, names, units
    ROWS     float64 little-endian, m x N_COLUMNS, the next m rows of the log
    EVTS     JSON: a list of further events
    PARB     uint64 little-endian w, then float64 little-endian, m x (1 + w): further
             parameter sets, each its time (s) and its w values
    TALY     JSON: {"events": [...], "in_force": [t, [values]] or null}, what the log
             changes in place (:meth:`~evo_door.render.log.RenderLog.tally`): its
             counting events and the set in force it holds back past its cap of sets;
             the last such record holds
    PARS     JSON: {"t": [...], "values": [[...], ...]}, further parameter sets (read
             only: written by earlier versions)

The side file holds what the log in memory holds, its caps included (the sets up to
:data:`~evo_door.render.log.MAX_PARAM_SETS`, the counts of what was not kept), so that
:func:`scan_partial` gives the content :meth:`~evo_door.render.log.RenderLog.write`
would have written. The parameter sets are binary: the JSON of a second of changes
under a flood (400 sets) held the interpreter lock, which the servo loop waits for, for
milliseconds.
"""

from __future__ import annotations

import json
import os
import queue
import struct
import threading
from pathlib import Path

import numpy as np

from evo_door.errors import UserError
from evo_door.files import to_json
from evo_door.render.columns import N_COLUMNS, ROW_DTYPE

#: finished rows that go to the side file at a time (1.02 s at 1 kHz)
SPILL_ROWS = 1024
#: suffix of the side file of a log being written
PARTIAL_SUFFIX = ".partial"
_MAGIC = b"EVO-DOOR RENDER LOG PARTIAL 1\n"
_RECORD = struct.Struct("<4sQ")
_WIDTH = struct.Struct("<Q")
_TAGS = (b"HEAD", b"ROWS", b"EVTS", b"PARB", b"TALY", b"PARS")


def partial_path(path) -> Path:
    """The side file of the log ``path``: ``path`` + ``.partial``."""
    return Path(str(path) + PARTIAL_SUFFIX)


class Spill:
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
        self._tally = None  # the log's tally_mark() when its tally was last sent
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

    def send_rows(self, log) -> None:
        """Queue what the side file lacks: finished rows, events, parameter sets, and the
        log's tally when it changed (after the sets: a tally never names a set in force
        that a later record of sets holds)."""
        if self._closed:
            return
        n_ev, n_par = len(log.events), len(log.param_times)
        if n_ev > self._events:
            self._queue.put((b"EVTS", log.events[self._events : n_ev]))
            self._events = n_ev
        if n_par > self._params:
            sets = (log.param_times[self._params : n_par], log.param_sets[self._params : n_par])
            self._queue.put((b"PARB", sets))
            self._params = n_par
        mark = log.tally_mark()
        if mark != self._tally:
            self._queue.put((b"TALY", log.tally()))
            self._tally = mark
        b = log.block_rows
        while self.rows < log.n:  # one view per block touched
            start = self.rows
            stop = min(log.n, (start // b + 1) * b)
            self._queue.put(
                (b"ROWS", log._blocks[start // b][start % b : start % b + stop - start])
            )
            self.rows = stop

    def close(self, log) -> None:
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
                        self._record(tag, np.ascontiguousarray(payload, dtype=ROW_DTYPE))
                    elif tag == b"PARB":
                        self._record(tag, _sets_payload(*payload))
                    elif tag == b"TALY":
                        self._record(tag, to_json(payload).encode())
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


def _sets_payload(times, sets) -> bytes:
    """A PARB record's payload: the width, then each set's time and values."""
    table = np.column_stack([np.asarray(times, dtype="<f8"), np.asarray(sets, dtype="<f8")])
    return _WIDTH.pack(table.shape[1] - 1) + table.astype("<f8", copy=False).tobytes()


def _sets_of(data: bytes) -> tuple[list[float], list[list[float]]]:
    """The times and sets of a PARB record's payload (a ValueError if it is damaged)."""
    (width,) = _WIDTH.unpack_from(data)
    body = np.frombuffer(data, dtype="<f8", offset=_WIDTH.size)
    if body.size % (width + 1):
        raise ValueError("a parameter record cut inside a set")
    table = body.reshape(-1, width + 1)
    return table[:, 0].tolist(), table[:, 1:].tolist()


def read_partial(path) -> tuple[dict, np.ndarray, list[dict], list[float], list[list[float]]]:
    """The header, rows, events, parameter times and sets of a side file.

    Records cut short (a kill while writing) and anything after them are ignored.
    """
    header, n, events, times, sets = scan_partial(path)
    parts = list(side_rows(path, n))
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
        if body + size > end or tag not in _TAGS:
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


_ROW_BYTES = N_COLUMNS * ROW_DTYPE.itemsize


def scan_partial(path) -> tuple[dict, int, list[dict], list[float], list[list[float]]]:
    """A side file's header, number of whole rows, events, parameter times and sets,
    read without its rows; the last tally applied (the counting events' counts, the
    set in force held back kept as the last set), as the log would have been written."""
    header = None
    n = 0
    events: list[dict] = []
    times: list[float] = []
    sets: list[list[float]] = []
    tally = None
    with _open_partial(path) as fh:
        for tag, offset, size in _records(fh):
            if tag == b"ROWS":
                if size % _ROW_BYTES:
                    break
                n += size // _ROW_BYTES
                continue
            fh.seek(offset)
            try:
                data = fh.read(size)
                if tag == b"PARB":
                    more_t, more_v = _sets_of(data)
                    times.extend(more_t)
                    sets.extend(more_v)
                    continue
                item = json.loads(data)
                if tag == b"HEAD":
                    header = item
                elif tag == b"EVTS":
                    events.extend(item)
                elif tag == b"TALY":
                    tally = _tally_of(item)
                else:
                    times.extend(item["t"])
                    sets.extend(item["values"])
            except (ValueError, KeyError, IndexError, TypeError, OverflowError, struct.error):
                break  # damaged: what follows is not read
    if header is None:
        raise UserError(f"{path}: render log side file without its header")
    if tally is not None:
        _apply_tally(tally, events, times, sets)
    return header, n, events, times, sets


def _tally_of(item) -> dict:
    """A TALY record's content, checked: a TypeError, ValueError, KeyError or IndexError
    if it is not one."""
    counting, held = item["events"], item["in_force"]
    if not (isinstance(counting, list) and all(isinstance(e, dict) for e in counting)):
        raise TypeError("not the events of a tally")
    if held is not None:
        held = (float(held[0]), [float(v) for v in held[1]])
    return {"events": counting, "in_force": held}


def _apply_tally(tally: dict, events: list[dict], times: list, sets: list) -> None:
    """The side file's last tally into what it read: each counting event (by kind)
    takes the tally's fields; the set in force held back is the last set."""
    counted = {e.get("kind"): e for e in tally["events"]}
    for i, e in enumerate(events):
        if isinstance(e, dict) and e.get("kind") in counted:
            events[i] = {**e, **counted.pop(e["kind"])}
    if tally["in_force"] is not None:
        t, values = tally["in_force"]
        if not (times and times[-1] == t and sets[-1] == values):  # not sent twice
            times.append(t)
            sets.append(values)


def side_rows(path, limit: int):
    """The side file's first ``limit`` rows, a record (about a second) at a time."""
    left = limit
    with _open_partial(path) as fh:
        for tag, offset, size in _records(fh):
            if left <= 0:
                return
            if tag != b"ROWS":
                continue
            fh.seek(offset)
            rows = np.frombuffer(fh.read(size), dtype=ROW_DTYPE).reshape(-1, N_COLUMNS)
            yield rows[:left].astype(np.float64, copy=False)
            left -= rows.shape[0]
    if left > 0:
        raise UserError(f"{path}: {left} rows of the render log missing from its side file")
