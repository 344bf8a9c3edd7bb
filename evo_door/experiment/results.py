"""Reading results files: summaries for ``evo-door show`` / ``runs`` and the fit plot."""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import numpy as np

from evo_door.errors import UserError
from evo_door.experiment import store
from evo_door.files import save_figure
from evo_door.optim.problem import Objective

A = store.ATTRS


class Results:
    """A results file, read once (see ``docs/experiments.md`` for the layout)."""

    def __init__(self, path):
        self.path = Path(path)
        self.tree = store.read_tree(self.path)
        self.attrs = self.tree[A]
        self.config = json.loads(self.tree["experiment"]["resolved"])

    @functools.cached_property
    def model(self):
        """The run's model, or None where it cannot be loaded (a user file moved away)."""
        from evo_door.models import get_model

        try:
            return get_model(self.attrs["model"])
        except UserError:
            return None

    @property
    def complete(self) -> bool:
        return self.attrs.get("status") == "complete"

    @property
    def free(self) -> list[str]:
        return list(self.tree["setup"][A]["free"])

    def jobs(self) -> list[dict]:
        keys = sorted((k for k in self.tree["jobs"] if k != A), key=int)
        return [self.tree["jobs"][k] for k in keys]

    def best(self) -> dict[str, float]:
        """Free parameter name -> value: the run's answer, or the GA's best so far."""
        if "best" in self.tree:
            return dict(self.tree["best"][A]["values"])
        best, fit = None, math.inf
        for job in self.jobs():
            if "ga" in job and job["ga"]["hof_fitness"].size and job["ga"]["hof_fitness"][0] <= fit:
                fit = float(job["ga"]["hof_fitness"][0])
                best = job["ga"]["hof_x"][0]
        return {} if best is None else dict(zip(self.free, map(float, best)))

    def truth(self) -> dict[str, float]:
        """True values of the free parameters, when the fitted trials carry them.

        Trials made by the virtual rig (or any model) store the parameters that made
        them; when every fitted trial has them, for this run's model, and they agree,
        they score the fit. Otherwise (measured data) an empty dict.
        """
        trials = self.tree.get("trials", {})
        found = None
        for key, group in trials.items():
            if key == A or not key.startswith("fit_"):
                continue
            truth = group[A].get("truth") or {}
            model = self.model
            names = {self.attrs.get("model"), model.name if model is not None else None}
            if truth.get("model") not in names or "params" not in truth:
                return {}
            values = {n: float(truth["params"][n]) for n in self.free if n in truth["params"]}
            if len(values) != len(self.free) or (found is not None and values != found):
                return {}
            found = values
        return found or {}

    def fitness(self) -> float:
        if "best" in self.tree:
            return float(self.tree["best"][A]["fitness"])
        fits = [float(j["ga"][A]["best_fitness"]) for j in self.jobs() if "ga" in j]
        return min(fits) if fits else math.nan

    def progress(self) -> str:
        return _progress(self.attrs, self.config)

    def summary(self) -> dict:
        """Everything ``show --json`` prints (JSON-able)."""
        cfg = self.config
        t = self.tree["timings"][A]
        out = {
            "file": str(self.path),
            "name": self.attrs.get("name"),
            "model": self.attrs.get("model"),
            "status": self.attrs.get("status"),
            "created": self.attrs.get("created"),
            "updated": self.attrs.get("updated"),
            "seed": self.attrs.get("seed"),
            "best": self.best(),
            "truth": self.truth(),
            "fitness": _num(self.fitness()),
            "fixed": cfg.get("fixed", {}),
            "free": cfg.get("free", {}),
            "objective": cfg["objective"],
            "algorithm": cfg["algorithm"],
            "per_trial": cfg["per_trial"],
            "target": cfg["target"],
            "progress": self.progress(),
            "evaluations": t.get("evaluations", 0),
            "blowups": sum(int(j["ga"][A]["blowups"]) for j in self.jobs() if "ga" in j),
            "seconds": t.get("total_s"),
            "evaluations_per_s": t.get("evaluations_per_s"),
            "versions": self.tree["versions"][A],
        }
        if "best" in self.tree:
            b = self.tree["best"][A]
            out["fit_errors"] = {k: _num(v) for k, v in b["fit_errors"].items()}
            out["validation_errors"] = {k: _num(v) for k, v in b["validation_errors"].items()}
            out["best_meaning"] = b.get("meaning", "")
        if "summary" in self.tree:
            s = self.tree["summary"]
            out["per_trial_fits"] = {
                trial: dict(zip(self.free, map(float, row)))
                for trial, row in zip(s[A]["trials"], s["x"])
            }
            out["table"] = {
                n: {
                    "min": float(s["min"][i]),
                    "max": float(s["max"][i]),
                    "mean": float(s["mean"][i]),
                }
                for i, n in enumerate(self.free)
            }
        return out

    def responses(self) -> list[dict]:
        if "response" not in self.tree:
            return []
        keys = sorted((k for k in self.tree["response"] if k != A), key=int)
        return [
            {
                **self.tree["response"][k][A],
                **{n: v for n, v in self.tree["response"][k].items() if n != A},
            }
            for k in keys
        ]


