"""The loop comes first: the servo loop's timing with the web console and a browser open.

Serving the page, its socket and the plots must not make the servo loop
late; the target is >= 99.9 % of cycles on time at 2500 Hz on the simulated device
with the console open and a browser connected. Each run is ``evo-door render --params
seed_trial --device sim --user swing --realtime --duration S --log LOG.h5`` in its own
process, as a user starts it, and its timing comes from the log (the ``statistics``
attribute of ``/render``):

(a) without the console;
(b) with ``--console`` and one headless Chromium page connected (drawing the door, the
    force-angle trace and the strip chart at display rate, 30 ticks a second);
(c) as (b), the page also moving a slider every 2 s (each change a control-port
    ``set``, a ``params`` broadcast and a new curve).

Each render also has ``--control`` with a token, so the benchmark can read the loop's
health at a given loop time: the whole run's figures (the log's) include Chromium
loading the page; the steady ones are those from ``STEADY_FROM`` s of loop time to the
end, once the page is connected and drawing. Chromium is started before the render
(as an operator's browser would already run) and opens the page when the URL appears.

    python benchmarks/bench_console.py                 # writes benchmarks/console.md
    python benchmarks/bench_console.py --seconds 10 --no-write
"""

from __future__ import annotations

import argparse
import os
import queue
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._util import free_port, machine_line, publish  # noqa: E402
from evo_door.render.session import read_session  # noqa: E402

RATE = 2500.0
ON_TIME = 0.999
CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
#: the page's slider moves in run (c): friction_closing between these (N), every TUNE_EVERY s
TUNE_VALUES = (5.0, 10.0)
TUNE_EVERY = 2.0
#: loop time (s) from which the steady figures count (the page is connected by then)
STEADY_FROM = 8.0
#: a shorter steady window (s) is not shown: the health request came too late (it
#: waits for the renderer's control port, which the paced loop can starve for seconds)
MIN_STEADY = 5.0
TOKEN = "bench"


def _browser():
    """Headless Chromium on a blank page."""
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1366,900"):
        options.add_argument(arg)
    options.binary_location = CHROMIUM
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.get("about:blank")
    return driver


def _open(driver, url: str) -> None:
    """The console's page in ``driver``, once it says it is connected."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get(url)
    WebDriverWait(driver, 30).until(
        lambda d: d.find_element(By.ID, "connection").text == "connected"
    )


def _health_at(port: int, t: float, proc) -> dict | None:
    """The loop's health once its time reaches ``t`` (s); None if the render ended."""
    from evo_door.errors import UserError
    from evo_door.render.control import request

    while proc.poll() is None:
        try:
            h = request("127.0.0.1", port, {"token": TOKEN, "get": "health"})
        except UserError:  # not listening yet
            h = {}
        if h.get("ok") and h.get("t", 0.0) >= t:
            return h
        time.sleep(0.1)
    return None


def _move_slider(driver, name: str, value: float) -> None:
    driver.execute_script(
        "const s = document.getElementById(arguments[0]); s.value = String(arguments[1]);"
        "s.dispatchEvent(new Event('input', {bubbles: true}));"
        "s.dispatchEvent(new Event('change', {bubbles: true}));",
        f"slider-{name}",
        value,
    )


