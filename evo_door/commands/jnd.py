"""``evo-door jnd``: measure a just-noticeable difference on a device (a 2IFC session)."""

from __future__ import annotations

import json
import sys
import threading
import time

from evo_door.commands._common import (
    DEVICE_DAMPING,
    Range,
    add_params_arguments,
    check_ranges,
    declare_ranges,
)
from evo_door.commands.render import WATCHDOG_RANGES, add_watchdog_arguments
from evo_door.errors import UserError, plain_text

ORDER = 61

#: every numeric flag's range, checked before any work
RANGES = {
    "--reference": Range(0, 1e9, above=True),
    "--trials": Range(10, 2000, "trials", integer=True),
    "--seed": Range(0, 2**32 - 1, integer=True),
    "--interval": Range(0.05, 60, "s"),
    "--pause": Range(0, 60, "s"),
    "--ramp": Range(0, 0.5, "s"),
    "--rate": Range(100, 5000, "Hz"),
    "--log-rate": Range(1, "--rate", "Hz"),
    "--device-damping": DEVICE_DAMPING,
    **WATCHDOG_RANGES,
}


def register(sub) -> None:
    # long: one function on purpose: the flags in the order --help lists them, no logic
    p = sub.add_parser(
        "jnd",
        help="measure a just-noticeable difference of one parameter on a device "
        "(two-interval forced choice, staircase or QUEST, Weber fraction with 95 %% interval)",
        description="Each trial renders the reference set and a comparison set (one "
        "parameter changed by a relative step) in random order, a neutral pause before "
        "each (the participant lets go); the participant says which interval felt stronger. The Weber fraction "
        "comes from a psychometric fit (docs/perception-lab.md).",
    )
    add_params_arguments(p)
    p.add_argument("--param", required=True, metavar="NAME", help="the parameter to measure")
    p.add_argument(
        "--reference",
        metavar="VALUE",
        help="its reference value (SI units, > 0; default: its value in --params)",
    )
    p.add_argument(
        "--neutral",
        metavar="P.yaml|defaults",
        help="render a neutral set in the pauses and the question: the sensation "
        "parameters of this parameter file or preset, or the model's defaults (the "
        "others stay --params'); default: none, the participant lets go in the pauses "
        "while the next interval's set comes in",
    )
    p.add_argument(
        "--device",
        default="sim",
        metavar="sim|hapticmaster://HOST:PORT",
        help="the device (default sim: a simulated device whose user swings the door)",
    )
    p.add_argument(
        "--participant",
        default="person",
        metavar="sim:WEBER[,SLOPE[,LAPSE]]|person[:ID]",
        help="who answers: a simulated participant, or a person at the terminal "
        "(keys 1 and 2, q stops; the default)",
    )
    p.add_argument(
        "--method",
        choices=("staircase", "quest"),
        default="staircase",
        help="how each step is chosen: a 3-down 1-up staircase (default) or QUEST",
    )
    p.add_argument("--trials", default=80, metavar="N", help="trials (default 80)")
    p.add_argument(
        "--seed", default=0, metavar="S", help="seed of the order (and a sim participant)"
    )
    p.add_argument("--interval", default=2.0, metavar="S", help="each interval (s, default 2)")
    p.add_argument(
        "--pause", default=1.0, metavar="S", help="pause before each interval (s, default 1)"
    )
    p.add_argument("--ramp", default=0.2, metavar="S", help="ramp of every switch (s, default 0.2)")
    p.add_argument("--rate", default=2500.0, metavar="HZ", help="loop rate (Hz, default 2500)")
    p.add_argument("--log-rate", metavar="HZ", help="log rate (Hz, default min(1000, --rate))")
    damping = "the device's own damping for the passivity check (N s/m; sim 2, a HapticMaster 0)"
    p.add_argument("--device-damping", metavar="N_S_M", help=damping)
    p.add_argument(
        "--realtime",
        action="store_true",
        help="pace the simulated device on the wall clock (implied by a person answering)",
    )
    add_watchdog_arguments(p, "a session always has a supervisor")
    p.add_argument("--json", action="store_true", help="print the estimate as one JSON object")
    p.add_argument("--out", required=True, metavar="J.h5", help="the JND file to write")
    p.add_argument(
        "--log", metavar="LOG.h5", help="also write the render log (every switch, answer)"
    )
    p.add_argument("--force", action="store_true", help="replace an existing --out or --log")
    declare_ranges(p, RANGES)
    p.set_defaults(func=run)


