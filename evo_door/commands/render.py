"""``evo-door render``: render a haptic parameter set, or a mechanism (any model on a
state vector: ``evo-door render MECHANISM.yaml``), on a device."""

from __future__ import annotations

import atexit
import gc
import sys
import threading

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
from evo_door.render.console.process import start_console, stop_console
from evo_door.render.hands_off import HANDS_OFF_RANGE, HANDS_OFF_SPEED
from evo_door.render.stopping import STOPPED, stop_on_ctrl_c, write_interrupted
from evo_door.render.summary import summary_lines
from evo_door.render.supervisor import BUDGET, BUDGET_RANGE

ORDER = 60

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
    "--seed": Range(0, 2**32 - 1, integer=True),  # numpy's seeds
    "--hands-off-speed": Range(*HANDS_OFF_RANGE, "rad/s"),
    "--token": TOKEN,
}
#: the ranges of the watchdog's and the supervisor's flags (:func:`add_watchdog_arguments`)
WATCHDOG_RANGES = {
    "--watchdog-misses": Range(1, 1000, "cycles", integer=True),
    "--supervisor-budget": Range(BUDGET_RANGE[0] * 1e3, BUDGET_RANGE[1] * 1e3, "ms"),
}
RANGES.update(WATCHDOG_RANGES)


def add_watchdog_arguments(p, budget_note: str) -> None:
    """``--watchdog-misses`` and ``--supervisor-budget``, as ``render`` and ``jnd`` take
    them; ``budget_note`` ends the budget's help."""
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
        f"for this long (ms; default {BUDGET * 1e3:g}; {budget_note})",
    )


def register(sub) -> None:
    # long: one function on purpose: the flags in the order --help lists them, a few lines
    # each and no logic; cut in parts, a newcomer would look in several for one flag
    p = sub.add_parser(
        "render",
        help="render the haptic model on a force-feedback device (servo loop, log)",
        description="Render a haptic parameter set on a device: each cycle reads the "
        "device, evaluates the haptic model's device-space force and commands it, "
        "within the device's force limit. Headless with --user and --duration. Given "
        "MODEL (a mechanism file, path/file.py:MODEL), renders that model instead: its "
        "handle on the device, its other states integrated in the loop "
        "(docs/renderer.md, 'Rendering a mechanism').",
    )
    p.add_argument(
        "model",
        nargs="?",
        metavar="MODEL",
        help="a model on a state vector to render (a mechanism file MECHANISM.yaml, "
        "path/file.py:MODEL); default: the haptic model",
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
        "shake, hold, open-shut (docs/renderer.md)",
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
        "--hands-off-speed",
        type=float,
        default=HANDS_OFF_SPEED,
        metavar="RAD_S",
        help="refuse a parameter set (the first, and every change pushed) whose door, "
        "released from rest anywhere in its stroke with no hand on it, moves faster than "
        f"this (rad/s; default {HANDS_OFF_SPEED:g}; {HANDS_OFF_RANGE[0]:g}.."
        f"{HANDS_OFF_RANGE[1]:g})",
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
    add_watchdog_arguments(p, f"{BUDGET_RANGE[0] * 1e3:g}..{BUDGET_RANGE[1] * 1e3:g}")
    p.add_argument(
        "--no-supervisor",
        action="store_true",
        help="render on a HapticMaster without the supervisor process (not recommended: "
        "a frozen or killed renderer then leaves its last force on the handle)",
    )
    declare_ranges(p, RANGES)
    p.set_defaults(func=run)


def make_device(spec: str, user: str | None, radius: float, seed: int, damping=None, path=None):
    """The device named by ``--device`` (``path``: the handle's path of a mechanism, on
    which the simulated device's virtual hand reads its script)."""
    if spec == "sim":
        from evo_door.render.device import SimDevice

        extra = {} if damping is None else {"damping": damping}
        return SimDevice(user or "hold", radius=radius, seed=seed, path=path, **extra), "sim"
    if spec.startswith("hapticmaster://"):
        from evo_door.render.hapticmaster import HapticMasterDevice
        from evo_door.render.hm_protocol import parse_address

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
    model = get_model(args.model or "haptic")
    if model.name != "haptic":
        _check_mechanism_options(args)
    params = model.load_params(args.params, parse_assignments(args.assignments))
    claim = _claim_log(args, args.log, [params.source])
    _check_supervisor_options(args)
    if model.name != "haptic":
        loop = _mechanism_loop(args, model, params)
        name = loop.device_name
    else:
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
            hands_off_speed=args.hands_off_speed,
        )
    device = loop.device
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
        with stop_on_ctrl_c(stop, loop):
            try:
                stats = _run_loop(loop, args, interactive, stop)
            except BaseException as exc:  # a second Ctrl-C too: keep the log, then raise
                if args.log:
                    write_interrupted(loop, args.log, exc)
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


