"""Parameter sets: named values for one model, checked against its declaration.

On disk a set is YAML::

    model: haptic
    description: the seed's rendering trial (section 4.5)
    values:
      inertia: 1.2        # kg m
      friction_closing: 1.5

Names missing from ``values`` take their declared default. Presets ship in
``evo_door/params/presets/<model>/<name>.yaml``; everywhere a parameter file is
accepted, a preset name (``seed_trial``) is accepted too.
"""

from __future__ import annotations

from dataclasses import dataclass
import json
from pathlib import Path
from typing import Mapping

import numpy as np
import yaml

from evo_door.errors import ParameterError, UserError
from evo_door.params.declaration import ParamTable, suggest
from evo_door.yaml_numbers import format_float, load as load_yaml

PRESET_DIR = Path(__file__).parent / "presets"


@dataclass(frozen=True)
class ParamSet:
    """A checked, complete set of values for one model's declaration."""

    table: ParamTable
    vector: np.ndarray
    description: str = ""
    source: str = ""

    def __post_init__(self):
        vec = np.array(self.vector, dtype=np.float64)
        vec.setflags(write=False)
        object.__setattr__(self, "vector", vec)

    @classmethod
    def from_mapping(cls, table: ParamTable, values: Mapping[str, float] | None = None,
                     description: str = "", source: str = "") -> "ParamSet":
        return cls(table, table.vector(values, source), description, source)

    @property
    def model(self) -> str:
        return self.table.model

    def __getitem__(self, name: str) -> float:
        return float(self.vector[self.table.index(name)])

    def as_dict(self) -> dict[str, float]:
        return self.table.as_dict(self.vector)

    def replace(self, values: Mapping[str, float], source: str = "") -> "ParamSet":
        """A copy with some values changed (checked)."""
        merged = self.as_dict()
        for name in values:
            self.table.index(name)  # unknown names raise with a suggestion
        merged.update(values)
        return ParamSet.from_mapping(self.table, merged, self.description, source or self.source)

    def to_yaml(self, path: str | Path | None = None) -> str:
        """YAML text of the set (units as comments); written to ``path`` when given."""
        lines = [f"model: {self.model}"]
        if self.description:
            lines.append(f"description: {json.dumps(self.description)}")
        lines.append("values:")
        width = max(len(n) for n in self.table.names)
        for p, v in zip(self.table, self.vector):
            lines.append(f"  {p.name + ':':<{width + 1}} {format_float(v):<22} # {p.unit}")
        text = "\n".join(lines) + "\n"
        if path is not None:
            Path(path).write_text(text)
        return text


def available_presets(model: str) -> list[str]:
    folder = PRESET_DIR / model
    return sorted(p.stem for p in folder.glob("*.yaml")) if folder.is_dir() else []


def preset_path(model: str, name: str) -> Path:
    path = PRESET_DIR / model / f"{name}.yaml"
    if not path.is_file():
        names = available_presets(model)
        raise UserError(
            f"no parameter file or preset {name!r} for model {model!r}"
            + suggest(name, names)
            + (f"; presets: {', '.join(names)}" if names else "")
        )
    return path


def load_params(table: ParamTable, spec: str | Path | None) -> ParamSet:
    """Load a parameter set from a YAML path or a preset name; ``None`` gives defaults."""
    if spec is None:
        return ParamSet.from_mapping(table, {}, "declared defaults", "defaults")
    path = Path(spec)
    if not path.is_file():
        if path.suffix or "/" in str(spec):
            raise UserError(f"{spec}: parameter file not found")
        path = preset_path(table.model, str(spec))
    try:
        doc = load_yaml(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" line {mark.line + 1}" if mark else ""
        raise UserError(f"{path}:{line} is not valid YAML ({getattr(exc, 'problem', exc)})") from None
    return params_from_document(table, doc, str(path))


def params_from_document(table: ParamTable, doc, source: str) -> ParamSet:
    """Check a parsed YAML document (``model``, ``description``, ``values``)."""
    if not isinstance(doc, dict):
        raise UserError(f"{source}: a parameter file is a mapping with 'model' and 'values'")
    unknown = set(doc) - {"model", "description", "values"}
    if unknown:
        key = sorted(unknown)[0]
        raise UserError(f"{source}: unknown key {key!r}" + suggest(key, ["model", "description", "values"]))
    model = doc.get("model", table.model)
    if model != table.model:
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
