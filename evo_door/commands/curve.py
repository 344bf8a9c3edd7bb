"""``evo-door curve MODEL``: the force-angle characteristic, opening and closing.

By default the **Coulomb curve**: the limit of slow motion, every dry friction at its
full level (tanh -> sign) and no viscous part. That is the curve a specification
reads (a 3 N friction reads 3 N, a 13 N latch peaks at 13 N) and the one to hold
against a just-noticeable difference; ``--speed RAD_S`` gives instead the curve felt at
a constant finite speed, with the model's tanh laws (at 0.02 rad/s the door's dry
frictions give only 63-87 % of their level). Either way the grid is refined where the
force changes fast, so that every latch peak is in the file
(:func:`~evo_door.sim.simulate.force_angle_curve`).
"""

from __future__ import annotations

import math

from evo_door.commands._common import (
    MODEL_HELP,
    add_channels_argument,
    add_params_arguments,
    model_and_params,
)
from evo_door.errors import UserError, WriteError

ORDER = 30
#: Least width (deg) of the panel next to closed in the plot.
ZOOM_DEG = 1.5
#: The panel widens to hold the latch found in the last SEARCH_DEG (deg).
SEARCH_DEG = 10.0
#: CSV header; ``speed`` is 0 on the rows of the Coulomb curve (its limit).
HEADER = "theta,force,direction,speed"


def register(sub) -> None:
    p = sub.add_parser(
        "curve",
        help="force a user needs to open / close the door slowly, against angle",
        description="Force-angle curve, opening and closing. Default: the Coulomb curve "
        "(slow-motion limit, dry friction at its full level); --speed RAD_S: the curve at "
        "that constant speed (tanh friction laws).",
    )
    p.add_argument("model", help=MODEL_HELP)
    add_params_arguments(p)
    add_channels_argument(p)
    p.add_argument(
        "--coulomb",
        action="store_true",
        help="the Coulomb curve: limit of slow motion, dry friction at its full level "
        "(tanh -> sign), no viscous part; the default",
    )
    p.add_argument(
        "--speed",
        type=float,
        metavar="RAD_S",
        help="instead, the curve at this constant speed (rad/s for a door, else the "
        "model's theta unit per second), with the model's tanh friction laws",
    )
    p.add_argument(
        "--points",
        type=int,
        default=721,
        help="uniform points from open to closed (default 721; [0, pi/2] for a door); "
        "points are added where the force changes fast (latch bands, friction reversals)",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="CURVE.csv",
        help="columns theta (rad for a door, else the model's unit), force (N, + toward "
        "closing), direction (opening|closing), speed (rad/s, the model's unit/s; 0 = the "
        "Coulomb curve)",
    )
    p.add_argument("--plot", metavar="CURVE.png", help="also draw the curves")
    p.set_defaults(func=run)


#: the most uniform points a curve takes (a hundredth of a milliradian over a door's
#: stroke; the refinement adds the fast parts on top)
MAX_POINTS = 100_000


def _check_options(args) -> None:
    """Every option before anything is computed or written (the targets:
    :func:`~evo_door.files.claim_outputs`)."""
    from evo_door.files import check_image_path

    if not 2 <= args.points <= MAX_POINTS:
        raise UserError(
            f"--points {args.points}: from 2 (both ends of the range) to {MAX_POINTS} "
            "(points are added where the force changes fast anyway)"
        )
    if args.speed is not None:
        if not (math.isfinite(args.speed) and args.speed > 0):
            raise UserError(f"--speed {args.speed:g}: must be a number above 0")
        if args.coulomb:
            raise UserError(
                f"--coulomb and --speed {args.speed:g}: give one (--coulomb, the default, "
                "is the limit of slow motion)"
            )
    if args.plot:
        # the CSV is written first: a plot that cannot be made must not leave it behind
        check_image_path(args.plot)


def run(args) -> int:
    from evo_door.files import Output, claim_outputs, write_text
    from evo_door.sim.simulate import force_angle_curve

    _check_options(args)
    model, params = model_and_params(args)
    claim = claim_outputs([Output(args.out), Output(args.plot, "--plot")], [params.source])
    curve = force_angle_curve(model, params, speed=args.speed, n=args.points)
    write_text(args.out, curve_csv(curve))
    print(f"wrote {args.out} ({describe(curve, model.theta_unit)})")
    for line in peak_lines(curve, model.theta_unit):
        print(f"  {line}")
    if args.plot:
        zoom = zoom_near_closed(curve, model.theta_range[1]) if model.theta_unit == "rad" else None
        try:
            plot_curve(
                curve,
                args.plot,
                title=f"{model.title}: force-angle curve\n{describe(curve, model.theta_unit)}",
                zoom=zoom,
                unit=model.theta_unit,
            )
        except WriteError as exc:  # a full disk: the table is whole, and stays
            raise exc.leaving(
                f"nothing was written to it; {args.out}, written before, is kept"
            ) from None
        print(f"wrote {args.plot}")
    claim.note()
    return 0


