"""The components a mechanism file is built from (:mod:`evo_door.models.blocks`).

Each component is a small class that declares, as data, its parameters (one
:class:`Spec` each: unit on a linear and on a rotary body, default, bounds, group,
meaning), which body kinds it may act on, how it connects (``on:`` one body, or
``between:`` two), its switching functions, and the numba source of its force law.
The source is a few lines of Python written into the mechanism's one generated
``rhs`` (:mod:`evo_door.models.blocks.codegen`): a component adds to the force
accumulators ``f[body]`` of the bodies it touches, with positions, speeds and
parameters already substituted as constant indices (``x[0]``, ``p[3]``).

Conventions: a body's coordinate grows toward *closed* (as ``theta`` does); a force is
positive toward closed. ``on: b`` is ``between: [ground, b]`` with the ground at 0.
"""

from __future__ import annotations

from dataclasses import dataclass

LINEAR, ROTARY = "linear", "rotary"


@dataclass(frozen=True)
class Spec:
    """One parameter of a component: its units on a linear and on a rotary body."""

    name: str
    linear_unit: str
    rotary_unit: str
    default: float | None  # None: the file must give it
    lower: float
    upper: float
    group: str
    meaning: str

    def unit(self, kind: str) -> str:
        return self.linear_unit if kind == LINEAR else self.rotary_unit


@dataclass(frozen=True)
class Site:
    """Where a component's law reads and writes, as source text: the positions and
    speeds of its two ends (``a`` is ``"0.0"`` for the ground), the accumulators of
    their forces (``fa`` is None for the ground), its parameters by name, and the
    index of its first switching function."""

    xa: str
    va: str
    xb: str
    vb: str
    fa: str | None
    fb: str
    p: dict[str, str]
    words: dict[str, str]
    own: tuple[str, ...] = ()  # the component's own states, ``x[i]``
    rate: tuple[str, ...] = ()  # and their derivatives, ``dx[i]``


class Component:
    """A component kind (see the module docstring)."""

    kind = ""
    title = ""
    acts_on: tuple[str, ...] = (LINEAR, ROTARY)
    connects: tuple[str, ...] = ("on", "between")  # the connections it takes
    specs: tuple[Spec, ...] = ()
    words: dict[str, tuple[str, ...]] = {}  # word options: name -> allowed (first: default)
    n_switches = 0
    optional: tuple[str, ...] = ()  # parameters with no default that may be left out
    #: import lines the law's source needs (library code only, never the file's)
    imports: tuple[str, ...] = ()
    #: parameters the file gives as a list of points: ``NAME_0``, ``NAME_1``, ... each
    tables: tuple[str, ...] = ()

    def all_specs(self, values: dict[str, float]) -> list[Spec]:
        """The specs of the parameters, a table's one a point (those ``values`` hold)."""
        out = []
        for s in self.specs:
            if s.name not in self.tables:
                out.append(s)
                continue
            i = 0
            while f"{s.name}_{i}" in values:
                out.append(Spec(f"{s.name}_{i}", s.linear_unit, s.rotary_unit, values[f"{s.name}_{i}"],
                                s.lower, s.upper, s.group, f"{s.meaning}, point {i}"))  # fmt: skip
                i += 1
        return out

    def check(self, values: dict[str, float], words: dict[str, str], at: str) -> None:
        """Refuse values that do not make the component (a UserError naming ``at``)."""

    def potential(self, s: Site) -> str | None:
        """Source of the component's potential energy (J), or None if it stores none."""
        return None

    def own_states(self, values: dict[str, float]) -> tuple[str, ...]:
        """Names of the component's own states (after the bodies' in ``x``), given the
        parameters the file sets."""
        return ()

    def law(self, s: Site) -> list[str]:
        """Source lines adding the component's force to ``s.fa`` and ``s.fb``."""
        raise NotImplementedError

    def switches(self, s: Site) -> list[str]:
        """Expressions of the component's switching functions."""
        return []

    def contact(self, s: Site) -> bool:
        """Whether the component makes its body's speed a stick-slip contact."""
        return False


def pair(s: Site, force: str) -> list[str]:
    """``force`` acts on b (toward closed), its reaction on a."""
    lines = [f"{s.fb} += {force}"]
    if s.fa is not None:
        lines.append(f"{s.fa} -= {force}")
    return lines


def relative(s: Site, b: str, a: str) -> str:
    """b's position (or speed) less a's; b's alone on the ground."""
    return b if s.fa is None else f"({b} - {a})"


