"""``evo-door data import|show``: bring measured trials in, look at them."""

from __future__ import annotations

from pathlib import Path

from evo_door.errors import UserError

ORDER = 40


def _add_read_options(p) -> None:
    p.add_argument(
        "--map",
        action="append",
        default=[],
        metavar="CHANNEL=SOURCE[:UNIT]",
        help="take a channel (t, force, theta, dtheta, ddtheta) from a column / "
        "TDMS channel / dataset, in a unit: force=Fz:kN, dtheta=Gyro:deg/s, "
        "theta=Incl:-1*deg+90, t=Time:ms; repeatable",
    )
    p.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="expected sampling rate (an error if the file differs); builds the "
        "time axis of files without one",
    )
    p.add_argument(
        "--trial",
        action="append",
        metavar="ID",
        help="only this trial (id or position; HDF5 group or TDMS group); repeatable",
    )


def register(sub) -> None:
    p = sub.add_parser("data", help="import measured trials (CSV, HDF5, NI TDMS) and show them")
    dsub = p.add_subparsers(dest="data_command", metavar="ACTION")
    p.set_defaults(func=lambda args: p.print_help() or 2)

    imp = dsub.add_parser("import", help="read trial files, check them, write one HDF5 trial file")
    imp.add_argument("inputs", nargs="+", metavar="IN", help="trial files: .csv, .h5/.hdf5, .tdms")
    imp.add_argument("--out", required=True, metavar="OUT.h5", help="HDF5 trial file to write")
    _add_read_options(imp)
    imp.add_argument("--user", metavar="ID", help="user id of the imported trials")
    imp.add_argument(
        "--kind",
        choices=("unlock", "lock", "impulse", "free", ""),
        help="what the user did in these trials",
    )
    imp.add_argument(
        "--theta0",
        type=float,
        metavar="RAD",
        help="initial angle in rad (0 fully open, pi/2 closed)",
    )
    imp.add_argument(
        "--dtheta0", type=float, metavar="RAD_S", help="initial angular speed in rad/s"
    )
    imp.add_argument(
        "--id",
        dest="trial_id",
        metavar="ID",
        help="trial id (one trial only; default: file name / group name)",
    )
    imp.add_argument(
        "--rate-bias",
        choices=("start", "all"),
        help="subtract the gyroscope's bias, measured on the rest before the first "
        "motion (start) or on every rest run (all); done first",
    )
    imp.add_argument(
        "--lowpass", type=float, metavar="HZ", help="zero-phase low-pass every channel"
    )
    imp.add_argument("--resample", type=float, metavar="HZ", help="resample to this rate")
    imp.add_argument("--trim", action="store_true", help="cut to the motion (+0.2 s each side)")
    imp.add_argument(
        "--angle-from-rate",
        action="store_true",
        help="add theta integrated from dtheta (eq. 3.11, bias removed on rest "
        "segments); needs --theta0 or a theta0 in the file",
    )
    imp.add_argument("--append", action="store_true", help="keep the trials already in OUT.h5")
    imp.set_defaults(func=run_import)

    show = dsub.add_parser(
        "show", help="summary table of a trial file; --plot draws force, angle and speed over time"
    )
    show.add_argument("path", metavar="TRIAL_FILE")
    _add_read_options(show)
    show.add_argument("--plot", metavar="OUT.png", help="write the figure")
    show.set_defaults(func=run_show)


def _read(path, args, **fields):
    from evo_door.data.io import read_trials

    trials = args.trial
    if trials:
        trials = [int(t) if t.lstrip("-").isdigit() else t for t in trials]
    return read_trials(path, trials or "all", map=args.map, rate=args.rate, **fields)


def run_import(args) -> int:
    from evo_door.data import preprocess
    from evo_door.data.io import file_format, write_trials

    if file_format(args.out) != "h5":
        raise UserError(f"--out {args.out}: write an HDF5 trial file (.h5)")
    fields = {
        "user_id": args.user,
        "kind": args.kind,
        "theta0": args.theta0,
        "dtheta0": args.dtheta0,
    }
    trials = []
    for path in args.inputs:
        trials += _read(path, args, **{k: v for k, v in fields.items() if v is not None})
    if args.trial_id:
        if len(trials) != 1:
            raise UserError(f"--id needs exactly one trial, the inputs hold {len(trials)}")
        trials = [trials[0].replace(trial_id=args.trial_id)]
    out = []
    for tr in trials:
        if args.rate_bias:
            tr = preprocess.remove_rate_bias(tr, args.rate_bias)
        if args.resample:
            tr = preprocess.resample(tr, args.resample)
        if args.lowpass:
            tr = preprocess.lowpass_trial(tr, args.lowpass)
        if args.trim:
            tr = preprocess.trim_to_motion(tr)
        if args.angle_from_rate:
            tr = preprocess.add_angle_from_rate(tr)
        out.append(tr)
    ids = [t.trial_id for t in out]
    dup = {i for i in ids if ids.count(i) > 1}
    if dup:
        raise UserError(
            f"trial id(s) {', '.join(sorted(dup))} appear twice among the inputs; "
            "import them separately with --id or --append"
        )
    write_trials(args.out, out, append=args.append)
    print(f"wrote {args.out}: {len(out)} trial(s): {', '.join(ids)}")
    return 0


def run_show(args) -> int:
    from evo_door.data.show import format_summary, plot_trials

    trials = _read(args.path, args)
    print(format_summary(trials, args.path))
    if args.plot:
        plot_trials(trials, args.plot, title=Path(args.path).name)
        print(f"wrote {args.plot}")
    return 0
