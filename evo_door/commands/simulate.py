"""``evo-door simulate MODEL``: response of a model to a sampled input force."""

from __future__ import annotations

from evo_door.commands._common import MODEL_HELP, add_params_arguments, model_and_params
from evo_door.commands.data import add_read_options, check_finite, check_positive, trial_selection
from evo_door.errors import UserError

ORDER = 20

#: The integration schemes, ``sorted(evo_door.sim.METHODS)``: written out so that the
#: parser does not import numba (tests/test_cli_startup.py checks they agree).
METHOD_NAMES = ("rk4", "semi_implicit")


def register(sub) -> None:
    p = sub.add_parser(
        "simulate", help="simulate a model's response to an input force (CSV in, CSV out)"
    )
    p.add_argument("model", help=MODEL_HELP)
    add_params_arguments(p)
    p.add_argument(
        "--input",
        required=True,
        metavar="IN.csv",
        help="a trial file (.csv, .h5, .tdms) read as `data import` reads it: time t (s; "
        "or --rate) and force (N, tangential at the handle, + toward closing); other "
        "channels are not used",
    )
    add_read_options(p, several=False)
    p.add_argument(
        "--theta0",
        type=float,
        default=None,
        metavar="RAD",
        help="initial angle in rad (0 open, pi/2 closed; a model's own unit otherwise); "
        "default: the input file's theta0, else the model's",
    )
    p.add_argument(
        "--dtheta0",
        type=float,
        default=None,
        metavar="RAD_S",
        help="initial angular speed in rad/s (default: the input file's dtheta0, else 0)",
    )
    p.add_argument(
        "--method", choices=METHOD_NAMES, help="integration scheme (default: the model's)"
    )
    p.add_argument(
        "--substeps", type=int, help="integration steps per input sample (default: the model's)"
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="OUT.csv",
        help="output columns t, force, theta, dtheta, ddtheta (SI)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.data.forcecsv import read_force
    from evo_door.data.trial import check_theta0
    from evo_door.files import Output, claim_outputs
    from evo_door.sim import simulate

    model, params = model_and_params(args)
    claim = claim_outputs([Output(args.out)], [args.input, params.source])
    if args.substeps is not None and args.substeps < 1:
        raise UserError(f"--substeps {args.substeps}: must be at least 1")
    check_positive(args.rate, "--rate")
    check_finite(args.dtheta0, "--dtheta0")
    if args.theta0 is not None:
        check_theta0(args.theta0, model.theta_range, model.theta_unit)
    inp = read_force(args.input, map=args.map, rate=args.rate, trial=trial_selection(args.trial))
    # the initial state: the options, else what the input file says, else the model's rest
    theta0, dtheta0 = args.theta0, args.dtheta0
    if theta0 is None and inp.theta0 is not None:
        theta0 = check_theta0(
            inp.theta0, model.theta_range, model.theta_unit, f"{args.input}: theta0"
        )
    if dtheta0 is None:
        dtheta0 = inp.dtheta0 if inp.dtheta0 is not None else 0.0
    response = simulate(
        model,
        params,
        inp.force,
        inp.dt,
        theta0=theta0,
        dtheta0=dtheta0,
        t0=float(inp.t[0]),
        method=args.method,
        substeps=args.substeps,
    )
    response.to_csv(args.out)
    claim.note()
    if not response.ok:
        raise UserError(
            f"simulation blew up (non-finite state); {args.out} holds NaN from "
            "that point: try --method semi_implicit or more --substeps"
        )
    print(
        f"wrote {args.out}: {inp.n} samples at {inp.rate:.6g} Hz, {inp.duration:.3f} s, "
        f"theta {response.theta.min():.4f}..{response.theta.max():.4f} {model.theta_unit}"
    )
    return 0
