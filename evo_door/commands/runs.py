"""``evo-door runs [DIR]``: the runs in a results folder, as a table."""

from __future__ import annotations

import json

from evo_door.commands._common import add_allow_model

ORDER = 43


def register(sub) -> None:
    p = sub.add_parser(
        "runs",
        help="list the runs in a results folder (default results/): status, objective, "
        "fitness, parameters",
    )
    p.add_argument(
        "folder",
        metavar="DIR",
        nargs="?",
        default="results",
        help="folder of results files (default results)",
    )
    p.add_argument("--json", action="store_true", help="one JSON list, a row per run")
    add_allow_model(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.reporting.format_json import list_runs
    from evo_door.reporting.format_tables import format_runs

    rows = list_runs(args.folder)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    if not rows:
        print(f"{args.folder}: no runs")
        return 0
    print(format_runs(rows))
    return 0
