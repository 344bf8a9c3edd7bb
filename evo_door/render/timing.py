"""How well a servo loop kept time: counts and histograms of its cycles.

A paced loop (:class:`~evo_door.render.loop.ServoLoop` on the wall clock) records,
per cycle, how late it started after its slot and how long its work took; a loop in
simulated time records the work only. :meth:`LoopTiming.schedule` turns them into the
period statistics of a render (mean period, p99 lateness, missed cycles, on-time
fraction), which the log keeps and ``evo-door render`` prints.
"""

from __future__ import annotations

import math

import numpy as np


class LoopTiming:
    """The loop's timing in constant memory: counts and histograms.

    A session of an hour at 2500 Hz is 9 million cycles: keeping every start time
    would grow without bound, so the lateness and the work of each cycle go into
    histograms with bins growing by :data:`GROWTH` (5 %) from :data:`FIRST` (1 us;
    below it, bin 0) to 1 s (the last bin takes everything longer), small enough to
    read a percentile from another thread at display rate. Percentiles are the upper
    edge of their bin: within 5 % above the true value.
    """

    FIRST = 1e-6  # s, upper edge of bin 0
    GROWTH = 1.05
    BINS = 2 + int(math.log(1.0 / FIRST) / math.log(GROWTH))

    def __init__(self, period: float):
        self.period = float(period)
        self.late = [0] * self.BINS  # lists: a cheaper += per cycle than an array's
        self.work = [0] * self.BINS
        self.starts = 0
        self.first = 0.0
        self.last = 0.0
        self.missed = 0  # slots skipped by a paced loop
        self.over = 0  # cycles whose work took longer than the period
        self.work_sum = 0.0
        self.worked = 0

    def _bin(self, seconds: float) -> int:
        if seconds <= self.FIRST:
            return 0
        return min(1 + int(math.log(seconds / self.FIRST) / _LOG_GROWTH), self.BINS - 1)

    def start(self, now: float, late: float) -> None:
        """A paced cycle started at ``now`` (s), ``late`` (s) after its slot."""
        if self.starts == 0:
            self.first = now
        self.last = now
        self.starts += 1
        self.late[self._bin(late)] += 1

    def worked_for(self, seconds: float) -> None:
        """A cycle's work (read, model, command, log) took ``seconds``."""
        self.work[self._bin(seconds)] += 1
        self.work_sum += seconds
        self.worked += 1
        if seconds > self.period:
            self.over += 1

    def period_mean(self) -> float:
        """Mean time between the starts of paced cycles (s); the period if unpaced."""
        if self.starts < 2:
            return self.period
        return (self.last - self.first) / (self.starts - 1)

    def percentile(self, which: str, q: float) -> float:
        """The ``q`` percentile (0-100) of ``"late"`` or ``"work"`` (s): its bin's
        upper edge (0 when nothing was counted)."""
        hist = self.late if which == "late" else self.work
        counts = np.cumsum(hist)
        if counts[-1] == 0:
            return 0.0
        k = int(np.searchsorted(counts, q / 100.0 * counts[-1]))
        return self.FIRST * self.GROWTH**k

    def schedule(self, cycles: int, paced: bool) -> dict:
        """The period statistics of ``cycles`` (the schedule's slots): ``period_mean_s``,
        ``lateness_p99_s`` (s), ``missed_cycles``, ``on_time_fraction``.

        A ``paced`` loop with two starts or more counts the slots it skipped; otherwise
        (simulated time) the period is exact and the work says if it could keep up: a
        cycle whose work took longer than the period counts as missed.
        """
        if paced and self.starts > 1:
            return {
                "period_mean_s": self.period_mean(),
                "lateness_p99_s": self.percentile("late", 99),
                "missed_cycles": int(self.missed),
                "on_time_fraction": 1.0 - self.missed / max(cycles, 1),  # of the slots
            }
        return {
            "period_mean_s": self.period,
            "lateness_p99_s": 0.0,
            "missed_cycles": int(self.over),
            "on_time_fraction": 1.0 - self.over / max(self.worked, 1),
        }


_LOG_GROWTH = math.log(LoopTiming.GROWTH)
