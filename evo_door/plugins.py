"""What the upper layers add to the lower layers' registries.

A lower layer never imports an upper one (``docs/architecture.md``): where it reads
something an upper layer owns, it keeps a registry and the upper layer fills it. This
module fills them. It sits above the renderer and below the experiments and the
command line, which import it, so that every way in (a command; an experiment, run in
this process or by an executor's worker) reads the same files. A library user who
works with the lower layers alone imports it once.

- :func:`evo_door.params.sets.register_file_reader`: a render log (the web console's
  session record) is a parameter set: the participant's chosen set, else the last set in
  force (:func:`render_log_params`).
"""

from __future__ import annotations

from pathlib import Path

from evo_door.errors import UserError
from evo_door.params.sets import ParamSet, register_file_reader


def render_log_params(table, path: Path) -> ParamSet | None:
    """A render log as a parameter set of ``table`` (the haptic model's), or None when
    ``path`` is not a render log."""
    # imported here: the renderer is heavy, and most parameter files are YAML
    from evo_door.render.session import is_render_log, session_params

    if not is_render_log(path):
        return None
    values, what = session_params(path)
    unknown = [name for name in values if name not in table.names]
    if unknown or set(values) != set(table.names):
        raise UserError(f"{path}: a render log holds a haptic set, not one of {table.model!r}")
    return ParamSet.from_mapping(table, values, what, str(path))


register_file_reader(render_log_params)