def render_run(seconds: float, console: bool, tune: bool, folder: Path) -> dict:
    """One render in its own process; the loop's statistics from its log, the page's
    connected time (s) and the load average over the run."""
    log = folder / f"render-{time.monotonic_ns()}.h5"
    port = free_port()
    command = [sys.executable, "-m", "evo_door", "render", "--params", "seed_trial"]
    command += ["--device", "sim", "--user", "swing", "--realtime", "--rate", f"{RATE:g}"]
    command += ["--duration", f"{seconds:g}", "--log", str(log)]
    command += ["--control", f"127.0.0.1:{port}", "--token", TOKEN]
    if console:
        command += ["--console", "--console-port", "0"]
    driver = _browser() if console else None
    load0 = os.getloadavg()[0]
    proc = subprocess.Popen(
        command,
        cwd=folder,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: queue.Queue = queue.Queue()
    output: list[str] = []

    def read() -> None:
        for line in proc.stdout:
            output.append(line)
            lines.put(line)
        lines.put(None)

    threading.Thread(target=read, daemon=True).start()
    connected = 0.0
    steady_from = None
    try:
        if console:
            url = None
            while url is None:
                line = lines.get(timeout=60)
                if line is None:
                    raise RuntimeError("render --console printed no URL:\n" + "".join(output))
                if line.startswith("console "):
                    url = line.split()[1]
            _open(driver, url)
            t_connected = time.monotonic()
            k = 0
            steady_from = _health_at(port, STEADY_FROM, proc)
            while proc.poll() is None:
                time.sleep(TUNE_EVERY if tune else 0.2)
                if tune and proc.poll() is None:
                    _move_slider(driver, "friction_closing", TUNE_VALUES[k % 2])
                    k += 1
            connected = time.monotonic() - t_connected
        else:
            steady_from = _health_at(port, STEADY_FROM, proc)
        proc.wait(seconds + 120)
    finally:
        if driver is not None:
            driver.quit()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    if proc.returncode not in (0, 1):  # 1: the watchdog tripped, still a log
        raise RuntimeError(f"render exited {proc.returncode}:\n" + "".join(output))
    session = read_session(log)
    log.unlink()
    stats = session["statistics"]
    steady = {}
    if steady_from is not None:
        cycles = stats["cycles"] - steady_from["cycles"]
        missed = stats["missed_cycles"] - steady_from["missed_cycles"]
        steady = {
            "steady_s": cycles / RATE,
            "steady_missed": missed,
            "steady_on_time": 1.0 - missed / max(cycles, 1),
        }
    return {
        **stats,
        **steady,
        "connected_s": connected,
        "changes": len(session["changes"]),
        "load": (load0 + os.getloadavg()[0]) / 2,
    }


def _row(what: str, s: dict) -> str:
    if s.get("steady_s", 0.0) >= MIN_STEADY:
        ok = s["steady_on_time"] >= ON_TIME and s["status"] == "done"
    else:
        ok = s["on_time_fraction"] >= ON_TIME and s["status"] == "done"
    steady = (
        f"{s['steady_on_time'] * 100:.3f} % ({s['steady_missed']} of {s['steady_s']:.0f} s)"
        if s.get("steady_s", 0.0) >= MIN_STEADY
        else "-"
    )
    return (
        f"| {what} | {s['period_mean_s'] * 1e3:.4f} ms | "
        f"{s['on_time_fraction'] * 100:.3f} % | {s['missed_cycles']} | "
        f"{s['lateness_p99_s'] * 1e6:.0f} us | {s['compute_p99_s'] * 1e6:.0f} us | {steady} | "
        f"{s['connected_s']:.1f} s | {s['changes']} | {s['load']:.2f} | {s['status']} | "
        f"{'yes' if ok else 'no'} |"
    )


RUNS = (
    ("(a) no console", False, False),
    ("(b) console, one Chromium page", True, False),
    ("(c) console, page moving a slider every 2 s", True, True),
)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="each render (s)")
    ap.add_argument("--repeat", type=int, default=1, help="rounds of (a), (b), (c)")
    ap.add_argument("--no-write", action="store_true", help="print only")
    args = ap.parse_args(argv)

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        render_run(2.0, False, False, folder)  # load numba's cache once
        for _ in range(args.repeat):  # interleaved: a busy spell hits every kind alike
            for what, console, tune in RUNS:
                try:
                    s = render_run(args.seconds, console, tune, folder)
                except Exception as exc:  # a page that never connected: say so, go on
                    why = " ".join(f"{type(exc).__name__} {exc}".split())[:120]
                    rows.append(f"| {what}, {args.seconds:g} s | failed: {why} |" + " |" * 10)
                else:
                    rows.append(_row(f"{what}, {args.seconds:g} s", s))
                print(rows[-1], flush=True)
    lines = [
        "# Console benchmark (`benchmarks/bench_console.py`)",
        "",
        machine_line(),
        "",
        "The loop comes first: `evo-door render --params seed_trial --device sim "
        f"--user swing --realtime --rate {RATE:g} --duration S --log LOG.h5`, each run in its "
        "own process, the timing from the log's `/render` `statistics`. (a) without the "
        "console; (b) with `--console` (its own process, polling the control port about "
        "30 times a second) and one headless Chromium page (`--headless=new --disable-gpu`, "
        "1366 x 900) connected, drawing at display rate; (c) as (b), the page also moving "
        f"the friction_closing slider every {TUNE_EVERY:g} s. Chromium starts before the "
        "render and opens the page when the URL appears; the whole run's figures (from the "
        "log) include the page loading, the steady ones count from "
        f"{STEADY_FROM:g} s of loop time to the end (the loop's health read through "
        "`--control` then, against the log's final statistics; the window is shorter when "
        "that answer came late, and not shown under 5 s). The last column judges the "
        "steady figure where there is one, else the whole run's.",
        "",
        "| run | mean period | on time, whole run | missed | p99 lateness | p99 cycle work "
        f"| on time from {STEADY_FROM:g} s (missed) | page connected | changes | load average "
        "| status | >= 99.9 % |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        "Target: >= 99.9 % of cycles on time at 2500 Hz with the console open "
        "and a browser connected. A cycle is late when it starts more than one period after "
        "its slot; missed cycles are slots skipped; the lateness p99 is over all cycles run. "
        "The load average (1 min, mean of the run's start and end) shows whether other "
        "processes shared the 2 cores. The render log's `priority` event says how the loop "
        'was scheduled (real-time where permitted: `docs/renderer.md`, "Keeping time").',
        "",
        "How it got here (the same day, steady figures of (b)): the loop spinning with the "
        "interpreter's 5 ms switch interval, 99.5-99.6 % (the control port starved); a "
        "`time.sleep(0)` per turn, 95-96.5 %; a 0.1 ms switch interval, 99.6 %; the loop's "
        "thread on a core of its own at niceness -20 and the console at +10, 99.78-99.86 %. "
        "Then the loop under real-time scheduling (SCHED_FIFO), sleeping until 0.15 ms "
        "before each slot, and the renderer's other threads real-time too while it runs: a "
        "normal thread preempted while holding the interpreter lock had been stalling the "
        "loop for 1-2 ms (a priority inversion). With the two cores also busy with other "
        "engineers' test suites (load average 2.5-5.5), (b) then kept 99.89-99.91 %.",
    ]
    publish("\n".join(lines) + "\n", "console.md", write=not args.no_write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
