"""A mechanism file read and checked: bodies, elements, connections, the handle.

:func:`read_mechanism` turns the YAML (format: ``docs/blocks.md``) into a
:class:`Mechanism`: names checked as identifiers, numbers as finite numbers, kinds,
keys and connections against the component library
(:mod:`evo_door.models.blocks.components`). Every mistake is one
:class:`~evo_door.errors.UserError` line naming the file and the body or element.
Nothing in the file is code: the names that reach the generated source are checked
identifiers, the numbers are parameter defaults and never enter the source.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

from evo_door.errors import UserError
from evo_door.models.blocks.components import (
    BODY_SPECS,
    BODY_WORDS,
    INERTIA_ABOUT,
    LINEAR,
    ROTARY,
    Spec,
)
from evo_door.models.blocks.library import COMPONENTS
from evo_door.models.blocks.transmissions import (
    TABLE_POINTS,
    TRANSMISSIONS,
    Transmission,
    check_fold,
)
from evo_door.models.blocks.units import quantity
from evo_door.params import Param
from evo_door.params.declaration import suggest
from evo_door.sim_settings import METHODS

_IDENT = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,39}")
_MODEL_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]{0,63}")
_TOP = ("name", "title", "handle", "bodies", "transmissions", "elements", "notes", "integration")
#: the ``integration:`` keys, with the defaults of a mechanism. Four steps a sample,
#: not one: a stiff element (the cable door's carriage on its damper) makes dopri5's
#: steps shorter than a sample, and where they are set by its error control a fit's
#: objective jumps by about the tolerance as a parameter moves a hair (a step more or
#: less in a period). SLSQP's finite differences then read the jumps as slopes: the
#: fit of ``examples/blocks/cable_fit.yaml`` ended in the wrong basin for three GA
#: seeds of six at one step a sample and seven of eight at two, for none of six at
#: four, whose steps are held at a quarter sample for every candidate. A trial is as
#: accurate at one step a sample (within 3e-5 rad/s of a converged reference on the
#: examples) and 1.7 to 3 times cheaper.
INTEGRATION = {"method": "dopri5", "tolerance": 1e-9, "substeps": 4}
GROUND = "ground"


@dataclass
class Body:
    name: str
    kind: str
    values: dict[str, float]
    range: tuple[float, float]
    start: float
    inertia_about: str = "axis"  # a rotary body's: "axis" or "centre_of_mass"


@dataclass
class Element:
    name: str
    kind: str
    a: str | None  # None: the ground
    b: str
    values: dict[str, float]
    words: dict[str, str]
    via: str | None = None  # the transmission whose output is its end b (else: b itself)
    units: str = LINEAR  # the kind whose units its parameters take
    via_a: str | None = None  # and its end a's


@dataclass
class Mechanism:
    name: str
    title: str
    handle: str
    bodies: dict[str, Body]
    elements: dict[str, Element]
    notes: str = ""
    params: list[Param] = field(default_factory=list)
    transmissions: dict[str, Transmission] = field(default_factory=dict)
    integration: dict = field(default_factory=lambda: dict(INTEGRATION))


def read_mechanism(path: Path) -> Mechanism:
    """The mechanism in the YAML file ``path`` (one-line errors, see the module)."""
    import yaml

    from evo_door.files import read_text
    from evo_door.yaml_numbers import Loader

    where = f"mechanism {path.name}"
    text = read_text(path, "mechanism file")  # binary or not UTF-8: one line
    try:
        tree = yaml.load(text, Loader=Loader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" (line {mark.line + 1})" if mark is not None else ""
        problem = f": {exc.problem}" if getattr(exc, "problem", None) else ""
        raise UserError(f"{where}: not valid YAML{line}{problem}") from None
    if not isinstance(tree, dict) or set(tree) != {"mechanism"}:
        raise UserError(f"{where}: the file must hold one mapping, mechanism: {{...}}")
    return parse_mechanism(tree["mechanism"], where)


def parse_mechanism(tree, where: str) -> Mechanism:
    """The mechanism of the ``mechanism:`` mapping ``tree``."""
    tree = _mapping(tree, where)
    _known_keys(tree, _TOP, where)
    for key in ("name", "handle", "bodies"):
        if key not in tree:
            raise UserError(f"{where}: missing {key}:")
    name = _text(tree["name"], f"{where}: name")
    if not _MODEL_NAME.fullmatch(name):
        raise UserError(f"{where}: name {name!r} must be letters, digits, _ and -")
    bodies = {n: _body(n, v, where) for n, v in _named(tree["bodies"], f"{where}: bodies").items()}
    if not bodies:
        raise UserError(f"{where}: bodies: give at least one body")
    transmissions = {
        n: _transmission(n, v, bodies, where)
        for n, v in _named(tree.get("transmissions") or {}, f"{where}: transmissions").items()
    }
    for n in transmissions:
        if n in bodies:
            raise UserError(f"{where}: transmission {n!r}: a body has that name")
    elements = {
        n: _element(n, v, bodies, transmissions, where)
        for n, v in _named(tree.get("elements") or {}, f"{where}: elements").items()
    }
    handle = _text(tree["handle"], f"{where}: handle")
    if handle not in bodies:
        raise UserError(
            f"{where}: handle {handle!r} is not a body" + suggest(handle, bodies)
            + f"; bodies: {', '.join(bodies)}"
        )  # fmt: skip
    _connected(bodies, elements, handle, where)
    mech = Mechanism(
        name=name,
        title=_text(tree.get("title", name), f"{where}: title"),
        handle=handle,
        bodies=bodies,
        elements=elements,
        notes=_text(tree.get("notes", ""), f"{where}: notes"),
        transmissions=transmissions,
        integration=_integration(tree.get("integration", {}), f"{where}: integration"),
    )
    mech.params = _declare(mech)
    return mech


def _integration(tree, where: str) -> dict:
    """The integration settings: ``method``, ``tolerance``, ``substeps`` (defaults
    :data:`INTEGRATION`)."""
    tree = _mapping(tree, where)
    _known_keys(tree, tuple(INTEGRATION), where)
    out = dict(INTEGRATION)
    if "method" in tree:
        method = tree["method"]
        if method not in METHODS:
            raise UserError(f"{where}: method {_shown(method)} is not one of {', '.join(METHODS)}")
        out["method"] = method
    if "tolerance" in tree:
        tol = _number(tree["tolerance"], f"{where}: tolerance")
        if not 1e-14 <= tol <= 1e-2:
            raise UserError(f"{where}: tolerance {tol:g} is outside [1e-14, 1e-2]")
        out["tolerance"] = tol
    if "substeps" in tree:
        n = tree["substeps"]
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 64:
            raise UserError(f"{where}: substeps must be a whole number from 1 to 64")
        out["substeps"] = n
    return out


def _mapping(value, where: str) -> dict:
    if not isinstance(value, dict):
        raise UserError(f"{where}: expected a mapping (key: value), got {_shown(value)}")
    return value


def _named(value, where: str) -> dict:
    """A mapping whose keys are checked identifiers."""
    value = _mapping(value, where)
    for key in value:
        if not (isinstance(key, str) and _IDENT.fullmatch(key)) or key == GROUND:
            raise UserError(
                f"{where}: {key!r} is not a name (a letter, then letters, digits and _, "
                f"at most 40; not {GROUND!r})"
            )
    return value


def _known_keys(tree: dict, known, where: str) -> None:
    for key in tree:
        if key not in known:
            raise UserError(
                f"{where}: unknown key {key!r}" + suggest(str(key), known)
                + f"; keys: {', '.join(known)}"
            )  # fmt: skip


def _text(value, where: str) -> str:
    if not isinstance(value, str):
        raise UserError(f"{where} must be text, got {_shown(value)}")
    return " ".join(value.split())


def _number(value, where: str, unit: str | None = None) -> float:
    """A finite number; with its declared ``unit``, text ``"NUMBER UNIT"`` converted."""
    if isinstance(value, str) and unit is not None:
        value = quantity(value, unit, where)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UserError(f"{where} must be a number, got {_shown(value)}")
    if not math.isfinite(value):
        raise UserError(f"{where} must be a finite number, got {value}")
    return float(value)


def _shown(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _values(tree: dict, specs: tuple[Spec, ...], where: str, kind: str) -> dict[str, float]:
    out = {}
    for spec in specs:
        if spec.name in tree:
            v = _number(tree[spec.name], f"{where}: {spec.name}", spec.unit(kind))
            if not spec.lower <= v <= spec.upper:
                raise UserError(
                    f"{where}: {spec.name} = {v:g} {spec.unit(kind)} is outside "
                    f"[{spec.lower:g}, {spec.upper:g}]"
                )
            out[spec.name] = v
    return out


def _body(name: str, tree, where: str) -> Body:
    at = f"{where}: body {name!r}"
    tree = _mapping(tree, at)
    kind = tree.get("kind")
    if kind not in BODY_SPECS:
        raise UserError(
            f"{at}: kind {kind!r} is not a body kind" + suggest(str(kind), BODY_SPECS)
            + f"; body kinds: {', '.join(BODY_SPECS)}"
        )  # fmt: skip
    specs = BODY_SPECS[kind]
    _known_keys(tree, BODY_WORDS + tuple(s.name for s in specs), at)
    values = _values(tree, specs, at, kind)
    need = "mass" if kind == LINEAR else "inertia"
    if need not in values:
        raise UserError(f"{at}: a {kind} body needs its {need}")
    for arm in ("arm", "arm_normal"):
        if arm in values and "mass" not in values:
            raise UserError(f"{at}: {arm} without a mass (the weight acts on the arm)")
    about = tree.get("inertia_about", INERTIA_ABOUT[0])
    if kind != ROTARY and "inertia_about" in tree:
        raise UserError(f"{at}: inertia_about is for a rotary body")
    if about not in INERTIA_ABOUT:
        raise UserError(
            f"{at}: inertia_about must be one of {', '.join(INERTIA_ABOUT)}, got {_shown(about)}"
        )
    if about == "centre_of_mass" and "mass" not in values:
        raise UserError(f"{at}: inertia_about: centre_of_mass needs the body's mass")
    closed = 0.5 * math.pi if kind == ROTARY else 1.0
    rng = tree.get("range", [0.0, closed])
    if not isinstance(rng, list) or len(rng) != 2:
        raise UserError(f"{at}: range must be [fully open, closed], got {_shown(rng)}")
    unit = "rad" if kind == ROTARY else "m"
    lo, hi = (_number(v, f"{at}: range", unit) for v in rng)
    if not lo < hi:
        raise UserError(f"{at}: range [{lo:g}, {hi:g}] must go from fully open up to closed")
    start = _number(tree.get("start", lo), f"{at}: start", unit)
    return Body(name, kind, values, (lo, hi), start, about)


def _entry(tree, kinds: dict, listed: str, at: str):
    """A transmission's or an element's mapping (a copy, its ``on`` key as written),
    its ``kind`` and what the library holds under it; one line for an unknown kind."""
    tree = dict(_mapping(tree, at))
    if True in tree and "on" not in tree:  # YAML 1.1 reads the key `on` as true
        tree["on"] = tree.pop(True)
    kind = tree.get("kind")
    found = kinds.get(kind) if isinstance(kind, str) else None
    if found is None:
        raise UserError(
            f"{at}: unknown kind {kind!r}" + suggest(str(kind), kinds)
            + f"; {listed}: {', '.join(kinds)}"
        )  # fmt: skip
    return tree, kind, found


def _transmission(name: str, tree, bodies: dict[str, Body], where: str) -> Transmission:
    """A transmission of the file, its map checked over its body's range."""
    at = f"{where}: transmission {name!r}"
    tree, kind, spec = _entry(tree, TRANSMISSIONS, "transmission kinds", at)
    data = ("q", "s") if kind == "table" else ()
    _known_keys(tree, ("kind", "on", *spec.words, *data, *(s.name for s in spec.specs)), at)
    if "on" not in tree:
        raise UserError(f"{at}: say which body drives it: on")
    body = bodies[_body_name(tree["on"], bodies, f"{at}: on")]
    if body.kind not in spec.inputs:
        raise UserError(f"{at}: a {kind} is driven by a {' or '.join(spec.inputs)} body; "
                        f"{body.name!r} is {body.kind}")  # fmt: skip
    words = _words(tree, spec.words, at)
    if kind == "table" and "output" not in tree:
        words["output"] = body.kind
    output = words["output"] if spec.output is None else spec.output
    values = _values(tree, spec.specs, at, LINEAR)
    for s in spec.specs:
        if s.name not in values:
            if s.default is None:
                raise UserError(f"{at}: a {kind} needs {s.name}")
            values[s.name] = s.default
    t = Transmission(name, kind, body.name, values, words, body.kind, output)
    if kind == "table":
        for key, of in (("q", body.kind), ("s", output)):
            unit = "m" if of == LINEAR else "rad"
            points = Spec(key, unit, unit, None, -100.0, 100.0, "geometry", "")
            values.update(_table(tree.get(key), points, LINEAR, at))
        if len(tree["q"]) != len(tree["s"]):
            raise UserError(f"{at}: q and s must hold as many points")
        t.values = {k: values[k] for k in sorted(values, key=lambda k: (k[0], int(k[2:])))}
    why = check_fold(t, *body.range)
    if why is not None:
        raise UserError(f"{at}: {why} (over {body.name}'s range {body.range[0]:g} .. "
                        f"{body.range[1]:g})")  # fmt: skip
    return t


