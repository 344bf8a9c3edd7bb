"""``evo-door params MODEL``: print a model's parameter declaration."""

from __future__ import annotations

import json

from evo_door.commands._common import (
    MODEL_HELP,
    add_channels_argument,
    add_params_arguments,
    model_name,
)

ORDER = 10


def register(sub) -> None:
    p = sub.add_parser(
        "params",
        help="print a model's parameter declaration (name, unit, default, bounds, group, meaning)",
    )
    p.add_argument("model", help=MODEL_HELP)
    add_params_arguments(p)
    p.add_argument("--json", action="store_true", help="print the declaration as JSON")
    add_channels_argument(p)
    p.add_argument(
        "--write", metavar="OUT.yaml", help="write the (loaded, overridden) parameter set as YAML"
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.models import get_declaration
    from evo_door.params import parse_assignments

    # the declaration only: a bundled model's is read without numba (quick start-up)
    model = get_declaration(model_name(args))
    values = None
    if args.params or args.assignments or args.write:
        ps = model.load_params(args.params, parse_assignments(args.assignments))
        values = ps.as_dict()
        if args.write:
            from evo_door.files import Output, claim_outputs

            # a parameter file written from --params and --set is derived: replaced
            # (and said), but never the file it was read from
            claim = claim_outputs([Output(args.write, "--write")], [ps.source])
            ps.to_yaml(args.write)
            print(f"wrote {args.write}")
            claim.note()
            return 0
    if args.json:
        rows = model.params.rows()
        if values:
            for row in rows:
                row["value"] = values[row["name"]]
        print(json.dumps({"model": model.name, "params": rows}, indent=2))
        return 0
    print(f"{model.title} ({model.name}): {len(model.params)} parameters, SI units")
    print(model.params.format_table(values))
    presets = model.presets()
    if presets:
        print(f"\npresets: {', '.join(presets)}")
    states = getattr(model, "states", ())  # a model on a state vector: what each state is
    if states:
        position, speed = getattr(model, "handle", (0, 1))
        handle = {position: " (the handle)", speed: " (its speed)"}
        named = [f"{name}{handle.get(i, '')}" for i, name in enumerate(states)]
        print(f"\nstates: {', '.join(named)}")
    if model.notes:
        print(f"\n{model.notes}")
    return 0
