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

import os
import sys
from typing import Any

__version__ = "0.2.0.dev0"

#: numba's cache locators: evo-door's, which stamp a kernel with every source it imports
#: (:mod:`evo_door.kernel_cache`), then numba's own list (``kernel_cache.LOCATORS``; a
#: test checks they agree). Named here, without importing numba, before any kernel is
#: decorated.
KERNEL_CACHE_LOCATORS = (
    "evo_door.kernel_cache.UserProvided,evo_door.kernel_cache.InTree,"
    "evo_door.kernel_cache.UserWide,UserProvidedCacheLocator,InTreeCacheLocator,"
    "UserWideCacheLocator,IPythonCacheLocator,ZipCacheLocator"
)


def _use_kernel_cache() -> None:
    """Put evo-door's locators in front of those numba reads (its environment variable,
    and its live setting when numba came first); a user's own list stays behind them."""
    own = os.environ.get("NUMBA_CACHE_LOCATOR_CLASSES", "")
    if own.startswith(KERNEL_CACHE_LOCATORS):
        return
    value = KERNEL_CACHE_LOCATORS + ("," + own if own else "")
    os.environ["NUMBA_CACHE_LOCATOR_CLASSES"] = value
    config = getattr(sys.modules.get("numba"), "config", None)
    if config is not None:
        config.CACHE_LOCATOR_CLASSES = value


_use_kernel_cache()

#: Whether numba's compilations are announced on stderr (set by the command line while a
#: command runs; :mod:`evo_door.kernel_cache`).
compile_notes = False

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
