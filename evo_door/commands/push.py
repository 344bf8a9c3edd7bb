"""``evo-door push``: change the parameters of a running renderer through its control port."""

from __future__ import annotations

from evo_door.commands._common import TOKEN, Range, check_ranges, declare_ranges
from evo_door.errors import UserError

ORDER = 61

#: the numeric flags' ranges (and the token's length), checked before any work
RANGES = {"--timeout": Range(0, 600, "s", above=True), "--token": TOKEN}


def register(sub) -> None:
    p = sub.add_parser(
        "push",
        help="change the parameters of a running renderer (evo-door render --control)",
        description="Send a parameter set of the rendered model (a YAML file or preset: the whole set, "
        "only the values that differ from the running set are sent) and/or single "
        "values (--set NAME=VALUE, SI units) to a renderer's control port. The renderer "
        "checks them against the declaration, the passivity condition and its hands-off "
        "speed (render --hands-off-speed) and applies them together between two cycles, "
        "or refuses them all and says why.",
    )
    p.add_argument("file", nargs="?", metavar="P.yaml", help="parameter file or preset name")
    p.add_argument(
        "--set",
        metavar="NAME=VALUE",
        action="append",
        default=[],
        dest="assignments",
        help="one parameter (SI units); repeatable; on top of the file",
    )
    p.add_argument(
        "--model",
        help="the model of P.yaml when the renderer runs a mechanism (the file it renders); "
        "default haptic",
    )
    p.add_argument("--to", required=True, metavar="HOST:PORT", help="the renderer's control port")
    p.add_argument("--token", help="the token the renderer was started with")
    p.add_argument(
        "--timeout", type=float, default=5.0, metavar="S", help="answer timeout (s, default 5)"
    )
    declare_ranges(p, RANGES)
    p.set_defaults(func=run)


def _fmt(name: str, value: float, units: dict) -> str:
    unit = units.get(name, "")
    if unit == "rad":
        return f"{name} = {value:.6g} rad ({value * 57.29577951308232:.4g} deg)"
    return f"{name} = {value:.6g} {unit}".rstrip()


def run(args) -> int:
    from evo_door.models import get_model
    from evo_door.params import parse_assignments
    from evo_door.params.declaration import suggest
    from evo_door.render.control import parse_control, request

    check_ranges(args)
    if args.file is None and not args.assignments:
        raise UserError("push: give a parameter file and/or --set NAME=VALUE")
    host, port = parse_control(args.to)
    overrides = parse_assignments(args.assignments)
    model = get_model(args.model or "haptic")
    wanted: dict[str, float] = {}
    if args.file is not None:  # read before anything is sent
        wanted.update(model.load_params(args.file, overrides).as_dict())
    elif args.model or all(name in model.params.names for name in overrides):
        for name, value in overrides.items():  # checked here first, then by the renderer
            model.params[name].check(value, "--set")
    base = {"token": args.token} if args.token else {}

    def ask(message: dict) -> dict:
        answer = request(host, port, {**base, **message}, timeout=args.timeout)
        if not answer.get("ok"):
            raise UserError(f"the renderer refused: {answer.get('error', 'no reason given')}")
        return answer

    running = ask({"get": "params"})
    units = running.get("units", {})
    current = running.get("params", {})
    rendered = str(running.get("model", "haptic"))
    if args.file is not None or args.model:
        if model.params.model != rendered:
            raise UserError(
                f"the renderer runs {rendered!r}, not {model.name!r}: give --model, the "
                "model the renderer renders"
            )
    if args.file is None:
        for name, value in overrides.items():  # the renderer checks the value
            if name not in units:
                raise UserError(
                    f"--set {name}: {rendered!r} has no parameter {name!r}"
                    + suggest(name, list(units))
                )
            wanted[name] = value
    send = {n: v for n, v in wanted.items() if current.get(n) != v}
    if not send:
        print(f"nothing to push: the renderer at {host}:{port} already runs these values")
        return 0
    answer = ask({"set": send})
    state = "in force" if answer.get("in_force") else "accepted, applied at the next cycle"
    print(f"{host}:{port}: {len(answer['applied'])} value(s) {state} at t = {answer['t']:.4f} s")
    for name, value in answer["applied"].items():
        note = "" if name in send and send[name] == value else " (clamped to be passive)"
        print(f"  {_fmt(name, value, units)}{note}")
    return 0
