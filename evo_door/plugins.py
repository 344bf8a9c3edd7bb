"""What the upper layers add to the lower layers' registries.

A lower layer never imports an upper one (``docs/architecture.md``): where it reads
something an upper layer owns, it keeps a registry and the upper layer fills it. This
module fills them. It sits above the renderer and below the experiments and the
command line, which import it, so that every way in (a command; an experiment, run in
this process or by an executor's worker) reads the same files. A library user who
works with the lower layers alone imports it once.

- :func:`evo_door.params.sets.register_file_reader`: a render log (the web console's
  session record) is a parameter set: the participant's chosen set, else the last set in
  force (:func:`render_log_params`); a results file whose specification could not reach
  its yield is one too: the nearest feel the supplier's process can hold
  (:func:`nearest_feel_params`), for ``render`` and ``push`` to put before a
  participant.
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


def nearest_feel_params(table, path: Path) -> ParamSet | None:
    """The nearest feel a results file stores (``tolerance/nearest_feel`` of a run, or
    of a pipeline's stage: the last stage that has one) as a set of ``table``'s model,
    or None when ``path`` is not a results file. Read as data: names and numbers, no
    model is loaded from the file."""
    import numpy as np

    from evo_door.files import open_h5
    from evo_door.files.metadata import read_attrs

    try:
        with open_h5(path) as f:
            groups = [f] if "tolerance" in f else []
            if "stages" in f:
                groups = [f["stages"][k] for k in f["stages"]]
            found = [
                (g.name, g["tolerance/nearest_feel"])
                for g in groups
                if "tolerance/nearest_feel" in g
            ]
            if not found:
                if "stages" in f or "tolerance" in f or "setup" in f:
                    raise UserError(
                        f"{path}: a results file, not a parameter file (it holds no nearest "
                        "feel: its specification reaches its yield, or it fits no chosen feel)"
                    )
                return None
            where, node = found[-1]
            attrs = read_attrs(node)
            model = str(attrs["model"])
            names = [str(n) for n in attrs["names"]]
            values = np.asarray(node["values"], dtype=np.float64)
    except OSError:
        return None
    except (KeyError, ValueError, TypeError):
        raise UserError(f"{path}: its nearest feel is damaged") from None
    if model != table.model:
        raise UserError(f"{path}: its nearest feel is a set of {model!r}, not of {table.model!r}")
    if len(names) != values.size:
        raise UserError(
            f"{path}: its nearest feel is damaged ({len(names)} names, {values.size} values)"
        )
    stage = where.rsplit("/", 1)[-1] if where.startswith("/stages/") else "the run"
    return ParamSet.from_mapping(
        table,
        dict(zip(names, map(float, values))),
        f"the nearest feel the process can hold ({stage})",
        str(path),
    )


register_file_reader(render_log_params)
register_file_reader(nearest_feel_params)
