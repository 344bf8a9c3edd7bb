"""``evo-door render``: render a haptic parameter set on a device (headless for now)."""

from __future__ import annotations

import atexit
import contextlib
import gc
import signal
import sys
import threading
import time

from evo_door.commands._common import (
    DAY,
    DEVICE_DAMPING,
    PORT,
    TOKEN,
    Range,
    add_params_arguments,
    check_ranges,
    declare_ranges,
)
from evo_door.errors import UserError
from evo_door.render.supervisor import BUDGET, BUDGET_RANGE

ORDER = 60

#: niceness added to the console's process (spawned before the servo loop starts, so it
#: keeps normal scheduling while the loop's thread runs real-time or at niceness -20)
CONSOLE_NICENESS = 10

#: every numeric flag's range (and the token's length), checked before any work
RANGES = {
    "--duration": Range(0, DAY, "s", above=True),
    # a cycle's work is about 0.1 ms at its 99th percentile (benchmarks/render.md):
    # 5 kHz leaves it half the period
    "--rate": Range(10, 5000, "Hz"),
    # a row per loop cycle at most: more is interpolation, and disk (--log-rate 1e8
    # wrote 12 GB in a minute)
    "--log-rate": Range(1, "--rate", "Hz"),
    "--device-damping": DEVICE_DAMPING,
    "--console-port": PORT,
    "--watchdog-misses": Range(1, 1000, "cycles", integer=True),
    "--seed": Range(0, 2**32 - 1, integer=True),  # numpy's seeds
    "--token": TOKEN,
}


