"""Models of the door: the haptic model (sensations) and the physical door (specifications)."""

from evo_door.models.base import REGISTRY, Model, available_models, get_model

__all__ = ["Model", "REGISTRY", "available_models", "get_model"]
