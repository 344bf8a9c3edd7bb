"""Build the door FMU (FMI 2.0 or 3.0, model exchange and co-simulation) from ``src/``.

The door is a force-driven hinge with a spring, its weight, damping, smoothed dry
friction and two end stops (README.md beside this file). This module holds its
variables once, as data: the modelDescription.xml is written from them, and so is the
C header ``door_variables.h`` that gives the C sources their value references and the
parameters' names, starts and bounds. The C physics is the same for both FMI versions
and both variable layouts.

    python examples/fmu/build.py --fmi 3 --layout untuned --out door3_untuned.fmu

or, from Python (``sys.path`` holding this folder)::

    from build import build_fmu
    build_fmu(Path("door2.fmu"), fmi=2, layout="tuned", interfaces=("me", "cs"))

``--faults`` (``faults=True``) builds the faulty door of the tests: it crashes, hangs or
fails on purpose for some damping values (:data:`FAULTS`, README.md).

Needs CMake and a C compiler, and the standard's headers: FMPy ships them (its
``c-code`` folder), or pass ``include_dir``.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass
from pathlib import Path

from evo_door.errors import UserError

HERE = Path(__file__).resolve().parent
SOURCES = HERE / "src"

LAYOUT_NAMES = ("tuned", "untuned")
INTERFACE_NAMES = ("me", "cs")
#: the co-simulation's RK4 takes steps of at most this many seconds
RK4_MAX_STEP = 1e-4
#: the value reference of the first parameter; the others follow in PARAMETERS' order
FIRST_PARAMETER_VR = 10
#: The faulty door of the tests (``faults=True``, C ``DOOR_FAULTS``): its derivatives and
#: its DoStep misbehave when ``damping`` is above a threshold (N.m.s/rad), the highest
#: one passed deciding: a segmentation fault, an endless (sleeping) loop, an error status.
FAULTS = {"crash": 9.0, "hang": 8.0, "error": 7.0}


@dataclass(frozen=True)
class Parameter:
    """One parameter of the door: ``name`` in the tuned layout (and the C enum
    ``DOOR_P_<NAME>``), ``untuned`` its name in the untuned layout."""

    name: str
    untuned: str
    unit: str
    start: float
    min: float
    max: float
    variability: str  # "tunable": settable any time; "fixed": before initialization ends
    description: str


PARAMETERS = (
    Parameter("inertia", "door.J", "kg.m2", 0.7, 0.05, 5.0, "tunable",
              "door's moment of inertia about the hinge"),
    Parameter("lever_arm", "door.r", "m", 0.55, 0.1, 1.0, "fixed",
              "handle's distance from the hinge"),
    Parameter("weight_moment", "door.W", "N.m", 17.0, 0.0, 60.0, "tunable",
              "door's weight times its centre-of-mass distance (pulls open)"),
    Parameter("spring_preload", "spring.T0", "N.m", 6.0, 0.0, 40.0, "tunable",
              "spring torque at closed, toward closing"),
    Parameter("spring_stiffness", "spring.k", "N.m/rad", 8.0, 0.0, 60.0, "tunable",
              "spring torque per rad of opening"),
    Parameter("damping", "hinge.d", "N.m.s/rad", 0.8, 0.0, 10.0, "tunable",
              "viscous hinge damping"),
    Parameter("friction", "hinge.Tf", "N.m", 0.5, 0.0, 10.0, "tunable",
              "dry hinge friction (smoothed: friction*tanh(omega/friction_speed))"),
    Parameter("friction_speed", "hinge.w0", "rad/s", 0.02, 1e-4, 1.0, "fixed",
              "speed over which the dry friction builds up"),
    Parameter("stop_stiffness", "stop.k", "N.m/rad", 2000.0, 10.0, 1e5, "fixed",
              "end stops (theta<0 and theta>pi/2): penalty stiffness"),
    Parameter("stop_damping", "stop.d", "N.m.s/rad", 10.0, 0.0, 1000.0, "fixed",
              "end stops' damping (only while penetrating)"),
)  # fmt: skip

#: The quantities the C computes, by value reference (C enum ``DOOR_VR_<KEY>``); a
#: layout names some of them. ``der_theta`` is omega again, under its own reference.
VALUE_REFERENCES = {
    "time": 0,
    "theta": 1,
    "omega": 2,
    "accel": 3,
    "force": 4,
    "angle": 5,
    "speed": 6,
    "der_theta": 7,
}


@dataclass(frozen=True)
class Signal:
    """A variable of a layout that is not a parameter: which quantity, under what name."""

    quantity: str  # a key of VALUE_REFERENCES
    name: str
    causality: str
    unit: str
    description: str
    initial: str | None = None
    start: float | None = None
    derivative_of: str | None = None  # the quantity this one is the derivative of


TIME = Signal("time", "time", "independent", "s", "simulation time")

LAYOUTS = {
    "tuned": (
        Signal("theta", "theta", "output", "rad", "door angle: 0 fully open, pi/2 closed",
               "exact", 0.0),
        Signal("omega", "dtheta", "output", "rad/s", "door's angular speed, + closing",
               "exact", 0.0, "theta"),
        Signal("accel", "ddtheta", "output", "rad/s2", "door's angular acceleration",
               "calculated", None, "omega"),
        Signal("force", "force", "input", "N", "hand's force at the handle, + toward closing",
               None, 0.0),
    ),
    "untuned": (
        Signal("theta", "door.phi", "local", "rad", "door angle: 0 fully open, pi/2 closed",
               "exact", 0.0),
        Signal("der_theta", "der(door.phi)", "local", "rad/s", "derivative of door.phi",
               "calculated", None, "theta"),
        Signal("omega", "door.w", "local", "rad/s", "door's angular speed, + closing",
               "exact", 0.0),
        Signal("accel", "der(door.w)", "local", "rad/s2", "derivative of door.w",
               "calculated", None, "omega"),
        Signal("force", "F_hand", "input", "N", "hand's force at the handle, + toward closing",
               None, 0.0),
        Signal("angle", "angle", "output", "deg", "door angle: 0 fully open, 90 closed",
               "calculated"),
        Signal("speed", "speed", "output", "deg/s", "door's angular speed, + closing",
               "calculated"),
    ),
}  # fmt: skip

#: every unit a variable may carry: SI base-unit exponents and the factor to them
UNITS: dict[str, tuple[dict[str, int], float]] = {
    "s": ({"s": 1}, 1.0),
    "m": ({"m": 1}, 1.0),
    "N": ({"kg": 1, "m": 1, "s": -2}, 1.0),
    "kg.m2": ({"kg": 1, "m": 2}, 1.0),
    "N.m": ({"kg": 1, "m": 2, "s": -2}, 1.0),
    "N.m/rad": ({"kg": 1, "m": 2, "s": -2, "rad": -1}, 1.0),
    "N.m.s/rad": ({"kg": 1, "m": 2, "s": -1, "rad": -1}, 1.0),
    "rad": ({"rad": 1}, 1.0),
    "rad/s": ({"rad": 1, "s": -1}, 1.0),
    "rad/s2": ({"rad": 1, "s": -2}, 1.0),
    "deg": ({"rad": 1}, math.pi / 180),
    "deg/s": ({"rad": 1, "s": -1}, math.pi / 180),
}

#: where an FMU keeps its binary, by FMI version and (system, machine)
PLATFORMS = {
    2: {("Linux", "x86_64"): "linux64", ("Darwin", "x86_64"): "darwin64",
        ("Windows", "AMD64"): "win64"},
    3: {("Linux", "x86_64"): "x86_64-linux", ("Linux", "aarch64"): "aarch64-linux",
        ("Darwin", "x86_64"): "x86_64-darwin", ("Darwin", "arm64"): "aarch64-darwin",
        ("Windows", "AMD64"): "x86_64-windows"},
}  # fmt: skip
LIBRARY_SUFFIX = {"Linux": ".so", "Darwin": ".dylib", "Windows": ".dll"}


def model_identifier(fmi: int) -> str:
    """The library's name and the FMU's modelIdentifier: ``door2`` or ``door3``."""
    return f"door{fmi}"


def parameter_name(parameter: Parameter, layout: str) -> str:
    return parameter.name if layout == "tuned" else parameter.untuned


def variables(layout: str) -> list[tuple[int, Signal | Parameter]]:
    """``(value reference, variable)`` in the modelDescription's order: time, the
    layout's signals, the parameters."""
    out: list[tuple[int, Signal | Parameter]] = [(VALUE_REFERENCES["time"], TIME)]
    out += [(VALUE_REFERENCES[s.quantity], s) for s in LAYOUTS[layout]]
    out += [(FIRST_PARAMETER_VR + i, p) for i, p in enumerate(PARAMETERS)]
    return out