def _participant(spec: str, seed: int):
    """The participant of ``--participant``, behind the polled interface."""
    from evo_door.perception.procedures import SimParticipant
    from evo_door.render.jnd import Immediate, TerminalPerson

    if spec.startswith("sim:") or spec == "sim":
        # its own stream: the answers do not move with the trial order's draws
        return Immediate(SimParticipant.from_spec(spec, seed=[seed, 1]))
    kind, _, who = spec.partition(":")
    if kind != "person":
        raise UserError(
            f"--participant {spec!r}: expected sim:WEBER[,SLOPE[,LAPSE]] or person[:ID]"
        )
    plain_text(who, "--participant person:ID")
    if not sys.stdin.isatty():
        raise UserError("--participant person: answers come from the terminal; stdin is not one")
    return TerminalPerson(who)


def _device(args, radius: float):
    from evo_door.commands.render import make_device
    from evo_door.render.device import SimDevice
    from evo_door.render.jnd import swing_user

    if args.device == "sim":
        extra = {} if args.device_damping is None else {"damping": args.device_damping}
        return SimDevice(swing_user(args.interval), radius=radius, seed=args.seed, **extra), "sim"
    return make_device(args.device, None, radius, args.seed, args.device_damping)


def _sets(args):
    """The reference set, the neutral values, the measured parameter's declaration
    and its reference value."""
    from evo_door.models import get_model
    from evo_door.models.haptic import PARAMS
    from evo_door.params.sets import parse_assignments
    from evo_door.render.jnd import neutral_values

    declared = PARAMS[args.param]  # did you mean, on a bad name
    model = get_model("haptic")
    params = model.load_params(args.params, parse_assignments(args.assignments))
    reference = params[args.param] if args.reference is None else args.reference
    if not reference > 0.0:
        raise UserError(
            f"--param {args.param}: its value in the set is {reference:g} {declared.unit}; a "
            "Weber fraction needs a reference above 0 (give --reference)"
        )
    declared.check(reference, "--reference")
    params = params.replace({args.param: reference}, source=params.source)
    if not args.neutral:  # let-go pauses: no neutral set
        return params, None, declared, float(reference)
    if args.neutral == "defaults":  # the model's declared sensations
        return params, neutral_values(params), declared, float(reference)
    neutral = neutral_values(params, model.load_params(args.neutral))
    return params, neutral, declared, float(reference)


def run(args) -> int:
    # long: the session's steps in order (inputs, claims, device, loop, run, file,
    # output); each a few lines, and the order is the point
    from evo_door.files import TRIALS, Output, claim_outputs
    from evo_door.perception.procedures import JndSession
    from evo_door.render.jnd import JndTiming

    check_ranges(args)
    if args.supervisor_budget is not None and not args.device.startswith("hapticmaster://"):
        raise UserError("--supervisor-budget goes with a hapticmaster:// device")
    timing = JndTiming(args.interval, args.pause, args.ramp)
    params, neutral, declared, reference = _sets(args)
    claim = claim_outputs(
        [Output(args.out, "--out", TRIALS), Output(args.log, "--log", TRIALS)],
        [params.source, None if args.neutral == "defaults" else args.neutral],
        force=args.force,
    )
    session = JndSession(
        args.param,
        declared.unit,
        reference,
        args.method,
        trials=args.trials,
        seed=[args.seed, 0],
        upper=declared.upper,
    )
    _hands_off(params, neutral, args.param, reference * (1.0 + session.max_step))
    participant = _participant(args.participant, args.seed)
    try:
        return _run_session(args, params, neutral, session, participant, timing, claim)
    finally:
        participant.close()


