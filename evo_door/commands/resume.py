"""``evo-door resume RUN.h5``: continue an interrupted run from its last generation."""

from __future__ import annotations

import sys

ORDER = 41


def register(sub) -> None:
    p = sub.add_parser(
        "resume", help="continue an interrupted run; ends as an uninterrupted one would"
    )
    p.add_argument("results", metavar="RUN.h5", help="results file of the interrupted run")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no summary")
    p.add_argument(
        "--progress",
        action="store_true",
        help="show the progress bar even when stderr is not a terminal (logs, CI)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.commands.run import show_progress
    from evo_door.experiment import Results
    from evo_door.experiment.results import format_show
    from evo_door.experiment.runner import ExperimentRun

    job = ExperimentRun.open(args.results)
    if job.status == "complete":
        print(f"{args.results}: already complete, nothing to do")
        return 0
    if not args.quiet:
        done = [(-1 if j.ga is None else j.ga.generation) for j in job.jobs if not j.done]
        where = f"generation {done[0]}" if done and done[0] >= 0 else "the start"
        print(f"{args.results}: resuming {job.config['name']} from {where}")
    try:
        job.run(progress=show_progress(args))
    except KeyboardInterrupt:
        print(
            f"evo-door: interrupted again; evo-door resume {job.path} continues it", file=sys.stderr
        )
        return 130
    if not args.quiet:
        print(format_show(Results(job.path)))
    return 0
