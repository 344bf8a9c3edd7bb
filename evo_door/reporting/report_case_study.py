"""What a report shows of a pipeline laid out like the case study (``docs/case-study.md``).

Beyond each stage's own section (:mod:`.report`), what the seed's chapter 5 shows,
found by what the stages do rather than by their names:

- a stage fitting ``per_trial`` with a range (the *physical* stage): seed figure 5.2,
  each trial with its own best fit and the responses at the minimum and the maximum of
  the per-trial range;
- every stage fitted to a chosen feel: a table of its **perceptual check** (does its
  answer feel like the chosen feel, within the force just-noticeable difference?), one
  row per stage, each naming its stage; the check itself, with its figure, is in the
  stage's own section (:mod:`.report_feel`). The seed names this as the open risk of
  its method;
- a later stage of the same target freeing the pad-friction sections (the
  *redesign*): the A(theta) chart (seed figure 5.6) and constant against variable
  friction on the target (seed figure 5.7), with the numbers.
"""

from __future__ import annotations

import math

import numpy as np

from evo_door.experiment.results import Results
from evo_door.files import save_figure
from evo_door.perception import verdict_text
from evo_door.perception.feel import DIRECTIONS
from evo_door.reporting.page import ReportPage
from evo_door.reporting.report_feel import JNDChanges

# -- the case study --------------------------------------------------------------------


def _target_model(res: Results):
    """(model, ParamSet) of a stage fitted to another model, else None."""
    from evo_door.models import get_model

    t = res.config["target"]
    if t.get("kind") != "model":
        return None
    model = get_model(t["model"])
    return model, model.load_params(t.get("params"), t.get("set") or {})


def _case_study(page: ReportPage, results: list[Results], changes: JNDChanges) -> None:
    page.h(2, "The case study", "case-study")
    physical = [r for r in results if r.complete and "table" in r.summary()]
    for res in physical[:1]:
        _figure_5_2(page, res)
    spec = [
        r
        for r in results
        if r.complete
        and _target_model(r) is not None
        and not any(n.startswith("friction_scale_") for n in r.free)
    ]
    redesign = [
        r
        for r in results
        if r.complete
        and _target_model(r) is not None
        and any(n.startswith("friction_scale_") for n in r.free)
    ]
    _perceptual_summary(page, results, changes)
    if spec and redesign:
        _a_of_theta(page, redesign[-1])
        _constant_vs_variable(page, spec[-1], redesign[-1])


def _perceptual_summary(page: ReportPage, results: list[Results], changes: JNDChanges) -> None:
    """One row per stage fitted to a chosen feel: its verdict per stroke, and whether
    its answer passes; the checks themselves are in the stages' sections."""
    rows = []
    for res in results:
        fc = res.record.perceptual_check
        if not res.complete or fc is None:
            continue
        judged = fc.judged(changes.apply(fc.jnd))
        rows.append(
            [
                res.stage or "run",
                fc.mechanism.source,
                fc.chosen.source,
                *(
                    f"{judged[d]['verdict']} ({judged[d]['worst_jnd']:.2f} JND: "
                    f"{judged[d]['worst_at']})"
                    for d in DIRECTIONS
                ),
                verdict_text(judged),
            ]
        )
    page.h(3, "Perceptual checks: each stage's answer against its chosen feel")
    if not rows:
        page.p("no stage is fitted to a chosen feel: no perceptual check")
        return
    page.table(
        [
            "stage",
            "answer",
            "chosen feel",
            "opening (worst, JND)",
            "closing (worst, JND)",
            "verdict",
        ],
        rows,
        "perceptual check per stage (figures and angles in each stage's section)",
    )


def _trial_response(res: Results, node, values: dict):
    """The model's response to a stored trial (a
    :class:`~evo_door.experiment.reader.StoredTrial`) with ``values`` (name -> value)."""
    from evo_door.sim import simulate

    model = res.model
    tr = node.trial()
    theta0, dtheta0 = tr.initial_state(default_theta0=model.theta0)
    setup = res.record.settings
    known = {n: v for n, v in values.items() if n in model.params}
    r = simulate(
        model,
        model.load_params(known),
        tr.force,
        tr.dt,
        theta0=theta0,
        dtheta0=dtheta0,
        t0=float(tr.t[0]),
        method=setup.method,
        substeps=int(setup.substeps),
        tolerance=setup.tolerance,
    )
    return tr, r


def _figure_5_2(page: ReportPage, res: Results) -> None:
    from matplotlib.figure import Figure

    from evo_door.channels import unit

    s = res.summary()
    channel = res.config["objective"]["derivative"]
    name = ("theta", "dtheta", "ddtheta")[channel]
    base = res.values()
    low = dict(base, **{n: s["table"][n]["min"] for n in res.free})
    high = dict(base, **{n: s["table"][n]["max"] for n in res.free})
    fits = s["per_trial_fits"]
    nodes = {stored.trial_id: stored for stored in res.record.trials if stored.role == "fit"}
    trials = [t for t in fits if t in nodes][:4]

    def draw(path):
        fig = Figure(figsize=(12, 2.8 * math.ceil(len(trials) / 2) + 0.8), layout="constrained")
        axes = fig.subplots(math.ceil(len(trials) / 2), 2, squeeze=False)
        scale = math.degrees(1.0)
        for ax, trial in zip(axes.flat, trials):
            node = nodes[trial]
            tr = node.trial()
            target = getattr(tr, name)
            ax.plot(tr.t, target * scale, color="0.55", lw=3, alpha=0.6, label="trial")
            for values, style, lab in (
                (dict(base, **fits[trial]), dict(color="tab:red", ls="--"), "its best fit"),
                (low, dict(color="tab:blue", ls=":"), "range minimum"),
                (high, dict(color="tab:green", ls="-."), "range maximum"),
            ):
                _, r = _trial_response(res, node, values)
                y = (r.theta, r.dtheta, r.ddtheta)[channel]
                ax.plot(tr.t, y * scale, lw=1.1, label=lab, **style)
            ax.set_title(trial, fontsize=9)
            ax.set_xlabel("t [s]")
            ax.set_ylabel(f"{name} [{unit(name).replace('rad', 'deg')}]")
            ax.grid(alpha=0.3)
        for ax in list(axes.flat)[len(trials) :]:
            ax.axis("off")
        axes.flat[0].legend(fontsize=8)
        fig.suptitle(
            f"{res.stage}: trials, best fits and the responses at the min / max "
            "of the per-trial range (seed figure 5.2)",
            fontsize=10,
        )
        save_figure(fig, path, dpi=110)

    page.h(3, "Measured trials, best fits and the parameter range (seed figure 5.2)")
    page.figure(
        f"{res.stage}-figure-5-2",
        draw,
        "each trial with its own best fit and the responses at the minimum and the "
        "maximum of the per-trial range (seed table 5.3)",
    )