def token(fmi: int, layout: str, interfaces: tuple[str, ...], faults: bool = False) -> str:
    """The guid (FMI 2) or instantiationToken (FMI 3): the same for the same build."""
    text = repr((fmi, layout, interfaces, PARAMETERS, LAYOUTS[layout], RK4_MAX_STEP))
    if faults:
        text += repr(FAULTS)
    return "{" + str(uuid.uuid5(uuid.NAMESPACE_OID, text)) + "}"


def check_arguments(fmi, layout, interfaces) -> tuple[str, ...]:
    """The interfaces as a tuple; UserError on a bad version, layout or interface."""
    if fmi not in (2, 3):
        raise UserError(f"fmi must be 2 or 3, not {fmi!r}")
    if layout not in LAYOUTS:
        raise UserError(f"layout must be one of {', '.join(LAYOUT_NAMES)}, not {layout!r}")
    interfaces = tuple(interfaces)
    unknown = [i for i in interfaces if i not in INTERFACE_NAMES]
    if unknown or not interfaces or len(set(interfaces)) != len(interfaces):
        raise UserError(
            f"interfaces must be 'me', 'cs' or both, each once, not {', '.join(interfaces)!r}"
        )
    return tuple(i for i in INTERFACE_NAMES if i in interfaces)


# ---------------------------------------------------------------- the C header


