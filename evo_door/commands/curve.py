"""``evo-door curve MODEL``: quasi-static force-angle characteristic."""

from __future__ import annotations

import numpy as np

from evo_door.commands._common import add_params_arguments, model_and_params
from evo_door.sim import quasi_static_curve

ORDER = 30
#: Width (deg) of the panel next to closed in the plot.
ZOOM_DEG = 1.5


def register(sub) -> None:
    p = sub.add_parser("curve", help="force a user needs to open / close the door slowly, against angle")
    p.add_argument("model", help="model name, e.g. haptic or door")
    add_params_arguments(p)
    p.add_argument("--speed", type=float, default=0.02, metavar="RAD_S",
                   help="constant angular speed of the slow motion (default 0.02 rad/s)")
    p.add_argument("--points", type=int, default=721, help="angles on [0, pi/2] (default 721)")
    p.add_argument("--out", required=True, metavar="CURVE.csv",
                   help="columns theta (rad), force (N, + toward closing), direction (opening|closing)")
    p.add_argument("--plot", metavar="CURVE.png", help="also draw the curves")
    p.set_defaults(func=run)


def run(args) -> int:
    model, params = model_and_params(args)
    curve = quasi_static_curve(model, params, n=args.points, speed=args.speed)
    with open(args.out, "w") as fh:
        fh.write("theta,force,direction\n")
        for direction in ("opening", "closing"):
            for th, f in zip(curve["theta"], curve[direction]):
                fh.write(f"{th:.10g},{f:.10g},{direction}\n")
    print(f"wrote {args.out}")
    if args.plot:
        # latch bands are a fraction of a degree wide: a second panel resolves them
        zoom = quasi_static_curve(model, params, n=4001, speed=args.speed,
                                  lo=np.pi / 2 - np.radians(ZOOM_DEG), hi=np.pi / 2)
        plot_curve(curve, args.plot, title=f"{model.title}: quasi-static force-angle curve",
                   zoom=zoom)
        print(f"wrote {args.plot}")
    return 0


def plot_curve(curve, path, title="", zoom=None) -> None:
    """Draw the opening and closing curves; ``zoom`` (a second curve) gets its own panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [curve] if zoom is None else [curve, zoom]
    fig, axes = plt.subplots(1, len(panels), figsize=(7 + 3.5 * (len(panels) - 1), 4.2),
                             constrained_layout=True, squeeze=False,
                             gridspec_kw={"width_ratios": [2, 1][:len(panels)]})
    for ax, c in zip(axes[0], panels):
        deg = np.degrees(c["theta"])
        ax.plot(deg, c["opening"], label="opening (dtheta < 0)", color="tab:blue")
        ax.plot(deg, c["closing"], label="closing (dtheta > 0)", color="tab:red")
        ax.axhline(0.0, color="0.6", lw=0.8)
        ax.grid(alpha=0.3)
    ax = axes[0][0]
    ax.set_xlabel("door angle theta [deg]  (0 = open, 90 = closed)")
    ax.set_ylabel("user force at the handle [N]  (+ toward closing)")
    ax.set_title(title, fontsize=10)
    ax.legend()
    if zoom is not None:
        axes[0][1].set_xlabel("theta [deg], near closed")
        axes[0][1].set_title("latch, last %.3g deg" % np.ptp(np.degrees(zoom["theta"])), fontsize=10)
    fig.savefig(path, dpi=120)
    plt.close(fig)
