"""Parameter sets: named values for one model, checked against its declaration.

On disk a set is YAML::

    model: haptic
    description: the seed's rendering trial (section 4.5)
    values:
      inertia: 1.2        # kg m
      friction_closing: 1.5

Names missing from ``values`` take their declared default. Everywhere a parameter
file is accepted, a preset name (``seed_trial``) is accepted too; a preset
``<name>.yaml`` of model ``<model>`` is looked for, first match wins, in

1. the model's own preset folders (``Model.preset_dirs``: a ``presets/`` folder next
   to the file that defines the model), as ``<name>.yaml`` or ``<model>/<name>.yaml``;
2. the bundled ``evo_door/params/presets/<model>/``;
3. the folders other installed packages register in the entry-point group
   ``evo_door.presets`` (value: a package or module whose folder holds
   ``<model>/<name>.yaml``), as PyBaMM's ``pybamm_parameter_sets`` does.

An HDF5 file of a format an upper layer owns (a render log is the renderer's) is read
as a set by a reader that layer registers (:func:`register_file_reader`): this layer
knows none of those formats and imports no upper layer (``docs/architecture.md``).
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import importlib.util
import json
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import yaml

if TYPE_CHECKING:  # numpy is imported where a vector is built, not on import
    import numpy as np

from evo_door.errors import ParameterError, UserError
from evo_door.files import read_text, write_text
from evo_door.params.declaration import ParamTable, suggest
from evo_door.yaml_numbers import format_float
from evo_door.yaml_numbers import load as load_yaml

PRESET_DIR = Path(__file__).parent / "presets"
#: Entry-point group through which other packages add preset folders.
PRESET_GROUP = "evo_door.presets"

#: Readers of HDF5 parameter files in another layer's format, tried in order:
#: ``reader(table, path)`` gives the file's :class:`ParamSet`, or None when the file is
#: not of its format. Filled by :mod:`evo_door.plugins` (a render log).
FILE_READERS: list[Callable[[ParamTable, Path], ParamSet | None]] = []


def register_file_reader(reader: Callable[[ParamTable, Path], ParamSet | None]) -> None:
    """Have :func:`load_params` read the HDF5 files ``reader`` knows (once per reader)."""
    if reader not in FILE_READERS:
        FILE_READERS.append(reader)


@dataclass(frozen=True)
class ParamSet:
    """A checked, complete set of values for one model's declaration."""

    table: ParamTable
    vector: np.ndarray
    description: str = ""
    source: str = ""

    def __post_init__(self):
        import numpy as np  # here: the declaration alone (evo-door params) needs no numpy

        vec = np.array(self.vector, dtype=np.float64)
        vec.setflags(write=False)
        object.__setattr__(self, "vector", vec)

    @classmethod
    def from_mapping(
        cls,
        table: ParamTable,
        values: Mapping[str, float] | None = None,
        description: str = "",
        source: str = "",
    ) -> ParamSet:
        return cls(table, table.vector(values, source), description, source)

    @property
    def model(self) -> str:
        return self.table.model

    def __getitem__(self, name: str) -> float:
        return float(self.vector[self.table.index(name)])

    def as_dict(self) -> dict[str, float]:
        return self.table.as_dict(self.vector)

    def replace(self, values: Mapping[str, float], source: str = "") -> ParamSet:
        """A copy with some values changed (checked)."""
        merged = self.as_dict()
        for name in values:
            self.table.index(name)  # unknown names raise with a suggestion
        merged.update(values)
        return ParamSet.from_mapping(self.table, merged, self.description, source or self.source)

    def to_yaml(self, path: str | Path | None = None, notes: dict | None = None) -> str:
        """YAML text of the set (units as comments, each followed by ``notes[name]``
        where given); written to ``path`` when given."""
        notes = notes or {}
        lines = [f"model: {self.model}"]
        if self.description:
            lines.append(f"description: {json.dumps(self.description)}")
        lines.append("values:")
        width = max(len(n) for n in self.table.names)
        for p, v in zip(self.table, self.vector):
            note = f"; {notes[p.name]}" if p.name in notes else ""
            lines.append(f"  {p.name + ':':<{width + 1}} {format_float(v):<22} # {p.unit}{note}")
        text = "\n".join(lines) + "\n"
        if path is not None:
            write_text(path, text)
        return text


