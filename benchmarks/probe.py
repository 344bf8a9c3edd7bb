"""The host probe: how fast this host runs plain Python at the hour, beside a run's figures.

A virtual machine's cores run the same work markedly longer in one hour than in another
(other guests on the same hardware), so a figure without the host's speed beside it
cannot be told from a regression. The suite measures the probe at its start
and end (:mod:`benchmarks.suite`), ``benchmarks.history`` lists it per run, and
``.ci/run`` prints it at its own start and end, before anything is installed (this
module imports nothing outside Python's standard library)::

    python3 -m benchmarks.probe          # prints its seconds
"""

from __future__ import annotations

import time

#: How many integer additions the host probe makes in a plain Python loop.
PROBE_ADDITIONS = 20_000_000


def host_probe(additions: int = PROBE_ADDITIONS) -> float:
    """Seconds a plain Python loop takes to add up ``additions`` integers (module
    docstring: the host's speed at the hour)."""
    t0 = time.perf_counter()
    total = 0
    for i in range(additions):
        total += i
    return time.perf_counter() - t0


def probe_sentence(probe) -> str:
    """The report's sentence for the host probe ``probe`` (seconds at a run's start and
    end, as :func:`host_probe` measured them), or "" where there is none."""
    if not probe:
        return ""
    times = " at the start and ".join(f"{t:.2f} s" for t in probe)
    end = " at the end" if len(probe) > 1 else ""
    return (
        f" Host probe ({PROBE_ADDITIONS / 1e6:g} million additions in a plain Python loop, "
        f"`benchmarks/probe.py`; longer in a slower hour of the host): {times}{end}."
    )


if __name__ == "__main__":
    print(f"{host_probe():.2f}")
