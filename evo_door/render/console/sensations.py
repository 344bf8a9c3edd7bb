"""What a page may change: the sensation parameters, their keys, a change checked, and
the force-angle curve a page draws of the set in force."""

from __future__ import annotations

import math

from evo_door.models.haptic import PARAMS
from evo_door.render.keys import GROUP, key_map, nice_step
from evo_door.render.messages import checked_values


def sensation_names() -> list[str]:
    """The parameters a page may change: the declaration's ``sensation`` group."""
    return [p.name for p in PARAMS if p.group == GROUP]


def declaration() -> dict:
    """The body of ``GET /api/declaration``."""
    keys: dict[str, list[str]] = {}
    for key, (name, step) in key_map().items():
        pair = keys.setdefault(name, ["", ""])
        pair[0 if step < 0 else 1] = key
    rows = []
    for p in PARAMS:
        if p.group != GROUP:
            continue
        rows.append(
            {
                "name": p.name,
                "unit": p.unit,
                "lower": p.lower,
                "upper": p.upper,
                "default": p.default,
                "group": p.group,
                "meaning": p.meaning,
                "step": nice_step(p.upper - p.lower),
                "keys": keys[p.name],
            }
        )
    return {"params": rows, "display": {"rad": "deg"}}


def check_values(values) -> dict[str, float]:
    """A page's change {name: SI value}, checked: declared sensation names, finite
    numbers within their bounds (a UserError with the reason otherwise)."""
    return checked_values(
        values, "values", set(sensation_names()), "sensation parameter of the declaration"
    )


def force_curve(values: dict) -> dict:
    """The quasi-static (Coulomb) force-angle curve of the haptic set ``values``."""
    from evo_door.models import get_model
    from evo_door.params.sets import ParamSet
    from evo_door.sim.simulate import force_angle_curve

    model = get_model("haptic")
    curve = force_angle_curve(model, ParamSet.from_mapping(model.params, values))
    return {
        "theta_deg": [math.degrees(x) for x in curve["theta"]],
        "opening": [float(x) for x in curve["opening"]],
        "closing": [float(x) for x in curve["closing"]],
    }
