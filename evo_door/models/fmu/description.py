"""What evo-door reads of an FMU before loading any of its code.

An FMU (Functional Mock-up Unit, FMI 2.0 or 3.0) is a zip archive holding
``modelDescription.xml`` and a shared library per platform. This module reads the
description through FMPy (``fmpy.read_model_description``) and turns it into what the
workbench needs:

- the checks a user's file must pass, each refused with one line (not a zip, no or a
  malformed description, FMI 1.0, no binary for this platform, no interface asked for);
- the parameter declaration: every real parameter (causality ``parameter``, fixed or
  tunable) becomes a :class:`~evo_door.params.Param` with the FMU's name, unit, start
  value as default, min and max as bounds and description as meaning;
- the channels: which variables carry the force, the angle and its derivatives, and the
  factor and offset that take each from the FMU's unit to SI (:class:`Channel`).

Nothing here imports numba or opens the shared library: ``evo-door params model.fmu``
reads the declaration alone.
"""

from __future__ import annotations

import math
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from evo_door.errors import UserError
from evo_door.params import Param, ParamTable

#: the interfaces, as a path's suffix says them (``model.fmu:cs``)
INTERFACES = {"me": "ModelExchange", "cs": "CoSimulation"}

#: the channels an FMU is read through: the input and the outputs of a trial, and the
#: variables that set the initial state (``theta0``, ``dtheta0``)
CHANNEL_KEYS = ("force", "theta", "dtheta", "ddtheta", "theta0", "dtheta0")

#: SI base-unit exponents each channel must have (kg, m, s, rad), to check a unit
_DIMENSIONS = {
    "force": (1, 1, -2, 0),
    "theta": (0, 0, 0, 1),
    "dtheta": (0, 0, -1, 1),
    "ddtheta": (0, 0, -2, 1),
    "theta0": (0, 0, 0, 1),
    "dtheta0": (0, 0, -1, 1),
}
#: units FMUs often name without defining them: name -> (factor to SI, kg, m, s, rad)
_KNOWN_UNITS = {
    "N": (1.0, 1, 1, -2, 0),
    "kN": (1e3, 1, 1, -2, 0),
    "rad": (1.0, 0, 0, 0, 1),
    "deg": (math.pi / 180.0, 0, 0, 0, 1),
    "rad/s": (1.0, 0, 0, -1, 1),
    "deg/s": (math.pi / 180.0, 0, 0, -1, 1),
    "rpm": (2.0 * math.pi / 60.0, 0, 0, -1, 1),
    "rad/s2": (1.0, 0, 0, -2, 1),
    "rad/s^2": (1.0, 0, 0, -2, 1),
    "deg/s2": (math.pi / 180.0, 0, 0, -2, 1),
    "deg/s^2": (math.pi / 180.0, 0, 0, -2, 1),
}
#: the platform names FMI 2 and FMI 3 give this machine's binaries
_REAL_TYPES = ("Real", "Float64")


@dataclass(frozen=True)
class Channel:
    """One channel read from (or written to) an FMU variable.

    ``si = factor * value + offset`` takes the FMU's value to the workbench's SI unit.
    """

    key: str
    name: str
    vr: int
    unit: str
    factor: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class FmuInfo:
    """The checked description of one FMU file."""

    path: Path
    description: Any  # fmpy.model_description.ModelDescription
    version: int  # 2 or 3
    interface: str  # "me" or "cs"
    identifier: str  # the shared library's name
    declaration: ParamTable
    #: name -> (value reference, variability) of every declared parameter
    parameters: dict
    channels: dict  # key -> Channel
    #: why the channels could not be matched ("" when they were)
    channel_problem: str = ""

    def check_channels(self) -> None:
        """Raise the one-line :class:`UserError` of channels that do not match."""
        if self.channel_problem:
            raise UserError(self.channel_problem)

    @property
    def name(self) -> str:
        return self.declaration.model

    @property
    def n_states(self) -> int:
        return len(self.description.derivatives) if self.interface == "me" else 0

    @property
    def n_events(self) -> int:
        return int(self.description.numberOfEventIndicators or 0) if self.interface == "me" else 0


