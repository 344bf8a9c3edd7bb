"""``evo-door run EXP.yaml``: run an experiment, results in HDF5."""

from __future__ import annotations

import sys

from evo_door.commands._common import (
    DAY,
    Range,
    add_progress_arguments,
    check_ranges,
    declare_ranges,
    show_progress,
)

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
    add_executor_argument(p)
    add_checkpoint_argument(p)
    add_progress_arguments(p)
    p.set_defaults(func=run)


#: the help of ``--executor`` (run, resume, batch)
EXECUTOR_HELP = (
    "where the GA's evaluations run: local (default: this process, numba threads), "
    "processes[:N] (a local pool), dask[:N] (a local Dask cluster) or tcp://HOST:PORT "
    "(a Dask scheduler); beats the file's executor; the result is the same on every one"
)


class _DefaultCheckpointEvery:
    """The default of ``--checkpoint-every``,
    ``evo_door.experiment.checkpoint.CHECKPOINT_EVERY``, read only when it is used or
    the help printed (building the parser imports nothing heavy)."""

    def __float__(self) -> float:
        from evo_door.experiment.checkpoint import CHECKPOINT_EVERY

        return CHECKPOINT_EVERY

    def __str__(self) -> str:
        return f"{float(self):g}"


def add_executor_argument(p, help=EXECUTOR_HELP) -> None:
    p.add_argument("--executor", metavar="EXECUTOR", default=None, help=help)


def add_checkpoint_argument(p) -> None:
    """``--checkpoint-every SECONDS`` (run, resume): how often a GA writes its file."""
    p.add_argument(
        "--checkpoint-every",
        metavar="SECONDS",
        default=_DefaultCheckpointEvery(),
        help="write the results file after a generation once the last write is this old "
        "(default %(default)s s; 0: every generation); every fit's end, Ctrl-C and SIGTERM "
        "write it anyway, so a kill loses at most this much of the GA's work",
    )
    declare_ranges(p, {"--checkpoint-every": Range(0, DAY, "s")})


def run(args) -> int:
    from evo_door.experiment import Results, load_experiment
    from evo_door.experiment.pipeline import is_pipeline
    from evo_door.experiment.runner import ExperimentRun
    from evo_door.reporting.format_text import format_show

    check_ranges(args)
    if is_pipeline(args.experiment):
        return run_pipeline(args)
    from evo_door.optim.executors import preflight

    exp = load_experiment(args.experiment, args.assignments)
    exp.executor = preflight(args.executor or exp.executor)
    job = ExperimentRun.create(exp, args.out, overwrite=args.force)
    job.checkpoint_every = args.checkpoint_every
    if not args.quiet:
        on = "" if exp.executor == "local" else f"; executor {exp.executor}"
        print(
            f"{exp.name}: {len(job.setup.fit)} fitted trial(s), "
            f"{len(job.setup.validation)} validation trial(s), free: "
            f"{', '.join(job.setup.free)}; writing {job.path}{on}"
        )
    if not interruptible(job, args, "the last finished generation"):
        return 130
    if not args.quiet:
        print(format_show(Results(job.path)))
    return 0


def interruptible(job, args, holds: str) -> bool:
    """Run ``job``; False (and what to do, on stderr) when Ctrl-C or SIGTERM stopped it."""
    try:
        job.run(progress=show_progress(args), executor=getattr(args, "executor", None))
    except KeyboardInterrupt:
        print(
            f"evo-door: interrupted; {job.path} holds {holds}: evo-door resume {job.path}",
            file=sys.stderr,
        )
        return False
    return True


def run_pipeline(args) -> int:
    """A pipeline file: every stage, one results file (evo_door.experiment.pipeline)."""
    from evo_door.experiment.pipeline import PipelineRun, load_pipeline
    from evo_door.optim.executors import preflight

    pipe = load_pipeline(args.experiment, args.assignments)
    if args.executor is not None:
        pipe.executor = args.executor
    for name in {pipe.executor} | {s.experiment.executor for s in pipe.stages}:
        if name is not None:
            preflight(name)
    job = PipelineRun.create(pipe, args.out, overwrite=args.force)
    job.checkpoint_every = args.checkpoint_every
    if not args.quiet:
        print(
            f"{pipe.name}: {len(pipe.stages)} stages ({', '.join(job.stage_names)}); "
            f"writing {job.path}"
        )
    return finish_pipeline(job, args)


def finish_pipeline(job, args) -> int:
    """Run (or resume) a pipeline and print where it ended (shared with ``resume``)."""
    from evo_door.experiment import Results
    from evo_door.experiment.pipeline_status import pipeline_summary
    from evo_door.reporting.format_text import format_pipeline, format_show

    if not interruptible(job, args, "the last finished generation of the running stage"):
        return 130
    if not args.quiet:
        print(format_pipeline(pipeline_summary(job.path)))
        for name in job.stage_names:
            print(f"\n== stage {name} ==")
            print(format_show(Results(job.path, name)))
        report_hint(job.path)
    return 0


def report_hint(path) -> None:
    print(f"\nevo-door show {path} --stage NAME looks at one stage again")
