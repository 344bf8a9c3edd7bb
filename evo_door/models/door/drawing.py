"""Drawing of the door mechanism (plain Python, matplotlib).

One panel per door angle: the door rod O-A-E (cut short near the hinge so the
linkage stays readable), the plate A-B-C-H, the vertical slot at B, the spring at C,
the fixed pad D, the centre of mass G and the stop H. Built on
:func:`~evo_door.models.door.kinematics.points`, so the drawing is the model's own
kinematics, not a separate sketch.
"""

from __future__ import annotations

import math

import numpy as np

from evo_door.models.door.kinematics import points

#: How much of the door rod to draw beyond the plate (m); the handle is 0.6 m away.
_ROD_SHOWN = 0.16


def draw_mechanism(params, angles_deg=(0.0, 45.0, 90.0), path=None, title=None):
    """Draw the mechanism at the given door angles (degrees; 0 open, 90 closed).

    ``params`` is a :class:`~evo_door.params.ParamSet` (or any name -> value mapping)
    of the ``door`` model. Returns the matplotlib figure; saves it when ``path`` is
    given.
    """
    # long: one figure: the common limits, then per angle the parts of the
    # linkage drawn in the order they are built; a helper per part would hide that order
    from matplotlib.figure import Figure

    angles = [float(a) for a in angles_deg]
    fig = Figure(figsize=(3.6 * len(angles) + 0.4, 4.4), layout="constrained")
    axes = fig.subplots(1, len(angles), squeeze=False)
    # common limits: every point over every angle, in cm
    all_pts = [points(math.radians(a), params) for a in angles]
    xy = np.array([v for pts in all_pts for k, v in pts.items() if k not in ("plate", "E", "G")])
    lo = xy.min(axis=0) * 100 - 2.5
    hi = xy.max(axis=0) * 100 + 2.5
    hi[0] = max(hi[0], _ROD_SHOWN * 100 + 1)
    hi[1] = max(hi[1], _ROD_SHOWN * 100 + 1)
    for ax, a, pts in zip(axes[0], angles, all_pts):
        cm = {k: 100 * v for k, v in pts.items()}
        u = np.array([math.cos(math.radians(a)), math.sin(math.radians(a))])
        rod_end = 100 * _ROD_SHOWN * u
        ax.plot(
            [0, rod_end[0]],
            [0, rod_end[1]],
            color="0.25",
            lw=5,
            solid_capstyle="round",
            label="door O-A-E (to E at L)",
        )
        ax.annotate(
            "",
            xy=rod_end + 1.5 * 100 * 0.01 * u,
            xytext=rod_end,
            arrowprops=dict(arrowstyle="->", color="0.25", linestyle="--"),
        )
        plate = np.vstack([cm["plate"], cm["plate"][:1]])
        ax.fill(plate[:, 0], plate[:, 1], color="tab:orange", alpha=0.35, lw=0)
        ax.plot(plate[:, 0], plate[:, 1], color="tab:orange", lw=1.5, label="plate A-B-C-H")
        # slot at B: a vertical guide over the B range of the stroke
        ax.axvline(cm["B"][0], color="tab:blue", lw=0.8, ls=":", label="slot at B (vertical)")
        # spring at C: a zig-zag down to the cabinet
        c = cm["C"]
        base = lo[1] + 0.5
        zz_y = np.linspace(base, c[1], 12)
        zz_x = c[0] + np.r_[0, 0.6 * (-1) ** np.arange(10), 0]
        ax.plot(zz_x, zz_y, color="tab:green", lw=1.2, label="spring K at C")
        ax.plot(*cm["D"], marker="s", color="tab:red", ms=8, ls="none", label="pad D (fixed)")
        g_inside = bool(np.all((cm["G"] >= lo) & (cm["G"] <= hi)))
        if g_inside:
            ax.plot(
                *cm["G"],
                marker="o",
                mfc="white",
                mec="k",
                ms=7,
                ls="none",
                label="centre of mass G",
            )
        for name in ("O", "A", "B", "C", "H"):
            ax.plot(*cm[name], marker="o", color="k", ms=3.5)
            ax.annotate(name, cm[name], textcoords="offset points", xytext=(4, 3), fontsize=9)
        ax.annotate("D", cm["D"], textcoords="offset points", xytext=(5, -10), fontsize=9)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.grid(alpha=0.25)
        ax.set_title(
            f"theta = {a:g} deg" + (" (open)" if a == 0 else " (closed)" if a == 90 else "")
        )
        ax.set_xlabel("x [cm] (out of the cabinet)")
    axes[0][0].set_ylabel("y [cm] (up)")
    g = 100 * np.hypot(float(params["G_x"]), float(params["G_y"]))
    axes[0][-1].plot(
        [], [], ls="none", label=f"(G, E: {g:.0f} and {100 * float(params['L']):.0f} cm out)"
    )
    axes[0][-1].legend(loc="lower right", fontsize=7, framealpha=0.9)
    if title:
        fig.suptitle(title)
    if path is not None:
        from evo_door.files import save_figure

        save_figure(fig, path, dpi=110)
    return fig
