"""Trials in HDF5: many trials in one file, one group each (layout in ``docs/data-format.md``).

::

    /                         format = "evo-door trials", format_version = 1
    /trials/<trial_id>/       trial_id, user_id, kind, sample_rate (Hz), n_samples,
                              [theta0 (rad), dtheta0 (rad/s)], source, sensors (JSON), meta (JSON)
        t        float64[n]   unit = "s"
        force    float64[n]   unit = "N"
        theta    float64[n]   unit = "rad"        (optional)
        dtheta   float64[n]   unit = "rad/s"      (optional)
        ddtheta  float64[n]   unit = "rad/s^2"    (optional)
        truth/                model, ...          (generated trials)
            params/           one attribute per parameter, SI
            units/            one attribute per parameter: its unit

Datasets may carry another ``unit`` (``deg``, ``kN``...): the reader converts to SI.
Groups keep their insertion order. HDF5 files of another layout are read as tables:
each group holding 1-D datasets is a trial, its datasets are columns mapped like CSV
columns.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evo_door import __version__
from evo_door.data._util import atomic_path, dumps, jsonable
from evo_door.data.columns import Column, trial_from_columns
from evo_door.data.trial import RESPONSE_CHANNELS, UNITS, Trial
from evo_door.errors import UserError

FORMAT = "evo-door trials"
FORMAT_VERSION = 1
_COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}


def _h5py():
    import h5py

    return h5py


def _open(path: Path):
    h5py = _h5py()
    if not path.is_file():
        raise UserError(f"{path}: file not found")
    if path.stat().st_size == 0:
        raise UserError(f"{path}: empty file")
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise UserError(f"{path}: not a readable HDF5 file ({exc})") from None


def _text(value) -> str:
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray) and value.shape == ():
        return _text(value.item())
    return str(value)


def _scalar(value):
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


# -- dict <-> group of attributes -----------------------------------------------------
def _dict_to_group(group, data: dict) -> None:
    for key, value in data.items():
        if isinstance(value, dict):
            _dict_to_group(group.create_group(str(key), track_order=True), value)
        elif value is None:
            group.attrs[str(key)] = "null"
            group.attrs.create(f"{key}.__json__", 1)
        elif isinstance(value, (str, bool, int, float, np.generic)):
            group.attrs[str(key)] = value
        else:
            group.attrs[str(key)] = dumps(value)
            group.attrs.create(f"{key}.__json__", 1)


def _group_to_dict(group) -> dict:
    out: dict = {}
    for key, value in group.attrs.items():
        if key.endswith(".__json__"):
            continue
        if f"{key}.__json__" in group.attrs:
            out[key] = json.loads(_text(value))
        else:
            out[key] = _scalar(value)
    for key, sub in group.items():
        if hasattr(sub, "attrs") and not hasattr(sub, "shape"):
            out[key] = _group_to_dict(sub)
    return out


# -- reading --------------------------------------------------------------------------
def list_trials(path) -> list[str]:
    """Trial ids in an evo-door HDF5 file, in file order."""
    path = Path(path)
    with _open(path) as f:
        if "trials" not in f:
            return [name for name, _ in _table_groups(f)]
        return list(f["trials"].keys())


def read_h5(path, trials="all", mapping=None, rate=None, fields=None) -> list[Trial]:
    """Read trials from an HDF5 file (evo-door layout, or any file of 1-D datasets)."""
    path = Path(path)
    with _open(path) as f:
        if "trials" in f or _text(f.attrs.get("format", "")) == FORMAT:
            return _read_layout(path, f, trials, mapping, rate, fields)
        return _read_tables(path, f, trials, mapping, rate, fields)


def _select(path, available: list[str], trials) -> list[str]:
    from evo_door.params.declaration import suggest

    if trials in (None, "all"):
        return available
    wanted = [trials] if isinstance(trials, (str, int)) else list(trials)
    out = []
    for w in wanted:
        if isinstance(w, int) and not isinstance(w, bool):
            if not -len(available) <= w < len(available):
                raise UserError(f"{path}: no trial number {w}; the file holds {len(available)}")
            out.append(available[w])
        elif w in available:
            out.append(w)
        else:
            raise UserError(f"{path}: no trial {w!r}" + suggest(str(w), available)
                            + f"; trials: {', '.join(available) or 'none'}")
    return out


def _read_layout(path, f, trials, mapping, rate, fields) -> list[Trial]:
    version = int(f.attrs.get("format_version", FORMAT_VERSION))
    if version > FORMAT_VERSION:
        raise UserError(f"{path}: trial format version {version} is newer than this "
                        f"evo-door reads ({FORMAT_VERSION}); upgrade evo-door")
    if "trials" not in f:
        raise UserError(f"{path}: no 'trials' group")
    root = f["trials"]
    out = []
    for name in _select(path, list(root.keys()), trials):
        g = root[name]
        where = f"{path}:/trials/{name}"
        if not hasattr(g, "keys"):
            raise UserError(f"{where}: is a dataset, expected a trial group")
        columns = {}
        for key, ds in g.items():
            if hasattr(ds, "shape"):
                unit = ds.attrs.get("unit")
                columns[key] = Column(key, np.asarray(ds[()], dtype=np.float64),
                                      _text(unit) if unit is not None else None)
        attrs = g.attrs
        meta_fields = {
            "trial_id": _text(attrs.get("trial_id", name)),
            "user_id": _text(attrs.get("user_id", "")),
            "kind": _text(attrs.get("kind", "")),
            "theta0": float(attrs["theta0"]) if "theta0" in attrs else None,
            "dtheta0": float(attrs["dtheta0"]) if "dtheta0" in attrs else None,
            "sensors": json.loads(_text(attrs["sensors"])) if "sensors" in attrs else {},
            "meta": json.loads(_text(attrs["meta"])) if "meta" in attrs else {},
            "truth": _group_to_dict(g["truth"]) if "truth" in g else None,
            "source": where,
        }
        meta_fields.update({k: v for k, v in (fields or {}).items() if v is not None})
        # the file's own channels only: no foreign-column guessing, no import record
        own = {k: c for k, c in columns.items() if k in UNITS}
        out.append(trial_from_columns(own, where, mapping, rate, meta_fields,
                                      record_import=False))
    return out


def _table_groups(f):
    """(name, group) of every group holding 1-D datasets, root first."""
    found = []

    def visit(name, obj):
        if hasattr(obj, "keys") and any(hasattr(v, "shape") and len(v.shape) == 1 for v in obj.values()):
            found.append((name, obj))

    if any(hasattr(v, "shape") and len(v.shape) == 1 for v in f.values()):
        found.append(("/", f))
    f.visititems(visit)
    return found


def _read_tables(path, f, trials, mapping, rate, fields) -> list[Trial]:
    groups = dict(_table_groups(f))
    if not groups:
        raise UserError(f"{path}: no trials: neither a 'trials' group nor any group of 1-D datasets")
    out = []
    for name in _select(path, list(groups), trials):
        g = groups[name]
        where = f"{path}:{name if name.startswith('/') else '/' + name}"
        columns = {}
        for key, ds in g.items():
            if hasattr(ds, "shape") and len(ds.shape) == 1:
                unit = ds.attrs.get("unit", ds.attrs.get("units"))
                columns[key] = Column(key, np.asarray(ds[()], dtype=np.float64),
                                      _text(unit) if unit is not None else None)
        tid = Path(path).stem if name == "/" else name.rsplit("/", 1)[-1]
        flds = {"trial_id": tid, **{k: v for k, v in (fields or {}).items() if v is not None}}
        out.append(trial_from_columns(columns, where, mapping, rate, flds))
    return out


# -- writing --------------------------------------------------------------------------
def check_trial_id(trial_id: str, where: str = "") -> None:
    if not trial_id or "/" in trial_id or trial_id in (".", ".."):
        raise UserError(f"{where or 'trial'}: trial id {trial_id!r} cannot name an HDF5 "
                        "group (empty or contains '/')")


def write_h5(path, trials, description: str = "") -> None:
    """Write ``trials`` to ``path`` (replaced), via a temporary file renamed at the end."""
    h5py = _h5py()
    trials = list(trials)
    seen = set()
    for tr in trials:
        check_trial_id(tr.trial_id, tr.label)
        if tr.trial_id in seen:
            raise UserError(f"{path}: two trials named {tr.trial_id!r}")
        seen.add(tr.trial_id)
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w", track_order=True) as f:
            f.attrs["format"] = FORMAT
            f.attrs["format_version"] = FORMAT_VERSION
            f.attrs["software"] = f"evo-door {__version__}"
            if description:
                f.attrs["description"] = description
            root = f.create_group("trials", track_order=True)
            for tr in trials:
                _write_trial(root, tr)


def _write_trial(root, tr: Trial) -> None:
    g = root.create_group(tr.trial_id, track_order=True)
    g.attrs["trial_id"] = tr.trial_id
    g.attrs["user_id"] = tr.user_id
    g.attrs["kind"] = tr.kind
    g.attrs["sample_rate"] = tr.rate
    g.attrs["n_samples"] = tr.n
    if tr.theta0 is not None:
        g.attrs["theta0"] = float(tr.theta0)
    if tr.dtheta0 is not None:
        g.attrs["dtheta0"] = float(tr.dtheta0)
    g.attrs["source"] = tr.source
    g.attrs["sensors"] = dumps(tr.sensors)
    g.attrs["meta"] = dumps(tr.meta)
    for name in ("t", "force", *RESPONSE_CHANNELS):
        values = getattr(tr, name)
        if values is None:
            continue
        ds = g.create_dataset(name, data=values, track_times=False, **_COMPRESSION)
        ds.attrs["unit"] = UNITS[name]
        info = tr.sensor(name)
        if info:
            ds.attrs["sensor"] = dumps(info)
    if tr.truth:
        _dict_to_group(g.create_group("truth", track_order=True), jsonable(tr.truth))
