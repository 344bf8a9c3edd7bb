"""The perceptual check of a run fitted to a chosen feel: made, stored, read back, judged.

A run is *fitted to a chosen feel* when its objective is ``perceptual`` or its target
is another model's behaviour (``target: {model: ...}``) or a force-angle curve
(``target: {curve: FILE.csv}``). When such a run completes, the force-angle curve of
its answer (the mechanism: the run's model with the best values, Coulomb level,
latch peaks resolved) is compared with the chosen feel's curve in units of the force
JND (:func:`evo_door.perception.perceptual_check`), and both curves are kept in the
results file's ``perceptual_check`` group so that ``show`` and ``report`` judge and
draw them without simulating again. A file written before the group existed has it
computed on read (:mod:`.reader`).

The JND is the run's own (its ``perception:`` settings, the defaults where it has
none); :meth:`FeelCheck.judged` gives the verdict under another one (``report --jnd``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from evo_door.errors import UserError
from evo_door.files import ATTRS, DamagedFile, Dataset, fields
from evo_door.perception import JND, FeelCurve, check_verdict, model_curve, perceptual_check
from evo_door.perception.feel import DIRECTIONS

#: the units of the settings and of the curves' datasets, as the file records them
_CURVE_UNITS = {"theta": "rad", "opening": "N", "closing": "N"}


@dataclass(frozen=True)
class FeelCheck:
    """A run's answer against the chosen feel: both curves and the JND they are judged by.

    ``mechanism`` is the answer's force-angle curve, ``chosen`` the chosen feel's (their
    ``source`` says what each is), ``jnd`` the run's JND settings; ``dynamics`` the felt
    inertia (kg m) and damping (N s/rad) of both, ``{"inertia": (mechanism, chosen)}``,
    where the chosen feel has them (None: a bare curve, or a file written before they
    were judged); ``recorded`` says whether the file holds the group (False: computed
    when the file was read).
    """

    mechanism: FeelCurve
    chosen: FeelCurve
    jnd: JND
    dynamics: dict | None = None
    recorded: bool = True

    def check(self, jnd: JND | None = None) -> dict:
        """:func:`~evo_door.perception.perceptual_check` of the curves (arrays per point)."""
        return perceptual_check(self.mechanism, self.chosen, jnd or self.jnd)

    def judged(self, jnd: JND | None = None) -> dict:
        """What ``show --json`` prints: per direction the share of the stroke beyond the
        JND, the worst difference and the verdict; the JND settings and their units; the
        sources of both curves. ``jnd`` judges it under other settings than the run's."""
        jnd = jnd or self.jnd
        out = check_verdict(self.check(jnd), jnd, self.judged_dynamics(jnd))
        out["jnd_units"] = dict(JND.UNITS)
        out["mechanism"] = self.mechanism.source
        out["chosen"] = self.chosen.source
        out["recorded"] = self.recorded
        return out

    def judged_dynamics(self, jnd: JND) -> dict | None:
        """The felt dynamics with their JNDs under ``jnd``, as check_verdict takes them."""
        if not self.dynamics:
            return None
        limit = {"inertia": jnd.inertia_threshold, "damping": jnd.damping_threshold}
        return {k: (m, c, limit[k](c)) for k, (m, c) in self.dynamics.items()}

    def to_tree(self) -> dict:
        """The ``perceptual_check`` group: the verdict and the JND as attributes, each
        curve as a group of datasets (``theta`` rad, ``opening`` and ``closing`` N)."""
        verdict = self.judged()
        return {
            ATTRS: {
                "jnd": json.dumps(self.jnd.as_dict()),
                "dynamics": json.dumps(self.dynamics),
                "passes": bool(verdict["passes"]),
                "verdict": json.dumps({d: verdict[d] for d in DIRECTIONS}),
            },
            "mechanism": _curve_tree(self.mechanism),
            "chosen": _curve_tree(self.chosen),
        }

    @classmethod
    def from_tree(cls, node) -> FeelCheck:
        """Read the group back (a tree, or a group read on demand), each value checked (a
        results file is data: :mod:`evo_door.files.fields`)."""
        a = node[ATTRS]
        dynamics = fields.json_value(a, "dynamics", None)
        if dynamics is not None:
            where = fields.place_of(a, "dynamics")
            dynamics = fields.as_mapping(dynamics, where, fields.as_numbers)
            for k, pair in dynamics.items():
                if k not in ("inertia", "damping") or len(pair) != 2:
                    raise DamagedFile(f"{where}: expected inertia and damping, each [m, c]")
        return cls(
            mechanism=_curve_from_tree(fields.group(node, "mechanism")),
            chosen=_curve_from_tree(fields.group(node, "chosen")),
            jnd=JND.from_mapping(fields.json_value(a, "jnd"), fields.place_of(a, "jnd")),
            dynamics=dynamics,
            recorded=True,
        )


