"""The loop comes first: the servo loop's timing with the control port under a flood.

Before the port had its limits, 200 concurrent clients took the loop to 97.3 % of its cycles on time, and
5,000 session events of 16 kB grew the renderer by 118 MB and its log to 164 MB. The
target is >= 99.9 % of cycles on time at 2500 Hz with 200 clients flooding the control
port, the renderer's memory and its log bounded. Each run is ``evo-door render --params
seed_trial --device sim --user swing --realtime --duration S --control PORT --token T
--log LOG.h5`` in its own process, as a user starts it; its timing comes from the log.

(a) no client;
(b) ``CLIENTS`` clients at once, from this process (asyncio), for the whole run: each
    sends batches of ``BATCH`` pipelined session events of 16 kB (every kind in turn)
    and absurd lines (a 400-digit integer, NaN, nesting 30,000 deep, 200 kB, binary
    garbage) as fast as the answers come; a client refused (the port serves 16 at
    once) or dropped connects again a second later.

The renderer's resident memory is sampled every 0.25 s (``/proc/PID/status``); its
growth is the peak over the run minus the figure when its port first answered.

    python benchmarks/bench_control.py                 # writes benchmarks/control.md
    python benchmarks/bench_control.py --seconds 5 --no-write
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._util import free_port, machine_line, publish  # noqa: E402

RATE = 2500.0
ON_TIME = 0.999
#: concurrent clients of run (b)
CLIENTS = 200
#: requests a flooding client writes at once before it reads their answers
BATCH = 20
#: resident memory the renderer may grow by under the flood (MiB)
RSS_TARGET_MIB = 64.0
#: each render's duration (s): a measured run, a ``--quick`` one (the suite's section)
SECONDS, QUICK_SECONDS = 20.0, 4.0
TOKEN = "bench"


def _rss_mib(pid: int) -> float | None:
    """Resident memory of process ``pid`` (MiB), None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def _messages() -> list[bytes]:
    """What a flooding client sends, in turn: events of every kind, 16 kB each, and
    absurd lines (each answered ok false)."""
    from evo_door.render.control import EVENT_KINDS

    text = "x" * 16_000
    events = [
        (json.dumps({"token": TOKEN, "event": {"kind": k, "text": text}}) + "\n").encode()
        for k in EVENT_KINDS
    ]
    absurd = [
        b'{"token": "bench", "get": "rows", "since": ' + b"7" * 400 + b"}\n",
        b'{"token": "bench", "set": {"friction_closing": NaN}}\n',
        b"[" * 30_000 + b"]" * 30_000 + b"\n",
        b'{"note": "' + b"y" * 200_000 + b'"}\n',
        bytes(b for b in range(256) if b != 10) + b"\n",
    ]
    return events * 4 + absurd


def _kind_of(line: bytes) -> str:
    """An answer's category for the counts."""
    try:
        answer = json.loads(line)
    except ValueError:
        return "unreadable"
    if answer.get("ok"):
        return "ok"
    error = answer.get("error", "")
    if "a second" in error:
        return "refused_rate"
    if "cap of session events" in error:
        return "refused_log_cap"
    if "connections at once" in error:
        return "refused_client_cap"
    return "refused_input"


async def _client(port: int, stop_at: float, counts: dict, order: int) -> None:
    """One flooding client until ``stop_at`` (time.monotonic)."""
    messages = itertools.cycle(_messages())
    for _ in range(order % len(_messages())):  # clients do not all send alike at once
        next(messages)
    while time.monotonic() < stop_at:
        writer = None
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", port, limit=2**20)
            counts["connections"] += 1
            while time.monotonic() < stop_at:
                batch = [next(messages) for _ in range(BATCH)]
                writer.write(b"".join(batch))
                await writer.drain()
                for _ in batch:
                    line = await asyncio.wait_for(reader.readline(), 10.0)
                    if not line:
                        raise ConnectionResetError
                    counts[_kind_of(line)] += 1
        except (OSError, TimeoutError, ConnectionError, asyncio.IncompleteReadError):
            counts["dropped"] += 1
        finally:
            if writer is not None:
                writer.close()
        await asyncio.sleep(1.0)  # refused or dropped: again a second later


async def _flood(port: int, stop_at: float, clients: int) -> dict:
    counts = dict.fromkeys(
        (
            "connections",
            "dropped",
            "ok",
            "refused_rate",
            "refused_log_cap",
            "refused_client_cap",
            "refused_input",
            "unreadable",
        ),
        0,
    )
    await asyncio.gather(*(_client(port, stop_at, counts, k) for k in range(clients)))
    return counts


def _wait_for_port(port: int, proc, timeout: float = 120.0) -> bool:
    """Wait until the render's loop runs and its port answers; False if it ended."""
    from evo_door.errors import UserError
    from evo_door.render.control import request

    deadline = time.monotonic() + timeout
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            h = request("127.0.0.1", port, {"token": TOKEN, "get": "health"}, timeout=2.0)
        except UserError:  # not listening yet
            h = {}
        if h.get("ok") and h.get("status") == "running":
            return True
        time.sleep(0.05)
    return False