def c_sources(
    fmi: int, layout: str, interfaces: tuple[str, ...], faults: bool = False
) -> dict[str, str]:
    """``door_variables.h`` and ``door_variables.c`` for one build."""
    layout_names = {VALUE_REFERENCES[s.quantity]: s.name for s in LAYOUTS[layout]}
    layout_names[VALUE_REFERENCES["time"]] = TIME.name
    names = [
        f'"{layout_names[vr]}"' if vr in layout_names else "NULL"
        for vr in range(FIRST_PARAMETER_VR)
    ]
    rows = [
        f'    {{"{parameter_name(p, layout)}", {p.start!r}, {p.min!r}, {p.max!r}, '
        f"{int(p.variability == 'fixed')}}},"
        for p in PARAMETERS
    ]
    vr_enum = [f"    DOOR_VR_{key.upper()} = {vr}," for key, vr in VALUE_REFERENCES.items()]
    p_enum = [f"    DOOR_P_{p.name.upper()} = {i}," for i, p in enumerate(PARAMETERS)]
    stamp = f'/* Written by examples/fmu/build.py (FMI {fmi}, layout "{layout}"): do not edit. */'
    fault_lines = ["/* the faulty door of the tests: damping thresholds, N.m.s/rad */"]
    fault_lines += [f"#define DOOR_FAULT_{k.upper()}_ABOVE {v!r}" for k, v in FAULTS.items()]
    header = "\n".join(
        [
            stamp,
            "#ifndef DOOR_VARIABLES_H",
            "#define DOOR_VARIABLES_H",
            "",
            f'#define DOOR_TOKEN "{token(fmi, layout, interfaces, faults)}"',
            f"#define DOOR_MODEL_EXCHANGE {int('me' in interfaces)}",
            f"#define DOOR_CO_SIMULATION {int('cs' in interfaces)}",
            f"#define DOOR_RK4_MAX_STEP {RK4_MAX_STEP!r}",
            *(fault_lines if faults else []),
            "",
            "enum {",
            *vr_enum,
            f"    DOOR_VR_FIRST_PARAMETER = {FIRST_PARAMETER_VR}",
            "};",
            "",
            "enum {",
            *p_enum,
            f"    DOOR_N_PARAMETERS = {len(PARAMETERS)}",
            "};",
            "",
            "typedef struct {",
            "    const char *name;",
            "    double start, min, max;",
            "    int fixed; /* settable only before initialization ends */",
            "} DoorParameter;",
            "",
            "extern const DoorParameter door_parameters[DOOR_N_PARAMETERS];",
            "/* the layout's name of each value reference below the parameters, NULL: none */",
            "extern const char *const door_signal_names[DOOR_VR_FIRST_PARAMETER];",
            "",
            "#endif",
            "",
        ]
    )
    source = "\n".join(
        [
            stamp,
            "#include <stddef.h>",
            "",
            '#include "door_variables.h"',
            "",
            "const DoorParameter door_parameters[DOOR_N_PARAMETERS] = {",
            *rows,
            "};",
            "",
            "const char *const door_signal_names[DOOR_VR_FIRST_PARAMETER] = {",
            "    " + ", ".join(names),
            "};",
            "",
        ]
    )
    return {"door_variables.h": header, "door_variables.c": source}


