"""``evo-door data import|show``: bring measured trials in, look at them."""

from __future__ import annotations

import math
from pathlib import Path

from evo_door.errors import UserError

ORDER = 40


def add_read_options(p, several: bool = True) -> None:
    """``--map``, ``--rate`` and ``--trial``: how a trial file is read (``data``, ``simulate``)."""
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
        action="append" if several else "store",
        metavar="ID",
        help="only this trial (id or position; HDF5 group or TDMS group)"
        + ("; repeatable" if several else "; needed when the file holds several"),
    )


def trial_selection(value):
    """``--trial`` values as read_trials takes them: positions as ints, ids as text."""
    if value is None:
        return None
    if isinstance(value, list):
        return [trial_selection(v) for v in value]
    return int(value) if value.lstrip("-").isdigit() else value


def check_positive(value, option: str) -> None:
    """A finite number above 0 (or None, not given), else a one-line error naming ``option``."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise UserError(f"{option} {value:g}: must be a number above 0")


def check_finite(value, option: str) -> None:
    """A finite number (or None), else a one-line error naming ``option``."""
    if value is not None and not math.isfinite(value):
        raise UserError(f"{option} {value:g}: must be a finite number")


def register(sub) -> None:
    p = sub.add_parser("data", help="import measured trials (CSV, HDF5, NI TDMS) and show them")
    dsub = p.add_subparsers(dest="data_command", metavar="ACTION")
    p.set_defaults(func=lambda args: p.print_help() or 2)

    imp = dsub.add_parser("import", help="read trial files, check them, write one HDF5 trial file")
    imp.add_argument("inputs", nargs="+", metavar="IN", help="trial files: .csv, .h5/.hdf5, .tdms")
    imp.add_argument("--out", required=True, metavar="OUT.h5", help="HDF5 trial file to write")
    add_read_options(imp)
    imp.add_argument("--user", metavar="ID", help="user id of the imported trials")
    imp.add_argument(
        "--kind",
        choices=("unlock", "lock", "impulse", "slow", "free", ""),
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
    imp.add_argument(
        "--force", action="store_true", help="replace OUT.h5 if it exists (else: refused)"
    )
    imp.set_defaults(func=run_import)

    show = dsub.add_parser(
        "show", help="summary table of a trial file; --plot draws force, angle and speed over time"
    )
    show.add_argument("path", metavar="TRIAL_FILE")
    add_read_options(show)
    show.add_argument("--plot", metavar="OUT.png", help="write the figure")
    show.set_defaults(func=run_show)


def _read(path, args, **fields):
    from evo_door.data.io import read_trials

    check_positive(args.rate, "--rate")
    return read_trials(
        path, trial_selection(args.trial) or "all", map=args.map, rate=args.rate, **fields
    )


#: s an import waits for another one writing the same trial file
LOCK_WAIT = 60.0


def run_import(args) -> int:
    # long: the import's steps in the order they run: claim the output, check
    # the options, read every input, preprocess, write, each refusal before any writing
    from evo_door.data import preprocess
    from evo_door.data.io import file_format, read_trials, write_trials
    from evo_door.data.trial import check_theta0
    from evo_door.files import TRIALS, Output, claim_outputs
    from evo_door.files.locks import FileLock

    if file_format(args.out) != "h5":
        raise UserError(f"--out {args.out}: write an HDF5 trial file (.h5)")
    claim = claim_outputs(
        [Output(args.out, kind=TRIALS)], args.inputs, force=args.force, append=args.append
    )
    # the trials' angle convention (0 fully open, pi/2 closed): 90 is a degree slip
    if args.theta0 is not None:
        check_theta0(args.theta0)
    check_finite(args.dtheta0, "--dtheta0")
    for option in ("rate", "lowpass", "resample"):
        check_positive(getattr(args, option), f"--{option}")
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
    # the file's lock over read, check and write: two imports at once both land (the
    # second waits) or one is refused, never one lost
    with FileLock(args.out).acquire("being written by another import", wait=LOCK_WAIT):
        if not (args.append or args.force) and Path(args.out).exists():
            raise UserError(
                f"--out {args.out}: a file is there already (another import made it just "
                "now); give --force to replace it or --append to add to its trials"
            )
        kept = read_trials(args.out) if args.append and Path(args.out).exists() else []
        clash = sorted(set(ids) & {t.trial_id for t in kept})
        if clash:
            raise UserError(
                f"{args.out} already holds trial(s) {', '.join(clash)}; "
                "give the new one another id (--id), or --force instead of --append to "
                "replace the file"
            )
        write_trials(args.out, kept + out)
    claim.note()
    if args.append:
        held = [t.trial_id for t in kept + out]
        print(f"added to {args.out}: {len(out)} trial(s): {', '.join(ids)}")
        print(f"{args.out} now holds {len(held)} trial(s): {', '.join(held)}")
    else:
        print(f"wrote {args.out}: {len(out)} trial(s): {', '.join(ids)}")
    return 0


def run_show(args) -> int:
    from evo_door.data.show import format_summary, plot_trials
    from evo_door.files import Output, claim_outputs

    claim = claim_outputs([Output(args.plot, "--plot")], [args.path])
    trials = _read(args.path, args)
    print(format_summary(trials, args.path))
    if args.plot:
        plot_trials(trials, args.plot, title=Path(args.path).name)
        print(f"wrote {args.plot}")
        claim.note()
    return 0
