"""The component library a mechanism file draws from: kind -> component.

The general components (:mod:`~evo_door.models.blocks.components`) and the seed's own
subsystems (:mod:`~evo_door.models.blocks.seed`), in one mapping that the reader and
the code generator take.
"""

from __future__ import annotations

from evo_door.models.blocks.components import COMPONENTS as GENERAL
from evo_door.models.blocks.components import Component
from evo_door.models.blocks.seed import Latch, SlottedPlate

#: kind -> component
COMPONENTS: dict[str, Component] = {**GENERAL, **{c.kind: c for c in (SlottedPlate(), Latch())}}
