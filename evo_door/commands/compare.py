"""``evo-door compare RUN1.h5 RUN2.h5 ...``: runs side by side.

A pipeline's results file holds one run per stage: ``--stage S`` takes stage S of every
pipeline given (a run's own file is compared as it is), and ``FILE:STAGE`` takes one
stage of one file, so a run can face a stage, or two stages of one pipeline each other.
"""

from __future__ import annotations

import json
from pathlib import Path

from evo_door.commands._common import add_allow_model
from evo_door.errors import UserError

ORDER = 44


def register(sub) -> None:
    p = sub.add_parser(
        "compare",
        help="runs side by side: status, objective, fitness, parameters, errors, timings "
        "and the settings that differ",
    )
    p.add_argument(
        "results",
        metavar="RUN.h5",
        nargs="+",
        help="two results files or more; PIPELINE.h5:STAGE is one stage of a pipeline's file",
    )
    p.add_argument(
        "--stage",
        metavar="NAME",
        help="the stage to compare of every pipeline's file given without its own :STAGE "
        "(a run's own file is compared as it is)",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="one JSON object: 'runs' (one entry per file, in order), 'differences' "
        "(dotted setting -> value per run)",
    )
    add_allow_model(p)
    p.set_defaults(func=run)


def split_stage(arg: str) -> tuple[str, str | None]:
    """``P.h5:STAGE`` -> (``P.h5``, ``STAGE``); a name that is a file stays whole.

    >>> split_stage("results/case.h5:latch")
    ('results/case.h5', 'latch')
    >>> split_stage("results/run.h5")
    ('results/run.h5', None)
    """
    if Path(arg).exists() or ":" not in arg:
        return arg, None
    path, stage = arg.rsplit(":", 1)
    if not stage.strip():
        raise UserError(f"{arg}: name the stage after the colon (FILE.h5:STAGE)")
    return path, stage.strip()


def chosen_runs(args) -> list:
    """The run (a :class:`~evo_door.experiment.reader.RunRecord`) for each RUN.h5 given:
    its own :STAGE, else --stage for a pipeline. Each file is read once, however many
    of its stages are compared."""
    from evo_door.experiment.reader import PipelineRecord, pick, read_results

    records = {}
    chosen = []
    any_pipeline = False
    for arg in args.results:
        path, stage = split_stage(arg)
        if path not in records:  # a missing or foreign file: one line here
            records[path] = read_results(path)
        record = records[path]
        pipeline = isinstance(record, PipelineRecord)
        any_pipeline |= pipeline
        if pipeline and stage is None:
            stage = args.stage
            if stage is None:
                names = ", ".join(record.stages)
                raise UserError(
                    f"{path}: a pipeline of stages {names}: name the stage to compare with "
                    f"--stage NAME, or {path}:NAME for this file alone"
                )
        chosen.append((path, stage, record))
    if args.stage is not None and not any_pipeline:
        raise UserError(
            f"--stage {args.stage}: none of the files given is a pipeline's; each holds one run"
        )
    return [(path, stage, pick(record, stage)) for path, stage, record in chosen]


def run(args) -> int:
    from evo_door.experiment import Results
    from evo_door.reporting.format_json import compare
    from evo_door.reporting.format_tables import format_compare

    if len(args.results) < 2:
        raise UserError(f"compare needs two results files or more, got only {args.results[0]}")
    doc = compare([Results(path, stage, run) for path, stage, run in chosen_runs(args)])
    print(json.dumps(doc, indent=2) if args.json else format_compare(doc))
    return 0