def _progress(attrs: dict, config: dict) -> str:
    done = attrs.get("generations_done") or []
    total = attrs.get("generations", 0)
    if config["algorithm"]["kind"] != "ga":
        return f"{attrs.get('jobs_done', 0)}/{attrs.get('jobs', 1)} fits"
    if len(done) == 1:
        return f"{max(done[0], 0)}/{total} gen"
    return f"{attrs.get('jobs_done', 0)}/{len(done)} fits x {total} gen"


def _num(v):
    v = float(v)
    return v if math.isfinite(v) else None


def _preprocess_text(pre: dict) -> str:
    """What was done to the target trials, as a tail for the objective line (or "")."""
    steps = []
    if pre.get("rate_bias", "none") != "none":
        steps.append(f"gyroscope bias removed ({pre['rate_bias']})")
    if pre.get("lowpass") is not None:
        steps.append(f"low-pass {pre['lowpass']:g} Hz")
    if pre.get("trim"):
        steps.append("trimmed to the motion")
    return f"; target preprocessed: {', '.join(steps)}" if steps else ""


def format_show(res: Results) -> str:
    """The human-readable ``evo-door show``."""
    s = res.summary()
    cfg = res.config
    alg = cfg["algorithm"]
    obj = cfg["objective"]
    lines = [
        f"{s['name']}  ({res.path})",
        f"  model {s['model']}, status {s['status']} ({s['progress']}), seed {s['seed']}, "
        f"created {s['created']}",
        f"  objective {obj['kind']} on derivative {obj['derivative']}, {obj['combine']} "
        f"over trials" + _preprocess_text(cfg["target"].get("preprocess") or {}),
        (
            "  algorithm "
            + (
                f"GA population {alg['population']} x {alg['generations']} "
                f"generations, reproduction {alg['reproduction_ratio']:g}, "
                f"mutation p {alg['mutation_probability']:g} amplitude "
                f"{alg['mutation_amplitude']:g}, polish {alg['polish']}"
                if alg["kind"] == "ga"
                else f"nlpql (SLSQP), max {alg['max_iterations']} iterations"
            )
        ),
        f"  {s['evaluations']} evaluations, {s['blowups']} blow-ups, {(s['seconds'] or 0):.1f} s",
    ]
    units = _units(res)
    if "table" in s:
        lines.append(f"\nper-trial fits ({len(s['per_trial_fits'])} trials), as seed table 5.3:")
        w = max(len(n) for n in res.free)
        lines.append(f"  {'parameter':<{w}}  {'min':>12}  {'max':>12}  {'mean':>12}  unit")
        for n, row in s["table"].items():
            lines.append(
                f"  {n:<{w}}  {row['min']:>12.6g}  {row['max']:>12.6g}  "
                f"{row['mean']:>12.6g}  {units.get(n, '')}"
            )
    funit = Objective(obj["kind"], obj["derivative"], obj["combine"]).unit
    lines.append(
        f"\nbest ({s.get('best_meaning') or 'best so far'}): fitness {_fmt(s['fitness'])} {funit}"
    )
    if s["best"]:
        w = max(len(n) for n in s["best"])
        truth = s["truth"]
        for n, v in s["best"].items():
            lo, hi = cfg["free"][n]
            line = f"  {n:<{w}}  {v:>14.8g} {units.get(n, ''):<8} in [{lo:g}, {hi:g}]"
            if n in truth:
                true = truth[n]
                rel = f" ({100 * (v - true) / true:+.2f} %)" if true != 0 else ""
                line = f"{line:<{w + 48}} true {true:.8g}{rel}"
            lines.append(line)
    if s["fixed"]:
        lines.append(
            "fixed: "
            + ", ".join(f"{k} = {v:g} {units.get(k, '')}".rstrip() for k, v in s["fixed"].items())
        )
    if s.get("fit_errors"):
        lines.append(
            f"fit error per trial in {funit}: "
            + ", ".join(f"{k} {_fmt(v)}" for k, v in s["fit_errors"].items())
        )
    if s.get("validation_errors"):
        lines.append(
            f"validation error in {funit}:    "
            + ", ".join(f"{k} {_fmt(v)}" for k, v in s["validation_errors"].items())
        )
    return "\n".join(lines)


