"""A render on a real device under its supervisor: the supervisor started with the
render, after the renderer's own connection (:mod:`evo_door.render.supervisor` is
the supervisor itself)."""

from __future__ import annotations

import sys

from evo_door.render.supervisor import BUDGET, Supervisor


def start_supervisor(device, loop, budget: float | None, enabled: bool = True):
    """A real device's supervisor (:mod:`evo_door.render.supervisor`), started, or None
    when not ``enabled`` (``--no-supervisor``: said on stderr and in the log);
    ``budget`` (s): how long without a heartbeat (default :data:`BUDGET`).

    The renderer connects first (the device's first connection is the renderer's
    own), then the supervisor opens its own; a device that refuses it is refused
    with one line unless ``--no-supervisor``.
    """
    if not enabled:
        print(
            "evo-door: warning: --no-supervisor: if this renderer freezes or dies, "
            "the device keeps its last force on the handle",
            file=sys.stderr,
        )
        loop.log.event(0.0, "supervisor", "none (--no-supervisor)")
        return None
    budget = BUDGET if budget is None else budget
    device.connect()
    try:
        supervisor = Supervisor(device.host, device.port, budget).start()
    except BaseException:
        device.close()
        raise
    loop.log.event(
        0.0,
        "supervisor",
        f"takes the force off after {budget * 1e3:g} ms without a heartbeat; {supervisor.priority}",
    )
    return supervisor
