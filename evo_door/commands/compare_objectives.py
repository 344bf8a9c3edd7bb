"""``evo-door compare-objectives EXP.yaml``: max-square against ISE, per derivative and seed."""

from __future__ import annotations

import sys

from evo_door.commands._common import add_progress_arguments, show_progress

ORDER = 45


def register(sub) -> None:
    # long: the command's options, one call each, in the order --help lists them
    p = sub.add_parser(
        "compare-objectives",
        help="the same estimation under max-square and ISE on derivatives 0, 1, 2 and "
        "several GA seeds: estimates, errors against the truth, validation error, "
        "evaluations and time side by side (CSV, Markdown, figure)",
    )
    p.add_argument("experiment", metavar="EXP.yaml", help="experiment file (docs/experiments.md)")
    p.add_argument(
        "--kinds",
        default="max_square,ise",
        metavar="K1,K2",
        help="objective kinds compared (default max_square,ise)",
    )
    p.add_argument(
        "--derivatives",
        metavar="0,1,2",
        help="derivatives compared: 0 angle, 1 angular speed, 2 acceleration (default: "
        "every one whose channel the trials carry; the others are left out with a note)",
    )
    p.add_argument(
        "--seeds",
        default="1",
        metavar="N",
        help="GA seeds per objective: the experiment's algorithm.seed + 0 .. N-1 (default 1)",
    )
    p.add_argument(
        "--set",
        metavar="KEY.PATH=VALUE",
        action="append",
        default=[],
        dest="assignments",
        help="override a setting of the experiment for every run, e.g. "
        "algorithm.generations=40; repeatable",
    )
    p.add_argument(
        "--out",
        metavar="DIR",
        help="folder of the runs (one results file each) and of compare.csv, compare.md, "
        "compare.png, runs.csv (default: results/<name>-objectives-<date>-<time>/)",
    )
    again = p.add_mutually_exclusive_group()
    again.add_argument(
        "--force", action="store_true", help="replace runs of this comparison already in --out"
    )
    again.add_argument(
        "--resume",
        action="store_true",
        help="keep the complete runs already in --out (same settings), continue an "
        "interrupted one, run the rest",
    )
    p.add_argument(
        "--stage",
        metavar="NAME",
        help="EXP.yaml is a pipeline: compare on this stage (docs/case-study.md)",
    )
    p.add_argument(
        "--from",
        dest="from_results",
        metavar="RUN.h5",
        help="with --stage: the pipeline's results file, for a stage that starts from "
        "earlier stages ({from: STAGE})",
    )
    add_progress_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    # long: the command's steps in the order they run: read the options, plan,
    # say what runs, run (Ctrl-C: how to continue), write, print
    from evo_door.errors import UserError
    from evo_door.experiment.comparison import (
        make_folder,
        parse_derivatives,
        parse_kinds,
        parse_seeds,
        plan_comparison,
        run_comparison,
    )
    from evo_door.experiment.comparison_summary import run_records, summarise
    from evo_door.reporting.comparison_outputs import format_summary, write_outputs

    kinds = parse_kinds(args.kinds)
    derivatives = None if args.derivatives is None else parse_derivatives(args.derivatives)
    seeds = parse_seeds(args.seeds)
    loader = None
    if args.stage is not None:
        from evo_door.experiment.pipeline import stage_loader

        loader = stage_loader(args.experiment, args.stage, args.from_results)
    elif args.from_results is not None:
        raise UserError("--from goes with --stage: the results of a pipeline's earlier stages")
    comp = plan_comparison(
        args.experiment,
        args.assignments,
        kinds,
        derivatives,
        seeds,
        args.out,
        force=args.force,
        resume=args.resume,
        loader=loader,
    )
    n = len(comp.variants)
    make_folder(comp)
    if not args.quiet:
        print(
            f"{comp.name}: {n} run(s): {', '.join(comp.kinds)} on derivative(s) "
            f"{', '.join(map(str, comp.derivatives))}, seed(s) "
            f"{', '.join(map(str, comp.seeds))}; writing {comp.folder}/"
        )
        for note in comp.notes():
            print(f"note: {note}")
    try:
        run_comparison(comp, progress=show_progress(args))
    except KeyboardInterrupt:
        print(
            f"evo-door: interrupted; the runs done so far are in {comp.folder}; the same "
            f"command with --out {comp.folder} --resume continues the comparison",
            file=sys.stderr,
        )
        return 130
    records = run_records(comp)
    rows = summarise(records)
    paths = write_outputs(comp, records, rows)
    if not args.quiet:
        print()
        print(format_summary(comp, rows))
        print(f"\nwrote {', '.join(str(p) for p in paths)}")
        print(f"each run: evo-door show FILE; all of them: evo-door runs {comp.folder}")
    return 0
