"""Mechanisms from blocks: a YAML file of bodies and components becomes a model.

A mechanism file (``docs/blocks.md``) names bodies (linear or rotary), transmissions
(:mod:`~evo_door.models.blocks.transmissions`) and elements from the component library
(:mod:`~evo_door.models.blocks.library`: spring, damper, friction, end stop,
soft-close damper, cable, detent, gas strut, table spring) that act on one body or
between two, or on a transmission's output.
:func:`load_mechanism` reads it (:mod:`~evo_door.models.blocks.mechanism`), writes its
one right-hand side as numba source (:mod:`~evo_door.models.blocks.codegen`) into a
cache folder named by the digest of that source and of evo-door's version, and imports
it: numba's own cache beside that file makes a second process with the same mechanism
compile nothing. The file is data: no code in it runs, its names are checked
identifiers and its numbers only parameter defaults.

The cache folder is ``$EVO_DOOR_MECHANISM_CACHE`` if set, else
``$XDG_CACHE_HOME/evo_door/mechanisms`` (``~/.cache/evo_door/mechanisms``).
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
from pathlib import Path

from evo_door.errors import UserError
from evo_door.params.declaration import suggest

#: environment variable naming the folder of generated mechanisms (tests use a tmp one)
CACHE_ENV = "EVO_DOOR_MECHANISM_CACHE"
#: file endings of a mechanism file
SUFFIXES = (".yaml", ".yml")


def is_mechanism_spec(name: str) -> bool:
    """``path/to/mechanism.yaml`` (a model given as a mechanism file)."""
    return str(name).strip().lower().endswith(SUFFIXES)


def cache_root() -> Path:
    """The folder of the generated mechanisms (see the module docstring)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base).expanduser() / "evo_door" / "mechanisms"


def load_mechanism(path: Path):
    """The :class:`~evo_door.models.base.Model` of the mechanism file ``path``."""
    from evo_door.models.base import Model
    from evo_door.models.blocks.mechanism import read_mechanism

    if not path.is_file():
        hint = ""
        if path.parent.is_dir():
            names = [q.name for q in path.parent.iterdir() if q.suffix in SUFFIXES]
            hint = suggest(path.name, names)
        raise UserError(f"mechanism file {path} not found{hint}")
    mech = read_mechanism(path)
    module, layout = _compiled(mech)
    handle = mech.bodies[mech.handle]
    return Model(
        **_declared(mech, path),
        rhs=module.rhs,
        switches=getattr(module, "switches", None),
        n_switches=layout.n_switches,
        states=layout.states,
        handle=layout.handle,
        x0=layout.x0,
        contacts=layout.contacts,
        method=mech.integration["method"],
        tolerance=mech.integration["tolerance"],
        substeps=mech.integration["substeps"],
        theta0=handle.range[0],
        theta_range=handle.range,
        rig_kinds=("impulse",),
    )


def mechanism_declaration(path: Path):
    """The :class:`~evo_door.models.base.Declaration` of the mechanism file ``path``:
    what a reader of its runs needs (names, units, bounds), from the file alone, its
    module neither generated nor compiled."""
    from evo_door import __version__
    from evo_door.models.base import Declaration
    from evo_door.models.blocks.codegen import generate
    from evo_door.models.blocks.mechanism import read_mechanism

    mech = read_mechanism(path)
    _, layout = generate(mech, __version__)  # source text only: its states' names
    return Declaration(**_declared(mech, path), states=layout.states, handle=layout.handle)


def _declared(mech, path: Path) -> dict:
    """The fields a mechanism's model and its declaration share."""
    from evo_door.params import ParamTable

    return dict(
        name=mech.name,
        title=mech.title,
        params=ParamTable(mech.name, mech.params),
        theta_unit="m" if mech.bodies[mech.handle].kind == "linear" else "rad",
        notes=mech.notes or _notes(mech, path),
    )


def mechanism_energy(path: Path):
    """The compiled ``energy(x, p)`` of the mechanism file ``path`` (J): kinetic energy
    of the bodies, potential energy of their weights and of the elements that store
    one (spring, cable, end stop, detent, gas strut)."""
    from evo_door.models.blocks.mechanism import read_mechanism

    return _compiled(read_mechanism(path))[0].energy


def _compiled(mech):
    """The mechanism's generated module, imported, and its layout."""
    from evo_door import __version__
    from evo_door.models.blocks.codegen import generate

    source, layout = generate(mech, __version__)
    text = f"{__version__}\n{_library_stamp(source)}\n{source}"
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    return _import(source, digest), layout


def _notes(mech, path: Path) -> str:
    bodies = ", ".join(f"{b.name} ({b.kind})" for b in mech.bodies.values())
    elements = ", ".join(f"{e.name} ({e.kind})" for e in mech.elements.values()) or "none"
    return f"Mechanism file {path.name}: bodies {bodies}; elements {elements}."


def _library_stamp(source: str) -> str:
    """A digest of the library code the generated source calls (the seed's blocks):
    every module of the packages its ``from evo_door... import`` lines name. numba's
    cache beside the generated file would not see an edit of that code; a new digest
    is a new folder, compiled afresh."""
    packages = set()
    for line in source.splitlines():
        if line.startswith("from evo_door."):
            spec = importlib.util.find_spec(line.split()[1])
            if spec is not None and spec.origin:
                packages.add(Path(spec.origin).parent)
    h = hashlib.sha256()
    for folder in sorted(packages):
        for file in sorted(folder.glob("*.py")):
            h.update(file.name.encode() + b"\0" + file.read_bytes())
    return h.hexdigest()


def _import(source: str, digest: str):
    """The generated module, written once into its cache folder and imported."""
    name = f"evo_door_mechanism_{digest}"
    if name in sys.modules:
        return sys.modules[name]
    folder = cache_root() / digest
    file = folder / "mech.py"
    try:
        if not file.is_file() or file.read_text(encoding="utf-8") != source:
            folder.mkdir(parents=True, exist_ok=True)
            tmp = folder / f".mech.{os.getpid()}.tmp"
            tmp.write_text(source, encoding="utf-8")
            os.replace(tmp, file)
    except OSError as exc:
        raise UserError(
            f"cannot write the compiled mechanism to {folder} ({exc.strerror}); set "
            f"{CACHE_ENV} to a folder you can write"
        ) from None
    spec = importlib.util.spec_from_file_location(name, file)
    if spec is None or spec.loader is None:
        raise UserError(f"cannot import the compiled mechanism {file}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except Exception:
        del sys.modules[name]
        raise
    return module