def zoom_near_closed(curve, closed) -> dict:
    """The part of ``curve`` near ``closed`` (rad) where the latch is: a second panel.

    Latch bands are a fraction of a degree wide. The panel spans the points the curve
    added in the last :data:`SEARCH_DEG` (where it changes fast), plus a quarter of
    that on the open side, at least the last :data:`ZOOM_DEG`.
    """
    import numpy as np

    theta = curve["theta"]
    near = curve["added"] & (theta >= closed - np.radians(SEARCH_DEG))
    lo = closed - np.radians(ZOOM_DEG)
    if near.any():
        first = theta[near].min()
        lo = min(lo, first - 0.25 * (closed - first))
    inside = theta >= lo
    return {d: curve[d][inside] for d in ("theta", "opening", "closing")}


def curve_csv(curve) -> str:
    """The CSV text: :data:`HEADER`, then the opening rows, then the closing rows."""
    import numpy as np

    lines = [HEADER]
    speed = f"{curve['speed']:.10g}"
    for direction in ("opening", "closing"):
        # rounding leaves +-1e-16 N where the force is zero: written as 0
        force = np.where(np.abs(curve[direction]) < 1e-12, 0.0, curve[direction])
        lines += [f"{th:.10g},{f:.10g},{direction},{speed}" for th, f in zip(curve["theta"], force)]
    return "\n".join(lines) + "\n"


def describe(curve, unit="rad") -> str:
    """Which curve it is, in words, with the speed and its unit."""
    if curve["coulomb"]:
        return "Coulomb curve: slow-motion limit, dry friction at its full level"
    return f"at {curve['speed']:g} {unit}/s, tanh friction laws"


def peak_lines(curve, unit="rad") -> list[str]:
    """The extreme forces of each direction and where they are, with units."""
    import numpy as np

    def where(i):
        t = curve["theta"][i]
        return f"{np.degrees(t):.3f} deg" if unit == "rad" else f"{t:.6g} {unit}"

    lines = []
    for direction in ("opening", "closing"):
        f = curve[direction]
        lo, hi = int(np.argmin(f)), int(np.argmax(f))
        lines.append(
            f"{direction}: max {f[hi]:.3f} N at {where(hi)}, min {f[lo]:.3f} N at {where(lo)}"
        )
    return lines


def plot_curve(curve, path, title="", zoom=None, unit="rad") -> None:
    """Write :func:`curve_figure` to ``path`` (the format from its extension)."""
    from evo_door.files import save_figure

    save_figure(curve_figure(curve, title, zoom, unit), path, dpi=120)


def curve_figure(curve, title="", zoom=None, unit="rad"):
    """The opening and closing curves; ``zoom`` (a second curve) gets its own panel.

    ``unit`` is the unit of ``theta``: angles in rad are drawn in degrees.
    """
    import numpy as np
    from matplotlib.figure import Figure

    panels = [curve] if zoom is None else [curve, zoom]
    fig = Figure(figsize=(7 + 3.5 * (len(panels) - 1), 4.4), layout="constrained")
    axes = fig.subplots(
        1, len(panels), squeeze=False, gridspec_kw={"width_ratios": [2, 1][: len(panels)]}
    )
    for ax, c in zip(axes[0], panels):
        x = np.degrees(c["theta"]) if unit == "rad" else c["theta"]
        ax.plot(x, c["opening"], label="opening (dtheta < 0)", color="tab:blue")
        ax.plot(x, c["closing"], label="closing (dtheta > 0)", color="tab:red")
        ax.axhline(0.0, color="0.6", lw=0.8)
        ax.grid(alpha=0.3)
    ax = axes[0][0]
    ax.set_xlabel(
        "door angle theta [deg]  (0 = open, 90 = closed)"
        if unit == "rad"
        else f"theta [{unit}]  (from open to closed)"
    )
    ax.set_ylabel("user force at the handle [N]  (+ toward closing)")
    if zoom is not None:
        axes[0][1].set_ylabel("user force at the handle [N]")
    fig.suptitle(title, fontsize=10)
    ax.legend()
    if zoom is not None:
        axes[0][1].set_xlabel("theta [deg], near closed")
        axes[0][1].set_title(
            f"latch, last {np.ptp(np.degrees(zoom['theta'])):.3g} deg", fontsize=10
        )
    return fig
