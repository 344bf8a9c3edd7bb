"""A paced loop's scheduling: real time where permitted, and the threads it shares its
interpreter with raised too, so that a busy machine does not make it late."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import pytest

import evo_door.render.priority as priority
from evo_door.render.device import SimDevice
from evo_door.render.loop import ServoLoop


def _realtime_permitted() -> bool:
    """Whether this process may put a thread under SCHED_FIFO (tried on a throwaway one)."""
    if not hasattr(os, "SCHED_FIFO"):
        return False
    answer = []

    def probe():
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
            answer.append(True)
        except OSError:
            answer.append(False)

    t = threading.Thread(target=probe)
    t.start()
    t.join()
    return answer[0]


needs_realtime = pytest.mark.skipif(
    not _realtime_permitted(), reason="real-time scheduling not permitted here"
)


def _priority_events(loop):
    return [e["message"] for e in loop.log.events if e["kind"] == "priority"]


@needs_realtime
def test_the_loop_and_its_interpreter_mates_run_real_time_and_are_put_back(seed_trial):
    seen = {}
    ready, sample, done = threading.Event(), threading.Event(), threading.Event()

    def mate():  # a thread of the process, started before the loop (the control port's)
        seen["tid"] = threading.get_native_id()
        ready.set()
        sample.wait(10.0)
        seen["during"] = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
        done.wait(10.0)
        seen["after"] = os.sched_getscheduler(0)

    t = threading.Thread(target=mate, daemon=True)
    t.start()
    ready.wait(10.0)
    # the widest budget: a loaded virtual machine holds a loop up for 100 ms now and then
    loop = ServoLoop(SimDevice("hold", seed=1), seed_trial, realtime=True, watchdog_misses=1000)

    def run():
        seen["loop_tid"] = threading.get_native_id()
        loop.run(0.4)
        seen["loop_after"] = os.sched_getscheduler(0)

    runner = threading.Thread(target=run)
    runner.start()
    time.sleep(0.2)
    seen["loop_during"] = os.sched_getscheduler(seen["loop_tid"])
    sample.set()
    runner.join(10.0)
    done.set()
    t.join(10.0)
    assert any("SCHED_FIFO" in m for m in _priority_events(loop))
    assert seen["loop_during"] == os.SCHED_FIFO
    assert seen["during"] == (os.SCHED_FIFO, priority.RT_PRIORITY_OTHERS)
    assert priority.RT_PRIORITY_OTHERS < priority.RT_PRIORITY
    # put back once the loop ends: nothing of the process stays real-time
    assert seen["loop_after"] == os.SCHED_OTHER and seen["after"] == os.SCHED_OTHER
    assert loop.statistics["on_time_fraction"] > 0.9


def test_without_permission_the_loop_says_so_and_runs_at_a_raised_niceness(seed_trial, monkeypatch):
    def refuse(*args):
        raise PermissionError("Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    # a normal-priority thread on a busy machine stalls for 4-8 ms, past the default
    # stall budget (10 cycles, 4 ms), which ends a render, and a loaded virtual machine
    # holds it up for 100 ms now and then (a CI run): 400 ms here, the widest
    loop = ServoLoop(SimDevice("hold", seed=1), seed_trial, realtime=True, watchdog_misses=1000)
    waits = []
    real_sleep = time.sleep
    monkeypatch.setattr(priority.time, "sleep", lambda s: (waits.append(s), real_sleep(s)))
    stats = loop.run(0.3)
    (message,) = _priority_events(loop)
    assert "real-time refused: Operation not permitted" in message or "normal priority" in message
    assert not loop.pacing.realtime_sched
    # a normal thread wakes late: it spins the last 1.5 ms rather than sleep into a slot
    assert stats["status"] == "done" and stats["cycles"] == 750  # no slot past the end
    assert all(w >= 0.0005 for w in waits)


@needs_realtime
def test_the_sleep_between_cycles_is_short_and_ends_before_the_slot(seed_trial, monkeypatch):
    # the widest budget: a loaded virtual machine holds a loop up for 100 ms now and then
    loop = ServoLoop(SimDevice("hold", seed=1), seed_trial, realtime=True, watchdog_misses=1000)
    waits = []
    real_sleep = time.sleep
    monkeypatch.setattr(priority.time, "sleep", lambda s: (waits.append(s), real_sleep(s)))
    loop.run(0.3)
    assert loop.pacing.realtime_sched is False  # put back
    # a real-time loop sleeps in most cycles (the core and the interpreter are free
    # then), never past the slot minus the spin margin
    assert len(waits) > 0.5 * 750
    assert max(waits) <= loop.period - priority.RT_SPIN + 1e-9


@needs_realtime
@pytest.mark.slow
def test_a_busy_machine_and_a_busy_interpreter_mate_leave_the_loop_on_time(seed_trial):
    """Every core busy with another process, and a thread of the renderer's own process
    working in bursts (as the control port does). At a normal priority the loop loses
    a third to a half of its cycles here; with the interpreter's other thread left at
    a normal priority, 1-7 % (it is preempted while holding the interpreter lock)."""
    hogs = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"])
        for _ in range(os.cpu_count() or 2)
    ]
    stop = threading.Event()

    def bursts():
        while not stop.is_set():
            t = time.perf_counter()
            while time.perf_counter() - t < 0.002:
                sum(range(200))
            time.sleep(0.005)

    mate = threading.Thread(target=bursts, daemon=True)
    mate.start()
    try:
        loop = ServoLoop(
            SimDevice("hold", seed=1), seed_trial, realtime=True, watchdog_misses=10**6
        )
        stats = loop.run(3.0)
    finally:
        stop.set()
        for h in hogs:
            h.kill()
            h.wait()
    # measured: 98.7-99.97 % with other engineers' test suites also on the machine
    assert stats["on_time_fraction"] >= 0.97, stats
