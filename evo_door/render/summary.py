"""What a render says when it ends: its summary lines (cycles, the door's travel, how
the loop kept time, the device's round trips, the watchdog, the clamps)."""

from __future__ import annotations

from evo_door.render.stopping import STOPPED


def summary_lines(loop, stats: dict, rate: float, name: str) -> list[str]:
    """The summary of a render that ran (its log has rows): ``stats`` are the loop's
    statistics, ``rate`` its rate (Hz), ``name`` the device's."""
    from evo_door.render.columns import THETA  # numpy: not at the command line's start

    stopped = stats["status"] == "stopped"
    first, last = loop.log.first()[THETA], loop.log.last()[THETA]  # rad (a mechanism's unit)
    status = STOPPED if stopped else stats["status"]
    lines = [
        f"rendered {stats['cycles']} cycles at {rate:g} Hz on {name} ({status}); "
        + loop.travel(first, last),
        timing_line(stats),
    ]
    if "round_trip_mean_s" in stats:
        lines.append(
            f"round trip mean {stats['round_trip_mean_s'] * 1e3:.3g} ms, "
            f"p99 {stats['round_trip_p99_s'] * 1e3:.3g} ms"
        )
    if stats["watchdog"]:
        lines.append(f"watchdog: {stats['watchdog']}")
    for ev in loop.log.events:
        if ev["kind"] == "clamp":
            lines.append(f"clamped at {ev['t']:.3f} s: {ev['changes']}")
    return lines


def timing_line(stats: dict) -> str:
    """How the loop kept time. An unpaced loop (simulated time) kept no period: it
    says so, with the wall-clock time it took, rather than the nominal period."""
    compute = f"compute p99 {stats['compute_p99_s'] * 1e6:.3g} us/cycle, faults {stats['faults']}"
    if not stats["realtime"]:
        simulated = stats["cycles"] / stats["rate_hz"]
        return (
            f"unpaced: {simulated:.4g} s of simulated time in {stats['wall_s']:.3g} s "
            f"(not kept on the wall clock; --realtime paces it), {compute}"
        )
    gaps = stats.get("gaps", 0)
    return (
        f"period mean {stats['period_mean_s'] * 1e3:.4g} ms, p99 lateness "
        f"{stats['lateness_p99_s'] * 1e3:.3g} ms, missed {stats['missed_cycles']} cycles"
        + (
            f" ({gaps} gap{'s' if gaps > 1 else ''}, the longest "
            f"{stats.get('gap_longest_s', 0.0) * 1e3:.0f} ms), "
            if gaps
            else ", "
        )
        + compute
    )
