"""``evo-door compare RUN1.h5 RUN2.h5 ...``: runs side by side."""

from __future__ import annotations

import json

from evo_door.errors import UserError

ORDER = 44


def register(sub) -> None:
    p = sub.add_parser(
        "compare",
        help="runs side by side: status, objective, fitness, parameters, errors, timings "
        "and the settings that differ",
    )
    p.add_argument("results", metavar="RUN.h5", nargs="+", help="two results files or more")
    p.add_argument(
        "--json",
        action="store_true",
        help="one JSON object: 'runs' (one entry per file, in order), 'differences' "
        "(dotted setting -> value per run)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.experiment import Results
    from evo_door.experiment.results import compare, format_compare

    if len(args.results) < 2:
        raise UserError(f"compare needs two results files or more, got only {args.results[0]}")
    doc = compare([Results(path) for path in args.results])
    print(json.dumps(doc, indent=2) if args.json else format_compare(doc))
    return 0