def split_spec(spec) -> tuple[Path, str | None, dict]:
    """``path.fmu[:me|:cs][?force=VAR&theta=VAR...]`` -> (path, interface, mapping).

    The optional suffix chooses the interface (model exchange or co-simulation); the
    optional query maps channels to the FMU's variables (:func:`resolve_channels`).
    """
    text = str(spec).strip()
    text, _, query = text.partition("?")
    mapping = {}
    for item in filter(None, query.split("&")):
        key, eq, value = item.partition("=")
        if not eq or not key.strip() or not value.strip():
            raise UserError(f"{spec}: channel mapping {item!r} is not CHANNEL=VARIABLE")
        mapping[key.strip()] = value.strip()
    head, sep, tail = text.rpartition(":")
    if sep and head.lower().endswith(".fmu"):
        if tail.lower() not in INTERFACES:
            raise UserError(
                f"{spec}: after the FMU's path, say the interface: :me (model exchange) "
                f"or :cs (co-simulation), not {tail!r}"
            )
        return Path(head).expanduser(), tail.lower(), mapping
    return Path(text).expanduser(), None, mapping


def join_spec(path, interface: str | None = None, mapping=None) -> str:
    """The model name :func:`split_spec` reads back (mapping sorted: one name per model)."""
    text = str(path) + (f":{interface}" if interface else "")
    if mapping:
        text += "?" + "&".join(f"{k}={v}" for k, v in sorted(dict(mapping).items()))
    return text


def is_fmu_spec(spec) -> bool:
    """A model name that names an FMU file (``x.fmu``, ``x.fmu:me``, ``x.fmu:cs``, with
    or without a channel mapping)."""
    text = str(spec).strip().partition("?")[0]
    head, sep, _ = text.rpartition(":")
    return text.lower().endswith(".fmu") or (bool(sep) and head.lower().endswith(".fmu"))


#: the most an FMU may unpack to (its binaries, sources and resources; a real one is a
#: few MiB): checked on the archive's own table before anything is extracted
MAX_UNPACKED = 512 * 2**20
#: the most its model description may be (read into memory whole)
MAX_DESCRIPTION = 16 * 2**20


def _check_archive(archive: zipfile.ZipFile, shown: str) -> None:
    """An FMU's archive before anything is read or extracted from it: its entries stay
    inside the folder it unpacks to (no absolute path, no ``..``), and they unpack to at
    most :data:`MAX_UNPACKED` bytes (a zip bomb of a megabyte can claim gigabytes)."""
    total = 0
    for info in archive.infolist():
        name = info.filename.replace("\\", "/")
        parts = name.split("/")
        if name.startswith("/") or ".." in parts or (len(name) > 1 and name[1] == ":"):
            raise UserError(
                f"FMU {shown}: its entry {info.filename!r} would unpack outside its folder; "
                "refused (a damaged or hostile archive)"
            )
        if name == "modelDescription.xml" and info.file_size > MAX_DESCRIPTION:
            raise UserError(
                f"FMU {shown}: its modelDescription.xml is {info.file_size / 2**20:.0f} MiB, "
                f"more than {MAX_DESCRIPTION // 2**20} MiB; refused"
            )
        total += info.file_size
        if total > MAX_UNPACKED:
            raise UserError(
                f"FMU {shown}: it unpacks to more than {MAX_UNPACKED // 2**20} MiB; refused "
                "before extracting (an FMU is a few MiB: a damaged or hostile archive)"
            )