def param_vector(params, table: ParamTable | None = None) -> np.ndarray:
    """The kernel vector of a ParamSet (or array): a writable C-contiguous float64 copy.

    ParamSet vectors are read-only, and numba types a read-only array differently
    from a writable one (a second compilation), hence the copy. With ``table`` the
    length is checked against that declaration.
    """
    import numpy as np

    p = np.array(getattr(params, "vector", params), dtype=np.float64, order="C")
    if table is not None and p.shape != (len(table),):
        raise UserError(f"model {table.model!r} takes {len(table)} parameters, got shape {p.shape}")
    return p


def _plugin_preset_roots() -> list[Path]:
    """Folders registered in the ``evo_door.presets`` entry-point group.

    A broken registration (a package that is gone) is skipped with a warning: it must
    not stop the bundled presets from loading.
    """
    roots: list[Path] = []
    for ep in importlib.metadata.entry_points(group=PRESET_GROUP):
        module = ep.value.partition(":")[0].strip()
        try:
            spec = importlib.util.find_spec(module)  # imports the parent packages
        except Exception as exc:
            spec, why = None, f"{type(exc).__name__}: {exc}"
        else:
            why = "no such module"
        if spec is None:
            warnings.warn(
                f"{PRESET_GROUP} entry point {ep.name!r} ({ep.value}): {why}; skipped", stacklevel=3
            )
        elif spec.submodule_search_locations:  # a package: its folder(s)
            roots.extend(Path(p) for p in spec.submodule_search_locations)
        elif spec.origin:  # a module: the folder it sits in
            roots.append(Path(spec.origin).parent)
    return roots


def preset_folders(model: str, preset_dirs: Iterable[str | Path] = ()) -> list[tuple[Path, bool]]:
    """Where presets of ``model`` are looked for, in order (see the module docstring).

    Returns ``(folder, flat)`` pairs; ``flat`` marks a model's own ``presets/`` folder
    read directly, whose files may belong to another model of the same file (their
    ``model:`` key tells).
    """
    folders: list[tuple[Path, bool]] = []
    for d in preset_dirs:
        folders += [(Path(d) / model, False), (Path(d), True)]
    folders.append((PRESET_DIR / model, False))
    folders += [(root / model, False) for root in _plugin_preset_roots()]
    return [(f, flat) for f, flat in folders if f.is_dir()]


def _preset_files(model: str, preset_dirs: Iterable[str | Path] = ()) -> dict[str, Path]:
    """Preset name -> file, the first folder of :func:`preset_folders` winning."""
    found: dict[str, Path] = {}
    for folder, flat in preset_folders(model, preset_dirs):
        for path in sorted(folder.glob("*.yaml")):
            if path.stem not in found and not (flat and _for_other_model(path, model)):
                found[path.stem] = path
    return found


def _for_other_model(path: Path, model: str) -> bool:
    """True when a YAML file says ``model: <another one>`` (unreadable files: False,
    so that loading them reports what is wrong)."""
    try:
        doc = load_yaml(read_text(path))
    except (UserError, yaml.YAMLError):
        return False
    return isinstance(doc, dict) and doc.get("model", model) != model


def available_presets(model: str, preset_dirs: Iterable[str | Path] = ()) -> list[str]:
    """Names of the presets of ``model`` (with a model's own ``preset_dirs``)."""
    return sorted(_preset_files(model, preset_dirs))


def preset_path(model: str, name: str, preset_dirs: Iterable[str | Path] = ()) -> Path:
    """The file of preset ``name`` of ``model``; a UserError with the closest names."""
    found = _preset_files(model, preset_dirs)
    if name not in found:
        raise UserError(
            f"no parameter file or preset {name!r} for model {model!r}"
            + suggest(name, found)
            + (f"; presets: {', '.join(sorted(found))}" if found else "")
        )
    return found[name]


