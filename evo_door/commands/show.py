"""``evo-door show RUN.h5``: best parameters, fitness and settings of a run."""

from __future__ import annotations

import json

ORDER = 42


def register(sub) -> None:
    p = sub.add_parser("show", help="print a run's best parameters, fitness and settings")
    p.add_argument("results", metavar="RUN.h5", help="results file")
    p.add_argument(
        "--json",
        action="store_true",
        help="one JSON object; its 'best' maps free parameter names to values",
    )
    p.add_argument("--plot", metavar="FIT.png", help="draw the best response next to the target")
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.experiment import Results
    from evo_door.experiment.results import format_show, plot_fit

    res = Results(args.results)
    if args.plot:
        plot_fit(res, args.plot)
    if args.json:
        print(json.dumps(res.summary(), indent=2))
    else:
        print(format_show(res))
        if args.plot:
            print(f"wrote {args.plot}")
    return 0
