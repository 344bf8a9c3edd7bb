"""Parameter declarations (:mod:`.declaration`) and value sets (:mod:`.sets`)."""

from evo_door.params.declaration import GROUPS, Param, ParamTable
from evo_door.params.sets import (
    ParamSet,
    available_presets,
    load_params,
    param_vector,
    params_from_document,
    parse_assignments,
    preset_path,
    register_file_reader,
)

__all__ = [
    "GROUPS",
    "Param",
    "ParamTable",
    "ParamSet",
    "available_presets",
    "load_params",
    "param_vector",
    "params_from_document",
    "parse_assignments",
    "preset_path",
    "register_file_reader",
]