def read_info(path: Path, interface: str | None = None, mapping=None) -> FmuInfo:
    """Read and check the FMU at ``path``; every defect is one :class:`UserError` line."""
    from fmpy import platform as fmi2_platform
    from fmpy import platform_tuple, read_model_description

    shown = str(path)
    if not path.is_file():
        raise UserError(f"FMU {shown} not found")
    if not zipfile.is_zipfile(path):
        raise UserError(f"FMU {shown} is not an FMU: not a zip archive")
    with zipfile.ZipFile(path) as archive:
        _check_archive(archive, shown)
        names = archive.namelist()
        if "modelDescription.xml" not in names:
            raise UserError(f"FMU {shown} has no modelDescription.xml")
        xml = archive.read("modelDescription.xml")
    # the version first, from the XML itself: FMPy reads an FMI 1.0 file by other rules
    import xml.etree.ElementTree as ET

    try:
        version = ET.fromstring(xml).get("fmiVersion") or ""
    except ET.ParseError as exc:
        raise UserError(f"FMU {shown}: modelDescription.xml is malformed: {exc}") from None
    if version.startswith("1."):
        raise UserError(
            f"FMU {shown} is FMI {version}; evo-door reads FMI 2.0 and 3.0 "
            "(export it again as FMI 2.0 or 3.0)"
        )
    if not version.startswith(("2.", "3.")):
        raise UserError(f"FMU {shown}: unknown FMI version {version!r} (FMI 2.0 and 3.0 are read)")
    try:
        md = read_model_description(str(path), validate=False)
    except Exception as exc:  # lxml's, FMPy's and the attrs' errors alike
        first = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise UserError(f"FMU {shown}: modelDescription.xml is malformed: {first}") from None
    major = int(version[0])
    offered = {k for k, v in (("me", md.modelExchange), ("cs", md.coSimulation)) if v}
    if not offered:
        raise UserError(f"FMU {shown} offers neither model exchange nor co-simulation")
    if interface is None:
        interface = "me" if "me" in offered else "cs"
    elif interface not in offered:
        raise UserError(
            f"FMU {shown} has no {INTERFACES[interface]} interface; it offers "
            + ", ".join(f"{INTERFACES[k]} (:{k})" for k in sorted(offered))
        )
    kind = md.modelExchange if interface == "me" else md.coSimulation
    identifier = kind.modelIdentifier
    folder = fmi2_platform if major == 2 else platform_tuple
    library = f"binaries/{folder}/{identifier}.so"
    if library not in names:
        platforms = sorted({n.split("/")[1] for n in names if n.startswith("binaries/")} - {""})
        raise UserError(
            f"FMU {shown} has no binary for this platform ({folder}: {library}); it has "
            + (", ".join(platforms) if platforms else "no binaries at all")
            + " (rebuild or export it for this platform)"
        )
    declaration, parameters = _declaration(md, shown)
    # the parameters can be listed whatever the channels: a channel that does not match
    # is said when the FMU is first run (and by an experiment when it is read)
    try:
        channels, problem = resolve_channels(md, shown, mapping), ""
    except UserError as exc:
        channels, problem = {}, str(exc)
    return FmuInfo(
        path, md, major, interface, identifier, declaration, parameters, channels, problem
    )


def _number(text, default: float) -> float:
    try:
        return float(text) if text is not None else default
    except ValueError:
        return default


def is_parameter(var) -> bool:
    """A parameter of the FMU (causality ``parameter`` or ``calculatedParameter``): never
    a channel, whatever its name (an FMU's ``theta0`` is often a spring's rest angle)."""
    return var.causality in ("parameter", "calculatedParameter")


def start_value(md, channel: Channel) -> float | None:
    """The start value the FMU declares for ``channel``'s variable, in SI (None if it
    declares none)."""
    var = next((v for v in md.modelVariables if v.name == channel.name), None)
    start = None if var is None else var.start
    if start is None:
        return None
    try:
        return float(start) * channel.factor + channel.offset
    except (TypeError, ValueError):
        return None


def unit_of(var) -> str:
    """The unit a variable declares (its own, else its type's), or ``""``."""
    unit = var.unit or (var.declaredType.unit if var.declaredType is not None else None)
    return unit or ""


