"""``evo-door curve MODEL``: quasi-static force-angle characteristic."""

from __future__ import annotations

import math
import os

import numpy as np

from evo_door.commands._common import MODEL_HELP, add_params_arguments, model_and_params
from evo_door.errors import UserError
from evo_door.files import check_folder, check_image_path, save_figure, write_text
from evo_door.sim import quasi_static_curve

ORDER = 30
#: Width (deg) of the panel next to closed in the plot.
ZOOM_DEG = 1.5


def register(sub) -> None:
    p = sub.add_parser(
        "curve", help="force a user needs to open / close the door slowly, against angle"
    )
    p.add_argument("model", help=MODEL_HELP)
    add_params_arguments(p)
    p.add_argument(
        "--speed",
        type=float,
        default=0.02,
        metavar="RAD_S",
        help="constant speed of the slow motion (default 0.02 rad/s; in the "
        "model's theta unit per second)",
    )
    p.add_argument(
        "--points",
        type=int,
        default=721,
        help="points from open to closed (default 721; [0, pi/2] for a door)",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="CURVE.csv",
        help="columns theta (rad for a door, else the model's unit), force (N, + "
        "toward closing), direction (opening|closing)",
    )
    p.add_argument("--plot", metavar="CURVE.png", help="also draw the curves")
    p.set_defaults(func=run)


def _check_options(args) -> None:
    """Every option and target before anything is computed or written."""
    if args.points < 2:
        raise UserError(f"--points {args.points}: must be at least 2 (both ends of the range)")
    if not (math.isfinite(args.speed) and args.speed > 0):
        raise UserError(f"--speed {args.speed:g}: must be a number above 0")
    targets = [args.out] + ([args.plot] if args.plot else [])
    for target in targets:
        folder = check_folder(target).parent
        if not os.access(folder, os.W_OK):
            raise UserError(f"{target}: cannot write in {folder}")
    if args.plot:
        # the CSV is written first: a plot that cannot be made must not leave it behind
        check_image_path(args.plot)


def run(args) -> int:
    _check_options(args)
    model, params = model_and_params(args)
    lo, hi = model.theta_range
    curve = quasi_static_curve(model, params, n=args.points, speed=args.speed, lo=lo, hi=hi)
    lines = ["theta,force,direction"]
    for direction in ("opening", "closing"):
        lines += [
            f"{th:.10g},{f:.10g},{direction}" for th, f in zip(curve["theta"], curve[direction])
        ]
    write_text(args.out, "\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    if args.plot:
        # latch bands are a fraction of a degree wide: a second panel resolves them
        zoom = None
        if model.theta_unit == "rad":
            zoom = quasi_static_curve(
                model, params, n=4001, speed=args.speed, lo=hi - np.radians(ZOOM_DEG), hi=hi
            )
        plot_curve(
            curve,
            args.plot,
            title=f"{model.title}: quasi-static force curve",
            zoom=zoom,
            unit=model.theta_unit,
        )
        print(f"wrote {args.plot}")
    return 0


def plot_curve(curve, path, title="", zoom=None, unit="rad") -> None:
    """Write :func:`curve_figure` to ``path`` (the format from its extension)."""
    save_figure(curve_figure(curve, title, zoom, unit), path, dpi=120)


def curve_figure(curve, title="", zoom=None, unit="rad"):
    """The opening and closing curves; ``zoom`` (a second curve) gets its own panel.

    ``unit`` is the unit of ``theta``: angles in rad are drawn in degrees.
    """
    from matplotlib.figure import Figure

    panels = [curve] if zoom is None else [curve, zoom]
    fig = Figure(figsize=(7 + 3.5 * (len(panels) - 1), 4.2), layout="constrained")
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
    ax.set_title(title, fontsize=10)
    ax.legend()
    if zoom is not None:
        axes[0][1].set_xlabel("theta [deg], near closed")
        axes[0][1].set_title(
            f"latch, last {np.ptp(np.degrees(zoom['theta'])):.3g} deg", fontsize=10
        )
    return fig