def _table(points, spec: Spec, kind: str, at: str) -> dict[str, float]:
    """A list of numbers ``spec.name: [..]``: the parameters ``NAME_0``, ``NAME_1``, ..."""
    if not isinstance(points, list) or not 2 <= len(points) <= TABLE_POINTS:
        raise UserError(f"{at}: {spec.name} must be a list of 2 to {TABLE_POINTS} numbers")
    out = {}
    for i, v in enumerate(points):
        x = _number(v, f"{at}: {spec.name}[{i}]", spec.unit(kind))
        if not spec.lower <= x <= spec.upper:
            raise UserError(f"{at}: {spec.name}[{i}] = {x:g} {spec.unit(kind)} is outside "
                            f"[{spec.lower:g}, {spec.upper:g}]")  # fmt: skip
        out[f"{spec.name}_{i}"] = x
    return out


def _words(tree: dict, options: dict[str, tuple[str, ...]], at: str) -> dict[str, str]:
    words = {}
    for word, allowed in options.items():
        value = tree.get(word, allowed[0])
        if value not in allowed:
            raise UserError(
                f"{at}: {word} must be one of {', '.join(allowed)}, got {_shown(value)}"
            )
        words[word] = value
    return words


def _element(
    name: str, tree, bodies: dict[str, Body], transmissions: dict[str, Transmission], where: str
) -> Element:
    at = f"{where}: element {name!r}"
    tree, kind, comp = _entry(tree, COMPONENTS, "kinds", at)
    _known_keys(tree, ("kind", *comp.connects, *comp.words, *(s.name for s in comp.specs)), at)
    ends = [c for c in comp.connects if c in tree]
    if len(ends) != 1:
        raise UserError(f"{at}: say what it acts on: {' or '.join(comp.connects)}")
    if ends[0] == "on":
        a, (b, via) = None, _end(tree["on"], bodies, transmissions, f"{at}: on")
        via_a = None
    else:
        pair = tree["between"]
        if not isinstance(pair, list) or len(pair) != 2:
            raise UserError(f"{at}: between must be two bodies [a, b], got {_shown(pair)}")
        (a, via_a), (b, via) = (_end(n, bodies, transmissions, f"{at}: between") for n in pair)
        if pair[0] == pair[1]:
            raise UserError(f"{at}: between connects {pair[0]!r} to itself")
    kinds = []
    for end, t in ((a, via_a), (b, via)):
        if end is None:
            continue
        if t is not None and t.output not in comp.acts_on:
            raise UserError(
                f"{at}: a {kind} acts on {' or '.join(comp.acts_on)} coordinates (its units); "
                f"transmission {t.name!r} outputs a {t.output} one"
            )
        if t is None and bodies[end].kind not in comp.acts_on:
            raise UserError(
                f"{at}: a {kind} acts on {' or '.join(comp.acts_on)} bodies (its units); "
                f"{end!r} is {bodies[end].kind}"
            )
        kinds.append(bodies[end].kind if t is None else t.output)
    if len(set(kinds)) > 1:
        raise UserError(f"{at}: it connects a linear coordinate to a rotary one (units differ)")
    words = _words(tree, comp.words, at)
    units = kinds[-1]
    values = _values(tree, tuple(s for s in comp.specs if s.name not in comp.tables), at, units)
    for spec in comp.specs:
        if spec.name in comp.tables:
            values.update(_table(tree.get(spec.name), spec, units, at))
    if kind == "friction" and a is not None and words["law"] == "sign":
        raise UserError(
            f"{at}: a friction between two bodies takes law: tanh (the sign law's stick "
            "needs a contact on their relative speed, which the integrators keep per body)"
        )
    _complete(comp, values, words, at)
    comp.check(values, words, at)
    return Element(
        name, kind, a, b, values, words,
        None if via is None else via.name, units, None if via_a is None else via_a.name,
    )  # fmt: skip