def _declaration(md, shown: str) -> tuple[ParamTable, dict]:
    params, where = [], {}
    # the file's name, not the modelName, and with its suffix: an FMU exported as
    # "door" (or saved as door.fmu) must not take the bundled door's presets and
    # parameter files
    name = Path(shown).name
    for var in md.modelVariables:
        if var.causality != "parameter" or var.type not in _REAL_TYPES:
            continue
        if var.shape:  # arrays (FMI 3) are not scalar specifications
            continue
        typ = var.declaredType
        lower = _number(var.min if var.min is not None else (typ.min if typ else None), -math.inf)
        upper = _number(var.max if var.max is not None else (typ.max if typ else None), math.inf)
        default = _number(var.start, 0.0)
        meaning = " ".join((var.description or "").split()) or f"FMU parameter {var.name}"
        if var.variability == "fixed":
            meaning += " (fixed: set before initialisation)"
        try:
            params.append(
                Param(
                    var.name, unit_of(var) or "1", default, lower, upper, "specification", meaning
                )
            )
        except ValueError as exc:
            raise UserError(f"FMU {shown}: {exc}") from None
        where[var.name] = (int(var.valueReference), var.variability)
    if not params:
        raise UserError(f"FMU {shown} declares no real parameter: there is nothing to fit")
    return ParamTable(name, params), where


def _si_factor(md, unit: str, key: str, var_name: str, shown: str) -> tuple[float, float]:
    """``(factor, offset)`` from ``unit`` to the SI unit of channel ``key``."""
    want = _DIMENSIONS[key]
    if not unit:
        return 1.0, 0.0  # no unit said: taken as SI
    for u in md.unitDefinitions:
        if u.name == unit and u.baseUnit is not None:
            b = u.baseUnit
            dims = (b.kg, b.m, b.s, b.rad)
            # an angle declared dimensionless (rad = 0) is still an angle
            if dims != want and dims != want[:3] + (0,):
                break
            return float(b.factor), float(b.offset)
    if unit in _KNOWN_UNITS:
        factor, kg, m, s, rad = _KNOWN_UNITS[unit]
        if (kg, m, s, rad) == want:
            return factor, 0.0
    raise UserError(
        f"FMU {shown}: variable {var_name!r} is in {unit!r}, which evo-door cannot "
        f"convert to the {key} channel's SI unit; map another variable (channels:)"
    )


def resolve_channels(md, shown: str, mapping=None) -> dict:
    """key -> :class:`Channel`: the variables named ``force``, ``theta``, ``dtheta``,
    ``ddtheta`` unless ``mapping`` names others (``{theta: angle, ...}``).

    ``force`` must be a real input; ``theta`` a real output (or a state); ``dtheta``
    and ``ddtheta`` are optional outputs. ``theta0`` / ``dtheta0`` are the variables
    the trial's initial angle and speed are written to before initialisation: the
    mapped ones, else ``theta`` / ``dtheta`` themselves where they may be set.

    A parameter of the FMU (:func:`is_parameter`) is never taken for a channel: not by
    its name (a parameter called ``theta`` or ``theta0`` stays a parameter and keeps its
    value), and a mapping that names one is refused.
    """
    mapping = dict(mapping or {})
    bad = [k for k in mapping if k not in CHANNEL_KEYS]
    if bad:
        from evo_door.params.declaration import suggest

        raise UserError(
            f"channels: unknown channel {bad[0]!r}"
            + suggest(bad[0], CHANNEL_KEYS)
            + f"; channels: {', '.join(CHANNEL_KEYS)}"
        )
    by_name = {v.name: v for v in md.modelVariables}
    reals = [v.name for v in md.modelVariables if v.type in _REAL_TYPES]
    out: dict[str, Channel] = {}
    for key in CHANNEL_KEYS:
        name = mapped_name = mapping.get(key)
        if name is None and key.endswith("0"):
            continue
        mapped = name is not None
        name = str(name) if mapped else key
        var = by_name.get(name)
        if var is not None and key != "force" and is_parameter(var):
            if mapped:
                raise UserError(
                    f"FMU {shown}: {mapped_name!r} is a parameter of the FMU (declared, "
                    f"kept at its value or fitted), not a state or an output: it cannot be "
                    f"the {key} channel (map a state or an output: channels: {{{key}: VARIABLE}})"
                )
            var = None  # a parameter is never a channel by its name (a rest angle 'theta')
        if var is None:
            if not mapped and key in ("dtheta", "ddtheta"):
                continue
            from evo_door.params.declaration import suggest

            inputs = [v.name for v in md.modelVariables if v.causality == "input"]
            outputs = [v.name for v in md.modelVariables if v.causality == "output"]
            what = (
                f"the channel mapping names {name!r}, which it does not have"
                if mapped
                else f"no variable is named {key!r}"
            )
            raise UserError(
                f"FMU {shown}: {what}"
                + suggest(name, reals)
                + f"; its inputs: {', '.join(inputs) or 'none'}, outputs: "
                + f"{', '.join(outputs) or 'none'} (map them: channels: {{{key}: VARIABLE}})"
            )
        if var.type not in _REAL_TYPES:
            raise UserError(f"FMU {shown}: channel {key} -> {name!r} is {var.type}, not real")
        if key == "force" and var.causality != "input":
            raise UserError(
                f"FMU {shown}: the force must be an input of the FMU; {name!r} is "
                f"{var.causality} (map the input: channels: {{force: VARIABLE}})"
            )
        if key.endswith("0") and var.initial not in ("exact", "approx"):
            raise UserError(
                f"FMU {shown}: {name!r} cannot be set before initialisation (initial "
                f"{var.initial or 'not given'}), so it cannot take the trial's {key}"
            )
        factor, offset = _si_factor(md, unit_of(var), key, name, shown)
        out[key] = Channel(key, name, int(var.valueReference), unit_of(var), factor, offset)
    for key, start in (("theta", "theta0"), ("dtheta", "dtheta0")):
        var = by_name.get(out[key].name) if key in out else None
        if start not in out and var is not None and var.initial in ("exact", "approx"):
            out[start] = out[key]
    return out