def flood_run(seconds: float, clients: int, folder: Path) -> dict:
    """One render of ``seconds`` in its own process, flooded by ``clients`` (0: none).

    Returns the loop's statistics from its log, the flood's answer counts, the
    renderer's memory growth (MiB), the log's size (MiB) and the events it kept.
    """
    from evo_door.files import open_h5, read_attrs
    from evo_door.render.session import SESSION_KINDS, read_session

    log = folder / f"flood-{time.monotonic_ns()}.h5"
    port = free_port()
    command = [sys.executable, "-m", "evo_door", "render", "--params", "seed_trial"]
    command += ["--device", "sim", "--user", "swing", "--realtime", "--rate", f"{RATE:g}"]
    command += ["--duration", f"{seconds:g}", "--log", str(log)]
    command += ["--control", f"127.0.0.1:{port}", "--token", TOKEN]
    proc = subprocess.Popen(
        command,
        cwd=folder,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    peak = {"rss": 0.0}
    sampling = threading.Event()

    def sample() -> None:
        while not sampling.wait(0.25):
            rss = _rss_mib(proc.pid)
            if rss is None:
                return
            peak["rss"] = max(peak["rss"], rss)

    counts: dict = {}
    try:
        if not _wait_for_port(port, proc):
            raise RuntimeError("the render's control port never answered:\n" + proc.stdout.read())
        rss0 = _rss_mib(proc.pid) or 0.0
        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        if clients:  # until the render ends: the loop's time left
            stop_at = time.monotonic() + max(0.0, seconds - _loop_time(port))
            counts = asyncio.run(_flood(port, stop_at, clients))
        output = proc.communicate(timeout=seconds + 120)[0]
        sampling.set()
        sampler.join(5.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    if proc.returncode not in (0, 1):  # 1: the watchdog tripped, still a log
        raise RuntimeError(f"render exited {proc.returncode}:\n{output}")
    stats = read_session(log)["statistics"]
    with open_h5(log) as f:
        events = read_attrs(f["render"]).get("events", [])
    dropped = [e.get("count", 0) for e in events if e.get("kind") == "dropped"]
    result = {
        **stats,
        **counts,
        "clients": clients,
        "rss_growth_mib": max(0.0, peak["rss"] - rss0),
        "log_mib": log.stat().st_size / 2**20,
        "events_kept": sum(1 for e in events if e.get("kind") in SESSION_KINDS),
        "events_dropped": dropped[0] if dropped else 0,
    }
    log.unlink()
    return result


def _loop_time(port: int) -> float:
    """The loop time (s) the render at ``port`` has run so far."""
    from evo_door.render.control import request

    answer = request("127.0.0.1", port, {"token": TOKEN, "get": "health"})
    return float(answer.get("t", 0.0)) if answer.get("ok") else 0.0


def row(what: str, s: dict) -> str:
    ok = s["on_time_fraction"] >= ON_TIME and s["status"] == "done"
    if s["clients"]:
        ok = ok and s["rss_growth_mib"] <= RSS_TARGET_MIB
    refused = sum(s.get(k, 0) for k in s if k.startswith("refused_"))
    return (
        f"| {what} | {s['on_time_fraction'] * 100:.3f} % | {s['missed_cycles']} | "
        f"{s['lateness_p99_s'] * 1e6:.0f} us | {s.get('connections', 0)} | {s.get('ok', 0)} | "
        f"{refused} ({s.get('refused_rate', 0)} rate, {s.get('refused_client_cap', 0)} "
        f"connections, {s.get('refused_log_cap', 0)} log cap, {s.get('refused_input', 0)} "
        f"input) | {s['events_kept']} / {s['events_dropped']} | {s['rss_growth_mib']:.1f} MiB | "
        f"{s['log_mib']:.1f} MiB | {os.getloadavg()[0]:.2f} | {s['status']} | "
        f"{'yes' if ok else 'no'} |"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=SECONDS, help="each render (s)")
    ap.add_argument("--repeat", type=int, default=1, help="rounds of (a), (b)")
    ap.add_argument("--no-write", action="store_true", help="print only")
    args = ap.parse_args(argv)

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for _ in range(args.repeat):  # interleaved: a busy spell hits both alike
            for what, clients in (("(a) no client", 0), (f"(b) {CLIENTS} clients", CLIENTS)):
                s = flood_run(args.seconds, clients, folder)
                rows.append(row(f"{what}, {args.seconds:g} s", s))
                print(rows[-1], flush=True)
    lines = [
        "# Control-port flood benchmark (`benchmarks/bench_control.py`)",
        "",
        machine_line(),
        "",
        "The loop comes first: `evo-door render --params seed_trial --device sim "
        f"--user swing --realtime --rate {RATE:g} --duration S --control PORT --token T --log "
        "LOG.h5`, each run in its own process, the timing from the log's `/render` "
        f"`statistics`. (a) no client; (b) {CLIENTS} clients at once from the benchmark's "
        f"process for the whole run, each writing {BATCH} pipelined requests at a time "
        "(session events of 16 kB of every kind, a 400-digit integer, NaN, nesting 30,000 "
        "deep, a 200 kB line, binary garbage) as fast as the answers come, and connecting "
        "again a second after a refusal or a drop. Answers are counted by kind: served, "
        "refused for a rate, for the cap of connections, for the log's cap of session "
        "events, for the input itself. Events kept / dropped are the log's (its session "
        "events; dropped: its `dropped` event's count). The memory is the renderer's "
        "resident set, its peak minus the figure when its port first answered.",
        "",
        "| run | on time | missed | p99 lateness | connections | served | refused "
        "| events kept / dropped | memory growth | log | load average | status "
        f"| >= 99.9 %, <= {RSS_TARGET_MIB:g} MiB |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        "Targets: >= 99.9 % of cycles on time at 2500 Hz with the clients "
        f"flooding, the renderer's memory growing by at most {RSS_TARGET_MIB:g} MiB and "
        "the log's session events within their cap (10,000 events, 4 MiB). A cycle is "
        "late when it starts more than one period after its slot; missed cycles are slots "
        "skipped. The load average (1 min, at the row's end) shows whether other processes "
        "shared the 2 cores; the clients themselves take most of one.",
    ]
    publish("\n".join(lines) + "\n", "control.md", write=not args.no_write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