def _hands_off(params, neutral, name: str, largest: float) -> None:
    """Every set the session can render (the reference, the largest comparison, the
    neutral set of the pauses) stays within the hands-off limit (docs/haptic-model.md,
    "Bounds that keep a hand safe"); else one line, before the device is touched."""
    from evo_door.render.hands_off import check_hands_off

    sets = [params, params.replace({name: largest}, source=params.source)]
    if neutral is not None:
        sets.append(params.replace(neutral, source="neutral"))
    for candidate in sets:
        check_hands_off(
            candidate, how="a JND session keeps the default limit: choose a gentler set"
        )


def _run_session(args, params, neutral, session, participant, timing, claim) -> int:
    from evo_door.render.loop import ServoLoop
    from evo_door.render.stopping import stop_on_ctrl_c

    device, name = _device(args, params["radius"])
    start = params if neutral is None else params.replace(neutral, source="neutral")
    paced = True if (args.realtime or participant.blind) else None
    loop = ServoLoop(
        device,
        start,
        args.rate,
        log_rate=args.log_rate or min(1000.0, args.rate),
        realtime=paced,
        device_name=name,
        watchdog_misses=args.watchdog_misses,
    )
    if args.device.startswith("hapticmaster://"):
        from evo_door.render.supervised import start_supervisor

        budget = None if args.supervisor_budget is None else args.supervisor_budget / 1e3
        loop.supervisor = start_supervisor(device, loop, budget)
    if args.log:
        loop.log.spill_to(args.log, loop_rate=loop.rate, device=name)
    else:
        loop.log.keep_recent()
    stop = threading.Event()
    t0 = time.perf_counter()
    try:
        with stop_on_ctrl_c(stop, loop):
            outcome = _render(args, loop, session, participant, params, neutral, timing, stop)
            return _finish(args, loop, session, participant, params, outcome, name, t0, claim)
    finally:
        loop.log.close()
        if loop.supervisor is not None:
            loop.supervisor.close()


def _render(args, loop, session, participant, params, neutral, timing, stop):
    from evo_door.render.jnd import run_session

    def progress(text: str) -> None:
        if not args.json:
            print(text, file=sys.stderr, flush=True)

    try:
        return run_session(
            loop, session, participant, params.as_dict(), neutral, timing, stop, progress
        )
    except BaseException as exc:  # a second Ctrl-C, a failure: keep the log
        if args.log:
            from evo_door.render.stopping import write_interrupted

            write_interrupted(loop, args.log, exc)
        raise


def _finish(args, loop, session, participant, params, outcome, name, t0, claim) -> int:
    """The JND file (always, with what was answered), the log, the printed estimate."""
    from datetime import UTC, datetime

    from evo_door.experiment.store import versions
    from evo_door.perception.jnd_file import read_jnd_file, write_jnd_file

    n = len(session.answers)
    fit = session.fit() if n >= 10 else None
    settings = {
        "params": str(params.source),
        "param": args.param,
        "reference": session.reference,
        "neutral": args.neutral or "none: the participant lets go in the pauses",
        "method": args.method,
        "trials": session.trials,
        "interval_s": args.interval,
        "pause_s": args.pause,
        "ramp_s": args.ramp,
        "rate_hz": loop.rate,
        "realtime": loop.realtime,
        "device": name,
        "participant": participant.describe(),
        "outcome": outcome.message,
    }
    write_jnd_file(
        args.out,
        session,
        fit,
        status=outcome.status,
        participant=participant.describe(),
        device=name,
        model="haptic",
        reference_params=params.as_dict(),
        settings=settings,
        seed=args.seed,
        created=datetime.now(UTC).astimezone().isoformat(timespec="seconds"),
        wall_s=time.perf_counter() - t0,
        versions=versions(),
    )
    if args.log:
        loop.write_log(args.log)
    claim.note()
    record = read_jnd_file(args.out)
    if args.json:
        print(json.dumps({**record.summary(), "out": str(args.out)}))
    else:
        from evo_door.perception.jnd_show import format_jnd

        print(format_jnd(record))
        print(f"wrote {args.out}" + (f" and {args.log}" if args.log else ""))
    if outcome.status == "refused":
        raise UserError(f"session ended after {n} trials, a change refused: {outcome.message}")
    return 0 if outcome.status in ("complete", "stopped") else 1
