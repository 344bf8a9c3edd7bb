"""Argument conventions shared by the sub-commands."""

from __future__ import annotations

import sys
from dataclasses import dataclass

from evo_door.errors import UserError

#: Help text of every MODEL argument.
MODEL_HELP = (
    "model: a name (haptic, door), package.module:MODEL, path/to/file.py:MODEL, "
    "path/to/mechanism.yaml (docs/blocks.md) or path/to/model.fmu (FMI 2.0 / 3.0; "
    ":me or :cs after it chooses the interface)"
)


def add_progress_arguments(parser) -> None:
    """``--quiet`` and ``--progress``, read by :func:`show_progress`."""
    parser.add_argument("--quiet", action="store_true", help="no progress bar, no summary")
    parser.add_argument(
        "--progress",
        action="store_true",
        help="show the progress bar even when stderr is not a terminal (logs, CI)",
    )


def show_progress(args) -> bool:
    """The progress bar: never with --quiet, always with --progress, else on a terminal."""
    if args.quiet:
        return False
    return bool(args.progress or sys.stderr.isatty())


def add_params_arguments(parser) -> None:
    """``--params P.yaml|PRESET`` and repeatable ``--set NAME=VALUE``."""
    parser.add_argument(
        "--params",
        metavar="P.yaml",
        help="parameter file or preset name (default: declared defaults)",
    )
    parser.add_argument(
        "--set",
        metavar="NAME=VALUE",
        action="append",
        default=[],
        dest="assignments",
        help="override one parameter (SI units); repeatable",
    )


def add_channels_argument(parser) -> None:
    """``--channels CHANNEL=VARIABLE``: an FMU's variables for the trial's channels."""
    parser.add_argument(
        "--channels",
        action="append",
        default=[],
        metavar="CHANNEL=VARIABLE",
        help="for an FMU model: the variable that carries a channel (force, theta, dtheta, "
        "ddtheta; theta0, dtheta0: the variables the initial state is written to), where "
        "the FMU does not name it so: force=F_hand, theta=angle; repeatable (units are "
        "converted from the FMU's)",
    )


def add_allow_model(p) -> None:
    """``--allow-model SPEC``: a command that reads results files loads a model that is
    code (a Python file, a module path, an FMU) only when the user names it too."""
    p.add_argument(
        "--allow-model",
        action="append",
        default=[],
        metavar="SPEC",
        help="run the model a results file names (path/file.py:MODEL, module:MODEL, "
        "model.fmu): only for files you trust, since loading it runs its code; "
        "repeatable (docs/trust.md)",
    )


def model_name(args) -> str:
    """``args.model`` with ``--channels`` added to an FMU's name (``x.fmu?force=F``)."""
    channels = getattr(args, "channels", None) or []
    if not channels:
        return args.model
    from evo_door.models.fmu import is_fmu_spec, join_spec, split_spec

    if not is_fmu_spec(args.model):
        raise UserError(f"--channels: only for an FMU model; {args.model!r} is not one")
    path, interface, mapping = split_spec(args.model)
    for item in channels:
        key, eq, var = item.partition("=")
        if not eq or not key.strip() or not var.strip():
            raise UserError(f"--channels {item!r}: expected CHANNEL=VARIABLE (force=F_hand)")
        mapping[key.strip()] = var.strip()
    return join_spec(path, interface, mapping)


def model_and_params(args):
    """The model named by ``args.model`` (and ``--channels``) and its checked parameter
    set."""
    from evo_door.models import get_model
    from evo_door.params import parse_assignments

    model = get_model(model_name(args))
    params = model.load_params(args.params, parse_assignments(args.assignments))
    return model, params


# -- numeric flags: one declared range each ---------------------------------------------
@dataclass(frozen=True)
class Range:
    """The values a flag takes: ``lower``..``upper`` in ``unit``, both included unless
    ``above`` (then ``> lower``). ``upper`` may name another flag (``"--rate"``) whose
    value is the bound. ``integer``: whole numbers only. ``length``: the flag is a
    text and the range is its length in characters."""

    lower: float
    upper: float | str
    unit: str = ""
    integer: bool = False
    above: bool = False
    length: bool = False