def _curve_tree(curve: FeelCurve) -> dict:
    return {
        ATTRS: {"source": curve.source, "origin": json.dumps(curve.origin)},
        **{
            k: Dataset(np.asarray(v, dtype=np.float64), {"unit": _CURVE_UNITS[k]})
            for k, v in curve.as_dict().items()
        },
    }


def _curve_from_tree(node) -> FeelCurve:
    a = node[ATTRS]
    theta = fields.array(node, "theta", shape=(None,))
    return FeelCurve(
        theta,
        fields.array(node, "opening", shape=theta.shape),
        fields.array(node, "closing", shape=theta.shape),
        source=fields.text(a, "source", ""),
        origin=fields.as_mapping(fields.json_value(a, "origin", {}), fields.place_of(a, "origin")),
    )


def fitted_to_feel(config: dict) -> bool:
    """Whether a run (its resolved configuration) was fitted to a chosen feel."""
    kind = (config.get("target") or {}).get("kind")
    return config["objective"]["kind"] == "perceptual" or kind in ("model", "curve")


def run_jnd(config: dict, feel=None) -> JND:
    """The JND a run judges a feel by: its chosen feel's, else its ``perception``
    settings (a file written before they were kept: the defaults)."""
    if feel is not None:
        return feel.jnd
    return JND.from_mapping(config.get("perception") or {})


def default_source(setting: str) -> str:
    """The source of a JND setting left at its default: a Weber fraction's is the
    literature's, and so is the position JND's; a floor's, a typical speed's and the
    handle's radius, the project's choice."""
    from evo_door.perception.jnd_file import LITERATURE, WEBER_SETTINGS

    if setting in WEBER_SETTINGS or setting == "position":
        return LITERATURE
    return "default (docs/perception.md)"


def run_jnd_sources(config: dict) -> dict[str, str]:
    """Where each of a run's JND settings came from (the resolved configuration's
    ``perception_sources``). A file written before they were kept: a setting at its
    default is the literature's, another one was set in the run's experiment file."""
    from evo_door.perception.jnd_file import LITERATURE

    stored = config.get("perception_sources") or {}
    jnd, default = run_jnd(config).as_dict(), JND().as_dict()
    unknown = "set in the run's experiment file (the file does not say where)"
    return {k: stored.get(k) or (LITERATURE if jnd[k] == default[k] else unknown) for k in jnd}


def jnds_used(jnd: JND, sources: dict[str, str]) -> dict[str, dict]:
    """Every JND setting with its value, unit and source: what ``show --json`` gives as
    ``jnds`` and the report's table "JNDs used" shows."""
    return {
        k: {"value": v, "unit": JND.UNITS[k], "source": sources.get(k) or default_source(k)}
        for k, v in jnd.as_dict().items()
    }


def jnd_value(entry: dict) -> str:
    """One entry of :func:`jnds_used` as text: a Weber fraction in %, else with its unit.

    >>> jnd_value({"value": 0.1, "unit": "1"}), jnd_value({"value": 0.5, "unit": "N"})
    ('10 %', '0.5 N')
    """
    value, unit = entry["value"], entry["unit"]
    return f"{100 * value:.3g} %" if unit == "1" else f"{value:g} {unit}"


def chosen_curve(config: dict, feel=None) -> FeelCurve:
    """The chosen feel's curve: the one the run stored (``setup/feel``, the perceptual
    objective's), else the target model's with its parameters, else the curve file."""
    if feel is not None:
        return feel.curve
    target = config["target"]
    if target.get("kind") == "curve":
        from evo_door.perception import read_curve_csv

        return read_curve_csv(target["curve"])
    from evo_door.models import get_model

    model = get_model(target["model"])
    params = model.load_params(target.get("params"), target.get("set") or {})
    return model_curve(model, params, source=f"{model.name} model (the target)")


def feel_check(model, full, config: dict, feel=None, recorded: bool = True) -> FeelCheck | None:
    """The perceptual check of ``model`` with the full parameter vector ``full`` against
    the run's chosen feel; None for a run not fitted to one.

    ``feel`` is the run's :class:`~evo_door.perception.FeelTarget` where it has one.
    """
    if not fitted_to_feel(config):
        return None
    full = np.asarray(full, dtype=np.float64)
    mechanism = model_curve(model, full, source=f"{model.name} model (the answer)")
    dynamics = None
    if feel is not None and feel.dynamics is not None:
        got = feel.dynamics_check(model, full)
        dynamics = {k: (float(m), float(c)) for k, (m, c, _) in got.items()}
    return FeelCheck(
        mechanism, chosen_curve(config, feel), run_jnd(config, feel), dynamics, recorded=recorded
    )


def try_feel_check(model, full, config: dict, feel=None, recorded: bool = True):
    """:func:`feel_check`, or None where it cannot be made (a target model that no longer
    loads, a curve file moved away, a curve that is not finite): a run's answer and a
    file's other contents are never lost to it."""
    try:
        return feel_check(model, full, config, feel, recorded)
    except (UserError, ValueError, KeyError):
        return None
