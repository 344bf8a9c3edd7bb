"""``evo-door simulate MODEL``: response of a model to a sampled input force."""

from __future__ import annotations

from evo_door.commands._common import MODEL_HELP, add_params_arguments, model_and_params
from evo_door.data.forcecsv import read_force_csv
from evo_door.errors import UserError
from evo_door.sim import METHODS, simulate

ORDER = 20


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
        help="columns t (s) and force (N, tangential at the handle, + toward closing)",
    )
    p.add_argument(
        "--theta0",
        type=float,
        default=None,
        metavar="RAD",
        help="initial angle in rad (0 open, pi/2 closed); default: the model's",
    )
    p.add_argument(
        "--dtheta0",
        type=float,
        default=0.0,
        metavar="RAD_S",
        help="initial angular speed in rad/s (default 0)",
    )
    p.add_argument(
        "--method", choices=sorted(METHODS), help="integration scheme (default: the model's)"
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
    model, params = model_and_params(args)
    if args.substeps is not None and args.substeps < 1:
        raise UserError("--substeps must be at least 1")
    t, force = read_force_csv(args.input)
    dt = float(t[1] - t[0])
    response = simulate(
        model,
        params,
        force,
        dt,
        theta0=args.theta0,
        dtheta0=args.dtheta0,
        t0=float(t[0]),
        method=args.method,
        substeps=args.substeps,
    )
    response.to_csv(args.out)
    if not response.ok:
        raise UserError(
            f"simulation blew up (non-finite state); {args.out} holds NaN from "
            "that point: try --method semi_implicit or more --substeps"
        )
    print(
        f"wrote {args.out}: {t.size} samples, {t[-1] - t[0]:.3f} s, "
        f"theta {response.theta.min():.4f}..{response.theta.max():.4f} {model.theta_unit}"
    )
    return 0