# ---------------------------------------------------------------- modelDescription.xml


def _number(x: float) -> str:
    return repr(float(x))


def _units(parent: ET.Element, names: list[str]) -> None:
    definitions = ET.SubElement(parent, "UnitDefinitions")
    for name in names:
        exponents, factor = UNITS[name]
        unit = ET.SubElement(definitions, "Unit", name=name)
        base = {k: str(v) for k, v in exponents.items()}
        if factor != 1.0:
            base["factor"] = _number(factor)
        ET.SubElement(unit, "BaseUnit", base)


def _attributes(variable: Signal | Parameter, layout: str, vr: int) -> tuple[dict, dict]:
    """The variable's own attributes and those of its value (FMI 2's <Real>); FMI 3 puts
    both on one element."""
    if isinstance(variable, Parameter):
        own = {
            "name": parameter_name(variable, layout),
            "valueReference": str(vr),
            "description": variable.description,
            "causality": "parameter",
            "variability": variable.variability,
        }
        value = {"start": _number(variable.start), "min": _number(variable.min)}
        value.update(max=_number(variable.max), unit=variable.unit)
        return own, value
    own = {"name": variable.name, "valueReference": str(vr), "description": variable.description}
    own.update(causality=variable.causality, variability="continuous")
    if variable.initial:
        own["initial"] = variable.initial
    value = {} if variable.start is None else {"start": _number(variable.start)}
    value["unit"] = variable.unit
    return own, value


