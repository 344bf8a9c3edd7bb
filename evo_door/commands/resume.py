"""``evo-door resume RUN.h5``: continue an interrupted run from its last generation."""

from __future__ import annotations

import sys

from evo_door.commands._common import (
    add_allow_model,
    add_progress_arguments,
    check_ranges,
    show_progress,
)
from evo_door.commands.run import add_checkpoint_argument, add_executor_argument

ORDER = 41


def register(sub) -> None:
    p = sub.add_parser(
        "resume", help="continue an interrupted run; ends as an uninterrupted one would"
    )
    p.add_argument("results", metavar="RUN.h5", help="results file of the interrupted run")
    add_executor_argument(
        p,
        "where the GA's evaluations run (local, processes[:N], dask[:N], tcp://HOST:PORT); "
        "default: the one the run used; the result does not depend on it",
    )
    add_checkpoint_argument(p)
    add_progress_arguments(p)
    add_allow_model(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.experiment import Results, store
    from evo_door.experiment.reader import check_file_models
    from evo_door.experiment.runner import ExperimentRun
    from evo_door.reporting.format_text import format_show

    check_ranges(args)
    if args.executor is not None:
        from evo_door.optim.executors import preflight

        preflight(args.executor)
    check_file_models(args.results)  # a file is data: it names no code to run
    if store.pipeline_attrs(args.results) is not None:
        return resume_pipeline(args)
    job = ExperimentRun.open(args.results)
    job.checkpoint_every = args.checkpoint_every
    if job.status == "complete":
        print(f"{args.results}: already complete, nothing to do")
        return 0
    if not args.quiet:
        done = [(-1 if j.ga is None else j.ga.generation) for j in job.jobs if not j.done]
        where = f"generation {done[0]}" if done and done[0] >= 0 else "the start"
        print(f"{args.results}: resuming {job.config['name']} from {where}")
    try:
        job.run(progress=show_progress(args), executor=args.executor)
    except KeyboardInterrupt:
        print(
            f"evo-door: interrupted again; evo-door resume {job.path} continues it", file=sys.stderr
        )
        return 130
    if not args.quiet:
        print(format_show(Results(job.path)))
    return 0


def resume_pipeline(args) -> int:
    from evo_door.commands.run import finish_pipeline
    from evo_door.experiment.pipeline import PipelineRun

    job = PipelineRun.open(args.results)
    job.checkpoint_every = args.checkpoint_every
    if job.status == "complete":
        print(f"{args.results}: already complete, nothing to do")
        return 0
    if not args.quiet:
        where = job.current.config["name"] if job.current else "the next stage"
        print(f"{args.results}: resuming pipeline {job.pipeline.name} at stage {where}")
    return finish_pipeline(job, args)