def _fmt(v) -> str:
    return "blew up" if v is None else f"{v:.4g}"


def _units(res: Results) -> dict:
    return {} if res.model is None else {p.name: p.unit for p in res.model.params}


def list_runs(folder) -> list[dict]:
    """One row per results file in ``folder`` (newest first); unreadable files are flagged."""
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"{folder}: no such folder")
    rows = []
    for path in sorted(folder.glob("*.h5")):
        try:
            p = store.peek(path)
        except UserError as exc:
            if "not an evo-door results file" in str(exc):
                continue
            rows.append(
                {
                    "file": path.name,
                    "name": "?",
                    "model": "?",
                    "status": "unreadable",
                    "progress": "",
                    "fitness": None,
                    "created": "",
                    "seed": "",
                }
            )
            continue
        a = p[A]
        if p["best"] is not None:
            fitness = p["best"]["fitness"]
        else:
            fits = [j["best_fitness"] for j in p["jobs"].values() if j]
            fitness = min(fits) if fits else math.nan
        rows.append(
            {
                "file": path.name,
                "name": a.get("name", ""),
                "model": a.get("model", ""),
                "status": a.get("status", ""),
                "progress": _progress(a, p["resolved"]),
                "fitness": _num(fitness),
                "created": a.get("created", ""),
                "seed": a.get("seed", ""),
            }
        )
    rows.sort(key=lambda r: r["created"], reverse=True)
    return rows


def format_runs(rows: list[dict]) -> str:
    header = ["file", "name", "model", "status", "progress", "best fitness", "seed", "created"]
    table = [
        [
            r["file"],
            r["name"],
            r["model"],
            r["status"],
            r["progress"],
            "" if r["fitness"] is None else f"{r['fitness']:.4g}",
            str(r["seed"]),
            r["created"],
        ]
        for r in rows
    ]
    widths = [
        max(len(h), *(len(row[i]) for row in table)) if table else len(h)
        for i, h in enumerate(header)
    ]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    out = [fmt.format(*header).rstrip(), fmt.format(*("-" * w for w in widths)).rstrip()]
    out += [fmt.format(*row).rstrip() for row in table]
    return "\n".join(out)


def plot_fit(res: Results, path, max_trials: int = 12) -> None:
    """Best response next to the target, one panel per trial (fitted, then validation)."""
    from matplotlib.figure import Figure

    from evo_door.channels import title, unit

    rows = res.responses()
    if not rows:
        raise UserError(
            f"{res.path}: the run is not complete, there is no best response yet "
            "(evo-door resume it first)"
        )
    rows = rows[:max_trials]
    n = len(rows)
    ncols = 1 if n == 1 else 2
    nrows = math.ceil(n / ncols)
    fig = Figure(
        figsize=(6.2 * ncols + (2.0 if n == 1 else 0.0), 2.6 * nrows + 1.0), layout="constrained"
    )
    axes = fig.subplots(nrows, ncols, squeeze=False)
    channel = rows[0]["channel"]
    for ax, r in zip(axes.flat, rows):
        t = np.asarray(r["t"])
        ax.plot(t, r["target"], color="0.25", lw=1.2, label="target")
        ax.plot(t, r["model"], color="tab:red", lw=1.0, ls="--", label="model (best)")
        ax.set_title(
            f"{r['trial_id']} ({'fitted' if r['role'] == 'fit' else 'validation'}), "
            f"error {_fmt(_num(r['error']))}",
            fontsize=9,
        )
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"{channel} [{unit(channel)}]")
        ax.grid(alpha=0.3)
        axf = ax.twinx()
        axf.plot(t, r["force"], color="tab:blue", lw=0.6, alpha=0.35)
        axf.set_ylabel("force [N]", color="tab:blue", fontsize=8)
        axf.tick_params(axis="y", labelcolor="tab:blue", labelsize=7)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    axes.flat[0].legend(loc="best", fontsize=8)
    obj = res.config["objective"]
    fig.suptitle(
        f"{res.attrs['name']}: {title(channel)}, best model vs target\n"
        f"model {res.attrs['model']}, objective {obj['kind']} (derivative "
        f"{obj['derivative']}, {obj['combine']}), fitness {_fmt(_num(res.fitness()))}",
        fontsize=10,
    )
    save_figure(fig, path, dpi=110)