def _end(value, bodies, transmissions, where: str) -> tuple[str, Transmission | None]:
    """An element's end: a body, or a transmission's output (and the body it is on)."""
    if isinstance(value, str) and value in transmissions:
        return transmissions[value].body, transmissions[value]
    return _body_name(value, bodies, where, transmissions), None


def _complete(comp, values: dict[str, float], words: dict[str, str], at: str) -> None:
    """Defaults of the parameters the file leaves out; the required ones checked."""
    if comp.kind == "friction":
        sided = {"level_opening", "level_closing"} & set(values)
        if ("level" in values) == bool(sided) or len(sided) == 1:
            raise UserError(f"{at}: give level, or level_opening and level_closing")
        if words["law"] == "sign":
            if "slope" in values:
                raise UserError(f"{at}: slope is for law: tanh (the sign law has none)")
            return
    for spec in comp.specs:
        if spec.name.startswith("level") or spec.name in comp.tables:
            continue
        if spec.name not in values and spec.name not in comp.optional:
            if spec.default is None:
                raise UserError(f"{at}: a {comp.kind} needs {spec.name}")
            values[spec.name] = spec.default


def _body_name(value, bodies, where: str, transmissions=()) -> str:
    if not isinstance(value, str) or value not in bodies:
        known = [*bodies, *transmissions]
        also = f"; transmissions: {', '.join(transmissions)}" if transmissions else ""
        raise UserError(
            f"{where}: {_shown(value)} is not a body" + suggest(str(value), known)
            + f"; bodies: {', '.join(bodies)}{also}"
        )  # fmt: skip
    return value


