"""The just-noticeable differences (JNDs) a feel is judged with, as settings.

A difference is noticeable where it exceeds the JND: for a force, the larger of a
Weber fraction of the reference force and an absolute floor (a fraction of a force
near zero means nothing); for the felt inertia and damping, a Weber fraction of the
reference, with a floor that follows from the force floor at the speeds and
accelerations of use. The defaults are within the ranges the psychophysics literature
reports (docs/perception.md cites them); every one is settable per experiment
(``perception:`` in a pipeline or experiment file) and per command.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from evo_door.errors import UserError


@dataclass(frozen=True)
class JND:
    """Just-noticeable differences, as fractions of the reference, and their floors.

    Attributes
    ----------
    force : float
        Weber fraction of force (7-10 %: Jones 1989; Pang, Tan and Durlach 1991).
    force_floor : float
        N: below ``force_floor / force`` the JND stays at this force.
    stiffness : float
        Weber fraction of stiffness (15-25 %: Jones and Hunter 1990; Tan et al. 1995).
    viscosity : float
        Weber fraction of viscous damping (15-35 %: Jones and Hunter 1993).
    inertia : float
        Weber fraction of inertia / mass (10-20 %: Ross and Brodie 1987; Jones 2000).
    speed : float
        rad/s, a typical door speed: a damping difference below ``force_floor / speed``
        gives a force below the force floor.
    acceleration : float
        rad/s^2, a typical door acceleration: an inertia difference below
        ``force_floor / acceleration`` gives a force below the force floor.
    position : float
        m at the handle: where a latch catches (the angle of its peak force) is felt
        differently beyond this distance (joint-angle JNDs of 0.8-2.5 deg, Tan,
        Srinivasan, Eberman and Cheng 1994, over the arm and hand that move a handle:
        3.5-8.4 mm; docs/perception.md).
    handle_radius : float
        m, the distance from the hinge to the handle: an angle difference of the door
        moves the hand by ``handle_radius`` times it (0.6 m, the case study's door).
    """

    force: float = 0.10
    force_floor: float = 0.5
    stiffness: float = 0.20
    viscosity: float = 0.25
    inertia: float = 0.15
    speed: float = 1.0
    acceleration: float = 10.0
    position: float = 0.005
    handle_radius: float = 0.6

    #: the settings' units, for messages and files
    UNITS = {
        "force": "1",
        "force_floor": "N",
        "stiffness": "1",
        "viscosity": "1",
        "inertia": "1",
        "speed": "rad/s",
        "acceleration": "rad/s^2",
        "position": "m",
        "handle_radius": "m",
    }

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0):
                raise UserError(f"perception.{f.name} {v!r}: must be a number above 0")
            if self.UNITS[f.name] == "1" and v >= 1.0:
                raise UserError(
                    f"perception.{f.name} {v:g}: a Weber fraction below 1 (0.1 is 10 %)"
                )

    @classmethod
    def from_mapping(cls, values: dict | None, where: str = "perception") -> JND:
        """From ``{name: value}`` (the ``perception:`` section); unknown names refused."""
        from evo_door.files.fields import as_mapping, as_number

        values = as_mapping(values or {}, where, as_number)
        names = [f.name for f in fields(cls)]
        for k in values:
            if k not in names:
                raise UserError(f"{where}: unknown setting {k!r}; settings: {', '.join(names)}")
        return cls(**values)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    def force_threshold(self, reference):
        """The force JND (N) at each reference force (N): max(force |F|, force_floor).

        >>> JND().force_threshold(20.0), JND().force_threshold(-2.0)
        (2.0, 0.5)
        """
        import numpy as np

        out = np.maximum(self.force * np.abs(reference), self.force_floor)
        return float(out) if np.ndim(out) == 0 else out

    def inertia_threshold(self, reference: float) -> float:
        """The inertia JND (kg m at the handle) at a reference inertia."""
        return max(self.inertia * abs(reference), self.force_floor / self.acceleration)

    def angle_threshold(self) -> float:
        """The JND (rad of door angle) of where a latch catches: ``position`` at the handle.

        >>> round(JND().angle_threshold(), 6)
        0.008333
        """
        return self.position / self.handle_radius

    def damping_threshold(self, reference: float) -> float:
        """The viscous damping JND (N s/rad at the handle) at a reference damping."""
        return max(self.viscosity * abs(reference), self.force_floor / self.speed)