class Spring(Component):
    kind, title = "spring", "linear spring with pre-load"
    acts_on = (LINEAR,)
    specs = (
        Spec("k", "N/m", "", None, 0.0, 1.0e7, "specification", "stiffness"),
        Spec("preload", "N", "", 0.0, -1.0e5, 1.0e5, "specification",
             "tension at the rest length (negative: pushes)"),
        Spec("at", "m", "", 0.0, -10.0, 10.0, "geometry",
             "rest length: b's position less a's where the tension is the pre-load"),
    )  # fmt: skip

    def law(self, s):
        t = f"({s.p['preload']} + {s.p['k']} * ({s.xb} - {s.xa} - {s.p['at']}))"
        return [f"tension = {t}", *pair(s, "-tension")]

    def potential(self, s):
        d = f"({s.xb} - {s.xa} - {s.p['at']})"
        return f"{s.p['preload']} * {d} + 0.5 * {s.p['k']} * {d} * {d}"


class Damper(Component):
    kind, title = "damper", "viscous damper"
    specs = (
        Spec("c", "N s/m", "N m s/rad", None, 0.0, 1.0e6, "specification",
             "damping coefficient"),
    )  # fmt: skip

    def law(self, s):
        return pair(s, f"-{s.p['c']} * {relative(s, s.vb, s.va)}")


class Friction(Component):
    """Dry friction on a body's speed, or (``law: tanh`` only) on the relative speed of
    two bodies: ``-level tanh(slope v)`` on b, its reaction on a."""

    kind, title = "friction", "dry friction"
    specs = (
        Spec("level", "N", "N m", None, 0.0, 1.0e5, "specification",
             "friction force, both directions"),
        Spec("level_opening", "N", "N m", None, 0.0, 1.0e5, "specification",
             "friction force while opening (speed < 0)"),
        Spec("level_closing", "N", "N m", None, 0.0, 1.0e5, "specification",
             "friction force while closing (speed > 0)"),
        Spec("slope", "s/m", "s/rad", 50.0, 1.0e-3, 1.0e6, "numerics",
             "slope of the tanh law at zero speed (law: tanh)"),
    )  # fmt: skip
    words = {"law": ("sign", "tanh")}

    def law(self, s):
        closing = s.p.get("level_closing", s.p.get("level"))
        opening = s.p.get("level_opening", s.p.get("level"))
        v = relative(s, s.vb, s.va)
        if s.words["law"] == "tanh":
            shape = f"math.tanh({s.p['slope']} * {v})"
            return pair(s, f"-({closing} if {v} > 0.0 else {opening}) * {shape}")
        return [
            f"if {v} > 0.0:",
            f"    {s.fb} -= {closing}",
            f"elif {v} < 0.0:",
            f"    {s.fb} += {opening}",
        ]

    def contact(self, s):
        return s.words["law"] == "sign"


class EndStop(Component):
    kind, title = "end_stop", "stiff stop with damping: pushes, never pulls"
    connects = ("on",)
    specs = (
        Spec("at", "m", "rad", None, -10.0, 10.0, "geometry", "where the stop touches"),
        Spec("k", "N/m", "N m/rad", 1.0e5, 1.0, 1.0e9, "numerics", "stiffness of the stop"),
        Spec("c", "N s/m", "N m s/rad", 100.0, 0.0, 1.0e6, "numerics", "damping of the stop"),
    )  # fmt: skip
    words = {"side": ("above", "below")}
    n_switches = 1

    def law(self, s):
        push = f"-{s.p['k']} * ({s.xb} - {s.p['at']}) - {s.p['c']} * {s.vb}"
        if s.words["side"] == "above":  # the body is held below `at`
            return [f"if {s.xb} > {s.p['at']}:", f"    {s.fb} += min({push}, 0.0)"]
        return [f"if {s.xb} < {s.p['at']}:", f"    {s.fb} += max({push}, 0.0)"]

    def switches(self, s):
        return [f"{s.xb} - {s.p['at']}"]

    def potential(self, s):
        inside = ">" if s.words["side"] == "above" else "<"
        d = f"({s.xb} - {s.p['at']})"
        return f"(0.5 * {s.p['k']} * {d} * {d} if {s.xb} {inside} {s.p['at']} else 0.0)"


