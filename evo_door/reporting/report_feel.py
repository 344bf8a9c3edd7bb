"""The report's perceptual check, per stage: the stage's own answer against its chosen feel.

Every run (every stage of a pipeline) fitted to a chosen feel gets this section in its
own part of the page: the table ``show`` prints (verdict per stroke, share of the
stroke beyond the JND, the largest difference, the angles beyond it) and the figure of
both force-angle curves with the chosen one's JND band. The curves are the results
file's (:mod:`evo_door.experiment.feel_check`), so nothing is simulated again; the JND
is the run's own ``perception`` settings, with the report's changes (``--jnd``, ``--force-floor``, a
pipeline file's ``report:``) applied on top (:class:`JNDChanges`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from evo_door.errors import UserError
from evo_door.experiment.feel_check import jnd_value, jnds_used, run_jnd_sources
from evo_door.experiment.results import Results
from evo_door.files import save_figure
from evo_door.perception import JND, verdict_text
from evo_door.perception.feel import DIRECTIONS
from evo_door.perception.jnd_file import (
    LITERATURE,
    WEBER_SETTINGS,
    measured_jnd,
    read_jnd_file,
    usable_weber,
)
from evo_door.reporting.page import ReportPage

#: the defaults of the force JND, for the help of ``evo-door report`` (the JND's own)
DEFAULT_JND = JND().force
FORCE_FLOOR = JND().force_floor


@dataclass(frozen=True)
class JNDChanges:
    """The report's changes to each run's JND: the force Weber fraction ``jnd`` and the
    ``force_floor`` (N), and the Weber fractions measured by the JND ``files``; None
    and no file keep the run's own (its ``perception:`` settings).

    ``jnd_from`` and ``floor_from`` say who gave ``jnd`` and ``force_floor`` (the
    command line, or a pipeline file's ``report:``); :meth:`check` reads the files into
    ``measured``: (setting, Weber fraction, source) for each setting they set.
    """

    jnd: float | None = None
    force_floor: float | None = None
    files: tuple = ()
    jnd_from: str = "--jnd"
    floor_from: str = "--force-floor"
    measured: tuple = ()

    def check(self) -> JNDChanges:
        if self.jnd is not None and not (0.0 < self.jnd < 1.0):
            raise UserError(f"--jnd {self.jnd:g}: a fraction between 0 and 1 (0.1 is 10 %)")
        if self.force_floor is not None and not (
            self.force_floor > 0.0 and math.isfinite(self.force_floor)
        ):
            raise UserError(f"--force-floor {self.force_floor:g}: a force above 0 N")
        if not self.files or self.measured:
            return self
        jnd = self.jnd
        for path in self.files:  # each file checked alone, so that an error names it
            record = read_jnd_file(path)
            usable_weber(record)
            if record.setting == "force" and jnd is not None:
                if self.jnd_from != "--jnd":  # the command line's file beats the pipeline's
                    jnd = None
                    continue
                raise UserError(
                    f"--jnd {jnd:g} and --jnd-file {path}: both set the force JND "
                    f"({record.param} is in {record.unit}); give one"
                )
        values, sources = measured_jnd(JND(), self.files)
        measured = tuple(
            (k, getattr(values, k), sources[k]) for k in WEBER_SETTINGS if sources[k] != LITERATURE
        )
        return replace(self, jnd=jnd, measured=measured)

    def apply(self, jnd: JND) -> JND:
        """``jnd`` with these changes."""
        given = {"force": self.jnd, "force_floor": self.force_floor}
        given.update({k: w for k, w, _ in self.measured})
        return replace(jnd, **{k: float(v) for k, v in given.items() if v is not None})

    def sources(self, run_sources: dict[str, str]) -> dict[str, str]:
        """The source of each setting of :meth:`apply`'s JND, from the run's own."""
        out = dict(run_sources)
        if self.jnd is not None:
            out["force"] = f"changed for this report ({self.jnd_from} {self.jnd:g})"
        if self.force_floor is not None:
            out["force_floor"] = (
                f"changed for this report ({self.floor_from} {self.force_floor:g} N)"
            )
        out.update({k: f"changed for this report (--jnd-file): {s}" for k, _, s in self.measured})
        return out


def stage_label(res: Results) -> str:
    return f"stage {res.stage}" if res.stage else "the run"


def perceptual_section(
    page: ReportPage, res: Results, changes: JNDChanges, key: str
) -> dict | None:
    """The section of ``res``'s perceptual check (nothing for a run not fitted to a
    chosen feel); returns the verdict shown (:meth:`FeelCheck.judged`), or None."""
    fc = res.record.perceptual_check
    if fc is None:
        return None
    jnd = changes.apply(fc.jnd)
    check = fc.check(jnd)
    judged = fc.judged(jnd)
    label = stage_label(res)
    page.h(3, f"Perceptual check of {label}: its answer against the chosen feel")
    changed = "" if jnd == fc.jnd else " (changed for this report; the run's own differ)"
    page.p(
        f"Force-angle curves (Coulomb level, latch peaks resolved) of {fc.mechanism.source} "
        f"of {label} and of the chosen feel ({fc.chosen.source}). A difference is noticeable "
        f"where it exceeds {100 * jnd.force:.3g} % of the chosen force, or {jnd.force_floor:g} N "
        f"where that is larger{changed}, at any angle outside the latch zone (the last "
        f"3 deg); the latch is judged by its peak forces and by where they are, within "
        f"{1000 * jnd.position:.3g} mm at the handle ({jnd.handle_radius:g} m from the hinge); "
        "where the chosen feel has dynamics, the felt inertia and damping within theirs. "
        f"Verdict: {verdict_text(judged)}."
    )
    page.table(
        ["setting", "value", "source"],
        jnd_rows(jnds_used(jnd, changes.sources(run_jnd_sources(res.config)))),
        f"{label}: JNDs used",
    )
    page.table(
        [
            "direction",
            "verdict",
            "stroke beyond the JND",
            "largest difference of the stroke",
            "angles beyond the JND [deg]",
            "latch peak",
            "peak's angle",
        ],
        perceptual_rows(judged),
        f"{label}: perceptual check",
    )
    page.p(
        f"The answer of {label} feels like the chosen feel, within the JND."
        if judged["passes"]
        else f"The answer of {label} differs noticeably from the chosen feel at the angles above.",
        "pass" if judged["passes"] else "fail",
    )

    def draw(path):
        _figure(path, check, jnd, fc, label)

    page.figure(
        f"{key}-perceptual-check",
        draw,
        f"{label}: force to move the door slowly, opening and closing, against angle; "
        "crosses mark where the answer leaves the JND band of the chosen feel",
    )
    return judged


def jnd_rows(jnds: dict) -> list[list[str]]:
    """One row per JND setting (:func:`~evo_door.experiment.feel_check.jnds_used`): its
    name, its value with its unit (a Weber fraction in %) and its source."""
    return [[k, jnd_value(e), e["source"]] for k, e in jnds.items()]


def perceptual_rows(judged: dict) -> list[list[str]]:
    """One row per direction: verdict, share of the stroke and largest difference beyond
    the JND, the angle bands where it is exceeded (the first 8)."""
    rows = []
    for d in DIRECTIONS:
        c = judged[d]
        w = c["worst"]
        bands = ", ".join(f"{a:.1f}..{b:.1f}" for a, b in c["bands_deg"][:8])
        more = f" (+{len(c['bands_deg']) - 8} more)" if len(c["bands_deg"]) > 8 else ""
        p, a = c["latch_peak"], c["peak_angle"]
        rows.append(
            [
                d,
                f"{c['verdict']} ({c['worst_jnd']:.2f} JND: {c['worst_at']})",
                f"{100 * c['fraction_beyond_jnd']:.1f} %",
                f"{w['difference_N']:+.2f} N at {w['angle_deg']:.2f} deg (JND {w['jnd_N']:.2f} N, "
                f"{w['jnd_units']:.2f} JND)",
                (bands + more) or "-",
                f"{p['mechanism_N']:.2f} N against {p['chosen_N']:.2f} N "
                f"({p['jnd_units']:.2f} JND)",
                f"{a['mechanism_deg']:.2f} deg against {a['chosen_deg']:.2f} deg "
                f"({a['jnd_units']:.2f} JND)",
            ]
        )
    for name, e in (judged.get("dynamics") or {}).items():
        rows.append(
            [
                f"felt {name}",
                f"{e['verdict']} ({e['jnd_units']:.2f} JND)",
                "",
                f"{e['mechanism']:.4g} against {e['chosen']:.4g} {e['unit']} "
                f"(JND {e['jnd']:.3g} {e['unit']})",
                "",
                "",
                "",
            ]
        )
    return rows


def _figure(path, check: dict, jnd: JND, fc, label: str) -> None:
    """The two panels (opening, closing): the chosen force with its JND band and the
    answer's, crosses where it leaves the band."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 6.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for ax, d in zip(axes, DIRECTIONS):
        c = check[d]
        deg = np.degrees(c["theta"])
        ax.fill_between(
            deg,
            c["chosen"] - c["threshold"],
            c["chosen"] + c["threshold"],
            color="0.85",
            label=f"chosen +- JND ({100 * jnd.force:.3g} %, at least {jnd.force_floor:g} N)",
        )
        ax.plot(deg, c["chosen"], color="k", lw=1.2, label=f"chosen ({fc.chosen.source})")
        ax.plot(
            deg,
            c["mechanism"],
            color="tab:red",
            lw=1.1,
            ls="--",
            label=f"{fc.mechanism.source}, {label}",
        )
        bad = c["fails"]
        ax.plot(deg[bad], c["mechanism"][bad], "x", color="tab:red", ms=3, label="beyond the JND")
        ax.set_ylabel(f"{d} force [N]\n(+ toward closing)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, ncol=2)
    axes[1].set_xlabel("theta [deg] (0 open, 90 closed)")
    fig.suptitle(f"{label}: force-angle curves, its answer against the chosen feel", fontsize=10)
    save_figure(fig, path, dpi=110)


def front_section(page: ReportPage, res: Results, key: str) -> None:
    """A smallest-change fit's Pareto front (``algorithm: {kind: nsga2}``): the feel's
    distance from the chosen one against the size of the change, the answer marked;
    nothing for another fit."""
    front = res.smallest_change()
    if front is None:
        return
    label = stage_label(res)
    kept = ", ".join(front.kept) or "none"
    page.p(
        f"{label}: smallest change within the JND: {len(front.front_f)} points on the "
        f"front; the answer changes the AS-IS door by {front.change:.3g} (mean share of the "
        f"search ranges) at a perceptual error of {front.error:.3g} JND^2; kept at their "
        f"AS-IS values: {kept}"
        + ("" if front.reachable else "; UNREACHABLE: this is the closest door"),
        "pass" if front.reachable else "fail",
    )
    page.figure(
        f"{key}-front",
        lambda p: _front_figure(p, front, label),
        f"{label}: the Pareto front of NSGA-II, perceptual error against the size of the "
        "change from the AS-IS door; the answer and the AS-IS door marked",
    )


def _front_figure(path, front, label: str) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.2), layout="constrained")
    ax = fig.subplots()
    f = np.asarray(front.front_f, dtype=np.float64)
    order = np.argsort(f[:, 1])
    ax.plot(
        f[order, 1],
        np.maximum(f[order, 0], 1e-12),
        "o-",
        ms=4,
        color="tab:blue",
        label="Pareto front",
    )
    ax.plot(
        [front.change],
        [max(front.error, 1e-12)],
        "*",
        ms=14,
        color="tab:green" if front.reachable else "tab:red",
        label="answer" + ("" if front.reachable else " (closest door: unreachable)"),
    )
    ax.set_yscale("log")
    ax.set_xlabel("size of the change from the AS-IS door [mean share of the search ranges]")
    ax.set_ylabel("perceptual error [JND^2]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title(f"{label}: the smallest change within the JND", fontsize=10)
    save_figure(fig, path, dpi=110)
