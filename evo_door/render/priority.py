"""A paced loop's thread: its scheduling priority, and how it waits for its slot.

A servo loop paced on the wall clock (:class:`~evo_door.render.loop.ServoLoop` with
``realtime``) holds its core; anything else the scheduler runs there costs it whole
periods. :class:`Pacing` gives the loop's thread precedence while it runs (real-time
scheduling where permitted, else a raised niceness), keeps the garbage collector and
the interpreter's thread switching out of its way, waits for each slot
(:meth:`Pacing.wait_until`) and puts everything back when the loop ends.
"""

from __future__ import annotations

import gc
import os
import sys
import threading
import time

#: the niceness of a paced loop's thread (-20 highest, 0 normal), where real-time
#: scheduling is not permitted but this is
NICENESS = -20
#: the real-time priority (SCHED_FIFO, 1-99) of a paced loop's thread, where permitted:
#: above every normal thread on its core, below the kernel's own real-time threads
RT_PRIORITY = 10
#: ... and of the process's other threads meanwhile (the control port, the log's spill):
#: they share the loop's interpreter lock, and a normal thread that the scheduler
#: preempts while holding it stalls the loop for milliseconds (a priority inversion)
RT_PRIORITY_OTHERS = 5
#: a real-time loop sleeps until this long (s) before its slot, then spins: it wakes
#: within tens of microseconds, and while it sleeps the core and the interpreter are free
RT_SPIN = 1.5e-4
#: the interpreter's thread switch interval while a paced loop runs (s; default 5 ms)
SWITCH_INTERVAL = 1e-4


def set_other_threads(own: int, policy: int, priority: int, only=None) -> int:
    """Set the scheduling of this process's threads but ``own`` (Linux); how many took it.

    ``only``: change only the real-time threads at that priority (to undo). Threads
    started later inherit their creator's scheduling: the control port's handlers do.
    """
    try:
        tids = [int(name) for name in os.listdir("/proc/self/task")]
    except OSError:
        return 0
    done = 0
    for t in tids:
        if t == own:
            continue
        try:
            if only is not None and (
                os.sched_getscheduler(t) != os.SCHED_FIFO
                or os.sched_getparam(t).sched_priority != only
            ):
                continue
            os.sched_setscheduler(t, policy, os.sched_param(priority))
            done += 1
        except OSError:  # gone meanwhile, or not permitted
            pass
    return done


