"""The specifications' tolerances of a run against its chosen feel, where the experiment
layer meets :mod:`evo_door.optim.tolerance`.

A run with the perceptual objective (a chosen feel, ``Setup.feel``) computes them when
it completes (:func:`stage_tolerances`) and its results file keeps them
(``tolerance/``); :func:`tolerances_of` reads them back, or computes them for a file
written before they were kept (``export-spec`` says so in a note). The specifications
are the rows of the run's specification table (:func:`evo_door.experiment.spec.spec_names`).
"""

from __future__ import annotations

import numpy as np

from evo_door.errors import UserError
from evo_door.experiment import store
from evo_door.experiment.spec import spec_names
from evo_door.optim.tolerance import Tolerances, tolerances

#: the note of tolerances computed for a results file that has none
COMPUTED_NOTE = "computed now: the results file has none (written before tolerances were kept)"


def stage_tolerances(setup, full, progress: bool = False) -> Tolerances | None:
    """The tolerances of a finished run's door ``full`` (its whole kernel vector), None
    for a run without a chosen feel or where they cannot be made (a run's answer is never
    lost to them)."""
    if setup.feel is None or not setup.objective.perceptual:
        return None
    names = spec_names(setup.model, setup.free)
    try:
        return tolerances(setup.model, full, setup.feel, names, progress=progress)
    except (UserError, ValueError):
        return None


def tolerances_of(res, compute: bool = True) -> Tolerances | None:
    """The tolerances of the complete run ``res`` (a
    :class:`~evo_door.experiment.results.Results`): as stored, else (``compute``)
    computed from its chosen feel with :data:`COMPUTED_NOTE`; None for a run without one."""
    if res.record.tolerance is not None:
        return res.record.tolerance
    tree = res.tree
    if not compute or tree is None or "feel" not in tree["setup"] or "best" not in tree:
        return None
    setup = store.setup_from_tree(tree)
    full = np.asarray(tree["best"]["full"], dtype=np.float64)
    out = stage_tolerances(setup, full)
    if out is not None:
        out.note = "; ".join(x for x in (out.note, COMPUTED_NOTE) if x)
        res.record.tolerance = out  # once a read: the table and the report share it
    return out


def plot_tolerances(tol: Tolerances, label: str, path) -> None:
    """The report's figure: each specification's bands as a share of its value (alone,
    and together), and the force-angle band of the Monte-Carlo's doors against the chosen
    feel's JND band, per stroke."""
    import math

    from matplotlib.figure import Figure

    from evo_door.files import save_figure

    n = len(tol.names)
    fig = Figure(figsize=(11.0, max(3.6, 0.9 + 0.24 * n)), layout="constrained")
    bands, curves = fig.subplots(1, 2, width_ratios=(1.0, 1.4))
    y = np.arange(n)[::-1]
    for which, colour, shift in (("alone", "tab:blue", 0.15), ("together", "tab:orange", -0.15)):
        rel = 100.0 * tol.relative(which)
        ok = np.isfinite(rel)
        bands.errorbar(
            np.zeros(ok.sum()),
            y[ok] + shift,
            xerr=rel[ok],
            fmt="o",
            ms=3,
            capsize=3,
            color=colour,
            label=f"{which}",
        )
    for i in np.flatnonzero(tol.capped):
        bands.annotate("cap", (100.0 * tol.relative("alone")[i], y[i] + 0.15), fontsize=6)
    bands.set_yticks(y, tol.names, fontsize=7)
    bands.axvline(0.0, color="0.5", lw=0.8)
    bands.set_xlabel("band, % of the value (+-)")
    bands.set_title(f"{label}: tolerances", fontsize=10)
    bands.legend(fontsize=8, loc="lower right")
    c = tol.curves
    if c:
        deg = np.degrees(c["theta"])
        for d, colour in (("opening", "tab:blue"), ("closing", "tab:red")):
            chosen, jnd = c[f"{d}_chosen"], c[f"{d}_jnd"]
            curves.fill_between(deg, chosen - jnd, chosen + jnd, color=colour, alpha=0.18, lw=0)
            curves.plot(deg, chosen, color=colour, lw=1.0, label=f"{d}: chosen +- JND")
            curves.plot(deg, c[f"{d}_low"], color=colour, lw=0.6, ls="--")
            curves.plot(deg, c[f"{d}_high"], color=colour, lw=0.6, ls="--", label=f"{d}: doors")
        # the stroke sets the scale: the latch's peaks (the last 3 deg) would flatten it
        stroke = deg <= deg[-1] - 3.0
        parts = [c[f"{d}_{k}"][stroke] for d in ("opening", "closing") for k in ("low", "high")]
        parts += [
            c[f"{d}_chosen"][stroke] + s * c[f"{d}_jnd"][stroke]
            for d in ("opening", "closing")
            for s in (-1, 1)
        ]
        lo, hi = min(map(np.min, parts)), max(map(np.max, parts))
        pad = 0.15 * (hi - lo) + 0.5
        curves.set_ylim(lo - pad, hi + pad)
        curves.set_xlabel("theta [deg] (0 open, 90 closed; the latch's peaks are off scale)")
        curves.set_ylabel("force [N] (+ toward closing)")
        curves.legend(fontsize=7)
        lb = 100.0 * tol.lower_bound if math.isfinite(tol.lower_bound) else math.nan
        curves.set_title(
            f"{tol.passed}/{tol.samples} doors within the together bands pass "
            f"(>= {lb:.1f} %, seed {tol.seed})",
            fontsize=10,
        )
    save_figure(fig, path, dpi=110)
