"""What the rig simulates (the model, or the door's richer truth) and what a trial records
of it: the true parameters, where they came from, the sensors' dynamics of a rich truth.
"""

from __future__ import annotations

from dataclasses import fields, replace
from pathlib import Path

from evo_door.data.sensors import FilteredSensor, Sensor
from evo_door.errors import UserError

#: What the rig simulates: the model itself, or the door's richer truth.
TRUTHS = ("model", "rich")


def params_source(model, params) -> str:
    """Where a parameter set came from, and what was set on top, as trial files record it.

    A preset by its name (``"default"``), not by the path of its file on this machine:
    the same command then writes the same file anywhere; the declared defaults as
    ``"defaults"``; a file of the user's by the path given. Values set on top (``--set``,
    a specification's ``set``) follow: ``"defaults, changed: M=1.5"``.
    """
    source = getattr(params, "source", "") or ""
    label, base = _named_source(model, source)
    if base is None:
        return label
    changed = [
        f"{name}={params[name]:g}"
        for name, value in base.as_dict().items()
        if params[name] != value
    ]
    return label + (f", changed: {', '.join(changed)}" if changed else "")


def _named_source(model, source: str):
    """(the name a trial file records for ``source``, the set it names or None)."""
    from evo_door.params.sets import preset_path

    if source == "defaults":
        return source, model.load_params(None)
    path = Path(source)
    if path.suffix not in (".yaml", ".yml") or not path.is_file():
        return source, None
    try:
        preset = preset_path(model.name, path.stem, model.preset_dirs)
    except UserError:
        preset = None
    name = path.stem if preset is not None and preset.resolve() == path.resolve() else source
    try:
        return name, model.load_params(str(path))
    except UserError:  # the file changed under us: its name alone
        return name, None


def truth_record(model, params, method, substeps, truth=None) -> dict:
    values = params.as_dict() if hasattr(params, "as_dict") else model.params.as_dict(params)
    out = {
        "model": model.name,
        "params": values,
        "units": {p.name: p.unit for p in model.params},
        "params_source": params_source(model, params),
        "method": method or model.method,
        "substeps": int(substeps or model.substeps),
    }
    if truth is not None:
        out.update(
            method=truth.method, substeps=truth.substeps, variant=truth.name, effects=truth.record()
        )
    return out


def with_dynamics(sensors: dict[str, Sensor], dynamics: dict) -> dict[str, Sensor]:
    """``sensors`` with the channels of ``dynamics`` (channel -> (bandwidth Hz, order))
    made :class:`~evo_door.data.sensors.FilteredSensor` (same range, noise, resolution)."""
    out = dict(sensors)
    for ch, (bandwidth, order) in dynamics.items():
        base = {f.name: getattr(sensors[ch], f.name) for f in fields(Sensor)}
        out[ch] = FilteredSensor(**base, bandwidth=bandwidth, order=order)
    return out


def make_truth(model, params, truth=None, truth_params=None, method=None, substeps=None):
    """The truth the rig simulates: None for the model itself, else a ``DoorTruth``.

    ``truth`` is None, ``"model"``, ``"rich"`` or a ready truth object;
    ``truth_params`` (a mapping name -> value, a YAML path or a ParamSet) sets the rich
    truth's parameters on top of its declared defaults.
    """
    if truth is None or (isinstance(truth, str) and truth == "model"):
        if truth_params:
            raise UserError("truth parameters need the rich truth (--truth rich)")
        return None
    if not isinstance(truth, str):
        return truth
    if truth not in TRUTHS:
        from evo_door.params.declaration import suggest

        raise UserError(
            f"unknown truth {truth!r}" + suggest(truth, TRUTHS) + f"; truths: {', '.join(TRUTHS)}"
        )
    from evo_door.models.door.truth import DoorTruth, load_truth_params
    from evo_door.params import ParamSet

    if isinstance(truth_params, ParamSet):
        values = truth_params
    elif isinstance(truth_params, (str, Path)):
        values = load_truth_params(truth_params)
    else:
        values = load_truth_params(None, dict(truth_params or {}))
        changed = sorted(truth_params or {})
        values = replace(
            values, source="defaults" + (f", changed: {', '.join(changed)}" if changed else "")
        )
    return DoorTruth(model, params, values, method, substeps)