class Pacing:
    """What a paced loop changes in its thread and process while it runs.

    :meth:`begin` on the loop's thread before the first cycle, :meth:`end` after the
    last (also when the loop raised); :meth:`wait_until` in each cycle. ``log``
    (a :class:`~evo_door.render.log.RenderLog`) gets one ``priority`` event that says
    which scheduling the loop got.
    """

    def __init__(self, log):
        self.log = log
        #: the loop thread runs under SCHED_FIFO (between begin and end)
        self.realtime_sched = False
        self._gc_was_enabled = True
        self._switch_interval = sys.getswitchinterval()
        self._saved = None  # what end() puts back of the priority; None: nothing raised

    def begin(self, paced: bool) -> None:
        """Save what :meth:`end` puts back; if ``paced``, raise the thread's priority."""
        # a paced loop must not stop for a cyclic garbage collection (tens of ms);
        # reference counting still frees the per-cycle arrays
        self._gc_was_enabled = gc.isenabled()
        self._switch_interval = sys.getswitchinterval()
        self._saved = None
        if paced:
            gc.disable()
            # another thread holding the GIL gives it back after 0.1 ms, not 5 ms
            sys.setswitchinterval(SWITCH_INTERVAL)
            self._saved = self._raise_priority()

    def end(self) -> None:
        """Put back the garbage collector, the switch interval and the priority."""
        if self._gc_was_enabled:
            gc.enable()
        sys.setswitchinterval(self._switch_interval)
        if self._saved is not None:
            self._restore_priority(self._saved)
            self._saved = None

    def _raise_priority(self):
        """Give this thread (the loop's) precedence over the machine's other work.

        A paced loop holds its core; anything else the scheduler runs there (a browser
        drawing the console, the console's process, a test suite) costs it whole
        periods. In order of preference, where permitted (Linux: per thread):

        * real-time scheduling (SCHED_FIFO, priority :data:`RT_PRIORITY`): no normal
          thread runs on the loop's core while it wants it, and it can sleep between
          cycles (:meth:`wait_until`) because it wakes on time;
        * niceness :data:`NICENESS`: a larger share of the core, but a sleep would wake
          late, so the loop spins;
        * neither: normal priority, said in the log.

        The kernel keeps 5 % of every second from real-time threads by default
        (``sched_rt_runtime_us``), so a loop that never sleeps (its cycle longer than
        its period) cannot lock the core up; it misses cycles and the watchdog trips.
        Returns what :meth:`_restore_priority` needs.
        """
        tid = threading.get_native_id()
        cpus = None
        try:  # one core of its own when there are several: no migrations
            cpus = os.sched_getaffinity(0)
            if len(cpus) > 1:
                os.sched_setaffinity(0, {max(cpus)})
        except (OSError, AttributeError):
            cpus = None
        self.realtime_sched = False
        try:
            policy = os.sched_getscheduler(0)
            param = os.sched_getparam(0)
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
        except (OSError, AttributeError) as exc:
            rt_refused = exc
        else:
            self.realtime_sched = True
            others = set_other_threads(tid, os.SCHED_FIFO, RT_PRIORITY_OTHERS)
            self.log.event(
                0.0,
                "priority",
                f"loop thread real-time (SCHED_FIFO, priority {RT_PRIORITY}); "
                f"{others} other thread(s) of the process at priority {RT_PRIORITY_OTHERS}",
            )
            return tid, None, cpus, (policy, param)
        try:
            before = os.getpriority(os.PRIO_PROCESS, tid)
            os.setpriority(os.PRIO_PROCESS, tid, NICENESS)
        except (OSError, AttributeError) as exc:  # not permitted, or not this OS
            self.log.event(0.0, "priority", f"normal priority ({rt_refused}; {exc})")
            return (tid, None, cpus, None)
        self.log.event(
            0.0,
            "priority",
            f"loop thread at niceness {NICENESS} (was {before}); real-time refused: {rt_refused}",
        )
        return tid, before, cpus, None

    def _restore_priority(self, saved) -> None:
        tid, before, cpus, sched = saved
        self.realtime_sched = False
        try:
            if sched is not None:
                os.sched_setscheduler(0, *sched)
                set_other_threads(tid, os.SCHED_OTHER, 0, only=RT_PRIORITY_OTHERS)
            if before is not None:
                os.setpriority(os.PRIO_PROCESS, tid, before)
            if cpus is not None:
                os.sched_setaffinity(0, cpus)
        except OSError:  # lowering a priority back may need no permission; never fatal
            pass

    def wait_until(self, t0: float, t: float) -> float:
        """Wait for the slot at ``t`` (s after ``t0``): sleep while it is far, then spin.

        A real-time loop (:meth:`begin`) sleeps until :data:`RT_SPIN` before the
        slot: it wakes within tens of microseconds, and the sleep leaves the
        interpreter to the process's other threads (the control port) and the core to
        the rest of the machine. Otherwise the loop spins from 1.5 ms before: a normal
        thread's sleep wakes 50-100 us late, more on a busy core. The spin holds the
        interpreter; the other threads get it at the switch interval, 0.1 ms while a
        paced loop runs (:data:`SWITCH_INTERVAL`). A ``time.sleep(0)`` per turn served
        them sooner but, being a system call, let the scheduler take the core from the
        loop: 2-3 % more cycles late with a browser drawing the console
        (``benchmarks/console.md``). Returns the time (s after ``t0``)."""
        if self.realtime_sched:
            far, early = RT_SPIN, RT_SPIN
        else:
            far, early = 0.002, 0.0015
        while True:
            now = time.perf_counter() - t0
            left = t - now
            if left <= 0:
                return now
            if left > far:
                time.sleep(left - early)
