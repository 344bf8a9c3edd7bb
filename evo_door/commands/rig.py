"""``evo-door rig generate``: trials from the virtual test rig (known true parameters)."""

from __future__ import annotations

from evo_door.commands._common import (
    MODEL_HELP,
    add_channels_argument,
    add_params_arguments,
    model_and_params,
)
from evo_door.errors import UserError

ORDER = 45


#: the largest campaign the virtual rig makes (each trial some seconds at 1 kHz)
MAX_USERS = 1000
MAX_TRIALS = 10_000


def register(sub) -> None:
    p = sub.add_parser("rig", help="virtual test rig: generate realistic trials from a model")
    rsub = p.add_subparsers(dest="rig_command", metavar="ACTION")
    p.set_defaults(func=lambda args: p.print_help() or 2)
    g = rsub.add_parser(
        "generate",
        help="simulate a measurement campaign (unlock, lock, impulse and slow "
        "trials by virtual users, seed sensors)",
    )
    g.add_argument("--model", required=True, help=MODEL_HELP)
    add_params_arguments(g)
    add_channels_argument(g)
    g.add_argument("--users", type=int, default=3, help="number of virtual users (default 3)")
    g.add_argument("--trials", type=int, default=10, help="number of trials (default 10)")
    g.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    g.add_argument(
        "--kinds",
        default=None,
        help="kinds cycled over the trials: unlock, lock, impulse, slow (the stroke opened "
        "from closed and closed again at 0.07-0.21 rad/s: friction and spring apart from "
        "inertia); default impulse,unlock,impulse,lock, keeping the kinds the model supports",
    )
    g.add_argument("--rate", type=float, default=1024.0, help="sampling rate in Hz (default 1024)")
    g.add_argument(
        "--all-sensors",
        action="store_true",
        help="record force, inclinometer and gyroscope in every trial (default: "
        "the seed's pairs: inclinometer for unlock/lock, gyroscope for impulse)",
    )
    g.add_argument(
        "--truth",
        default="model",
        metavar="TRUTH",
        help="what the rig simulates: 'model' (default: the model itself) or 'rich' (the "
        "physical door with Stribeck friction, handle play and sensor dynamics, "
        "docs/model-mismatch.md; --model door)",
    )
    g.add_argument(
        "--truth-set",
        metavar="NAME=VALUE",
        action="append",
        default=[],
        dest="truth_assignments",
        help="override one parameter of the rich truth (SI units; e.g. stribeck_ratio=2); "
        "repeatable",
    )
    g.add_argument(
        "--out",
        required=True,
        metavar="OUT.h5",
        help="trial file (.h5; .csv for a single trial; .tdms)",
    )
    g.add_argument("--force", action="store_true", help="replace OUT if it exists (else: refused)")
    g.set_defaults(func=run_generate)


def run_generate(args) -> int:
    from evo_door.data.io import file_format, write_trials
    from evo_door.data.rig import (
        Campaign,
        RigSettings,
        generate_trials,
        make_truth,
        params_source,
    )
    from evo_door.data.show import format_summary
    from evo_door.files import TRIALS, Output, claim_outputs
    from evo_door.params import parse_assignments

    file_format(args.out)
    if not (1 <= args.users <= MAX_USERS and 1 <= args.trials <= MAX_TRIALS):
        raise UserError(
            f"--users {args.users} --trials {args.trials}: from 1 to {MAX_USERS} users and "
            f"{MAX_TRIALS} trials (a campaign larger than any lab's)"
        )
    if args.rate <= 0:
        raise UserError("--rate must be positive")
    if args.seed < 0:
        raise UserError("--seed must be a whole number >= 0")
    model, params = model_and_params(args)
    claim = claim_outputs([Output(args.out, kind=TRIALS)], [params.source], force=args.force)
    truth = make_truth(
        model, params, args.truth, parse_assignments(args.truth_assignments, "--truth-set")
    )
    kinds = None if args.kinds is None else [k.strip() for k in args.kinds.split(",") if k.strip()]
    trials = generate_trials(
        model,
        params,
        Campaign(users=args.users, trials=args.trials, seed=args.seed, kinds=kinds),
        RigSettings(rate=args.rate, all_sensors=args.all_sensors),
        truth,
    )
    rich = "" if truth is None else f", truth {truth.name} ({truth.values.source})"
    write_trials(
        args.out,
        trials,
        description=f"virtual rig: model {model.name}, "
        f"params {params_source(model, params) or 'defaults'}, "
        f"{args.users} users, {args.trials} trials, seed {args.seed}{rich}",
    )
    print(format_summary(trials, args.out, model.theta_unit))
    print(f"wrote {args.out}")
    claim.note()
    return 0
