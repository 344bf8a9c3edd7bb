"""What every 1-DOF model of the workbench provides, and the model registry.

A model is data plus one compiled function:

- ``params``: its :class:`~evo_door.params.ParamTable` (the declaration);
- ``accel``: a numba-compiled ``accel(theta, dtheta, force, p) -> ddtheta`` where
  ``theta`` (rad) is the door angle (0 fully open, pi/2 closed), ``force`` (N) the
  user's tangential force at the handle (positive toward closing) and ``p`` the flat
  parameter vector in declaration order. ``accel`` must be affine in ``force``
  (true of any mechanical model driven by an external force); the quasi-static
  force-angle curve relies on it.
- integration defaults: the scheme and sub-steps per sample that keep the model's
  stiffest element stable at 1024 Hz.

Models are registered by import path so that ``evo_door.models`` imports nothing
heavy until a model is asked for.
"""

from __future__ import annotations

import importlib
import importlib.util
from dataclasses import dataclass, field
from typing import Callable

from evo_door.errors import UserError
from evo_door.params import ParamSet, ParamTable, load_params
from evo_door.params.declaration import suggest


@dataclass(frozen=True)
class Model:
    """A registered 1-DOF model (see module docstring)."""

    name: str
    title: str
    params: ParamTable
    accel: Callable
    method: str = "semi_implicit"
    substeps: int = 2
    #: Default initial angle (rad) for simulations that do not give one.
    theta0: float = 0.0
    #: Free-form notes shown by ``evo-door params MODEL``.
    notes: str = ""
    extras: dict = field(default_factory=dict)

    def load_params(self, spec=None, overrides=None) -> ParamSet:
        """A parameter set from a file or preset name (or defaults), with overrides."""
        ps = load_params(self.params, spec)
        return ps.replace(overrides, source=ps.source) if overrides else ps


#: name -> "module:attribute" of the Model object.
REGISTRY: dict[str, str] = {
    "haptic": "evo_door.models.haptic:MODEL",
    "door": "evo_door.models.door:MODEL",
}


def available_models() -> list[str]:
    """Registered models whose module is importable."""
    names = []
    for name, target in REGISTRY.items():
        module = target.split(":")[0]
        if importlib.util.find_spec(module) is not None:
            names.append(name)
    return names


def get_model(name: str) -> Model:
    """The registered model ``name`` (imports its module on first use).

    ``name`` may also be an import path ``package.module:ATTRIBUTE`` naming a
    :class:`Model` object, so that users can bring their own model (a drawer, a
    button) without registering it here.
    """
    if ":" in name and name not in REGISTRY:
        module, _, attr = name.partition(":")
        try:
            obj = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as exc:
            raise UserError(f"cannot import model {name!r}: {exc}") from None
        if not isinstance(obj, Model):
            raise UserError(f"{name!r} is not an evo_door Model")
        return obj
    if name not in REGISTRY:
        raise UserError(f"unknown model {name!r}" + suggest(name, REGISTRY)
                        + f"; models: {', '.join(available_models())}")
    module, attr = REGISTRY[name].split(":")
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name == module:
            raise UserError(f"model {name!r} is not available in this version") from None
        raise
    return getattr(mod, attr)