def register(sub) -> None:
    p = sub.add_parser(
        "render",
        help="render the haptic model on a force-feedback device (servo loop, log)",
        description="Render a haptic parameter set on a device: each cycle reads the "
        "device, evaluates the haptic model's device-space force and commands it, "
        "within the device's force limit. Headless with --user and --duration.",
    )
    add_params_arguments(p)
    p.add_argument(
        "--device",
        default="sim",
        metavar="sim|hapticmaster://HOST:PORT",
        help="the device (default sim: a simulated admittance device)",
    )
    p.add_argument(
        "--user",
        metavar="SCRIPT",
        help="virtual user of the simulated device: open, close, unlock, lock, swing, "
        "shake, hold (docs/renderer.md)",
    )
    p.add_argument("--duration", type=float, metavar="S", help="render time (s)")
    p.add_argument("--rate", type=float, default=2500.0, metavar="HZ", help="loop rate (Hz)")
    p.add_argument(
        "--log-rate", type=float, default=1000.0, metavar="HZ", help="log rate (Hz, default 1000)"
    )
    p.add_argument(
        "--log",
        metavar="LOG.h5",
        help="write the log (HDF5, a trial file); while rendering, its rows go to "
        "LOG.h5.partial as they come, which --recover turns into a log after a crash",
    )
    p.add_argument(
        "--recover",
        metavar="LOG.h5.partial",
        help="write the log a crashed render left in its side file (to --log, default "
        "the name without .partial) and exit",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace an existing --log (a participant's session: else refused)",
    )
    p.add_argument(
        "--clamp",
        action="store_true",
        help="scale down a parameter set the device cannot render passively (logged) "
        "instead of refusing it",
    )
    p.add_argument(
        "--device-damping",
        type=float,
        metavar="N_S_M",
        help="the device's own physical damping (N s/m) for the passivity check "
        "(default: sim 2; a HapticMaster 0 unless given)",
    )
    p.add_argument(
        "--control",
        metavar="[HOST:]PORT",
        help="serve the control port (evo-door push): 127.0.0.1 unless HOST is given, "
        "which then requires --token",
    )
    p.add_argument("--token", help="token the control port requires of every request")
    p.add_argument(
        "--console",
        action="store_true",
        help="serve the operator's web console (evo-door console) for this render and "
        "print its URL; the loop keeps the wall clock (as --realtime); runs until Ctrl-C "
        "without --duration",
    )
    p.add_argument(
        "--console-port",
        type=int,
        default=8765,
        metavar="P",
        help="the console's port (default 8765; 0: any free)",
    )
    p.add_argument(
        "--console-host",
        default="127.0.0.1",
        metavar="H",
        help="the console's address (default 127.0.0.1; any other requires a token)",
    )
    p.add_argument(
        "--friction",
        choices=("implicit", "tanh"),
        default="implicit",
        help="dry-friction law: implicit Coulomb, stable at any level (default), or the "
        "model's tanh, which rings above 2 m v_s / T (for comparison)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated sensor noise")
    p.add_argument(
        "--realtime",
        action="store_true",
        help="pace a simulated device on the wall clock (implied by --console and by a run "
        "without --duration; a real device always is); else --duration S of simulated "
        "time runs as fast as the machine allows",
    )
    p.add_argument(
        "--watchdog-misses",
        type=int,
        default=10,
        metavar="N",
        help="consecutive late cycles that trip the watchdog (default 10; 1..1000)",
    )
    p.add_argument(
        "--supervisor-budget",
        type=float,
        metavar="MS",
        help="a HapticMaster's supervisor takes the force off when the loop has not beaten "
        f"for this long (ms; default {BUDGET * 1e3:g}; "
        f"{BUDGET_RANGE[0] * 1e3:g}..{BUDGET_RANGE[1] * 1e3:g})",
    )
    p.add_argument(
        "--no-supervisor",
        action="store_true",
        help="render on a HapticMaster without the supervisor process (not recommended: "
        "a frozen or killed renderer then leaves its last force on the handle)",
    )
    declare_ranges(p, RANGES)
    p.set_defaults(func=run)


def make_device(spec: str, user: str | None, radius: float, seed: int, damping=None):
    """The device named by ``--device``."""
    if spec == "sim":
        from evo_door.render.device import SimDevice

        extra = {} if damping is None else {"damping": damping}
        return SimDevice(user or "hold", radius=radius, seed=seed, **extra), "sim"
    if spec.startswith("hapticmaster://"):
        from evo_door.render.hapticmaster import HapticMasterDevice, parse_address

        if user:
            raise UserError("--user drives the simulated device only")
        host, port = parse_address(spec)
        return HapticMasterDevice(host, port, damping=damping or 0.0), spec
    raise UserError(f"--device {spec!r}: expected 'sim' or 'hapticmaster://HOST:PORT'")


def run(args) -> int:
    check_ranges(args)
    if args.recover:
        return _recover(args)
    from evo_door.models import get_model
    from evo_door.params.sets import parse_assignments
    from evo_door.render.loop import ServoLoop

    # the web console has the keys: the terminal's key UI never runs next to it
    interactive = (
        args.duration is None and not args.console and sys.stdin.isatty() and sys.stdout.isatty()
    )
    if args.duration is None and not interactive and args.control is None and not args.console:
        raise UserError(
            "give --duration S (and --user SCRIPT on the simulated device) for a headless "
            "run, --control PORT or --console to run until interrupted, or run on a "
            "terminal to step the sensations with the keys"
        )
    if args.duration is not None and args.user is None and args.device == "sim":
        raise UserError("a headless run on the simulated device needs --user SCRIPT")
    params = get_model("haptic").load_params(args.params, parse_assignments(args.assignments))
    claim = _claim_log(args, args.log, [params.source])
    _check_supervisor_options(args)
    device, name = make_device(
        args.device, args.user, params["radius"], args.seed, args.device_damping
    )
    loop = ServoLoop(
        device,
        params,
        args.rate,
        log_rate=args.log_rate,
        clamp=args.clamp,
        realtime=_paced(args),
        device_name=name,
        friction=args.friction,
        watchdog_misses=args.watchdog_misses,
    )
    loop.supervisor = _start_supervisor(args, device, loop)
    try:
        return _render(loop, args, interactive, name, claim)
    finally:
        if loop.supervisor is not None:
            loop.supervisor.close()


def _render(loop, args, interactive: bool, name: str, claim) -> int:
    """Run the loop (the log's side file, Ctrl-C, the report)."""
    if args.log:  # crash safety: the rows so far go to LOG.h5.partial as they come
        loop.log.spill_to(args.log, loop_rate=loop.rate, device=name)
    else:  # nothing will read the early rows: a day's session stays in a few MB
        loop.log.keep_recent()
    stop = threading.Event()
    # the interpreter's last collection of what numba and h5py loaded takes a second on
    # a busy machine: a render that ended (a stalled device's within half a second)
    # would leave its process behind that long; frozen objects are not collected
    atexit.unregister(gc.freeze)  # once, however often run in one process
    atexit.register(gc.freeze)
    try:
        with _stop_on_ctrl_c(stop, loop):
            try:
                stats = _run_loop(loop, args, interactive, stop)
            except BaseException as exc:  # a second Ctrl-C too: keep the log, then raise
                if args.log:
                    _write_interrupted(loop, args.log, exc)
                raise
            code = _report(loop, args, stats, name, claim)
            # the device may still hold a force: not a success, whatever else went well
            return max(code, 1) if getattr(loop.device, "failsafe_warning", "") else code
    finally:
        loop.log.close()
        if loop.log.spill_error:
            print(f"evo-door: warning: {loop.log.spill_error}", file=sys.stderr)
        warning = getattr(loop.device, "failsafe_warning", "")
        if warning:  # on every way out, once
            print(f"evo-door: warning: {warning}", file=sys.stderr)


def _check_supervisor_options(args) -> None:
    """``--no-supervisor`` and ``--supervisor-budget``: for a real device, not both."""
    real = args.device.startswith("hapticmaster://")
    budget = args.supervisor_budget
    if not real and (args.no_supervisor or budget is not None):
        flag = "--no-supervisor" if args.no_supervisor else "--supervisor-budget"
        raise UserError(f"{flag} goes with a hapticmaster:// device (the simulated one has none)")
    if budget is not None:
        if args.no_supervisor:
            raise UserError("--supervisor-budget goes without --no-supervisor")
        low, high = (b * 1e3 for b in BUDGET_RANGE)
        if not low <= budget <= high:
            raise UserError(f"--supervisor-budget {budget:g}: must be in {low:g}..{high:g} ms")


def _start_supervisor(args, device, loop):
    """A real device's supervisor (:mod:`evo_door.render.supervisor`), started, or None.

    The renderer connects first (the device's first connection is the renderer's
    own), then the supervisor opens its own; a device that refuses it is refused
    with one line unless ``--no-supervisor``.
    """
    if not args.device.startswith("hapticmaster://"):
        return None  # in-process: nothing could act while the process is frozen
    if args.no_supervisor:
        print(
            "evo-door: warning: --no-supervisor: if this renderer freezes or dies, "
            "the device keeps its last force on the handle",
            file=sys.stderr,
        )
        loop.log.event(0.0, "supervisor", "none (--no-supervisor)")
        return None
    from evo_door.render.supervisor import Supervisor

    budget = BUDGET if args.supervisor_budget is None else args.supervisor_budget / 1e3
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


def _paced(args) -> bool | None:
    """Whether the loop keeps the wall clock: with ``--realtime``, a console (a person
    feels and watches it), or no ``--duration`` (a person ends it); a real device
    always (None: the loop's default). A simulated device with only ``--duration``
    runs in simulated time, as fast as the machine allows."""
    return True if (args.realtime or args.console or args.duration is None) else None


#: what the log and the summary say of a render ended by Ctrl-C (or the key UI's q)
STOPPED = "stopped by the operator"


@contextlib.contextmanager
def _stop_on_ctrl_c(stop: threading.Event, loop):
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


def _recover(args) -> int:
    """``--recover``: a crashed render's side file as a log."""
    from pathlib import Path

    from evo_door.render.log import recover

    source = Path(args.recover)
    if not source.is_file():
        raise UserError(f"--recover {args.recover}: no such file")
    if source.suffix != ".partial" and not args.log:
        raise UserError(f"--recover {args.recover}: not a side file (*.partial); give --log OUT.h5")
    if args.log is None and source.suffix == ".partial":
        args.log = str(source.with_suffix(""))  # recover's default: the name without .partial
    claim = _claim_log(args, args.log, [source])
    out = recover(source, args.log)
    claim.note()
    print(f"recovered {out} from {source} (the render ended without a clean stop)")
    return 0


def _claim_log(args, log, inputs):
    """The rule of every output (:func:`~evo_door.files.claim_outputs`) for the log: a
    trial file, a participant's session, replaced only with ``--force``."""
    from evo_door.files import TRIALS, Output, claim_outputs

    return claim_outputs([Output(log, "--log", TRIALS)], inputs, force=args.force)


def _write_interrupted(loop, path, exc: BaseException) -> None:
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


def _report(loop, args, stats: dict, name: str, claim) -> int:
    """The render's summary lines; the log (``claim``: what writing it replaces)."""
    stopped = stats["status"] == "stopped"
    if stopped:  # the log says who ended it, and when
        loop.log.event(loop.snapshot()["t"], "stopped", STOPPED)
    if loop.log.n < 2:  # stopped before it rendered: nothing to summarise or log
        print(f"{STOPPED} before the render started; no log written")
        loop.log.close()
        if loop.log.spill_path is not None:
            loop.log.spill_path.unlink(missing_ok=True)
        return 0
    first, last = loop.log.first()[12], loop.log.last()[12]  # theta (rad)
    status = STOPPED if stopped else stats["status"]
    print(
        f"rendered {stats['cycles']} cycles at {args.rate:g} Hz on {name} ({status}); "
        f"door {first * 57.29577951308232:.1f} -> {last * 57.29577951308232:.1f} deg"
    )
    print(_timing_line(stats))
    if "round_trip_mean_s" in stats:
        print(
            f"round trip mean {stats['round_trip_mean_s'] * 1e3:.3g} ms, "
            f"p99 {stats['round_trip_p99_s'] * 1e3:.3g} ms"
        )
    if stats["watchdog"]:
        print(f"watchdog: {stats['watchdog']}")
    for ev in loop.log.events:
        if ev["kind"] == "clamp":
            print(f"clamped at {ev['t']:.3f} s: {ev['changes']}")
    if args.log:
        loop.write_log(args.log)
        print(f"wrote {args.log}")
        claim.note()
    return 1 if loop.watchdog.tripped else 0


def _timing_line(stats: dict) -> str:
    """How the loop kept time. An unpaced loop (simulated time) kept no period: it
    says so, with the wall-clock time it took, rather than the nominal period."""
    compute = f"compute p99 {stats['compute_p99_s'] * 1e6:.3g} us/cycle, faults {stats['faults']}"
    if not stats["realtime"]:
        simulated = stats["cycles"] / stats["rate_hz"]
        return (
            f"unpaced: {simulated:.4g} s of simulated time in {stats['wall_s']:.3g} s "
            f"(not kept on the wall clock; --realtime paces it), {compute}"
        )
    return (
        f"period mean {stats['period_mean_s'] * 1e3:.4g} ms, p99 lateness "
        f"{stats['lateness_p99_s'] * 1e3:.3g} ms, missed {stats['missed_cycles']} cycles, "
        + compute
    )


def _run_loop(loop, args, interactive: bool, stop: threading.Event) -> dict:
    """Run the loop, with the control port (--control) and the key UI (a terminal),
    until its duration or ``stop`` (Ctrl-C, the key UI's q)."""
    server = console = None
    token = args.token
    if args.control is not None or args.console:
        import secrets

        from evo_door.render.control import ControlServer, is_loopback, parse_control

        if args.control is not None:
            host, port = parse_control(args.control)
        else:  # the console's own: loopback, any free port, a random token
            host, port = "127.0.0.1", 0
            token = token or secrets.token_urlsafe(16)
        server = ControlServer(loop, host, port, token=token).start()
        print(f"control port {server.address[0]}:{server.address[1]} (evo-door push)", flush=True)
        if args.console and not token and not is_loopback(args.console_host):
            token = secrets.token_urlsafe(16)  # the page's only (the port has none)
    elif args.token:
        raise UserError("--token goes with --control")
    try:
        if server is not None and args.console:
            console = _start_console(args, server.address, token)
        if not interactive:
            return loop.run(args.duration, stop=stop)
        from evo_door.render.keys import run_terminal

        result: dict = {}

        def serve() -> None:
            try:
                result.update(loop.run(stop=stop))
            finally:
                stop.set()

        thread = threading.Thread(target=serve, name="evo-door-servo", daemon=True)
        thread.start()
        try:
            run_terminal(loop, stop)
        finally:
            stop.set()
            thread.join()
        return result
    finally:
        try:
            if console is not None:
                _stop_console(console)
        finally:
            if server is not None:
                server.close()


#: how long ``render --console`` waits for the console to print its URL (s)
CONSOLE_START = 30.0


def _start_console(args, address, token):
    """Spawn ``evo-door console`` for the control port at ``address``; print its URL."""
    import os
    import subprocess

    from evo_door.commands.console import TOKEN_ENV

    host, port = address
    if host in ("0.0.0.0", "::"):
        host = "127.0.0.1"
    command = [
        sys.executable,
        "-m",
        "evo_door",
        "console",
        "--control",
        f"[{host}]:{port}" if ":" in host else f"{host}:{port}",
        "--host",
        args.console_host,
        "--port",
        str(args.console_port),
        "--with-parent",
    ]
    env = dict(os.environ)
    env.pop(TOKEN_ENV, None)
    if token:
        env[TOKEN_ENV] = token  # not on the command line, which every local user can read
    # its own session: Ctrl-C reaches the renderer, which then stops the console
    child = subprocess.Popen(
        command,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        text=True,
        start_new_session=True,
        # below the servo loop: the page's curves and messages can wait, its cycles not
        preexec_fn=(lambda: os.nice(CONSOLE_NICENESS)) if hasattr(os, "nice") else None,
    )
    url: list[str] = []
    errors: list[str] = []
    started = threading.Event()

    def relay_out() -> None:
        for line in child.stdout:
            if not started.is_set():
                url.append(line.strip())
                started.set()
            else:
                sys.stdout.write(line)
        started.set()  # closed: the console ended

    def relay_err() -> None:  # its errors: kept until it runs, then shown
        for line in child.stderr:
            if started.is_set() and url and url[0].startswith("console "):
                sys.stderr.write(line)
            else:
                errors.append(line.strip())

    for target in (relay_out, relay_err):
        threading.Thread(target=target, name="evo-door-console-io", daemon=True).start()
    started.wait(CONSOLE_START)
    first = url[0] if url else ""
    if not first.startswith("console "):
        _stop_console(child)
        time.sleep(0.1)  # its last words
        why = next((e for e in reversed(errors) if e), "") or "it printed no URL"
        raise UserError(
            f"--console: the console did not start: {why.removeprefix('evo-door: error: ')}"
        )
    print(first, flush=True)
    return child


def _stop_console(child) -> None:
    """End the console process and wait for it."""
    import subprocess

    if child.poll() is None:
        child.terminate()
        try:
            child.wait(5.0)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