def _a_of_theta(page: ReportPage, res: Results) -> None:
    from matplotlib.figure import Figure

    values = res.values()
    names = sorted(
        (n for n in values if n.startswith("friction_scale_")),
        key=lambda n: int(n.rsplit("_", 1)[1]),
    )
    a = np.array([values[n] for n in names])
    n = len(a)
    edges = np.linspace(0.0, 90.0, n + 1)
    page.h(3, "Redesign: pad friction varying with the angle (seed figure 5.6)")
    page.table(
        ["section", "angles [deg]", "A_k", "F_atD A_k [N]"],
        [
            [
                str(k + 1),
                f"{edges[k]:.2f}..{edges[k + 1]:.2f}",
                f"{a[k]:.3f}",
                f"{values.get('F_atD', math.nan) * a[k]:.2f}",
            ]
            for k in range(n)
        ],
        f"stage {res.stage}: A(theta), F_atD = {values.get('F_atD', math.nan):.2f} N",
    )

    def draw(path):
        fig = Figure(figsize=(8, 3.6), layout="constrained")
        ax = fig.subplots()
        ax.stairs(a, edges, lw=2, color="tab:purple", label="A_k")
        ax.set_xlim(0, 90)
        ax.set_ylim(0, 1.05)
        ax.set_xlabel("theta [deg] (0 open, 90 closed)")
        ax.set_ylabel("A(theta) [1]")
        ax.grid(alpha=0.3)
        ax.set_title(
            f"{res.stage}: scale of the pad friction F_atD per section (eq. 5.8-5.9)", fontsize=10
        )
        save_figure(fig, path, dpi=110)

    page.figure(f"{res.stage}-a-of-theta", draw, "A(theta): the pad friction's scale per section")


def _constant_vs_variable(page: ReportPage, spec: Results, redesign: Results) -> None:
    from matplotlib.figure import Figure

    e0, e1 = spec.channel_errors(), redesign.channel_errors()
    common = [t for t in e1 if t in e0]
    if not common:
        return
    unit_ = e1[common[0]]["unit"]
    rows = []
    for t in common:
        a, b = e0[t]["rms"], e1[t]["rms"]
        rows.append(
            [t, e1[t]["role"], f"{a:.4g}", f"{b:.4g}", f"{100 * (b - a) / a:+.1f} %" if a else "-"]
        )
    total0 = math.sqrt(np.mean([e0[t]["rms"] ** 2 for t in common]))
    total1 = math.sqrt(np.mean([e1[t]["rms"] ** 2 for t in common]))
    rows.append(
        ["all", "", f"{total0:.4g}", f"{total1:.4g}", f"{100 * (total1 - total0) / total0:+.1f} %"]
    )
    page.h(3, "Constant against variable pad friction, on the chosen behaviour (seed figure 5.7)")
    page.table(
        ["trial", "role", f"RMS constant [{unit_}]", f"RMS variable [{unit_}]", "change"],
        rows,
        f"RMS error against the chosen behaviour: stage {spec.stage} (constant "
        f"F_atD) and stage {redesign.stage} (F_atD A(theta))",
    )
    r0 = {r.trial_id: r for r in spec.responses()}
    r1 = {r.trial_id: r for r in redesign.responses()}
    shown = [t for t in common if t in r0 and t in r1][:4]

    def draw(path):
        fig = Figure(figsize=(12, 2.8 * math.ceil(len(shown) / 2) + 0.8), layout="constrained")
        axes = fig.subplots(math.ceil(len(shown) / 2), 2, squeeze=False)
        for ax, t in zip(axes.flat, shown):
            a, b = r0[t], r1[t]
            ax.plot(b.t, b.target, color="0.55", lw=3, alpha=0.6, label="chosen (target)")
            ax.plot(a.t, a.model, color="tab:blue", lw=1, ls=":", label="constant friction")
            ax.plot(b.t, b.model, color="tab:red", lw=1.1, ls="--", label="variable friction")
            ax.set_title(f"{t}: RMS {e0[t]['rms']:.3g} -> {e1[t]['rms']:.3g} {unit_}", fontsize=9)
            ax.set_xlabel("t [s]")
            ax.set_ylabel(f"{b.channel} [{unit_}]")
            ax.grid(alpha=0.3)
        for ax in list(axes.flat)[len(shown) :]:
            ax.axis("off")
        axes.flat[0].legend(fontsize=8)
        fig.suptitle("constant against variable pad friction (seed figure 5.7)", fontsize=10)
        save_figure(fig, path, dpi=110)

    page.figure(
        "constant-vs-variable",
        draw,
        "the chosen behaviour with the constant-friction and the variable-friction mechanism",
    )
