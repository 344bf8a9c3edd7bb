"""``evo-door draw MODEL``: a mechanism file's block diagram (SVG), or the door's drawing.

A mechanism file (``drawer.yaml``, ``docs/blocks.md``) is drawn as its block diagram,
read from the file only (nothing is compiled): ``<file>.svg`` in the current folder
unless ``--out`` says otherwise. The built-in ``door`` is drawn at several door angles
from its kinematics, in any image format matplotlib writes (``door.svg`` by default).
An existing output is replaced with a note on stderr (a figure is derived); never an
input of the command nor an HDF5 file.
"""

from __future__ import annotations

from pathlib import Path

from evo_door.commands._common import add_params_arguments, model_and_params
from evo_door.errors import UserError

ORDER = 35
#: the door's angles when --angles is not given (deg)
DOOR_ANGLES = "0,45,90"


def register(sub) -> None:
    p = sub.add_parser(
        "draw",
        help="draw a mechanism file's block diagram (SVG: bodies, elements, the hand), or "
        "the door's mechanism (linkage, plate, spring, pad) at several angles",
    )
    p.add_argument("model", help="a mechanism file (path/to/drawer.yaml, docs/blocks.md), or door")
    add_params_arguments(p)
    p.add_argument(
        "--angles",
        default=None,
        metavar="DEG,DEG,...",
        help=f"door only: door angles in degrees, 0 = open, 90 = closed (default {DOOR_ANGLES})",
    )
    p.add_argument(
        "--out",
        metavar="FILE.svg",
        help="file to write (default: the mechanism file's name with .svg, in the current "
        "folder; door.svg for the door, whose drawing may also be .png, .pdf, ...)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.models.blocks import is_mechanism_spec

    if is_mechanism_spec(args.model):
        return _draw_mechanism(args)
    return _draw_door(args)


def _claim(out: Path, inputs):
    """May ``out`` be written? Never over an input nor an HDF5 file (where evo-door
    keeps data: a figure never replaces one); another existing file is replaced, with
    a note (a figure is derived: the README's rule)."""
    from evo_door.files import Output, claim_outputs

    return claim_outputs([Output(out)], inputs)


def _draw_mechanism(args) -> int:
    from evo_door.files import write_text
    from evo_door.models.blocks.drawing import mechanism_svg
    from evo_door.models.blocks.mechanism import read_mechanism

    given = [f for f, v in (("--params", args.params), ("--set", args.assignments),
                            ("--angles", args.angles)) if v]  # fmt: skip
    if given:
        raise UserError(
            f"{' and '.join(given)}: for the door; a mechanism file is drawn with its own "
            "values (edit the file to draw others)"
        )
    source = Path(args.model.strip()).expanduser()
    mech = read_mechanism(source)  # one line for a missing or a bad file
    out = Path(args.out) if args.out else Path(f"{source.stem}.svg")
    if out.suffix.lower() != ".svg":
        raise UserError(f"--out {out}: a mechanism's diagram is SVG; give a file.svg")
    claim = _claim(out, [source])
    write_text(out, mechanism_svg(mech))
    bodies = ", ".join(mech.bodies)
    elements = ", ".join(mech.elements) or "none"
    print(
        f"wrote {out}: mechanism {mech.name}, {len(mech.bodies)} "
        f"{'body' if len(mech.bodies) == 1 else 'bodies'} ({bodies}), "
        f"{len(mech.elements)} element{'' if len(mech.elements) == 1 else 's'} ({elements}); "
        f"the hand on {mech.handle}"
    )
    claim.note()
    return 0


def _draw_door(args) -> int:
    model, params = model_and_params(args)
    if model.name != "door":
        raise UserError(
            f"model {model.name!r} has no drawing; draw takes a mechanism file "
            "(path/to/drawer.yaml) or door"
        )
    text = args.angles or DOOR_ANGLES
    try:
        angles = [float(a) for a in text.split(",") if a.strip()]
    except ValueError:
        raise UserError(f"--angles {text!r}: expected degrees separated by commas") from None
    if not angles or any(not (-5.0 <= a <= 95.0) for a in angles):
        raise UserError(f"--angles {text!r}: give one to six angles in [0, 90] deg")
    if len(angles) > 6:
        raise UserError(f"--angles {text!r}: at most six angles")
    from evo_door.files import check_image_path
    from evo_door.models.door.drawing import draw_mechanism

    out = Path(args.out or "door.svg")
    claim = _claim(out, [params.source])
    check_image_path(out)
    draw_mechanism(
        params,
        angles,
        out,
        title=f"{model.title}: {Path(params.source).stem if params.source else 'defaults'}",
    )
    print(f"wrote {out}")
    claim.note()
    return 0
