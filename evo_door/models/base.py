"""What every 1-DOF model of the workbench provides, and how models are found.

A model is data plus one compiled function:

- ``params``: its :class:`~evo_door.params.ParamTable` (the declaration);
- ``accel``: a numba-compiled ``accel(theta, dtheta, force, p) -> ddtheta`` where
  ``theta`` is the model's coordinate (for the doors the angle in rad, 0 fully open,
  pi/2 closed), ``force`` (N) the user's force at the handle (positive toward closing)
  and ``p`` the flat parameter vector in declaration order. ``accel`` must be affine
  in ``force`` (true of any mechanical model driven by an external force); the
  quasi-static force-angle curve relies on it.
- integration defaults: the scheme and sub-steps per sample that keep the model's
  stiffest element stable at 1024 Hz.

:func:`get_model` finds a model by

- name: a model another installed package registers in the entry-point group
  ``evo_door.models`` (the bundled ``haptic`` and ``door`` are registered that way
  too, with :data:`REGISTRY` as the fallback of an install whose metadata is stale);
- import path ``package.module:ATTRIBUTE`` (the module must be importable);
- file path ``path/to/file.py:ATTRIBUTE``: a model in a user's own Python file,
  relative to the current folder, no PYTHONPATH needed;
- mechanism file ``path/to/drawer.yaml``: bodies and components as data, compiled into
  one right-hand side (:mod:`evo_door.models.blocks`, ``docs/blocks.md``).

Whatever the source, :func:`check_model` refuses a model the integrators could not
run, with one line, before anything is simulated. Nothing heavy is imported until a
model is asked for.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.abc
import importlib.metadata
import importlib.util
import math
import re
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

from evo_door.errors import UserError
from evo_door.models.blocks import is_mechanism_spec, load_mechanism, mechanism_declaration
from evo_door.models.check import RIG_KINDS, check_model  # noqa: F401 (RIG_KINDS: re-exported)
from evo_door.params import ParamSet, ParamTable, available_presets, load_params
from evo_door.params.declaration import suggest

if TYPE_CHECKING:
    from evo_door.sim.plant import Plant

#: Entry-point group through which installed packages register models.
MODEL_GROUP = "evo_door.models"


@dataclass(frozen=True)
class Model:
    """A 1-DOF model (see the module docstring).

    Attributes
    ----------
    name, title : str
        Short name (presets folder, parameter files' ``model:``) and one-line title.
    params : ParamTable
        The declaration; its ``model`` is ``name``.
    accel : numba dispatcher
        ``accel(theta, dtheta, force, p) -> ddtheta``, compiled with ``@njit``.
    method, substeps
        Integration defaults (``"rk4"`` or ``"semi_implicit"``, steps per sample).
    theta0 : float
        Initial coordinate of simulations that do not give one.
    notes : str
        Free text shown by ``evo-door params MODEL``.
    rig_kinds : tuple of str
        Trials the virtual rig can make with the model. ``unlock`` and ``lock`` need a
        latch near closed that the rig's hand can feel; only a model that has one says
        so. ``impulse`` (a push from fully open, then free motion) suits any model.
        ``slow`` (the stroke opened from closed and closed again at a slow speed, in
        rad/s and starting through the latch) needs an angle in rad and a closed door.
    theta_range : (float, float)
        The coordinate from fully open to closed, in ``theta_unit``: the grid of
        ``evo-door curve``.
    theta_unit : str
        Unit of ``theta`` (``"rad"`` for a door; ``"m"`` for a drawer's stroke); its
        speed is in ``theta_unit``/s.
    preset_dirs : tuple of Path
        The model's own preset folders (filled by :func:`get_model`: a ``presets/``
        folder next to the model's file).
    switches : numba cfunc or None
        ``switches(theta, dtheta, force, p, g)``, compiled: writes the values of the
        model's ``n_switches`` switching functions into ``g`` (where the right-hand
        side has a kink or a jump: a latch band's edge, a stop). The integrators
        locate their sign changes within the step (:mod:`evo_door.sim.located`).
    n_switches : int
        How many values ``switches`` writes.
    stick_slip : bool
        The model's dry friction is a sign law (``sgn(0) = 0``): the integrators
        hold the door at rest while the friction can, as the renderer does.
    tolerance : float
        Tolerance of the adaptive ``dopri5`` method (per step, rad and rad/s).
    rhs : numba function or None
        A model on a **state vector** gives ``rhs(x, force, p, dx)`` instead of
        ``accel``: it writes the derivative ``dx`` of the state ``x`` (both float64
        arrays of ``len(states)``), affine in ``force`` (:mod:`evo_door.sim.states`).
    states : tuple of str
        Names of the states of an ``rhs`` model, in the order of ``x``.
    handle : (int, int)
        Indices in ``x`` of the coordinate the hand holds (``theta``) and of its speed.
    x0 : tuple of float
        Initial state of an ``rhs`` model (default all 0.0); ``theta0`` and the trial's
        own start replace the handle's entries.
    start : numba function or None
        ``start(x, p)``: completes the initial state from the parameters (an elastic
        element at rest, say), after the handle's entries are set.
    contacts : tuple of int
        Indices in ``x`` of the speeds of an ``rhs`` model's dry-friction contacts whose
        law is a sign (``sgn(0) = 0``): each sticks and slips on its own, as
        ``stick_slip`` does for a one-coordinate model.
    """

    name: str
    title: str
    params: ParamTable
    accel: Callable | None = None
    method: str = "semi_implicit"
    substeps: int = 2
    theta0: float = 0.0
    notes: str = ""
    rig_kinds: tuple[str, ...] = ("impulse",)
    theta_range: tuple[float, float] = (0.0, 0.5 * math.pi)
    theta_unit: str = "rad"
    preset_dirs: tuple[Path, ...] = ()
    switches: Callable | None = None
    n_switches: int = 0
    stick_slip: bool = False
    tolerance: float = 1e-7
    rhs: Callable | None = None
    states: tuple[str, ...] = ()
    handle: tuple[int, int] = (0, 1)
    x0: tuple[float, ...] = ()
    start: Callable | None = None
    contacts: tuple[int, ...] = ()

    @cached_property
    def plant(self) -> Plant:
        """What the simulator, the objectives and the curves run
        (:class:`~evo_door.sim.plant.Plant`): the compiled integrators on ``accel``, or
        on the state vector of ``rhs``."""
        # numba is imported only when a model runs
        if self.rhs is not None:
            from evo_door.sim.state_plant import StatePlant

            return StatePlant(self)
        from evo_door.sim.accel_plant import AccelPlant

        return AccelPlant(self)

    def load_params(self, spec=None, overrides=None) -> ParamSet:
        """A checked parameter set: ``spec`` is None (declared defaults), a preset name,
        a YAML path or a mapping name -> value (on top of the defaults); ``overrides``
        (name -> value) are applied on top."""
        return load_params(self.params, spec, overrides, self.preset_dirs)

    def presets(self) -> list[str]:
        """Names of the presets this model can load (same lookup as :meth:`load_params`,
        with those of the models whose parameter files it reads)."""
        names = {n for m in self.params.reads for n in available_presets(m, self.preset_dirs)}
        return sorted(names)


@dataclass(frozen=True)
class Declaration:
    """What can be read of a model without its compiled kernel: its name, title,
    parameter declaration, notes and presets (``evo-door params MODEL``).

    A bundled model keeps it in a module of its own that does not import numba (for
    example :mod:`evo_door.models.haptic_params`), so that reading it is quick;
    :func:`get_declaration` returns it, or the :class:`Model` itself (which has the
    same attributes) for any other model.
    """

    name: str
    title: str
    params: ParamTable
    notes: str = ""
    preset_dirs: tuple[Path, ...] = ()
    theta_unit: str = "rad"  # as :attr:`Model.theta_unit`
    states: tuple[str, ...] = ()  # as :attr:`Model.states` (a model on a state vector)
    handle: tuple[int, int] = (0, 1)  # as :attr:`Model.handle`

    def load_params(self, spec=None, overrides=None) -> ParamSet:
        """As :meth:`Model.load_params`."""
        return load_params(self.params, spec, overrides, self.preset_dirs)

    def presets(self) -> list[str]:
        """As :meth:`Model.presets`."""
        return available_presets(self.params.model, self.preset_dirs)


#: name -> "module:attribute" of the bundled models: the fallback when the installed
#: metadata does not (yet) list them in the ``evo_door.models`` entry-point group.
REGISTRY: dict[str, str] = {
    "haptic": "evo_door.models.haptic:MODEL",
    "haptic_tanh": "evo_door.models.haptic:MODEL_TANH",
    "door": "evo_door.models.door:MODEL",
}

#: name -> "module:attribute" of the bundled models' :class:`Declaration` (no numba),
#: for the names of :data:`REGISTRY` whose declaration lives apart from the kernels.
DECLARATIONS: dict[str, str] = {
    "haptic": "evo_door.models.haptic_params:DECLARATION",
    "door": "evo_door.models.door_params:DECLARATION",
}

#: Models already loaded, by the key :func:`get_model` resolves a name to. Module-level
#: on purpose: a model is one compiled object per process (its numba functions are
#: compiled or loaded once, and a pickled problem finds it again by name); it holds one
#: entry per model a process names, never evicted.
_MODELS: dict[str, Model] = {}
#: User files already executed, by absolute path: a file is run once per process, so
#: its numba functions are compiled (or loaded from cache) once; one entry per file.
_FILE_MODULES: dict[Path, object] = {}


# -- finding models -------------------------------------------------------------------
def available_models() -> list[str]:
    """Names of the registered models (entry points and bundled) whose module exists."""
    names = set()
    for name, target in {**REGISTRY, **_entry_point_targets()}.items():
        try:
            if importlib.util.find_spec(target.split(":")[0]) is not None:
                names.add(name)
        except Exception:  # a broken package's __init__: not available
            pass
    return sorted(names)


def _entry_point_targets() -> dict[str, str]:
    return {ep.name: ep.value for ep in importlib.metadata.entry_points(group=MODEL_GROUP)}


def is_file_spec(name: str) -> bool:
    """``path/to/file.py:ATTRIBUTE`` (as opposed to a name or a module path)."""
    path, sep, _ = name.rpartition(":")
    return bool(sep) and path.endswith(".py")


def resolve_model_name(name: str, base_dir=None) -> str:
    """``name`` with a relative ``file.py:ATTRIBUTE`` or mechanism file made absolute.

    The file is looked for in ``base_dir`` (an experiment file's folder) first, then
    in the current folder (where neither has it, the name points into ``base_dir``, so
    that the error names the folder the user most likely meant); names and module
    paths are returned as they are. Stored absolute, the name still finds the model
    when a run is shown or resumed from another folder.
    """
    from evo_door.models.fmu import is_fmu_spec, join_spec, split_spec

    if is_fmu_spec(name):
        fmu, interface, mapping = split_spec(name)
        return join_spec(_beside(fmu, base_dir), interface, mapping)
    if is_mechanism_spec(name):
        return str(_beside(Path(name.strip()).expanduser(), base_dir))
    if not is_file_spec(name):
        return name
    file, _, attr = name.rpartition(":")
    return f"{_beside(Path(file).expanduser(), base_dir)}:{attr}"


def _beside(p: Path, base_dir) -> Path:
    """``p`` made absolute: in ``base_dir`` first, then in the current folder."""
    if not p.is_absolute():
        here = Path.cwd() / p
        beside = Path(base_dir) / p if base_dir is not None else here
        p = here if here.is_file() and not beside.is_file() else beside
    return p.resolve()


def get_model(name: str) -> Model:
    """The model called ``name``: a registered name, ``module:ATTR``, ``file.py:ATTR``
    or a mechanism file ``drawer.yaml``.

    The same model is returned for the same name (and for one file however its path
    is written), checked once by :func:`check_model`.
    """
    from evo_door.models.fmu import is_fmu_spec, load_fmu

    name = str(name).strip()
    fmu = is_fmu_spec(name)
    mechanism = is_mechanism_spec(name)
    key = resolve_model_name(name) if is_file_spec(name) or fmu or mechanism else name
    _NAMED_BY_USER.add(key)  # (named by the caller: see model_in_file for a file's names)
    if key in _MODELS:
        return _MODELS[key]
    if fmu:
        model, folder = load_fmu(key), Path(key.partition("?")[0].rpartition(".fmu")[0]).parent
    elif mechanism:
        model, folder = load_mechanism(Path(key)), Path(key).parent
    elif is_file_spec(name):
        path, _, attr = key.rpartition(":")
        model, folder = _from_file(name, Path(path), attr)
    elif ":" in name and name not in REGISTRY:
        model, folder = _from_module(name, name)
    else:
        model, folder = _registered(name)
    model = check_model(model, name)
    model = _with_presets_beside(model, folder)
    _MODELS[key] = model
    return model


#: the model names that are code (a file, a module path, an FMU) the user has named in
#: this process: on the command line, in an experiment they run, with ``--allow-model``;
#: a name read from a file is loaded only when it is one of them (:func:`model_in_file`)
_NAMED_BY_USER: set[str] = set()


def is_code_spec(name: str) -> bool:
    """Whether loading the model ``name`` runs code that is not installed: a Python
    file, a module path or an FMU (a registered name is installed code).

    >>> is_code_spec("door"), is_code_spec("x/drawer.py:MODEL"), is_code_spec("m.fmu")
    (False, True, True)
    >>> is_code_spec("x/drawer.yaml")  # a mechanism file is data (docs/blocks.md)
    False
    """
    from evo_door.models.fmu import is_fmu_spec

    name = str(name).strip()
    if is_fmu_spec(name) or is_file_spec(name):
        return True
    return ":" in name and name not in REGISTRY


def _trust_key(name: str) -> str:
    from evo_door.models.fmu import is_fmu_spec

    name = str(name).strip()
    if is_file_spec(name) or is_fmu_spec(name):
        return resolve_model_name(name)
    return name


def allow_model(name: str) -> None:
    """Let a model that is code be loaded when a file names it (``--allow-model``; an
    experiment the user runs names its own models through :func:`get_model`)."""
    _NAMED_BY_USER.add(_trust_key(name))


def model_in_file(name: str, where: str = "a file") -> Model:
    """The model a file names (a results file, a trial file, a log), loaded only if it
    is installed (a registered name, an entry point) or the user named it too
    (:func:`allow_model`, :func:`get_model`); otherwise refused in one line, without
    running it: a file someone sent you is data, never code."""
    check_named_in_file(name, where)
    return get_model(name)


def check_named_in_file(name: str, where: str = "a file") -> None:
    """Refuse, in one line and without loading it, a model that a file names and that
    is code the user has not named (:func:`model_in_file`)."""
    if is_code_spec(name) and _trust_key(name) not in _NAMED_BY_USER:
        raise UserError(
            f"{where} names model {name!r}, code that evo-door would run to read it; a "
            "model a file names runs only when you name it too: --allow-model "
            f"{name!r} (only for files you trust: docs/trust.md)"
        )


def get_declaration(name: str) -> Declaration | Model:
    """The declaration of the model called ``name`` (as :func:`get_model` finds it),
    read without importing numba when it is a bundled model of :data:`DECLARATIONS`
    that no installed package registers differently; else the :class:`Model` itself.
    """
    name = str(name).strip()
    if is_mechanism_spec(name):
        return _mechanism_declaration(name)
    if name not in DECLARATIONS or name in _MODELS:
        return get_model(name)
    targets = {
        ep.value for ep in importlib.metadata.entry_points(group=MODEL_GROUP) if ep.name == name
    }
    if targets - {REGISTRY[name]}:
        return get_model(name)
    declaration, _ = _from_module(DECLARATIONS[name], name)
    # the presets folder get_model would add: beside the model's module, not this one
    spec = importlib.util.find_spec(REGISTRY[name].split(":")[0])
    origin = getattr(spec, "origin", None)
    return _with_presets_beside(declaration, Path(origin).parent if origin else None)


def _mechanism_declaration(name: str) -> Declaration | Model:
    """A mechanism file's declaration read from the file (its module is neither
    generated nor compiled), or its model once loaded."""
    key = resolve_model_name(name)
    if key in _MODELS or not Path(key).is_file():
        return get_model(name)  # the model, or the missing file's one-line refusal
    return _with_presets_beside(mechanism_declaration(Path(key)), Path(key).parent)


def _with_presets_beside(model, folder: Path | None):
    """``model`` (a Model or a Declaration) with the ``presets/`` folder of ``folder``
    (where its file or module is) among its preset folders, when there is one."""
    presets = folder / "presets" if folder is not None else None
    if presets is not None and presets.is_dir() and presets not in model.preset_dirs:
        model = replace(model, preset_dirs=model.preset_dirs + (presets,))
    return model


def _registered(name: str):
    """A model from the ``evo_door.models`` entry points, else the bundled registry."""
    eps = [ep for ep in importlib.metadata.entry_points(group=MODEL_GROUP) if ep.name == name]
    values = sorted({ep.value for ep in eps})
    if len(values) > 1:
        raise UserError(
            f"model {name!r} is registered twice ({' and '.join(values)}); "
            "uninstall one of the packages"
        )
    if values:
        return _from_module(values[0], name)
    if name in REGISTRY:
        module = REGISTRY[name].split(":")[0]
        try:
            return _from_module(REGISTRY[name], name)
        except UserError:
            if importlib.util.find_spec(module) is None:
                raise UserError(f"model {name!r} is not available in this version") from None
            raise
    known = sorted(
        set(REGISTRY) | {ep.name for ep in importlib.metadata.entry_points(group=MODEL_GROUP)}
    )
    raise UserError(
        f"unknown model {name!r}"
        + suggest(name, known)
        + f"; models: {', '.join(available_models())}, or a model in a file, "
        "path/to/file.py:ATTRIBUTE"
    )


def _from_module(target: str, name: str):
    """``package.module:ATTRIBUTE`` -> (object, folder of the module's file)."""
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name.strip())
    except Exception as exc:
        if isinstance(exc, ModuleNotFoundError) and exc.name == module_name.strip():
            raise UserError(
                f"cannot import model {name!r}: no module named {module_name.strip()!r}"
            ) from None
        raise UserError(f"cannot import model {name!r}: {_one_line(exc)}") from None
    obj = _attribute(module, attr.strip(), f"module {module_name.strip()!r}", name)
    file = getattr(module, "__file__", None)
    return obj, (Path(file).parent if file else None)


def _from_file(name: str, path: Path, attr: str):
    """``path/to/file.py:ATTRIBUTE`` -> (object, the file's folder)."""
    shown = name.rpartition(":")[0]
    if not path.is_file():
        hint = ""
        if path.parent.is_dir():
            hint = suggest(path.name, [p.name for p in path.parent.glob("*.py")])
        raise UserError(f"model file {shown} not found{hint}")
    module = _FILE_MODULES.get(path)
    if module is None:
        module = _exec_file(path, shown)
        _FILE_MODULES[path] = module
    return _attribute(module, attr, f"model file {shown}", name), path.parent


#: The model file last run for each file name (its stem): where a module name that numba's
#: cache beside the file recorded is found again (:class:`_CacheNames`).
_BY_STEM: dict[str, object] = {}
_USER_MODULE = re.compile(r"evo_door_user_(\w+)_[0-9a-f]{10}")


class _CacheNames(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds a model file's module under a name its numba cache recorded.

    numba's cache beside a model file refers to the module its functions were compiled
    in by name, and reads that reference before it checks that the cache is fresh. The
    name depends on where the file was when compiled: a folder copied or moved with its
    ``__pycache__``, or a cache written by another evo-door, names a module this process
    never made, and the import failed. The name is the file's: it is found again as the
    module last run from a file of that name (a stale cache is then found stale and
    compiled afresh; a fresh one is this file's own code, by numba's checks).
    """

    def find_spec(self, name, path=None, target=None):
        found = _USER_MODULE.fullmatch(name)
        if found is None or found.group(1) not in _BY_STEM:
            return None
        return importlib.util.spec_from_loader(name, self)

    def create_module(self, spec):
        return _BY_STEM[_USER_MODULE.fullmatch(spec.name).group(1)]

    def exec_module(self, module):
        """The module has run already."""


def _install_aliases() -> None:
    if not any(isinstance(f, _CacheNames) for f in sys.meta_path):
        sys.meta_path.append(_CacheNames())


def _exec_file(path: Path, shown: str):
    # A unique module name per file: two drawer.py in two folders do not collide,
    # and the module is in sys.modules while it runs (dataclasses, pickling need it).
    digest = hashlib.sha1(str(path).encode()).hexdigest()[:10]
    stem = re.sub(r"[^0-9A-Za-z_]", "_", path.stem)
    module_name = f"evo_door_user_{stem}_{digest}"
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise UserError(f"model file {shown}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    _install_aliases()
    _BY_STEM[stem] = module
    # like `python file.py`, the file may import modules that sit beside it
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(module)
    except Exception as exc:
        del sys.modules[module_name]
        raise UserError(
            f"model file {shown} does not import: {_one_line(exc)}{_line_in(exc, path)}"
        ) from None
    finally:
        sys.path.remove(str(path.parent))
    return module


def _attribute(module, attr: str, where: str, name: str):
    if not attr:
        raise UserError(f"{name!r}: say which object is the model, e.g. {name}MODEL")
    try:
        return getattr(module, attr)
    except AttributeError:
        models = [k for k, v in vars(module).items() if isinstance(v, Model)]
        listed = f"; models there: {', '.join(models)}" if models else "; it defines no Model"
        public = [k for k in vars(module) if not k.startswith("_")]
        raise UserError(
            f"{where} has no attribute {attr!r}" + suggest(attr, models or public) + listed
        ) from None


_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _one_line(exc: BaseException) -> str:
    text = " ".join(_ANSI.sub("", str(exc)).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _line_in(exc: BaseException, path: Path) -> str:
    """`` (line N)`` of the deepest frame of the user's file in the traceback."""
    if isinstance(exc, SyntaxError):
        return ""  # its message already names the line
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if Path(f.filename) == path]
    return f" (line {frames[-1].lineno})" if frames else ""