def model_description(
    fmi: int, layout: str, interfaces: tuple[str, ...], faults: bool = False
) -> bytes:
    """The modelDescription.xml of one build, as UTF-8 bytes."""
    listed = variables(layout)
    index = {id(v): i + 1 for i, (_, v) in enumerate(listed)}  # FMI 2 refers by index
    by_quantity = {s.quantity: (vr, s) for vr, s in listed if isinstance(s, Signal)}
    root = ET.Element(
        "fmiModelDescription",
        {
            "fmiVersion": f"{fmi}.0",
            "modelName": "door",
            ("guid" if fmi == 2 else "instantiationToken"): token(fmi, layout, interfaces, faults),
            "description": "A dishwasher-like door on a hinge, driven by the hand's force "
            f"(evo-door's example FMU, layout {layout}"
            + ("; faulty on purpose: a test fixture" if faults else "")
            + ")",
            "generationTool": "evo-door examples/fmu/build.py",
            "variableNamingConvention": "structured",
        },
    )
    if fmi == 2:
        root.set("numberOfEventIndicators", "0")
    state = {"canGetAndSetFMUstate": "true", "canSerializeFMUstate": "true"}
    if fmi == 3:
        state = {k.replace("FMUstate", "FMUState"): v for k, v in state.items()}
    identifier = {"modelIdentifier": model_identifier(fmi)}
    # the C allocates with calloc, not with FMI 2's allocateMemory callback
    memory = {"canNotUseMemoryManagementFunctions": "true"} if fmi == 2 else {}
    if "me" in interfaces:
        extra = {"completedIntegratorStepNotNeeded": "true"} if fmi == 2 else {}
        ET.SubElement(root, "ModelExchange", {**identifier, **state, **extra, **memory})
    if "cs" in interfaces:
        cs = {"canHandleVariableCommunicationStepSize": "true"}
        ET.SubElement(root, "CoSimulation", {**identifier, **cs, **state, **memory})
    units = {v.unit for _, v in listed}
    _units(root, [name for name in UNITS if name in units])
    categories = ET.SubElement(root, "LogCategories")
    ET.SubElement(categories, "Category", name="logStatusError", description="errors")
    ET.SubElement(root, "DefaultExperiment", startTime="0", stopTime="2", stepSize="0.0009765625")

    model_variables = ET.SubElement(root, "ModelVariables")
    for vr, variable in listed:
        own, value = _attributes(variable, layout, vr)
        if isinstance(variable, Signal) and variable.derivative_of:
            state_vr, state_variable = by_quantity[variable.derivative_of]
            value["derivative"] = str(index[id(state_variable)] if fmi == 2 else state_vr)
        if fmi == 2:
            element = ET.SubElement(model_variables, "ScalarVariable", own)
            ET.SubElement(element, "Real", value)
        else:
            ET.SubElement(model_variables, "Float64", {**own, **value})

    outputs = [(vr, v) for vr, v in listed if getattr(v, "causality", "") == "output"]
    derivatives = [(vr, v) for vr, v in listed if getattr(v, "derivative_of", None)]
    initial = [(vr, v) for vr, v in listed if getattr(v, "initial", None) == "calculated"]
    structure = ET.SubElement(root, "ModelStructure")
    groups = (("Outputs", "Output", outputs), ("Derivatives", "ContinuousStateDerivative",
              derivatives), ("InitialUnknowns", "InitialUnknown", initial))  # fmt: skip
    for group, element, members in groups:
        if fmi == 2 and members:
            parent = ET.SubElement(structure, group)
            for _, v in members:
                ET.SubElement(parent, "Unknown", index=str(index[id(v)]))
        elif fmi == 3:
            for vr, _ in members:
                ET.SubElement(structure, element, valueReference=str(vr))
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


# ---------------------------------------------------------------- building


def fmi_headers() -> Path:
    """The standard's C headers that FMPy ships."""
    try:
        import fmpy
    except ImportError as e:
        raise UserError("the FMI headers: install fmpy (it ships them) or pass include_dir") from e
    return Path(fmpy.__file__).parent / "c-code"


def binary_path(fmi: int) -> str:
    """Where the FMU keeps its library on this machine, e.g. binaries/linux64/door2.so."""
    system, machine = platform.system(), platform.machine()
    folder = PLATFORMS[fmi].get((system, machine))
    if folder is None or system not in LIBRARY_SUFFIX:
        raise UserError(f"no FMI {fmi} platform folder known for {system} {machine}")
    return f"binaries/{folder}/{model_identifier(fmi)}{LIBRARY_SUFFIX[system]}"


def _run(command: list[str], what: str) -> None:
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        lines = (done.stdout + done.stderr).splitlines()
        first = next((ln for ln in lines if "error" in ln.lower()), lines[-1] if lines else "")
        sys.stderr.write(done.stdout + done.stderr)
        raise UserError(f"{what} failed (exit {done.returncode}): {first.strip()}")


