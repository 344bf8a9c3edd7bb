"""``evo-door bench``: the benchmark suite of a source checkout (``python -m benchmarks``).

The benchmarks are not part of the installed package: this command finds the
``benchmarks/`` folder next to the ``evo_door`` package (an editable install or a
clone) and runs its suite in this process; elsewhere it says where to get it.
"""

from __future__ import annotations

import sys
from pathlib import Path

ORDER = 90


def register(sub) -> None:
    p = sub.add_parser(
        "bench",
        help="run the benchmark suite (source checkout only): times and ratios against "
        "scipy solve_ivp and a plain GA loop, scaling, targets; JSON and PNG",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: fewer repeats and points, small GAs; not a measurement",
    )
    p.add_argument(
        "--only",
        metavar="SECTION[,SECTION]",
        help="only these sections: trial, ga, scaling, executors, device, startup, casestudy, "
        "seeds, control, fmu, jnd, pathsim",
    )
    p.add_argument(
        "--out", metavar="DIR", help="folder of the results (default benchmarks/results/)"
    )
    p.add_argument(
        "--compare",
        metavar="JSON",
        nargs="+",
        help="OLD.json: run, then print new / old per metric; OLD.json NEW.json: compare only",
    )
    p.set_defaults(func=run)


def source_root() -> Path | None:
    """The checkout holding ``benchmarks/suite.py`` next to this package, if any."""
    root = Path(__file__).resolve().parents[2]
    return root if (root / "benchmarks" / "suite.py").is_file() else None


def run(args) -> int:
    from evo_door.errors import UserError

    root = source_root()
    if root is None:
        raise UserError(
            "evo-door bench needs a source checkout (the benchmarks are not installed): "
            "clone the repository, `pip install -e .` there and run `python -m benchmarks`"
        )
    argv = ["--quick"] * args.quick
    for flag, value in (("--only", args.only), ("--out", args.out)):
        if value is not None:
            argv += [flag, value]
    if args.compare:
        argv += ["--compare", *args.compare]
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    from benchmarks.suite import main

    return main(argv, prog="evo-door bench")