def _connected(bodies, elements, handle: str, where: str) -> None:
    """Every body is reached from the handle through elements between two bodies."""
    reached, todo = {handle}, [handle]
    while todo:
        here = todo.pop()
        for e in elements.values():
            if e.a is not None and here in (e.a, e.b):
                other = e.b if here == e.a else e.a
                if other not in reached:
                    reached.add(other)
                    todo.append(other)
    for body in bodies:
        if body not in reached:
            raise UserError(
                f"{where}: body {body!r} is never connected to the handle {handle!r} "
                "(give an element between: [...] them)"
            )


def _declare(mech: Mechanism) -> list[Param]:
    """The declaration: each body's and element's parameters, ``name.parameter``."""
    params = []
    for body in mech.bodies.values():
        for spec in BODY_SPECS[body.kind]:
            if spec.name == "hand_lever" and body.name != mech.handle:
                continue
            value = body.values.get(spec.name, spec.default)
            if value is None or (spec.name.startswith("arm") and "mass" not in body.values):
                continue
            if spec.name == "inertia" and body.inertia_about == "centre_of_mass":
                spec = replace(spec, meaning="moment of inertia about the centre of mass")
            params.append(_param(body.name, spec, value, body.kind))
    for t in mech.transmissions.values():
        for key, value in t.values.items():
            named = [s for s in TRANSMISSIONS[t.kind].specs if s.name == key]
            spec = named[0] if named else Spec(  # a table's point
                key, t.unit(key), t.unit(key), value, -100.0, 100.0, "geometry",
                f"point {key[2:]} of the table, {key[0]}",
            )  # fmt: skip
            params.append(_param(t.name, spec, value, LINEAR))
    for e in mech.elements.values():
        for spec in COMPONENTS[e.kind].all_specs(e.values):
            if spec.name in e.values:
                params.append(_param(e.name, spec, e.values[spec.name], e.units))
    return params


def _param(owner: str, spec: Spec, value: float, kind: str) -> Param:
    return Param(
        f"{owner}.{spec.name}", spec.unit(kind), value, spec.lower, spec.upper, spec.group,
        f"{owner}: {spec.meaning}",
    )  # fmt: skip