def compile_library(
    build_dir: Path,
    fmi: int,
    layout: str,
    interfaces: tuple[str, ...],
    include_dir: Path,
    faults: bool = False,
) -> Path:
    """Write the generated C into ``build_dir``, configure and build with CMake; the
    library's path."""
    cmake = shutil.which("cmake")
    if cmake is None:
        raise UserError("cmake is not on PATH: install it (e.g. apt-get install cmake)")
    generated = build_dir / "generated"
    generated.mkdir(parents=True)
    for name, text in c_sources(fmi, layout, interfaces, faults).items():
        (generated / name).write_text(text)
    cmake_dir = build_dir / "cmake"
    configure = [cmake, "-S", str(SOURCES), "-B", str(cmake_dir), "-DCMAKE_BUILD_TYPE=Release"]
    configure += [f"-DFMI_VERSION={fmi}", f"-DFMI_INCLUDE_DIR={include_dir}"]
    configure += [
        f"-DDOOR_GENERATED_DIR={generated}",
        f"-DMODEL_IDENTIFIER={model_identifier(fmi)}",
        f"-DDOOR_FAULTS={'ON' if faults else 'OFF'}",
    ]
    _run(configure, "cmake configure")
    _run([cmake, "--build", str(cmake_dir), "--config", "Release"], "cmake --build")
    suffix = LIBRARY_SUFFIX.get(platform.system(), ".so")
    found = sorted(cmake_dir.rglob(model_identifier(fmi) + suffix))
    if not found:
        raise UserError(f"cmake built no {model_identifier(fmi)}{suffix} in {cmake_dir}")
    return found[0]


def build_fmu(
    out: Path,
    fmi: int = 2,
    layout: str = "tuned",
    interfaces=("me", "cs"),
    *,
    force: bool = False,
    include_dir: Path | None = None,
    faults: bool = False,
) -> Path:
    """Build the door FMU into ``out`` (a .fmu zip) and return its path.

    Parameters
    ----------
    out : the FMU to write; an existing file is refused unless ``force``.
    fmi : 2 or 3.
    layout : "tuned" (states theta, dtheta as outputs, input force) or "untuned"
        (local states door.phi, door.w, input F_hand, outputs angle and speed in deg).
    interfaces : "me", "cs" or both: which of ModelExchange and CoSimulation the
        modelDescription declares (the binary refuses to instantiate the other).
    include_dir : the FMI headers; FMPy's by default.
    faults : build the faulty door of the tests (:data:`FAULTS`): its derivatives and
        DoStep crash, hang or return an error status for damping values above the
        thresholds. A test fixture, never a model.
    """
    interfaces = check_arguments(fmi, layout, interfaces)
    out = Path(out)
    if out.exists() and not force:
        raise UserError(f"{out} exists: pass force=True (--force) to write over it")
    if not out.parent.is_dir():
        raise UserError(f"{out.parent} is not a folder")
    include_dir = Path(include_dir) if include_dir else fmi_headers()
    in_zip = binary_path(fmi)
    with tempfile.TemporaryDirectory(prefix="door-fmu-") as tmp:
        library = compile_library(Path(tmp), fmi, layout, interfaces, include_dir, faults)
        partial = out.with_name(f".{out.name}.partial")
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as zf:
            description = model_description(fmi, layout, interfaces, faults)
            zf.writestr("modelDescription.xml", description)
            zf.write(library, in_zip)
        os.replace(partial, out)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version")
    parser.add_argument("--layout", choices=LAYOUT_NAMES, default="tuned")
    parser.add_argument(
        "--interfaces", default="me,cs", help="me, cs or me,cs (default: both in one FMU)"
    )
    parser.add_argument("--out", type=Path, required=True, help="the .fmu to write")
    parser.add_argument("--force", action="store_true", help="write over an existing --out")
    parser.add_argument("--include-dir", type=Path, help="the FMI headers (default: FMPy's)")
    parser.add_argument(
        "--faults",
        action="store_true",
        help="the faulty door of the tests: damping > {crash:g} crashes, > {hang:g} hangs, "
        "> {error:g} fails (N.m.s/rad)".format(**FAULTS),
    )
    args = parser.parse_args(argv)
    started = time.perf_counter()
    try:
        out = build_fmu(
            args.out,
            args.fmi,
            args.layout,
            tuple(i.strip() for i in args.interfaces.split(",") if i.strip()),
            force=args.force,
            include_dir=args.include_dir,
            faults=args.faults,
        )
    except UserError as e:
        print(f"build.py: error: {e}", file=sys.stderr)
        return 2
    size = out.stat().st_size / 1024
    faulty = ", faulty on purpose" if args.faults else ""
    print(
        f"wrote {out} (FMI {args.fmi}.0, layout {args.layout}, {args.interfaces}{faulty}; "
        f"{size:.1f} KiB) in {time.perf_counter() - started:.1f} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
