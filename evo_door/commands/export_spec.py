"""``evo-door export-spec RUN.h5``: a fit's specification table (seed tables 5.3 / 5.4)."""

from __future__ import annotations

from evo_door.commands._common import add_allow_model

ORDER = 46

#: ``evo_door.experiment.spec.FORMATS``, written out so that the parser does not import
#: the experiment package (tests/test_cli_startup.py checks they agree).
FORMAT_NAMES = ("csv", "md", "tex", "html", "yaml")


def register(sub) -> None:
    p = sub.add_parser(
        "export-spec",
        help="a fit's specification table (symbol, unit, value, per-trial range, "
        "identifiability, tolerances against a chosen feel) as CSV, Markdown, LaTeX, "
        "HTML, or a parameter file",
    )
    p.add_argument("results", metavar="RUN.h5", help="results file (a run's or a pipeline's)")
    p.add_argument("--stage", metavar="NAME", help="the stage of a pipeline's results file")
    p.add_argument(
        "--format",
        default="md",
        metavar="|".join(FORMAT_NAMES),
        help="md (default), csv, tex (booktabs), html, or yaml: a parameter file that "
        "--params, experiments and the renderer read back",
    )
    p.add_argument("--out", metavar="FILE", help="write here (default: print)")
    add_allow_model(p)
    p.set_defaults(func=run)


def run(args) -> int:
    import sys

    from evo_door.errors import UserError
    from evo_door.experiment import Results
    from evo_door.experiment.spec import FORMATS, export
    from evo_door.files import Output, claim_outputs

    if args.format not in FORMATS:
        raise UserError(f"--format {args.format!r}: choose one of {', '.join(FORMATS)}")
    claim = claim_outputs([Output(args.out)], [args.results])
    text = export(
        Results(args.results, args.stage),  # one open
        args.format,
        args.out,
        log=lambda line: print(line, file=sys.stderr),
    )
    if args.out:
        print(f"wrote {args.out}")
        claim.note()
    else:
        print(text, end="")
    return 0
