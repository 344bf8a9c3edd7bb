"""``evo-door render-check``: does a render log agree with the haptic model?"""

from __future__ import annotations

import json

from evo_door.commands._common import DAY, DEVICE_DAMPING, Range, check_ranges, declare_ranges

ORDER = 63

#: the numeric flags' ranges, checked before any work
RANGES = {
    "--device-damping": DEVICE_DAMPING,
    # no more than the device's force (200 N): else it could never move
    "--device-friction": Range(0, 200, "N"),
    "--window": Range(0, DAY, "s", above=True),
}


def register(sub) -> None:
    p = sub.add_parser(
        "render-check",
        help="simulate the haptic model under a render log's force and compare with the log",
        description="Is what was fitted what the participant felt? Simulates the haptic "
        "model under the user force a render log measured, from the logged angle and "
        "speed, and prints how far its angle and speed are from the log's (RMS and "
        "largest, with units). By default the sets the log rendered, plus what the "
        "device itself added (its damping and dry friction, as the log records them); "
        "with --params, that set as it is (a set fitted to the log already holds what "
        "the device added). docs/renderer.md, 'Does the log agree with the model?'.",
    )
    p.add_argument("log", metavar="LOG.h5", help="a render log (evo-door render --log)")
    p.add_argument(
        "--params",
        metavar="P.yaml",
        help="a haptic parameter file or preset to simulate instead of the log's sets",
    )
    p.add_argument(
        "--set",
        metavar="NAME=VALUE",
        action="append",
        default=[],
        dest="assignments",
        help="override one parameter of --params (SI units); repeatable",
    )
    p.add_argument(
        "--device-damping",
        metavar="B",
        help="the device's own viscous damping, N s/m (default: the log's; 0 with --params)",
    )
    p.add_argument(
        "--device-friction",
        metavar="F",
        help="the device's own dry friction, N (default: the log's; 0 with --params)",
    )
    p.add_argument(
        "--window",
        metavar="S",
        help="also start again from the logged state every S seconds (long sessions drift)",
    )
    p.add_argument("--json", action="store_true", help="the numbers as JSON (SI units)")
    declare_ranges(p, RANGES)
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.errors import UserError
    from evo_door.models import get_model
    from evo_door.params import parse_assignments
    from evo_door.render.check import format_agreement, render_agreement

    check_ranges(args)
    params = None
    if args.params is not None:
        params = get_model("haptic").load_params(args.params, parse_assignments(args.assignments))
    elif args.assignments:
        raise UserError("--set goes with --params (the log's own sets are simulated as logged)")
    agreement = render_agreement(
        args.log,
        params,
        device_damping=args.device_damping,
        device_friction=args.device_friction,
        window=args.window,
    )
    if args.json:
        out = {
            "log": str(args.log),
            "model": agreement.model,
            "device": agreement.device,
            "starts_s": agreement.starts,
            **{_key(k): v for k, v in agreement.errors().items()},
        }
        print(json.dumps(out, indent=2))
    else:
        print(format_agreement(agreement, args.log))
    return 0


#: the JSON keys of the numbers, with their units
_UNITS = {
    "theta_rms": "rad",
    "theta_max": "rad",
    "theta_max_t": "s",
    "dtheta_rms": "rad_s",
    "dtheta_max": "rad_s",
    "dtheta_max_t": "s",
    "theta_span": "rad",
    "speed_max": "rad_s",
}


def _key(name: str) -> str:
    return f"{name}_{_UNITS[name]}" if name in _UNITS else name
