"""``evo-door emulate hapticmaster``: a HapticMaster emulator on the loopback interface."""

from __future__ import annotations

import math
import sys

from evo_door.errors import UserError

ORDER = 92


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
        default=math.inf,
        help="stop after this many seconds (default: until Ctrl-C)",
    )
    p.set_defaults(func=run)


def _hand(script_name: str):
    """The user-force callback of a render --user script: a hand on the door's circle."""
    import numpy as np

    from evo_door.models.haptic import PARAMS, on_path
    from evo_door.render.device import hand_force, user_script

    script = user_script(script_name)
    radius = PARAMS["radius"].default  # the handle's circle, as the render command's
    out = np.zeros(3)

    def force(t, position, velocity):
        target = np.asarray(on_path(script.target(t), radius), dtype=np.float64)
        hand_force(
            position, velocity, target, script.stiffness, script.damping, script.max_force, out
        )
        return out.copy()

    start = tuple(float(c) for c in on_path(script.theta_start, radius))
    return force, start


def run(args) -> int:
    from evo_door.render.emulator import HapticMasterEmulator

    if not 0 <= args.port < 65536:
        raise UserError(f"--port {args.port}: expected 0..65535")
    for name in ("inertia", "damping", "coulomb", "noise"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value >= 0) or (name == "inertia" and value == 0):
            raise UserError(f"--{name} {value!r}: expected a finite, non-negative number")
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
        emulator.serve_forever(args.seconds)
    except KeyboardInterrupt:
        print("emulator stopped", file=sys.stderr)
    finally:
        emulator.close()
    print(f"served {emulator.commands} commands")
    return 0
