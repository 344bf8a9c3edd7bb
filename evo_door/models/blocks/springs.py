"""More components (:mod:`evo_door.models.blocks.components`): detent, bump, gas
strut, tabulated spring.

- ``detent``: clicks every ``pitch`` (a knob's 12 clicks per turn: pitch 30 deg), a force
  ``-amplitude sin(2 pi (x_b - x_a - phase) / pitch)`` on b: at rest at
  ``phase + k pitch``, its potential ``amplitude pitch / (2 pi) (1 - cos(...))``.
- ``bump``: one click at a position (:class:`Bump`); several make a set of clicks.
- ``gas_strut``: pushes its ends apart with ``preload + slope (length - d)``,
  ``d = x_b - x_a`` (``length``: where it pushes with the pre-load; ``slope``: the
  rise of the force as it is compressed), damped by ``c_extension`` while it extends
  (``d`` rising) and ``c_compression`` while it is compressed. Through a slider-crank
  transmission it acts along its own geometry.
- ``spring_table``: a spring whose tension over its deflection ``d = x_b - x_a`` is the
  monotone cubic through the points ``deflection``, ``force`` (each point a parameter,
  ``deflection_0``, ``force_0``, ...), a straight line with the end slope beyond them;
  its potential the integral of that curve from the first point.
"""

from __future__ import annotations

from evo_door.errors import UserError
from evo_door.models.blocks.components import LINEAR, Component, Site, Spec, pair, relative

_TWO_PI = "6.283185307179586"


class Detent(Component):
    kind, title = "detent", "detent: a click every pitch"
    specs = (
        Spec("amplitude", "N", "N m", None, 0.0, 1.0e5, "specification",
             "peak force of a click"),
        Spec("pitch", "m", "rad", None, 1.0e-6, 100.0, "geometry", "distance between clicks"),
        Spec("phase", "m", "rad", 0.0, -100.0, 100.0, "geometry",
             "where a click holds the body at rest"),
    )  # fmt: skip

    def _angle(self, s: Site) -> str:
        d = relative(s, s.xb, s.xa)
        return f"{_TWO_PI} * ({d} - {s.p['phase']}) / {s.p['pitch']}"

    def law(self, s):
        return pair(s, f"-{s.p['amplitude']} * math.sin({self._angle(s)})")

    def potential(self, s):
        size = f"{s.p['amplitude']} * {s.p['pitch']} / {_TWO_PI}"
        return f"{size} * (1.0 - math.cos({self._angle(s)}))"


class Bump(Component):
    """One click at a position: a hill of half-width ``width`` centred on ``at`` that the
    body climbs over, ``V = amplitude width / pi (1 + cos(pi u / width))`` for
    ``|u| < width``, ``u = x_b - x_a - at``, and the force ``amplitude sin(pi u /
    width)`` pushing the body off it (peak ``amplitude`` at ``u = +-width / 2``);
    nothing beyond. A negative amplitude is a notch that holds the body. Its edges
    are switching functions."""

    kind, title = "bump", "bump: one click at a position"
    specs = (
        Spec("amplitude", "N", "N m", None, -1.0e5, 1.0e5, "specification",
             "peak force of the click (negative: a notch)"),
        Spec("at", "m", "rad", None, -100.0, 100.0, "geometry", "centre of the bump"),
        Spec("width", "m", "rad", None, 1.0e-6, 100.0, "geometry", "half-width of the bump"),
    )  # fmt: skip
    n_switches = 2

    def _u(self, s: Site) -> str:
        return f"({relative(s, s.xb, s.xa)} - {s.p['at']})"

    def law(self, s):
        u, w = self._u(s), s.p["width"]
        return [
            f"if abs({u}) < {w}:",
            *(
                f"    {line}"
                for line in pair(s, f"{s.p['amplitude']} * math.sin(math.pi * {u} / {w})")
            ),
        ]

    def switches(self, s):
        u, w = self._u(s), s.p["width"]
        return [f"{u} - {w}", f"{u} + {w}"]

    def potential(self, s):
        u, w, a = self._u(s), s.p["width"], s.p["amplitude"]
        return f"({a} * {w} / math.pi * (1.0 + math.cos(math.pi * {u} / {w})) if abs({u}) < {w} else 0.0)"


class GasStrut(Component):
    kind, title = "gas_strut", "gas strut: pre-load, slope, damping by direction"
    acts_on = (LINEAR,)
    specs = (
        Spec("preload", "N", "", None, -1.0e5, 1.0e5, "specification",
             "push at the length `length`"),
        Spec("slope", "N/m", "", 0.0, -1.0e7, 1.0e7, "specification",
             "rise of the push per metre of compression"),
        Spec("length", "m", "", None, -10.0, 10.0, "geometry",
             "b's position less a's where it pushes with the pre-load"),
        Spec("c_extension", "N s/m", "", 0.0, 0.0, 1.0e6, "specification",
             "damping while it extends"),
        Spec("c_compression", "N s/m", "", 0.0, 0.0, 1.0e6, "specification",
             "damping while it is compressed"),
    )  # fmt: skip

    def law(self, s):
        d, v = relative(s, s.xb, s.xa), relative(s, s.vb, s.va)
        return [
            f"stroke = {v}",
            f"push = {s.p['preload']} + {s.p['slope']} * ({s.p['length']} - {d})",
            f"push -= ({s.p['c_extension']} if stroke > 0.0 else {s.p['c_compression']}) * stroke",
            *pair(s, "push"),
        ]

    def potential(self, s):
        u = f"({s.p['length']} - {relative(s, s.xb, s.xa)})"
        return f"{s.p['preload']} * {u} + 0.5 * {s.p['slope']} * {u} * {u}"


class TabulatedSpring(Component):
    kind, title = "spring_table", "spring from a table of force over deflection"
    specs = (
        Spec("deflection", "m", "rad", None, -100.0, 100.0, "geometry",
             "deflection (b's position less a's)"),
        Spec("force", "N", "N m", None, -1.0e6, 1.0e6, "specification",
             "tension at that deflection (pulls the ends together)"),
    )  # fmt: skip
    tables = ("deflection", "force")
    imports = ("from evo_door.models.blocks.kinematics import pchip, pchip_integral",)

    def check(self, values, words, at):
        d = [values[f"deflection_{i}"] for i in range(sum(k.startswith("d") for k in values))]
        if sum(k.startswith("f") for k in values) != len(d):
            raise UserError(f"{at}: deflection and force must hold as many points")
        for i in range(1, len(d)):
            if not d[i] > d[i - 1]:
                raise UserError(f"{at}: its deflection points must rise; deflection[{i}] does not")

    def law(self, s):
        n = sum(1 for k in s.p if k.startswith("deflection_"))
        first = s.p["deflection_0"].removeprefix("p[").removesuffix("]")
        return [
            f"tension = pchip({relative(s, s.xb, s.xa)}, p, {int(first)}, {n})[0]",
            *pair(s, "-tension"),
        ]

    def potential(self, s):
        n = sum(1 for k in s.p if k.startswith("deflection_"))
        first = int(s.p["deflection_0"].removeprefix("p[").removesuffix("]"))
        return f"pchip_integral({relative(s, s.xb, s.xa)}, p, {first}, {n})"