#: a TCP port; 0 asks the system for any free one
PORT = Range(0, 65535, integer=True)
#: a device's own viscous damping (N s/m): above 1000 N s/m a hand moving at 0.2 m/s
#: would feel the device's whole 200 N, so no device that is meant to be moved has it
DEVICE_DAMPING = Range(0, 1000, "N s/m")
#: a secret shared with a control port: at least a character (an empty one would mean
#: none), at most what fits comfortably in a request line
TOKEN = Range(1, 256, "characters", length=True)
#: a session's duration (s): up to a day
DAY = 86400.0


def declare_ranges(parser, ranges: dict[str, Range]) -> None:
    """Make the flags of ``ranges`` keep their text (no argparse ``type``): parsing and
    range happen in :func:`check_ranges`, which refuses a bad value in one line (an
    argparse type error prints the usage too)."""
    actions = {opt: a for a in parser._actions for opt in a.option_strings}
    for flag in ranges:
        actions[flag].type = None
    parser.set_defaults(_ranges=ranges)


def check_ranges(args) -> None:
    """Parse and check every flag that :func:`declare_ranges` declared (before any
    work); sets each to its number. A UserError names the flag, the value and the
    range, with the unit."""
    from evo_door.errors import UserError

    ranges = getattr(args, "_ranges", {})
    for flag, r in ranges.items():  # the numbers first: a bound may name another flag
        if not r.length:
            _set_number(args, flag, r, UserError)
    for flag, r in ranges.items():
        value = getattr(args, _dest(flag))
        if value is None:
            continue
        if r.length:  # a text: Unicode a file and a socket can carry, or refused here
            from evo_door.errors import plain_text

            plain_text(value, flag)
        size = len(value) if r.length else value
        upper = getattr(args, _dest(r.upper)) if isinstance(r.upper, str) else r.upper
        low_ok = size > r.lower if r.above else size >= r.lower
        if not (low_ok and size <= upper):
            shown = f"{len(value)} characters" if r.length else _num(value)
            raise UserError(f"{flag} {shown}: must be {_range_text(r, upper)}")


def _dest(flag: str) -> str:
    return flag.lstrip("-").replace("-", "_")


def _set_number(args, flag: str, r: Range, error) -> None:
    import math

    dest = _dest(flag)
    text = getattr(args, dest)
    if text is None or isinstance(text, (int, float)) and not isinstance(text, bool):
        value = text  # the default, or a caller's number
    else:
        try:
            value = int(text) if r.integer else float(text)
        except ValueError:
            kind = "a whole number" if r.integer else "a number"
            raise error(f"{flag} {text!r}: expected {kind}") from None
    if value is not None and not math.isfinite(value):
        raise error(f"{flag} {value}: must be finite, {_range_text(r, r.upper)}")
    if value is not None and r.integer and value != int(value):
        raise error(f"{flag} {_num(value)}: expected a whole number")
    setattr(args, dest, value)


def _range_text(r: Range, upper) -> str:
    """``in 0..1000 N s/m``, ``> 0 and <= 600 s``; a bound from a flag says which."""
    unit = f" {r.unit}" if r.unit else ""
    bound = r.upper if isinstance(upper, str) else _num(upper)
    whose = f" (up to {r.upper})" if isinstance(r.upper, str) else ""
    if r.above:
        return f"> {_num(r.lower)} and <= {bound}{unit}{whose}"
    return f"in {_num(r.lower)}..{bound}{unit}{whose}"


def _num(x) -> str:
    """A number as people write it: whole ones in full (4294967295, not 4.29497e+09)."""
    if float(x).is_integer() and abs(x) < 1e15:
        return str(int(x))
    return f"{x:g}"