@dataclass(frozen=True)
class StateLayout:
    """Where the handle's angle and speed are in a model-exchange FMU's continuous
    states, and how each converts to SI (``si = factor * value + offset``)."""

    angle: int
    speed: int
    angle_si: tuple[float, float]
    speed_si: tuple[float, float]


def state_layout(info: FmuInfo, what: str) -> StateLayout:
    """The :class:`StateLayout` of ``info``'s FMU, or the one-line :class:`UserError`
    saying why ``what`` (which sets the state to any angle and speed) cannot be had:
    a co-simulation FMU (its states are its own), more states than the angle and the
    speed (the others would have to be chosen too), or states not told apart."""
    shown = info.path.name
    if info.interface != "me":
        raise UserError(
            f"FMU {shown} is run by co-simulation: {what} needs the derivatives at any "
            "angle and speed, which only a model-exchange FMU gives"
            + (" (use its model exchange: model.fmu:me)" if info.description.modelExchange else "")
        )
    info.check_channels()
    states = [d.variable.derivative for d in info.description.derivatives]
    names = [s.name if s is not None else "?" for s in states]
    if len(states) != 2:
        raise UserError(
            f"FMU {shown} has {len(states)} continuous state(s) ({', '.join(names) or 'none'}): "
            f"{what} sets the handle's angle and speed alone, so it needs exactly those two"
        )
    ch = info.channels

    def find(keys) -> int:
        for key in keys:
            if key in ch and ch[key].name in names:
                return names.index(ch[key].name)
        return -1

    angle = find(("theta0", "theta"))
    speed = find(("dtheta0", "dtheta"))
    if angle >= 0 and speed < 0:  # the state whose derivative the angle's is
        der = next((d.variable.name for d in info.description.derivatives
                    if d.variable.derivative is states[angle]), None)  # fmt: skip
        speed = names.index(der) if der in names and names.index(der) != angle else -1
    if angle < 0 or speed < 0 or angle == speed:
        raise UserError(
            f"FMU {shown}: {what} needs to know which of its states ({', '.join(names)}) are "
            "the angle and the speed: map them (channels: {theta0: STATE, dtheta0: STATE})"
        )
    md = info.description
    return StateLayout(
        angle,
        speed,
        _si_factor(md, unit_of(states[angle]), "theta", names[angle], shown),
        _si_factor(md, unit_of(states[speed]), "dtheta", names[speed], shown),
    )
