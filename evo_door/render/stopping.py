"""How a render stops: Ctrl-C (or SIGTERM) ends it between two cycles, its log whole;
a render ended by an exception still writes the log it has.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading

#: what the log and the summary say of a render ended by Ctrl-C (or the key UI's q)
STOPPED = "stopped by the operator"


@contextlib.contextmanager
def stop_on_ctrl_c(stop: threading.Event, loop):
    """Ctrl-C (SIGINT) sets ``stop``: the loop ends between two cycles and the render
    ends as one that ran its course, its log whole (status ``stopped``, exit 0), with
    or without ``--duration``. Another Ctrl-C while the loop still runs interrupts at
    once (a device that hangs); while the log is written it is ignored. SIGTERM does
    the same (its default would end the process before the device's force is taken
    off)."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signals go to the main thread only: an embedding caller's own
        return

    def on_sigint(signum, frame) -> None:
        if not stop.is_set():
            stop.set()
        elif loop.status in ("new", "running"):
            raise KeyboardInterrupt
        else:
            print("evo-door: writing the log, one moment", file=sys.stderr, flush=True)

    previous = signal.signal(signal.SIGINT, on_sigint)
    previous_term = signal.signal(signal.SIGTERM, on_sigint)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        signal.signal(signal.SIGTERM, previous_term)


def write_interrupted(loop, path, exc: BaseException) -> None:
    """Write the log of a render that ``exc`` ended (stderr says so); the side file
    stays if even that fails."""
    log = loop.log
    if log.n < 2:  # ended before it rendered (a bad option, a device that failed to start)
        log.close()
        if log.spill_path is not None:
            log.spill_path.unlink(missing_ok=True)
        return
    what = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    log.event((log.n - 1) / log.rate, "interrupted", f"the render ended on {what}")
    stats = {**loop.statistics, "interrupted": what}
    try:
        log.write(path, loop_rate=loop.rate, device=loop.device_name, statistics=stats)
    except Exception as err:  # the first error is the one to raise
        print(
            f"evo-door: the log of the interrupted render was not written ({err}); "
            f"its rows so far are in {log.spill_path}",
            file=sys.stderr,
        )
    else:
        print(f"evo-door: render interrupted ({what}); wrote {path}", file=sys.stderr)