def load_params(
    table: ParamTable,
    spec=None,
    overrides: Mapping[str, float] | None = None,
    preset_dirs: Iterable[str | Path] = (),
) -> ParamSet:
    """The one parameter-set loader: defaults, a preset, a YAML file or a mapping.

    Parameters
    ----------
    table : ParamTable
        The declaration everything is checked against.
    spec : None, str, Path or mapping
        ``None``: the declared defaults; a YAML path; a preset name (looked up as the
        module docstring says); a mapping name -> value, on top of the defaults.
    overrides : mapping, optional
        Values applied on top of ``spec`` (``--set``, an experiment's ``set:``).
    preset_dirs : iterable of paths
        The model's own preset folders (``Model.preset_dirs``).

    Examples
    --------
    >>> from evo_door.models import get_model
    >>> table = get_model("haptic").params
    >>> ps = load_params(table, "seed_trial", {"open_force": 15.0})
    >>> ps["open_force"], ps["inertia"], ps.source.endswith("seed_trial.yaml")
    (15.0, 1.2, True)
    >>> load_params(table, {"inertia": 0.01})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    evo_door.errors.ParameterError: inline values: parameter 'inertia' = 0.01 kg m is outside ...
    """
    if spec is None:
        ps = ParamSet.from_mapping(table, {}, "declared defaults", "defaults")
    elif isinstance(spec, Mapping):
        ps = ParamSet.from_mapping(table, spec, "inline values", "inline values")
    else:
        ps = _load_file(table, spec, preset_dirs)
    if not overrides:
        return ps
    # a bad override names the set as the user gave it (a preset by its name), never the
    # file's path in the installation; the set keeps its source (an input of the command)
    shown = str(spec) if isinstance(spec, (str, Path)) else ps.source
    return dataclasses.replace(ps.replace(overrides, source=shown), source=ps.source)


def _load_file(table: ParamTable, spec, preset_dirs) -> ParamSet:
    path = Path(spec)
    if path.suffix.lower() in (".h5", ".hdf5") and path.is_file():
        for reader in FILE_READERS:  # another layer's format (a render log)?
            ps = reader(table, path)
            if ps is not None:
                return ps
    shown = str(spec)  # what errors name: the file as given, a preset by its name
    if not path.is_file():
        if path.suffix or "/" in str(spec):
            raise UserError(f"{spec}: parameter file not found")
        path = _preset_of_family(table, str(spec), preset_dirs)
        shown = f"preset {spec}"
    try:
        doc = load_yaml(read_text(path, "parameter file"))
    except UserError as exc:  # unreadable, binary...: named as given
        raise UserError(str(exc).replace(str(path), shown)) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" line {mark.line + 1}" if mark else ""
        raise UserError(
            f"{shown}:{line} is not valid YAML ({getattr(exc, 'problem', exc)})"
        ) from None
    ps = params_from_document(table, doc, shown)
    return dataclasses.replace(ps, source=str(path))


def _preset_of_family(table: ParamTable, name: str, preset_dirs) -> Path:
    """The preset ``name`` of ``table``'s model, else of a model it reads."""
    for model in table.reads[1:]:
        if name in available_presets(model, preset_dirs) and not _preset_files(
            table.model, preset_dirs
        ).get(name):
            return preset_path(model, name, preset_dirs)
    return preset_path(table.model, name, preset_dirs)


def params_from_document(table: ParamTable, doc, source: str) -> ParamSet:
    """Check a parsed YAML document (``model``, ``description``, ``values``)."""
    if not isinstance(doc, dict):
        raise UserError(f"{source}: a parameter file is a mapping with 'model' and 'values'")
    unknown = set(doc) - {"model", "description", "values"}
    if unknown:
        key = sorted(unknown, key=str)[0]
        raise UserError(
            f"{source}: unknown key {key!r}" + suggest(key, ["model", "description", "values"])
        )
    model = doc.get("model", table.model)
    if model not in table.reads:
        raise UserError(f"{source}: parameters are for model {model!r}, not {table.model!r}")
    values = doc.get("values") or {}
    if not isinstance(values, dict):
        raise UserError(f"{source}: 'values' must map parameter names to numbers")
    return ParamSet.from_mapping(table, values, str(doc.get("description", "")), source)


def parse_assignments(items: list[str] | None, source: str = "--set") -> dict[str, float]:
    """``["name=value", ...]`` from the command line to a dict of floats."""
    out: dict[str, float] = {}
    for item in items or []:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise UserError(f"{source} {item!r}: expected NAME=VALUE")
        try:
            out[name.strip()] = float(text)
        except ValueError:
            raise ParameterError(f"{source} {item!r}: {text!r} is not a number") from None
    return out
