"""The component library a mechanism file draws from: kind -> component.

The general components (:mod:`~evo_door.models.blocks.components`), those of
:mod:`~evo_door.models.blocks.springs` (detent, bump, gas strut, tabulated spring) and
the seed's own subsystems (:mod:`~evo_door.models.blocks.seed`: its slotted plate and
its latch), in one mapping that the reader and the code generator take.
"""

from __future__ import annotations

from evo_door.models.blocks.components import COMPONENTS as GENERAL
from evo_door.models.blocks.components import Component
from evo_door.models.blocks.seed import Latch, SlottedPlate
from evo_door.models.blocks.springs import Bump, Detent, GasStrut, TabulatedSpring

#: kind -> component
COMPONENTS: dict[str, Component] = {
    **GENERAL,
    **{c.kind: c for c in (Detent(), Bump(), GasStrut(), TabulatedSpring())},
    **{c.kind: c for c in (SlottedPlate(), Latch())},
}