class SoftClose(Component):
    """Past ``engage`` the piston brakes the body: ``pull - c_fluid v``. With ``tau`` the
    fluid is compliant and its force is a state of its own, ``F``, lagging the viscous
    force: ``tau F' = -c_fluid v - F`` while engaged (the body feels ``pull + F``),
    ``tau F' = -F`` (relaxing, not felt) once the body has left the piston."""

    kind, title = "soft_close", "soft-close damper engaging over the last stretch"
    acts_on = (LINEAR,)
    connects = ("on",)
    specs = (
        Spec("engage", "m", "", None, -10.0, 10.0, "geometry",
             "position from which the damper brakes the body (to the end)"),
        Spec("c_fluid", "N s/m", "", None, 0.0, 1.0e6, "specification",
             "damping of the fluid once engaged"),
        Spec("pull", "N", "", 0.0, -1.0e4, 1.0e4, "specification",
             "force pulling the body shut once engaged"),
        Spec("tau", "s", "", None, 1.0e-5, 10.0, "specification",
             "time constant of the fluid's compliance (optional: a state of its own)"),
    )  # fmt: skip
    optional = ("tau",)
    n_switches = 1

    def own_states(self, values):
        return ("fluid",) if "tau" in values else ()

    def law(self, s):
        engaged = f"{s.xb} > {s.p['engage']}"
        if not s.own:
            brake = f"{s.p['pull']} - {s.p['c_fluid']} * {s.vb}"
            return [f"if {engaged}:", f"    {s.fb} += {brake}"]
        (fluid,), (rate,) = s.own, s.rate
        viscous = f"-{s.p['c_fluid']} * {s.vb}"
        return [
            f"if {engaged}:",
            f"    {s.fb} += {s.p['pull']} + {fluid}",
            f"    {rate} = ({viscous} - {fluid}) / {s.p['tau']}",
            "else:",
            f"    {rate} = -{fluid} / {s.p['tau']}",
        ]

    def switches(self, s):
        return [f"{s.xb} - {s.p['engage']}"]


class Cable(Component):
    kind, title = "cable", "elastic cable: pulls, never pushes"
    acts_on = (LINEAR,)
    specs = (
        Spec("k", "N/m", "", None, 0.0, 1.0e9, "specification", "axial stiffness"),
        Spec("length", "m", "", 0.0, -10.0, 10.0, "geometry",
             "b's position less a's where the cable comes taut"),
    )  # fmt: skip
    n_switches = 1

    def law(self, s):
        stretch = f"{s.xb} - {s.xa} - {s.p['length']}"
        return [f"tension = max({s.p['k']} * ({stretch}), 0.0)", *pair(s, "-tension")]

    def switches(self, s):
        return [f"{s.xb} - {s.xa} - {s.p['length']}"]

    def potential(self, s):
        stretch = f"max({s.xb} - {s.xa} - {s.p['length']}, 0.0)"
        return f"0.5 * {s.p['k']} * {stretch} * {stretch}"


#: kind -> component
COMPONENTS: dict[str, Component] = {
    c.kind: c for c in (Spring(), Damper(), Friction(), EndStop(), SoftClose(), Cable())
}

#: the parameters of a body, by its kind: (spec, ...); ``mass`` of a rotary body and
#: ``arm`` give its weight's moment, ``-m g (arm cos(theta) - arm_normal sin(theta))``
#: (none without a ``mass``)
BODY_SPECS: dict[str, tuple[Spec, ...]] = {
    LINEAR: (Spec("mass", "kg", "", None, 1.0e-6, 1.0e5, "specification", "mass"),),
    ROTARY: (
        Spec("inertia", "", "kg m^2", None, 1.0e-9, 1.0e5, "specification",
             "moment of inertia about the axis"),
        Spec("mass", "", "kg", None, 0.0, 1.0e5, "specification",
             "mass whose weight acts on the lever arm (optional)"),
        Spec("arm", "", "m", 0.0, -10.0, 10.0, "geometry",
             "distance from the axis to the centre of mass (weight moment m g arm cos)"),
        Spec("arm_normal", "", "m", None, -10.0, 10.0, "geometry",
             "offset of the centre of mass across the arm, toward closed at angle 0 "
             "(optional; weight moment + m g arm_normal sin)"),
        Spec("hand_lever", "", "m", 1.0, 1.0e-6, 10.0, "geometry",
             "distance from the axis to where the hand pushes (handle only)"),
    ),
}  # fmt: skip
#: what a body entry may hold besides its parameters
BODY_WORDS = ("kind", "range", "start", "inertia_about")
#: where a rotary body's ``inertia`` is taken: about its axis, or about its centre of
#: mass (the axis's is then ``inertia + mass (arm^2 + arm_normal^2)``)
INERTIA_ABOUT = ("axis", "centre_of_mass")
GRAVITY = 9.80665