def _spec(args) -> str | None:
    """The rendered model as the console process loads it (``--model``): the name given,
    a mechanism file made absolute; None for the haptic model (the default)."""
    if not args.model:
        return None
    from evo_door.models import resolve_model_name

    return resolve_model_name(args.model)


def _check_mechanism_options(args) -> None:
    """What a mechanism's render does not take (yet): a UserError naming it."""
    haptic_only = {
        "--clamp": args.clamp,
        "--friction": args.friction != "implicit",
    }
    flag = next((name for name, given in haptic_only.items() if given), None)
    if flag is not None:
        raise UserError(
            f"{flag} goes with the haptic model; a mechanism ({args.model}) renders with "
            "--duration, --control (evo-door push changes its parameters), --console or "
            "the terminal's keys, its parameters set by --params and --set"
        )


def _mechanism_loop(args, model, params):
    """The servo loop of a mechanism (:class:`~evo_door.render.mechanism.MechanismLoop`)
    on the device ``--device`` names."""
    from evo_door.render.mechanism import RADIUS, MechanismLoop, RenderedModel

    path = RenderedModel(model).path
    device, name = make_device(
        args.device, args.user, RADIUS, args.seed, args.device_damping, path=path
    )
    return MechanismLoop(
        device,
        model,
        params,
        args.rate,
        log_rate=args.log_rate,
        realtime=_paced(args),
        device_name=name,
        watchdog_misses=args.watchdog_misses,
        hands_off_speed=args.hands_off_speed,
    )


def _check_supervisor_options(args) -> None:
    """``--no-supervisor`` and ``--supervisor-budget``: for a real device, not both."""
    real = args.device.startswith("hapticmaster://")
    budget = args.supervisor_budget
    if not real and (args.no_supervisor or budget is not None):
        flag = "--no-supervisor" if args.no_supervisor else "--supervisor-budget"
        raise UserError(f"{flag} goes with a hapticmaster:// device (the simulated one has none)")
    if budget is not None and args.no_supervisor:  # its range: RANGES
        raise UserError("--supervisor-budget goes without --no-supervisor")


def _start_supervisor(args, device, loop):
    """A real device's supervisor (:func:`~evo_door.render.supervised.start_supervisor`)
    as the options ask, or None for the simulated device (in-process: nothing could
    act while the process is frozen)."""
    if not args.device.startswith("hapticmaster://"):
        return None
    from evo_door.render.supervised import start_supervisor

    budget = None if args.supervisor_budget is None else args.supervisor_budget / 1e3
    return start_supervisor(device, loop, budget, enabled=not args.no_supervisor)


def _paced(args) -> bool | None:
    """Whether the loop keeps the wall clock: with ``--realtime``, a console (a person
    feels and watches it), or no ``--duration`` (a person ends it); a real device
    always (None: the loop's default). A simulated device with only ``--duration``
    runs in simulated time, as fast as the machine allows."""
    return True if (args.realtime or args.console or args.duration is None) else None


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
    for line in summary_lines(loop, stats, args.rate, name):
        print(line)
    if args.log:
        loop.write_log(args.log)
        print(f"wrote {args.log}")
        claim.note()
    return 1 if loop.watchdog.tripped else 0


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
            console = start_console(
                server.address, token, args.console_host, args.console_port, _spec(args)
            )
        if not interactive:
            return loop.run(args.duration, stop=stop)
        from evo_door.models import get_model
        from evo_door.render.console.sensations import tunable_keys
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
            # the parameters the web console changes, with its steps (the haptic
            # model's sensations; a mechanism's specification and numerics)
            table = loop.params.table
            keys = tunable_keys(table, loop.params.as_dict())
            unit = get_model(args.model or "haptic").theta_unit
            run_terminal(loop, stop, keys=keys, table=table, unit=unit)
        finally:
            stop.set()
            thread.join()
        return result
    finally:
        try:
            if console is not None:
                stop_console(console)
        finally:
            if server is not None:
                server.close()
