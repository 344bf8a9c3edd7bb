"""``evo-door emulate hapticmaster``: a HapticMaster emulator on the loopback interface."""

from __future__ import annotations

import sys

from evo_door.commands._common import DAY, DEVICE_DAMPING, PORT, Range, check_ranges, declare_ranges

ORDER = 92

#: the numeric flags' ranges, checked before any work
RANGES = {
    "--port": PORT,
    # a HapticMaster moves about 2-4 kg; the renderer sets its own (set inertia)
    "--inertia": Range(0, 1000, "kg", above=True),
    "--damping": DEVICE_DAMPING,
    # no more than the device's force (200 N): else it could never move
    "--coulomb": Range(0, 200, "N"),
    "--noise": Range(0, 50, "N"),
    "--seconds": Range(0, DAY, "s", above=True),
}


def register(sub) -> None:
    p = sub.add_parser(
        "emulate",
        help="emulate a force-feedback device over its network protocol (hapticmaster)",
    )
    p.add_argument("device", choices=["hapticmaster"], help="the device to emulate")
    p.add_argument("--port", type=int, default=7654, help="TCP port (default 7654; 0: any free)")
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1, this machine only)",
    )
    p.add_argument("--inertia", type=float, default=4.0, help="device mass, kg (default 4)")
    p.add_argument("--damping", type=float, default=2.0, help="device damping, N s/m (default 2)")
    p.add_argument(
        "--coulomb", type=float, default=0.0, help="device Coulomb friction, N (default 0)"
    )
    p.add_argument(
        "--user",
        metavar="SCRIPT",
        help="a scripted virtual hand on the handle (the render command's --user scripts)",
    )
    p.add_argument(
        "--noise", type=float, default=0.0, help="force-sensor noise, N (std; default 0)"
    )
    p.add_argument(
        "--seconds",
        type=float,
        help="stop after this many seconds (default: until Ctrl-C)",
    )
    declare_ranges(p, RANGES)
    p.set_defaults(func=run)


def _hand(script_name: str):
    """The user-force callback of a render --user script: a hand on the door's circle."""
    import numpy as np

    from evo_door.models.haptic import PARAMS, on_path
    from evo_door.render.device import Hand, user_script

    script = user_script(script_name)
    radius = PARAMS["radius"].default  # the handle's circle, as the render command's
    hand = Hand(script, radius)
    out = np.zeros(3)

    def force(t, position, velocity):
        hand.force(t, position, velocity, out)
        return out.copy()

    start = tuple(float(c) for c in on_path(script.theta_start, radius))
    return force, start


def run(args) -> int:
    import math

    from evo_door.render.emulator import HapticMasterEmulator

    check_ranges(args)
    user, start = (None, (0.0, 0.0, 0.0)) if not args.user else _hand(args.user)
    emulator = HapticMasterEmulator(
        args.port,
        args.host,
        inertia=args.inertia,
        damping=args.damping,
        coulomb_friction=args.coulomb,
        user_force=user,
        sensor_noise=args.noise,
        position=start,
        realtime=True,  # as the device's controller: answers within milliseconds
    )
    print(
        f"emulating a HapticMaster at {emulator.address} "
        f"(inertia {args.inertia:g} kg, damping {args.damping:g} N s/m, "
        f"Coulomb friction {args.coulomb:g} N; {emulator.scheduling}); Ctrl-C stops",
        flush=True,
    )
    try:
        emulator.serve_forever(math.inf if args.seconds is None else args.seconds)
    except KeyboardInterrupt:
        print("emulator stopped", file=sys.stderr)
    finally:
        emulator.close()
    print(f"served {emulator.commands} commands")
    return 0
