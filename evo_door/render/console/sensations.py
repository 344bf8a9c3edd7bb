"""What a page may change of the rendered model: the parameters, their keys, a change
checked, and the force-angle curve a page draws of the set in force.

The console learns the rendered model from the renderer (its control port's ``get:
params`` names it, ``get: declaration`` lists its rows), and which parameters a page
may change from the declaration alone:

- a declaration with a ``sensation`` group (the haptic model): that group, as always;
- any other (a mechanism file, a model on a state vector): its ``specification``
  (masses, stiffnesses, pre-loads, frictions, dampings) and ``numerics`` groups (an
  end stop's stiffness and damping, a friction's tanh slope: what the explicit loop is
  most often tuned by). Its ``geometry`` (where a stop or a detent sits, where a
  soft-close engages, a lever's length) stays as the render started: changed live, it
  would move a part under the hand.

Each such parameter gets a slider, two keys and a step as the terminal's keys do
(:func:`~evo_door.render.keys.keys_for`: 1/20 of its range rounded down to 1, 2 or 5
times a power of ten); past the 35 pairs of keys, a parameter has a slider only. A
sensation's range is its declared one, chosen for people. A mechanism's declared
bounds are sanity bounds (a mass from 1e-6 to 1e5 kg, a stop from 1 to 1e9 N/m), whose
twentieth would be no step at all: its slider's range is the declared one cut to
:data:`WINDOW` times the value the console started from (from 0, or the lower bound:
a 3 kg drawer's mass 0..12 kg, step 0.5 kg), the whole declared range for a value of
0. The page may not go past it (``evo-door push`` may, within the declaration).
"""

from __future__ import annotations

import math

from evo_door.render.keys import GROUP, keys_for, nice_step
from evo_door.render.messages import checked_values

#: the groups a page changes of a model without sensations (not its geometry: where
#: its parts are; nor a ``device`` group: the haptic model's device's own)
GROUPS = ("specification", "numerics")
#: a mechanism's slider reaches this many times the value the console started from
WINDOW = 4.0


def tunable_params(table) -> list:
    """The declared parameters of ``table`` a page may change (see the module docstring)."""
    sensation = [p for p in table if p.group == GROUP]
    return sensation or [p for p in table if p.group in GROUPS]


def window(p, value: float) -> tuple[float, float]:
    """A mechanism's slider range for the declared parameter ``p`` at ``value``: the
    declared range cut to :data:`WINDOW` times the value, on the value's side of 0.

    >>> from evo_door.params import Param
    >>> window(Param("m", "kg", 3.0, 1e-6, 1e5, "specification", ""), 3.0)
    (1e-06, 12.0)
    >>> window(Param("f", "N", 0.0, -1e4, 1e4, "specification", ""), 0.0)
    (-10000.0, 10000.0)
    """
    if value > 0.0:
        return max(p.lower, 0.0), min(p.upper, WINDOW * value)
    if value < 0.0:
        return max(p.lower, WINDOW * value), min(p.upper, 0.0)
    return p.lower, p.upper


def slider_ranges(table, start: dict | None = None) -> dict[str, tuple[float, float]]:
    """Each parameter a page may change of ``table`` -> its slider's range: a sensation's
    declared one, a mechanism's :func:`window` about its value in ``start`` (default:
    its declared default)."""
    params = tunable_params(table)
    start = start or {}
    if any(p.group == GROUP for p in params):
        return {p.name: (p.lower, p.upper) for p in params}
    return {p.name: window(p, float(start.get(p.name, p.default))) for p in params}


def tunable_keys(table, start: dict | None = None) -> dict[str, tuple[str, float]]:
    """key -> (parameter name, signed step) for what a page may change of ``table``,
    the step :func:`~evo_door.render.keys.nice_step` of its slider's range (the haptic
    model's: :func:`~evo_door.render.keys.key_map`'s); the terminal's keys of a
    mechanism."""
    ranges = slider_ranges(table, start)
    steps = {name: nice_step(hi - lo) for name, (lo, hi) in ranges.items()}
    return keys_for(tunable_params(table), steps)


class Tunable:
    """The rendered ``model`` as a page sees it: what it may change, with what keys, and
    the model's force-angle curve."""

    def __init__(self, model, start: dict | None = None):
        self.model = model
        self.table = model.params
        self.params = tunable_params(self.table)
        self.names = [p.name for p in self.params]
        #: the haptic console: sensations, the door's picture, the latch, JND sessions
        self.sensations = any(p.group == GROUP for p in self.table)
        #: each parameter's slider range: a sensation's declared one, a mechanism's
        #: :func:`window` about the value the console started from
        self.ranges = slider_ranges(self.table, start)
        self.steps = {name: nice_step(hi - lo) for name, (lo, hi) in self.ranges.items()}
        self.keys = tunable_keys(self.table, start)
        self.what = (
            "sensation parameter of the declaration"
            if self.sensations
            else f"parameter of {self.table.model!r} the console changes (its specification "
            "and numerics; its geometry stays)"
        )

    def view(self) -> dict:
        """The model as the page draws it: its name and title, the handle's coordinate
        (its unit and range: an angle in rad, a linear handle's position in m), and
        whether the page shows the door (its latch, its JND sessions)."""
        lo, hi = (float(v) for v in self.model.theta_range)
        return {
            "name": self.table.model,
            "title": self.model.title,
            "unit": self.model.theta_unit,
            "range": [lo, hi],
            "door": self.sensations,
            "jnd": self.sensations,
        }

    def declaration(self) -> dict:
        """The body of ``GET /api/declaration``."""
        keys: dict[str, list[str]] = {}
        for key, (name, step) in self.keys.items():
            pair = keys.setdefault(name, ["", ""])
            pair[0 if step < 0 else 1] = key
        rows = []
        for p in self.params:
            row = {
                "name": p.name,
                "unit": p.unit,
                "lower": p.lower,
                "upper": p.upper,
                "default": p.default,
                "group": p.group,
                "meaning": p.meaning,
                "step": self.steps[p.name],
                "keys": keys.get(p.name, ["", ""]),
            }
            if not self.sensations:  # the slider's range, inside the declared one
                row["range"] = list(self.ranges[p.name])
            rows.append(row)
        return {"params": rows, "display": {"rad": "deg"}, "model": self.view()}

    def check_values(self, values) -> dict[str, float]:
        """A page's change {name: SI value}, checked: names a page may change, finite
        numbers within their bounds (a UserError with the reason otherwise)."""
        return checked_values(values, "values", set(self.names), self.what, table=self.table)

    def curve(self, values: dict) -> dict:
        """The quasi-static (Coulomb) force-angle curve of the set ``values``, against the
        handle's coordinate ``theta`` in its ``unit`` (and ``theta_deg`` for an angle)."""
        from evo_door.params.sets import ParamSet
        from evo_door.sim.simulate import force_angle_curve

        model = self.model
        curve = force_angle_curve(model, ParamSet.from_mapping(model.params, values))
        out = {
            "unit": model.theta_unit,
            "theta": [float(x) for x in curve["theta"]],
            "opening": [float(x) for x in curve["opening"]],
            "closing": [float(x) for x in curve["closing"]],
        }
        if model.theta_unit == "rad":
            out["theta_deg"] = [math.degrees(x) for x in curve["theta"]]
        return out
