"""``evo-door show RUN.h5``: best parameters, fitness, status and settings of a run."""

from __future__ import annotations

import json

from evo_door.commands._common import add_allow_model
from evo_door.errors import UserError

ORDER = 42


def register(sub) -> None:
    p = sub.add_parser("show", help="print a run's best parameters, fitness, status and settings")
    p.add_argument(
        "results",
        metavar="RUN.h5",
        help="results file (a run's or a pipeline's), a render log (a participant's session) "
        "or a JND file (evo-door jnd)",
    )
    p.add_argument(
        "--stage",
        metavar="NAME",
        help="one stage of a pipeline's results file (without it: every stage, after the "
        "pipeline's status)",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="one JSON object; its 'best' maps free parameter names to values, 'status' is "
        "complete, running or interrupted, 'at_bound' names the estimates on a bound",
    )
    p.add_argument("--plot", metavar="FIT.png", help="draw the best response next to the target")
    p.add_argument(
        "--convergence",
        metavar="CONV.png",
        help="draw the best and mean fitness per generation (an interrupted run: so far)",
    )
    add_allow_model(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.errors import NotResultsFileError
    from evo_door.experiment.reader import PipelineRecord, pick, read_results
    from evo_door.perception.jnd_file import is_jnd_file
    from evo_door.render.session import format_session, is_render_log, read_session

    try:
        record = read_results(args.results)  # the one open of a results file
    except NotResultsFileError:
        if is_jnd_file(args.results):
            return _show_jnd(args)
        if not is_render_log(args.results):
            raise
        return _show_session(args, format_session, read_session)
    if isinstance(record, PipelineRecord) and args.stage is None:
        return _show_pipeline(args, record)
    return _show_run(args, pick(record, args.stage))


def _show_session(args, format_session, read_session) -> int:
    """A renderer's log: the participant's session."""
    if args.stage or args.plot or args.convergence:
        raise UserError(
            f"{args.results}: a render log: --stage, --plot and --convergence are for "
            "results files (evo-door data show --plot draws a log)"
        )
    session = read_session(args.results)
    print(json.dumps(session) if args.json else format_session(session, args.results))
    return 0


def _show_jnd(args) -> int:
    """A JND file: the session and its estimate."""
    from evo_door.perception.jnd_file import read_jnd_file
    from evo_door.perception.jnd_show import format_jnd

    if args.stage or args.plot or args.convergence:
        raise UserError(
            f"{args.results}: a JND file: --stage, --plot and --convergence are for results "
            "files (evo-door report J.h5 draws its track and fit)"
        )
    record = read_jnd_file(args.results)
    print(json.dumps(record.summary()) if args.json else format_jnd(record))
    return 0


def _show_pipeline(args, record) -> int:
    """Every started stage of a pipeline's file, after the pipeline's status."""
    from evo_door.experiment import Results
    from evo_door.experiment.pipeline_status import pipeline_summary
    from evo_door.reporting.format_text import format_pipeline, format_show

    pipeline = pipeline_summary(record)
    if args.plot or args.convergence:
        names = ", ".join(s["name"] for s in pipeline["stages"])
        raise UserError(
            f"{args.results}: a pipeline: name the stage to draw with --stage ({names})"
        )
    stages = {name: Results.of(run) for name, run in record.runs.items()}
    if args.json:
        doc = {**pipeline, "stage_results": {n: r.summary() for n, r in stages.items()}}
        print(json.dumps(doc, indent=2))
    else:
        print(format_pipeline(pipeline))
        for name, res in stages.items():
            print(f"\n== stage {name} ==")
            print(format_show(res))
    return 0


def _show_run(args, run) -> int:
    """One run, or one stage of a pipeline's file, and its figures."""
    from evo_door.experiment import Results
    from evo_door.files import Output, check_image_path, claim_outputs
    from evo_door.reporting.figures import plot_convergence, plot_fit
    from evo_door.reporting.format_text import format_show

    claim = claim_outputs(
        [Output(args.plot, "--plot"), Output(args.convergence, "--convergence")], [args.results]
    )
    res = Results(args.results, args.stage, run)
    # both image names checked before either figure is written: a bad second one must
    # not leave the first behind
    for target in (args.plot, args.convergence):
        if target:
            check_image_path(target)
    # figures first: a figure that cannot be written stops before anything is printed
    if args.plot:
        plot_fit(res, args.plot)
    if args.convergence:
        plot_convergence(res, args.convergence)
    if args.json:
        print(json.dumps(res.summary(), indent=2))
    else:
        print(format_show(res))
        for written in (args.plot, args.convergence):
            if written:
                print(f"wrote {written}")
    claim.note()
    return 0
