"""``evo-door report RUN.h5``: one self-contained HTML page, figures embedded."""

from __future__ import annotations

import sys

from evo_door.commands._common import add_allow_model

ORDER = 47

#: The force JND's defaults (``DEFAULT_JND``, ``FORCE_FLOOR`` N of
#: :mod:`evo_door.reporting.report`, the :class:`~evo_door.perception.JND`'s), for the help
#: only, written out so that the parser does not import the experiment package
#: (tests/test_cli_startup.py checks they agree).
DEFAULT_JND = 0.10
FORCE_FLOOR = 0.5


def register(sub) -> None:
    p = sub.add_parser(
        "report",
        help="one self-contained HTML page of a run or a pipeline (figures embedded, and "
        "as PNG): convergence, fits, parameter tables, identifiability, the perceptual check",
    )
    p.add_argument(
        "results",
        metavar="RUN.h5",
        help="results file (a run's or a pipeline's), or a JND file (its track and fit)",
    )
    p.add_argument(
        "--out", metavar="DIR", help="folder of the page and its figures (default RUN-report/)"
    )
    p.add_argument(
        "--jnd",
        type=float,
        help="force just-noticeable difference, a fraction, for every perceptual check "
        "(default: the pipeline file's report.jnd, else each run's perception.force, "
        f"by default {DEFAULT_JND:g})",
    )
    p.add_argument(
        "--force-floor",
        type=float,
        metavar="N",
        help="the smallest force JND, N (default: the pipeline file's report.force_floor, "
        f"else each run's perception.force_floor, by default {FORCE_FLOOR:g} N)",
    )
    p.add_argument(
        "--jnd-file",
        action="append",
        default=[],
        metavar="J.h5",
        help="a JND file (evo-door jnd): its measured Weber fraction judges every "
        "perceptual check instead of the run's (repeatable; several on one setting: "
        "their geometric mean); not with --jnd on the force JND",
    )
    add_allow_model(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from evo_door.errors import NotResultsFileError
    from evo_door.experiment.pipeline_status import pipeline_summary
    from evo_door.experiment.reader import read_results
    from evo_door.files import Output, claim_outputs, partial_output
    from evo_door.perception.jnd_file import is_jnd_file
    from evo_door.reporting.report import default_folder, pipeline_settings, write_report

    try:
        record = read_results(args.results)  # the one open of a results file
    except NotResultsFileError:
        if is_jnd_file(args.results):
            return _report_jnd(args)
        raise

    def log(text):
        if sys.stderr.isatty():
            print(text, file=sys.stderr, flush=True)

    # the page and its figures are derived: a report made again replaces them (and
    # says so); the folder is made if need be, never where the results file is
    folder = Path(args.out) if args.out else default_folder(args.results)
    claim = claim_outputs([Output(folder / "report.html", makes_folder=True)], [args.results])
    settings = pipeline_settings(
        record, pipeline_summary(record), args.jnd, args.force_floor, args.jnd_file
    )
    with partial_output(folder):  # a full disk: no half report left behind
        page = write_report(record, args.out, settings, log)
    print(f"wrote {page} (and its figures as PNG in {page.parent})")
    claim.note()
    return 0


def _report_jnd(args) -> int:
    """A JND file's page: the session, its track and its psychometric fit."""
    from pathlib import Path

    from evo_door.errors import UserError
    from evo_door.files import Output, claim_outputs, partial_output
    from evo_door.perception.jnd_file import read_jnd_file
    from evo_door.reporting.report_jnd import default_jnd_folder, write_jnd_report

    if args.jnd is not None or args.force_floor is not None:
        raise UserError(
            f"{args.results}: a JND file: --jnd and --force-floor are for results files"
        )
    folder = Path(args.out) if args.out else default_jnd_folder(args.results)
    claim = claim_outputs([Output(folder / "report.html", makes_folder=True)], [args.results])
    with partial_output(folder):
        page = write_jnd_report(read_jnd_file(args.results), folder)
    print(f"wrote {page} (and its figures as PNG in {page.parent})")
    claim.note()
    return 0
