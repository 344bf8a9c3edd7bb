"""What a report shows of a pipeline laid out like the case study (``docs/case-study.md``).

Beyond each stage's own section (:mod:`.report`), what the seed's chapter 5 shows,
found by what the stages do rather than by their names:

- a stage fitting ``per_trial`` with a range (the *physical* stage): seed figure 5.2,
  each trial with its own best fit and the responses at the minimum and the maximum of
  the per-trial range;
- a stage fitting a mechanism to another model (the *specification*): the force-angle
  curves of the specified mechanism against the chosen haptic behaviour, and the
  **perceptual check**: over the stroke, where does the mechanism's force differ from
  the chosen behaviour's by more than a force just-noticeable difference (JND, default
  10 %, relative to the larger of the chosen force and a floor of 1 N, below which a
  relative threshold means nothing)? The seed names this as the open risk of its
  method;
- a later stage of the same target freeing the pad-friction sections (the
  *redesign*): the A(theta) chart (seed figure 5.6) and constant against variable
  friction on the target (seed figure 5.7), with the numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from evo_door.errors import UserError
from evo_door.experiment.page import Page as _Page  # the name the sections use
from evo_door.experiment.results import Results
from evo_door.files import save_figure

#: a force JND: the relative difference of force a hand notices (Weber fraction)
DEFAULT_JND = 0.10
#: below this force (N) the JND is taken of this force: 10 % of 0 N is no threshold
FORCE_FLOOR = 1.0


@dataclass
class Settings:
    jnd: float = DEFAULT_JND
    force_floor: float = FORCE_FLOOR

    def check(self) -> Settings:
        if not (0.0 < self.jnd < 1.0):
            raise UserError(f"--jnd {self.jnd:g}: a fraction between 0 and 1 (0.1 is 10 %)")
        if not (self.force_floor > 0.0 and math.isfinite(self.force_floor)):
            raise UserError(f"--force-floor {self.force_floor:g}: a force above 0 N")
        return self


# -- the case study --------------------------------------------------------------------
def _free(res: Results) -> list[str]:
    return list(res.free)


def _target_model(res: Results):
    """(model, ParamSet) of a stage fitted to another model, else None."""
    from evo_door.models import get_model

    t = res.config["target"]
    if t.get("kind") != "model":
        return None
    model = get_model(t["model"])
    return model, model.load_params(t.get("params"), t.get("set") or {})


def _case_study(page: _Page, results: list[Results], settings: Settings) -> None:
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
    if not spec:
        page.p("no stage fits a mechanism to a chosen behaviour: no perceptual check")
        return
    chosen_res = spec[-1]
    final = redesign[-1] if redesign else chosen_res
    _perceptual_check(page, chosen_res, final, settings)
    if redesign:
        _a_of_theta(page, redesign[-1])
        _constant_vs_variable(page, chosen_res, redesign[-1])


def _trial_response(res: Results, node, values: dict):
    """The model's response to a stored trial (a :class:`~.reader.StoredTrial`) with
    ``values`` (name -> value)."""
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


def _figure_5_2(page: _Page, res: Results) -> None:
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


def perceptual_check(mech_curve: dict, chosen_curve: dict, settings: Settings) -> dict:
    """Where the mechanism's force-angle curve differs from the chosen one by more than
    a JND; both curves on the union of their grids (each is linear between its points).

    Returns per direction (``opening``, ``closing``): ``theta`` (rad), ``mechanism``,
    ``chosen``, ``threshold`` (N), ``fails`` (bool per point), ``fraction`` of the
    stroke failing, ``worst`` (angle rad, difference N, threshold N) and ``bands``
    (failing angle intervals, rad).
    """
    theta = np.union1d(mech_curve["theta"], chosen_curve["theta"])
    out = {}
    for d in ("opening", "closing"):
        fm = np.interp(theta, mech_curve["theta"], mech_curve[d])
        fc = np.interp(theta, chosen_curve["theta"], chosen_curve[d])
        threshold = settings.jnd * np.maximum(np.abs(fc), settings.force_floor)
        diff = fm - fc
        fails = np.abs(diff) > threshold
        k = int(np.argmax(np.abs(diff) / threshold))
        widths = np.diff(theta)
        failing = np.sum(widths * (fails[:-1] & fails[1:]))
        out[d] = {
            "theta": theta,
            "mechanism": fm,
            "chosen": fc,
            "threshold": threshold,
            "fails": fails,
            "fraction": float(failing / (theta[-1] - theta[0])),
            "worst": (float(theta[k]), float(diff[k]), float(threshold[k])),
            "bands": _bands(theta, fails),
        }
    return out


def _bands(theta, fails) -> list[tuple[float, float]]:
    """The runs of consecutive failing points as (first, last) angle intervals."""
    f = np.concatenate([[False], np.asarray(fails, dtype=bool), [False]])
    starts = np.flatnonzero(f[1:] & ~f[:-1])
    ends = np.flatnonzero(~f[1:] & f[:-1]) - 1
    return [(float(theta[a]), float(theta[b])) for a, b in zip(starts, ends)]


def _perceptual_check(page: _Page, spec: Results, final: Results, settings: Settings) -> None:
    target_model, curves, constant = _perceptual_curves(spec, final)
    check = perceptual_check(curves["mechanism"], curves["chosen"], settings)
    page.h(3, "Perceptual check: the specified mechanism against the chosen feel")
    page.p(
        f"Force-angle curves (Coulomb level, latch peaks resolved) of the mechanism of stage "
        f"{final.stage} and of the chosen behaviour ({target_model.name} model, the target of "
        f"stage {spec.stage}). A difference is noticeable where it exceeds {100 * settings.jnd:g} % "
        f"of the chosen force, or of {settings.force_floor:g} N where that force is smaller."
    )
    page.table(
        [
            "direction",
            "verdict",
            "stroke beyond the JND",
            "largest difference",
            "angles beyond the JND [deg]",
        ],
        _perceptual_rows(check),
        "perceptual check",
    )
    failing = any(c["fails"].any() for c in check.values())
    page.p(
        "The mechanism's force differs noticeably from the chosen feel at the angles above."
        if failing
        else "The mechanism's force stays within the JND of the chosen feel over the stroke.",
        "fail" if failing else "pass",
    )

    def draw(path):
        _perceptual_figure(path, check, settings, target_model.name, final, spec, constant)

    page.figure(
        "perceptual-check",
        draw,
        "force to move the door slowly, opening and closing, against angle; crosses "
        "mark where the mechanism leaves the JND band of the chosen feel",
    )


def _perceptual_curves(spec: Results, final: Results):
    """``(target model, {"mechanism", "chosen"} curves, constant)``: the force-angle
    curves of the final stage's mechanism and of the chosen feel, and of the
    specification stage's mechanism (constant friction) when the final stage is another
    one (else None)."""
    from evo_door.sim.simulate import force_angle_curve

    target_model, chosen = _target_model(spec)
    model = final.model
    mech = model.load_params({n: v for n, v in final.values().items() if n in model.params})
    curves = {
        "mechanism": force_angle_curve(model, mech),
        "chosen": force_angle_curve(target_model, chosen),
    }
    constant = None
    if final is not spec:
        p0 = model.load_params({n: v for n, v in spec.values().items() if n in model.params})
        constant = force_angle_curve(model, p0)
    return target_model, curves, constant


def _perceptual_rows(check: dict) -> list[list]:
    """One row per direction: verdict, share of the stroke and largest difference
    beyond the JND, the angle bands where it is exceeded (the first 8)."""
    rows = []
    for d, c in check.items():
        angle, diff, thr = c["worst"]
        bands = ", ".join(
            f"{math.degrees(a):.1f}..{math.degrees(b):.1f}" for a, b in c["bands"][:8]
        )
        more = f" (+{len(c['bands']) - 8} more)" if len(c["bands"]) > 8 else ""
        rows.append(
            [
                d,
                "noticeable" if c["fails"].any() else "within the JND",
                f"{100 * c['fraction']:.1f} %",
                f"{diff:+.2f} N at {math.degrees(angle):.2f} deg (JND {thr:.2f} N)",
                (bands + more) or "-",
            ]
        )
    return rows


def _perceptual_figure(path, check, settings, target_name, final, spec, constant) -> None:
    """The two panels (opening, closing): the chosen force with its JND band, the
    mechanism's (crosses beyond the band), and the constant-friction one if any."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 6.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for ax, d in zip(axes, ("opening", "closing")):
        c = check[d]
        deg = np.degrees(c["theta"])
        ax.fill_between(
            deg,
            c["chosen"] - c["threshold"],
            c["chosen"] + c["threshold"],
            color="0.85",
            label=f"chosen +- JND ({100 * settings.jnd:g} %)",
        )
        ax.plot(deg, c["chosen"], color="k", lw=1.2, label=f"chosen ({target_name})")
        ax.plot(
            deg,
            c["mechanism"],
            color="tab:red",
            lw=1.1,
            ls="--",
            label=f"mechanism (stage {final.stage})",
        )
        if constant is not None:
            ax.plot(
                np.degrees(constant["theta"]),
                constant[d],
                color="tab:blue",
                lw=0.9,
                ls=":",
                label=f"constant friction (stage {spec.stage})",
            )
        bad = c["fails"]
        ax.plot(deg[bad], c["mechanism"][bad], "x", color="tab:red", ms=3, label="beyond the JND")
        ax.set_ylabel(f"{d} force [N]\n(+ toward closing)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, ncol=2)
    axes[1].set_xlabel("theta [deg] (0 open, 90 closed)")
    fig.suptitle(
        "force-angle curves: specified mechanism against the chosen haptic behaviour",
        fontsize=10,
    )
    save_figure(fig, path, dpi=110)


def _a_of_theta(page: _Page, res: Results) -> None:
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


def _constant_vs_variable(page: _Page, spec: Results, redesign: Results) -> None:
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
