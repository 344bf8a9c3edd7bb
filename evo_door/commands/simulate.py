"""``evo-door simulate MODEL``: response of a model to a sampled input force."""

from __future__ import annotations

import sys

from evo_door.commands._common import (
    MODEL_HELP,
    Range,
    add_channels_argument,
    add_params_arguments,
    check_ranges,
    declare_ranges,
    model_and_params,
)
from evo_door.commands.data import add_read_options, check_finite, check_positive, trial_selection
from evo_door.errors import UserError

ORDER = 20

#: the numeric flags' ranges, checked before any work (dopri5's tolerance per step,
#: rad and rad/s; 1 itself is refused by the integrators: no error is allowed that big)
RANGES = {
    "--tolerance": Range(1e-13, 0.5),  # (evo_door.sim.simulate.TOLERANCE_FLOOR and up)
    "--substeps": Range(1, 1000, integer=True),
}

#: How far (a fraction of the model's range: 4.5 deg for a door) a response may pass an
#: end of the range before it is pointed out. The end stops are stiff springs that a
#: hand's push of 200 N presses in by less than that (tests/test_outputs.py checks it
#: for the door and the haptic model); a force read in kN instead of N goes far beyond.
RANGE_MARGIN = 0.05

#: The integration schemes, ``sorted(evo_door.sim.METHODS)``: written out so that the
#: parser does not import numba (tests/test_cli_startup.py checks they agree).
METHOD_NAMES = ("dopri5", "rk4", "semi_implicit")


def register(sub) -> None:
    p = sub.add_parser(
        "simulate", help="simulate a model's response to an input force (CSV in, CSV out)"
    )
    p.add_argument("model", help=MODEL_HELP)
    add_params_arguments(p)
    add_channels_argument(p)
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
        "default: the input file's theta0, else the model's (an FMU's own start value)",
    )
    p.add_argument(
        "--dtheta0",
        type=float,
        default=None,
        metavar="RAD_S",
        help="initial angular speed in rad/s (default: the input file's dtheta0, else 0; "
        "an FMU's own start value)",
    )
    p.add_argument(
        "--method", choices=METHOD_NAMES, help="integration scheme (default: the model's)"
    )
    p.add_argument(
        "--substeps", type=int, help="integration steps per input sample (default: the model's)"
    )
    p.add_argument(
        "--tolerance",
        metavar="TOL",
        help="dopri5's tolerance per step, in rad and rad/s (default: the model's)",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="OUT.csv",
        help="output columns t, force, theta, dtheta, ddtheta (SI)",
    )
    declare_ranges(p, RANGES)
    p.set_defaults(func=run)


def run(args) -> int:
    from evo_door.data.forcecsv import read_force
    from evo_door.data.trial import check_theta0
    from evo_door.files import Output, claim_outputs
    from evo_door.sim import simulate

    check_ranges(args)
    model, params = model_and_params(args)
    claim = claim_outputs([Output(args.out)], [args.input, params.source])
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
    if dtheta0 is None:  # else the model's own (0 at rest; an FMU's start value)
        dtheta0 = inp.dtheta0
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
        tolerance=args.tolerance,
    )
    response.to_csv(args.out)
    claim.note()
    outside = range_warning(model, response)
    if outside:
        print(f"evo-door: warning: {outside}", file=sys.stderr)
    if not response.ok:
        raise UserError(
            f"simulation blew up (non-finite state); {args.out} holds NaN from "
            "that point: try --method dopri5, a smaller --tolerance or more --substeps"
        )
    print(
        f"wrote {args.out}: {inp.n} samples at {inp.rate:.6g} Hz, {inp.duration:.3f} s, "
        f"theta {response.theta.min():.4f}..{response.theta.max():.4f} {model.theta_unit}"
    )
    return 0


def range_warning(model, response) -> str | None:
    """What to say when ``response`` leaves the model's physical range (None if not).

    The range is ``model.theta_range`` (fully open to closed; the door and the haptic
    model both keep the default 0..pi/2 rad, held by their end stops). A response that
    passes an end by more than :data:`RANGE_MARGIN` of the range is most likely driven
    by a force in the wrong unit or sign, which the simulation itself cannot tell.
    """
    import numpy as np

    lo, hi = (float(v) for v in model.theta_range)
    theta = response.theta[np.isfinite(response.theta)]
    if theta.size == 0:
        return None
    margin = RANGE_MARGIN * (hi - lo)
    low, high = float(theta.min()), float(theta.max())
    if lo - margin <= low and high <= hi + margin:
        return None
    worst = high if high - hi >= lo - low else low
    at = float(response.t[int(np.flatnonzero(response.theta == worst)[0])])
    end = "closed" if worst > hi else "fully open"
    if model.theta_unit == "rad":
        reach, span = f"{np.degrees(worst):.1f} deg", f"{np.degrees(lo):g}..{np.degrees(hi):g} deg"
    else:
        unit = model.theta_unit
        reach, span = f"{worst:.4g} {unit}", f"{lo:.4g}..{hi:.4g} {unit}"
    return (
        f"the response reaches {reach} at t = {at:.3f} s, past {end}: outside the "
        f"model's range {span} (fully open..closed); is the force in N (--map force=COL:UNIT)?"
    )
