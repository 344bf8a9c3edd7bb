"""Argument conventions shared by the sub-commands."""

from __future__ import annotations

import sys

#: Help text of every MODEL argument.
MODEL_HELP = "model: a name (haptic, door), package.module:MODEL or path/to/file.py:MODEL"


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


def model_and_params(args):
    """The model named by ``args.model`` and its checked parameter set."""
    from evo_door.models import get_model
    from evo_door.params import parse_assignments

    model = get_model(args.model)
    params = model.load_params(args.params, parse_assignments(args.assignments))
    return model, params
