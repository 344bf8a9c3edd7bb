"""``evo-door run EXP.yaml``: run an experiment, results in HDF5."""

from __future__ import annotations

import sys

from evo_door.commands._common import add_progress_arguments, show_progress

ORDER = 40


def register(sub) -> None:
    p = sub.add_parser("run", help="run a GA / SLSQP experiment file; results in an HDF5 file")
    p.add_argument("experiment", metavar="EXP.yaml", help="experiment file (docs/experiments.md)")
    p.add_argument(
        "--out", metavar="RUN.h5", help="results file (default: results/<name>-<date>-<time>.h5)"
    )
    p.add_argument(
        "--set",
        metavar="KEY.PATH=VALUE",
        action="append",
        default=[],
        dest="assignments",
        help="override a setting of the file, e.g. algorithm.seed=3; repeatable",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace an existing results file at --out (a complete or interrupted run)",
    )
    add_progress_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.experiment import Results, load_experiment
    from evo_door.experiment.results import format_show
    from evo_door.experiment.runner import ExperimentRun

    exp = load_experiment(args.experiment, args.assignments)
    job = ExperimentRun.create(exp, args.out, overwrite=args.force)
    if not args.quiet:
        print(
            f"{exp.name}: {len(job.setup.fit)} fitted trial(s), "
            f"{len(job.setup.validation)} validation trial(s), free: "
            f"{', '.join(job.setup.free)}; writing {job.path}"
        )
    try:
        job.run(progress=show_progress(args))
    except KeyboardInterrupt:
        print(
            f"evo-door: interrupted; {job.path} holds the last finished generation: "
            f"evo-door resume {job.path}",
            file=sys.stderr,
        )
        return 130
    if not args.quiet:
        print(format_show(Results(job.path)))
    return 0
