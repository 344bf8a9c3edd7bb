"""The seed's own subsystems as components: its slotted-plate linkage and its latch.

AMESim held the door as a few supercomponents (seed chapter 3: PLATE, RELATIVESPEED,
FRICTIONFORCE, LATCH). Two of them do not split into springs and frictions acting on
one coordinate each, so the library takes them whole, as a mechanism file names any
other component:

- ``slotted_plate``: the plate A-B-C between a rotary body and the ground (the door's
  closed chain O-A-B, its spring and friction at C, the joint frictions at A and B, the
  pad D rubbing the plate and the slot's Coulomb friction). The slot's normal force
  follows from the moment balance of *every* load on the massless plate, so the slot
  friction couples them all: no set of separate elements acting through a ratio can
  hold it.
- ``latch``: the three-spring catch near closed (unlock spring with its hold, lock
  ramp with its hold, the seat) with its wall beyond closed, as one block.

Both call the door's own compiled blocks (:mod:`evo_door.models.door`), so a mechanism
built from them is the built-in door's physics, not a copy of it
(``examples/blocks/door.yaml``). Their parameters are the door's declarations
(:data:`evo_door.models.door_params.TABLE`: units, defaults, bounds, meaning), under
the element's name (``plate.F_load``, ``latch.unlock_force``).
"""

from __future__ import annotations

import math

from evo_door.models.blocks.components import ROTARY, Component, Site, Spec


def _spec(door_name: str, name: str | None = None, meaning: str | None = None) -> Spec:
    """The door's declaration of ``door_name`` as a component's parameter ``name``."""
    from evo_door.models.door_params import TABLE  # the door's package: on demand

    p = TABLE[door_name]
    return Spec(
        name or door_name, "", p.unit, p.default, p.lower, p.upper, p.group,
        meaning or p.meaning.removeprefix("latch: "),
    )  # fmt: skip


class _DoorSpecs:
    """A component's ``specs``, made from the door's declarations when first asked for:
    reading a mechanism that does not use the seed's blocks (``evo-door draw``, say)
    never imports the door's compiled package."""

    def __init__(self, make):
        self.make = make

    def __set_name__(self, owner, name):
        self.name = f"_{name}"

    def __get__(self, obj, owner=None):
        cls = owner if owner is not None else type(obj)
        if self.name not in cls.__dict__:
            setattr(cls, self.name, tuple(self.make()))
        return cls.__dict__[self.name]


class SlottedPlate(Component):
    """The seed's plate linkage (``docs/physical-model.md``) on a rotary body at the
    hinge O: its generalised force on the body's angle by virtual work."""

    kind, title = "slotted_plate", "the seed's plate: linkage O-A-B, spring at C, pad D, slot B"
    acts_on = (ROTARY,)
    connects = ("on",)
    specs = _DoorSpecs(
        lambda: (
            _spec(n)
            for n in ("L_OA", "L_Bx", "L_By", "L_Cx", "L_Cy", "L_Dx", "L_Dy", "K", "F_load")
            + ("F_atC", "T_atA", "T_atB", "mu", "F_atD", "a", "a_rot")
        )
    )
    imports = (
        "from evo_door.models.door.frictionforce import friction_force",
        "from evo_door.models.door.kinematics import pose",
        "from evo_door.models.door.plate import plate, spring_potential",
        "from evo_door.models.door.relativespeed import relative_speed",
    )

    def law(self, s):
        p = s.p
        geometry = ", ".join(p[n] for n in ("L_OA", "L_Bx", "L_By", "L_Cx", "L_Cy"))
        v = s.vb
        return [
            f"pose_ = pose({s.xb}, {geometry})",
            f"plate_ = plate(pose_, {v}, {p['L_Cy']}, {p['K']}, {p['F_load']}, "
            f"{p['F_atC']}, {p['T_atA']}, {p['a']}, {p['a_rot']})",
            f"pad_ = relative_speed(pose_, {v}, {p['L_Dx']}, {p['L_Dy']}, {p['F_atD']}, {p['a']})",
            f"slot_ = friction_force(pose_, {v}, pad_.F_Dx, pad_.F_Dy, pad_.T_B, plate_.m, "
            f"{p['mu']}, {p['T_atB']}, {p['a']}, {p['a_rot']})",
            f"{s.fb} += plate_.q + slot_.q",
        ]

    def potential(self, s):
        p = s.p
        geometry = ", ".join(p[n] for n in ("L_OA", "L_Bx", "L_By", "L_Cx", "L_Cy"))
        return f"spring_potential(pose({s.xb}, {geometry}), {p['L_Cy']}, {p['K']}, {p['F_load']})"


#: the latch's parameters: its name in the block, the door's declaration
_LATCH = (
    ("unlock_force", "unlock_force"),
    ("lock_force", "lock_force"),
    ("loose_angle", "latch_loose_angle"),
    ("open_stiffness", "latch_open_stiffness"),
    ("close_stiffness", "latch_close_stiffness"),
    ("open_hold", "latch_open_hold"),
    ("close_hold", "latch_close_hold"),
    ("seat_force", "latch_seat_force"),
    ("damping", "latch_damping"),
    ("sharpness", "latch_sharpness"),
    ("wall_stiffness", "wall_stiffness"),
    ("wall_damping", "wall_damping"),
)


class Latch(Component):
    """The seed's catch at ``closed`` on a rotary body (:mod:`evo_door.models.door.latch`):
    its forces act at ``lever`` from the axis, as the door's act at the handle."""

    kind, title = "latch", "the seed's latch: unlock and lock springs, seat, wall"
    acts_on = (ROTARY,)
    connects = ("on",)
    specs = _DoorSpecs(
        lambda: (
            *(_spec(door, name) for name, door in _LATCH),
            _spec("L", "lever", "distance from the axis at which the latch's forces act"),
            Spec("closed", "", "rad", 0.5 * math.pi, -10.0, 10.0, "geometry",
                 "the body's closed position (the latch's frame; pi/2 for the door)"),
        )
    )  # fmt: skip
    n_switches = 7
    imports = (
        "from evo_door.models.door.latch import latch, latch_potential",
        "from evo_door.models.blocks.seed_kernels import latch_switch",
    )

    def _args(self, s: Site) -> str:
        return ", ".join(s.p[name] for name, _ in _LATCH)

    def _theta(self, s: Site) -> str:
        # the door's latch has its closed position at pi/2
        return f"({s.xb} - {s.p['closed']} + {0.5 * math.pi!r})"

    def law(self, s):
        lever = s.p["lever"]
        return [f"{s.fb} += latch({self._theta(s)}, {s.vb}, {lever}, {self._args(s)})"]

    def potential(self, s):
        """The catch's springs (the door's :func:`latch_potential`) and the wall's."""
        p, theta = s.p, self._theta(s)
        springs = ", ".join(
            p[n] for n in ("unlock_force", "lock_force", "loose_angle", "open_stiffness")
            + ("close_stiffness", "open_hold", "close_hold", "seat_force")
        )  # fmt: skip
        past = f"({theta} - {0.5 * math.pi!r})"
        wall = (
            f"(0.5 * {p['wall_stiffness']} * {p['lever']} * {past} ** 2 if {past} > 0.0 else 0.0)"
        )
        catch = f"({p['unlock_force']} > 0.0 or {p['lock_force']} > 0.0)"
        spring = f"({p['lever']} * latch_potential({theta}, {springs}) if {catch} else 0.0)"
        return f"{spring} + {wall}"

    def switches(self, s):
        return [
            f"latch_switch({j}, {self._theta(s)}, {s.vb}, {self._args(s)})"
            for j in range(self.n_switches)
        ]
