"""Build the hybrid hinge FMU (FMI 2.0 or 3.0, model exchange only) from this folder's C.

The variables are declared once, here, as data: :func:`model_description` writes the
modelDescription.xml from them and :func:`variables_header` the C header that gives
``hinge.c`` their value references and the parameters' names, starts and bounds. The
physics and the events are described in ``hinge.h``; the tests that use the FMU are in
``tests/test_fmu_events.py``. CMake, a C compiler and FMPy (for the standard's headers)
are needed; the examples' builder (``examples/fmu/build.py``) lends its helpers.
"""

from __future__ import annotations

import platform
import shutil
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass, replace
from pathlib import Path

from tests.helpers import door_fmu_builder

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class Parameter:
    name: str
    unit: str
    start: float
    min: float
    max: float
    variability: str  # "tunable" or "fixed"
    description: str


PARAMETERS = (
    Parameter("inertia", "kg.m2", 0.7, 0.05, 5.0, "tunable", "moment of inertia about the hinge"),
    Parameter("lever_arm", "m", 0.55, 0.1, 1.0, "fixed", "handle's distance from the hinge"),
    Parameter("weight_moment", "N.m", 17.0, 0.0, 60.0, "tunable",
              "weight times centre-of-mass distance (pulls open)"),
    Parameter("spring_preload", "N.m", 6.0, 0.0, 40.0, "tunable",
              "spring torque at closed, toward closing"),
    Parameter("spring_stiffness", "N.m/rad", 8.0, 0.0, 60.0, "tunable",
              "spring torque per rad of opening"),
    Parameter("damping", "N.m.s/rad", 0.8, 0.0, 10.0, "tunable", "viscous hinge damping"),
    Parameter("friction", "N.m", 0.5, 0.0, 10.0, "tunable",
              "dry friction, smoothed: friction*tanh(omega/friction_speed)"),
    Parameter("friction_speed", "rad/s", 0.02, 1e-4, 1.0, "fixed",
              "speed over which the dry friction builds up"),
    Parameter("stop_stiffness", "N.m/rad", 2000.0, 10.0, 1e5, "fixed",
              "closed stop (theta > pi/2): penalty stiffness"),
    Parameter("stop_damping", "N.m.s/rad", 10.0, 0.0, 1000.0, "fixed",
              "closed stop's damping, while pressed"),
    Parameter("latch_angle", "rad", 1.45, 0.5, 1.5, "tunable",
              "the catch engages when the door closes past this angle"),
    Parameter("latch_play", "rad", 0.05, 0.001, 0.5, "tunable",
              "the catch lets go this far below latch_angle"),
    Parameter("latch_torque", "N.m", 10.0, 0.0, 100.0, "tunable",
              "while latched, the catch pulls the door shut with this torque"),
    Parameter("release_time", "s", 1e9, 0.0, 1e12, "fixed",
              "time event: the damping boost switches on at this time"),
    Parameter("boost_damping", "N.m.s/rad", 5.0, 0.0, 100.0, "tunable",
              "damping added from release_time on"),
    Parameter("restitution", "1", 0.5, 0.0, 1.0, "tunable",
              "open stop (theta = 0): the door bounces back at this fraction of its speed"),
)  # fmt: skip

FIRST_PARAMETER_VR = 20


@dataclass(frozen=True)
class Variable:
    """A variable that is not a parameter, with its value reference ``vr``."""

    name: str
    vr: int
    type: str  # "Real" or "Boolean"
    causality: str
    variability: str
    unit: str
    description: str
    initial: str | None = None
    start: float | None = None
    derivative_of: str | None = None


VARIABLES = (
    Variable("time", 0, "Real", "independent", "continuous", "s", "simulation time"),
    Variable("theta", 1, "Real", "output", "continuous", "rad",
             "door angle: 0 fully open, pi/2 closed", "exact", 0.0),
    Variable("dtheta", 2, "Real", "output", "continuous", "rad/s",
             "angular speed, + closing", "exact", 0.0, "theta"),
    Variable("ddtheta", 3, "Real", "output", "continuous", "rad/s2",
             "angular acceleration", "calculated", None, "dtheta"),
    Variable("force", 4, "Real", "input", "continuous", "N",
             "hand's force at the handle, + toward closing", None, 0.0),
    Variable("latched", 5, "Boolean", "output", "discrete", "",
             "the catch holds the door", "calculated"),
    Variable("damping_boost", 6, "Boolean", "output", "discrete", "",
             "the boost damping acts", "calculated"),
    Variable("z_latch", 7, "Real", "local", "continuous", "rad",
             "event indicator: theta - latch_angle", "calculated"),
    Variable("z_release", 8, "Real", "local", "continuous", "rad",
             "event indicator: theta - (latch_angle - latch_play)", "calculated"),
    Variable("z_stop", 9, "Real", "local", "continuous", "rad",
             "event indicator: theta (the open stop)", "calculated"),
)  # fmt: skip

