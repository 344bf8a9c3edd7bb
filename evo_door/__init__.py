"""evo-door: a workbench for re-engineering how a product feels.

Physical and haptic models of a dishwasher door, compiled fixed-step integrators,
genetic-algorithm parameter estimation from measured trials and translation of a
chosen haptic feel back into technical specifications.

The Python API (``docs/api.md``): ``evo_door.Experiment``, ``evo_door.Pipeline``,
``evo_door.trial_file``, ``evo_door.load`` and the result types, all from
:mod:`evo_door.api`, imported when first used (PEP 562) so that ``import evo_door``
stays light. This module is the bottom layer; reaching up to ``evo_door.api``, and
only from :func:`__getattr__`, is the one exception (``docs/architecture.md``).
"""

from __future__ import annotations

from typing import Any

__version__ = "0.2.0.dev0"

#: the names :mod:`evo_door.api` offers at the package's top
API = (
    "Checks",
    "Estimate",
    "Experiment",
    "Identifiable",
    "Pipeline",
    "PipelineResult",
    "Run",
    "TrialFile",
    "UserError",
    "load",
    "trial_file",
)


def __getattr__(name: str) -> Any:
    if name in API:
        import evo_door.api

        return getattr(evo_door.api, name)
    raise AttributeError(f"module 'evo_door' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *API])
