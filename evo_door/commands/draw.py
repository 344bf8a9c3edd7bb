"""``evo-door draw door``: a drawing of the mechanism at several door angles."""

from __future__ import annotations

from evo_door.commands._common import add_params_arguments, model_and_params
from evo_door.errors import UserError

ORDER = 35


def register(sub) -> None:
    p = sub.add_parser(
        "draw", help="draw the door mechanism (linkage, plate, spring, pad) at several angles"
    )
    p.add_argument("model", help="a model with a mechanism drawing (door)")
    add_params_arguments(p)
    p.add_argument(
        "--angles",
        default="0,45,90",
        metavar="DEG,DEG,...",
        help="door angles in degrees, 0 = open, 90 = closed (default 0,45,90)",
    )
    p.add_argument("--out", required=True, metavar="door.png", help="image file to write")
    p.set_defaults(func=run)


def run(args) -> int:
    model, params = model_and_params(args)
    if model.name != "door":
        raise UserError(f"model {model.name!r} has no mechanism to draw; only 'door' has")
    try:
        angles = [float(a) for a in args.angles.split(",") if a.strip()]
    except ValueError:
        raise UserError(f"--angles {args.angles!r}: expected degrees separated by commas") from None
    if not angles or any(not (-5.0 <= a <= 95.0) for a in angles):
        raise UserError(f"--angles {args.angles!r}: give one to six angles in [0, 90] deg")
    if len(angles) > 6:
        raise UserError(f"--angles {args.angles!r}: at most six angles")
    from pathlib import Path

    from evo_door.files import Output, claim_outputs
    from evo_door.models.door.drawing import draw_mechanism

    claim = claim_outputs([Output(args.out)], [params.source])
    draw_mechanism(
        params,
        angles,
        args.out,
        title=f"{model.title}: {Path(params.source).stem if params.source else 'defaults'}",
    )
    print(f"wrote {args.out}")
    claim.note()
    return 0