EVENT_INDICATORS = ("z_latch", "z_release", "z_stop")
UNITS = {  # name: SI base-unit exponents
    "s": {"s": 1},
    "m": {"m": 1},
    "N": {"kg": 1, "m": 1, "s": -2},
    "kg.m2": {"kg": 1, "m": 2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "1": {},
}


def variant(theta_start: float | None = None, rename=None) -> tuple[tuple, tuple]:
    """``(parameters, variables)`` of a variant of the hinge: the angle's start value
    ``theta_start`` (rad, the C's too), parameters renamed (``{"latch_angle":
    "theta0"}``: the XML's and the C table's name; the C code keeps its macros)."""
    rename = dict(rename or {})
    parameters = tuple(replace(p, name=rename.get(p.name, p.name)) for p in PARAMETERS)
    variables = VARIABLES
    if theta_start is not None:
        variables = tuple(
            replace(v, start=float(theta_start)) if v.name == "theta" else v for v in VARIABLES
        )
    return parameters, variables


def token(fmi: int, parameters=PARAMETERS, variables=VARIABLES) -> str:
    """The guid / instantiationToken: a hash of the declaration."""
    import uuid

    return "{" + str(uuid.uuid5(uuid.NAMESPACE_OID, repr((fmi, parameters, variables)))) + "}"


def variables_header(fmi: int, parameters=PARAMETERS, variables=VARIABLES) -> str:
    """``hinge_variables.h``: value references, parameter indices and the parameter table."""
    lines = ["/* Written by tests/fmu_events/hinge_fmu.py: do not edit. */", "#pragma once", ""]
    lines += [f"#define HINGE_VR_{v.name.upper()} {v.vr}" for v in VARIABLES]
    theta = next(v for v in variables if v.name == "theta")
    lines += [f"#define HINGE_THETA_START {float(theta.start or 0.0)!r}"]
    lines += [f"#define HINGE_VR_FIRST_PARAMETER {FIRST_PARAMETER_VR}"]
    lines += [f"#define HINGE_N_PARAMETERS {len(PARAMETERS)}"]
    lines += [f"#define HINGE_N_EVENT_INDICATORS {len(EVENT_INDICATORS)}"]
    lines += [f'#define HINGE_TOKEN "{token(fmi, parameters, variables)}"']
    lines += [f"#define HINGE_P_{p.name.upper()} {i}" for i, p in enumerate(PARAMETERS)]
    lines += ["typedef struct { const char *name; double start, min, max; int fixed; } "
              "HingeParameter;", "#define HINGE_PARAMETER_TABLE { \\"]  # fmt: skip
    lines += [
        f'    {{"{p.name}", {p.start!r}, {p.min!r}, {p.max!r}, {int(p.variability == "fixed")}}}, \\'
        for p in parameters
    ]
    return "\n".join([*lines, "}", ""])


def _variable_elements(fmi: int, parent: ET.Element, parameters, variables) -> dict[str, int]:
    """The <ModelVariables> children; FMI 2's index (1-based) of each name."""
    by_name = {v.name: v for v in variables}
    index = {}
    rows = [(v.vr, v) for v in variables] + [
        (FIRST_PARAMETER_VR + i, p) for i, p in enumerate(parameters)
    ]
    for n, (vr, v) in enumerate(rows, start=1):
        index[v.name] = n
        own = {"name": v.name, "valueReference": str(vr), "description": v.description}
        if isinstance(v, Parameter):
            own.update(causality="parameter", variability=v.variability)
            value = {"start": repr(v.start), "min": repr(v.min), "max": repr(v.max), "unit": v.unit}
            kind = "Real"
        else:
            own.update(causality=v.causality, variability=v.variability)
            if v.initial:
                own["initial"] = v.initial
            value = {"start": repr(v.start)} if v.start is not None else {}
            if v.unit:
                value["unit"] = v.unit
            if v.derivative_of:
                state = by_name[v.derivative_of]
                value["derivative"] = str(index[state.name] if fmi == 2 else state.vr)
            kind = v.type
        if fmi == 2:
            ET.SubElement(ET.SubElement(parent, "ScalarVariable", own), kind, value)
        else:
            ET.SubElement(parent, "Float64" if kind == "Real" else kind, {**own, **value})
    return index


def model_description(fmi: int, parameters=PARAMETERS, variables=VARIABLES) -> bytes:
    """The modelDescription.xml (UTF-8) of the FMI ``fmi`` build."""
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": f"{fmi}.0",
        "modelName": "hinge",
        ("guid" if fmi == 2 else "instantiationToken"): token(fmi, parameters, variables),
        "description": "a door on a hinge with a latch, a timed damping boost and a "
        "bouncing open stop (evo-door's event tests)",
        "generationTool": "evo-door tests/fmu_events/hinge_fmu.py",
    })  # fmt: skip
    if fmi == 2:
        root.set("numberOfEventIndicators", str(len(EVENT_INDICATORS)))
    me = {"modelIdentifier": f"hinge{fmi}"}
    if fmi == 2:
        me["canNotUseMemoryManagementFunctions"] = "true"
    else:
        me["needsCompletedIntegratorStep"] = "true"
    ET.SubElement(root, "ModelExchange", me)
    used = {p.unit for p in parameters} | {v.unit for v in variables if v.unit}
    units = ET.SubElement(root, "UnitDefinitions")
    for name in (u for u in UNITS if u in used):
        ET.SubElement(ET.SubElement(units, "Unit", name=name), "BaseUnit",
                      {k: str(e) for k, e in UNITS[name].items()})  # fmt: skip
    ET.SubElement(root, "DefaultExperiment", startTime="0", stopTime="2")
    index = _variable_elements(fmi, ET.SubElement(root, "ModelVariables"), parameters, variables)
    outputs = [v for v in variables if v.causality == "output"]
    derivatives = [v for v in variables if v.derivative_of]
    initial = [v for v in variables if v.initial == "calculated" and v.causality == "output"]
    structure = ET.SubElement(root, "ModelStructure")
    if fmi == 2:
        for group, members in (("Outputs", outputs), ("Derivatives", derivatives),
                               ("InitialUnknowns", initial)):  # fmt: skip
            parent = ET.SubElement(structure, group)
            for v in members:
                ET.SubElement(parent, "Unknown", index=str(index[v.name]))
    else:
        by_name = {v.name: v for v in variables}
        indicators = [by_name[n] for n in EVENT_INDICATORS]
        for element, members in (("Output", outputs), ("ContinuousStateDerivative", derivatives),
                                 ("InitialUnknown", initial), ("EventIndicator", indicators)):  # fmt: skip
            for v in members:
                ET.SubElement(structure, element, valueReference=str(v.vr))
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def build_hinge_fmu(out: Path, fmi: int = 2, theta_start=None, rename=None) -> Path:
    """Build the hybrid hinge FMU (model exchange, FMI ``fmi``) into ``out``; its path.
    ``theta_start`` and ``rename`` make a :func:`variant`."""
    parameters, variables = variant(theta_start, rename)
    example = door_fmu_builder()  # its platform table, headers and runner
    cmake = shutil.which("cmake")
    if cmake is None:
        raise RuntimeError("cmake is not on PATH")
    system = platform.system()
    folder = example.PLATFORMS[fmi][(system, platform.machine())]
    library_name = f"hinge{fmi}{example.LIBRARY_SUFFIX[system]}"
    with tempfile.TemporaryDirectory(prefix="hinge-fmu-") as tmp:
        generated, build = Path(tmp, "generated"), Path(tmp, "build")
        generated.mkdir()
        (generated / "hinge_variables.h").write_text(variables_header(fmi, parameters, variables))
        configure = [cmake, "-S", str(HERE), "-B", str(build), "-DCMAKE_BUILD_TYPE=Release"]
        configure += [f"-DFMI_VERSION={fmi}", f"-DFMI_INCLUDE_DIR={example.fmi_headers()}"]
        configure += [f"-DHINGE_GENERATED_DIR={generated}"]
        example._run(configure, "cmake configure")
        example._run([cmake, "--build", str(build)], "cmake --build")
        out = Path(out)
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("modelDescription.xml", model_description(fmi, parameters, variables))
            zf.write(build / library_name, f"binaries/{folder}/{library_name}")
    return out
