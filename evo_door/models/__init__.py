"""Models of the door: the haptic model (sensations) and the physical door (specifications).

Other models plug in by entry point (group ``evo_door.models``), import path or file
path: see :func:`get_model`.
"""

from evo_door.models.base import (
    REGISTRY,
    Declaration,
    Model,
    allow_model,
    available_models,
    check_model,
    get_declaration,
    get_model,
    is_code_spec,
    model_in_file,
    resolve_model_name,
)

__all__ = [
    "Declaration",
    "Model",
    "REGISTRY",
    "allow_model",
    "available_models",
    "check_model",
    "get_declaration",
    "get_model",
    "is_code_spec",
    "model_in_file",
    "resolve_model_name",
]
