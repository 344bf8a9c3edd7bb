"""Trials in HDF5: many trials in one file, one group each (layout in ``docs/data-format.md``).

::

    /                         format = "evo-door trials", format_version = 1
    /trials/<trial_id>/       trial_id, user_id, kind, sample_rate (Hz), n_samples,
                              [theta0 (rad), dtheta0 (rad/s)], source, sensors, meta
        t        float64[n]   unit = "s"
        force    float64[n]   unit = "N"
        theta    float64[n]   unit = "rad"        (optional)
        dtheta   float64[n]   unit = "rad/s"      (optional)
        ddtheta  float64[n]   unit = "rad/s^2"    (optional)
        truth/                model, ...          (generated trials)
            params/           one attribute per parameter, SI
            units/            one attribute per parameter: its unit

Attributes are encoded as everywhere in evo-door (:mod:`evo_door.files`: dicts as
``json:`` text); files of evo-door 0.1 (JSON text without the prefix, or flagged by a
``NAME.__json__`` attribute) read as before: the prefix tells the two apart, so the
layout keeps its version number. Datasets may carry another ``unit``
(``deg``, ``kN``...): the reader converts to SI.
Groups keep their insertion order. HDF5 files of another layout are read as tables:
each group holding 1-D datasets is a trial, its datasets are columns mapped like CSV
columns.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evo_door import __version__
from evo_door.data.columns import Column, trial_from_columns
from evo_door.data.trial import RESPONSE_CHANNELS, UNITS, Trial
from evo_door.errors import UserError
from evo_door.files import (
    ATTRS,
    Dataset,
    attrs_tree,
    jsonable,
    open_h5,
    read_attrs,
    read_group,
    tree_attrs,
    write_h5,
)
from evo_door.files import fields as typed

FORMAT = "evo-door trials"
FORMAT_VERSION = 1
#: The root ``format`` of a results file (``evo_door.experiment.store.FORMAT``; not
#: imported from there: data sits below experiment).
RUN_FORMAT = "evo-door run"
#: gzip level of trial datasets: files are written once and kept, so smaller is better
_COMPRESSION = 4


def _text(value) -> str:
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray) and value.shape == ():
        return _text(value.item())
    return str(value)


def _json_field(attrs, key: str) -> dict:
    """A metadata dict: decoded already, or JSON text as format 1 stored it; a mapping,
    or one line naming the attribute."""
    value = attrs.get(key, {})
    where = typed.place_of(attrs, key)
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except RecursionError:
            raise UserError(f"{where}: JSON nested too deeply") from None
        except ValueError:
            raise UserError(
                f"{where}: expected a mapping (JSON), got {typed.show(value)}"
            ) from None
    return typed.as_mapping(value, where)


# -- reading --------------------------------------------------------------------------
def read_h5(path, trials="all", mapping=None, rate=None, fields=None) -> list[Trial]:
    """Read trials from an HDF5 file (evo-door layout, or any file of 1-D datasets)."""
    path = Path(path)
    with open_h5(path, "file") as f:
        # a run's file holds trials too (/trials), but read as trials it would only
        # confuse: say what it is and where its trials are
        if _text(f.attrs.get("format", "")) == RUN_FORMAT:
            raise UserError(
                f"{path}: is an evo-door results file (a run), not trials; "
                f"`evo-door show {path}` shows it, its trials are in /trials"
            )
        try:
            if "trials" in f or _text(f.attrs.get("format", "")) == FORMAT:
                return _read_layout(path, f, trials, mapping, rate, fields)
            return _read_tables(path, f, trials, mapping, rate, fields)
        except OSError as exc:  # a damaged group or attribute, beyond one dataset
            raise UserError(f"{path}: corrupt HDF5 file ({_first_line(exc)})") from None


def _first_line(exc: Exception) -> str:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return text if len(text) <= 80 else text[:77] + "..."


def _values(path, ds) -> np.ndarray:
    """A dataset's numbers, or one line naming the file and the dataset."""
    if ds.dtype.kind not in "biuf":  # text, complex, compound...: not a signal
        raise UserError(f"{path}: dataset {ds.name} is not numeric ({ds.dtype})")
    try:
        return np.asarray(ds[()], dtype=np.float64)
    except OSError as exc:  # h5py: a damaged compressed chunk fails its filter
        raise UserError(f"{path}: corrupt HDF5 data in {ds.name} ({_first_line(exc)})") from None
    except (TypeError, ValueError):
        raise UserError(f"{path}: dataset {ds.name} is not numeric ({ds.dtype})") from None


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
            raise UserError(
                f"{path}: no trial {w!r}"
                + suggest(str(w), available)
                + f"; trials: {', '.join(available) or 'none'}"
            )
    return out


def _read_layout(path, f, trials, mapping, rate, given) -> list[Trial]:
    version = typed.integer(read_attrs(f), "format_version", FORMAT_VERSION)
    if version > FORMAT_VERSION:
        raise UserError(
            f"{path}: trial format version {version} is newer than this "
            f"evo-door reads ({FORMAT_VERSION}); upgrade evo-door"
        )
    if "trials" not in f or not hasattr(f["trials"], "keys"):
        raise UserError(f"{path}: no 'trials' group")
    root = f["trials"]
    if not len(root):
        raise UserError(f"{path}: no trials: its 'trials' group is empty")
    out = []
    for name in _select(path, list(root.keys()), trials):
        g = root[name]
        where = f"{path}:/trials/{name}"
        if not hasattr(g, "keys"):
            raise UserError(f"{where}: is a dataset, expected a trial group")
        columns = {}
        for key, ds in g.items():
            if hasattr(ds, "shape") and key in UNITS:
                if len(ds.shape) != 1:
                    raise UserError(
                        f"{path}: {ds.name}: expected a 1-D array, got shape {ds.shape}"
                    )
                columns[key] = Column(
                    key, _values(path, ds), typed.text(read_attrs(ds), "unit", None)
                )
        attrs = read_attrs(g)
        truth = g["truth"] if "truth" in g else None
        if truth is not None and not hasattr(truth, "keys"):
            raise UserError(f"{path}: {truth.name}: expected a group, got a dataset")
        meta_fields = {
            "trial_id": typed.text(attrs, "trial_id", name),
            "user_id": typed.text(attrs, "user_id", ""),
            "kind": typed.text(attrs, "kind", ""),
            "theta0": typed.number(attrs, "theta0", None),
            "dtheta0": typed.number(attrs, "dtheta0", None),
            "sensors": _json_field(attrs, "sensors"),
            "meta": _json_field(attrs, "meta"),
            "truth": tree_attrs(read_group(truth)) if truth is not None else None,
            "source": where,
        }
        meta_fields.update({k: v for k, v in (given or {}).items() if v is not None})
        # the file's own channels only: no foreign-column guessing, no import record
        own = {k: c for k, c in columns.items() if k in UNITS}
        tr = trial_from_columns(own, where, mapping, rate, meta_fields, record_import=False)
        stored = typed.text(attrs, "data_digest", None)
        as_stored = (
            mapping is None
            and rate is None
            and all(c.unit in (None, UNITS[k]) for k, c in own.items())
        )
        if stored is not None and as_stored and tr.digest() != stored:
            raise UserError(f"{where}: damaged: its signals do not match their checksum")
        out.append(tr)
    return out


def _table_groups(f):
    """(name, group) of every group holding 1-D datasets, root first."""
    found = []

    def visit(name, obj):
        if hasattr(obj, "keys") and any(
            hasattr(v, "shape") and len(v.shape) == 1 for v in obj.values()
        ):
            found.append((name, obj))

    if any(hasattr(v, "shape") and len(v.shape) == 1 for v in f.values()):
        found.append(("/", f))
    f.visititems(visit)
    return found


def _read_tables(path, f, trials, mapping, rate, fields) -> list[Trial]:
    groups = dict(_table_groups(f))
    if not groups:
        raise UserError(
            f"{path}: no trials: neither a 'trials' group nor any group of 1-D datasets"
        )
    out = []
    for name in _select(path, list(groups), trials):
        g = groups[name]
        where = f"{path}:{name if name.startswith('/') else '/' + name}"
        columns = {}
        for key, ds in g.items():
            if hasattr(ds, "shape") and len(ds.shape) == 1:
                unit = ds.attrs.get("unit", ds.attrs.get("units"))
                columns[key] = Column(
                    key, _values(path, ds), _text(unit) if unit is not None else None
                )
        tid = Path(path).stem if name == "/" else name.rsplit("/", 1)[-1]
        flds = {"trial_id": tid, **{k: v for k, v in (fields or {}).items() if v is not None}}
        out.append(trial_from_columns(columns, where, mapping, rate, flds))
    return out


# -- writing --------------------------------------------------------------------------
def check_trial_id(trial_id: str, where: str = "") -> None:
    if not trial_id or "/" in trial_id or trial_id in (".", ".."):
        raise UserError(
            f"{where or 'trial'}: trial id {trial_id!r} cannot name an HDF5 "
            "group (empty or contains '/')"
        )


def write_h5_trials(path, trials, description: str = "") -> None:
    """Write ``trials`` to ``path`` (replaced), atomically (:func:`evo_door.files.write_h5`)."""
    trials = list(trials)
    seen = set()
    for tr in trials:
        check_trial_id(tr.trial_id, tr.label)
        if tr.trial_id in seen:
            raise UserError(f"{path}: two trials named {tr.trial_id!r}")
        seen.add(tr.trial_id)
    root = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "software": f"evo-door {__version__}",
    }
    if description:
        root["description"] = description
    tree = {ATTRS: root, "trials": {tr.trial_id: trial_tree(tr) for tr in trials}}
    write_h5(path, tree, compression=_COMPRESSION, compress_above=1)


def trial_tree(tr: Trial) -> dict:
    """One trial as the tree :func:`evo_door.files.write_h5` writes (attributes and
    channel datasets): a trial file's ``/trials/<id>`` group, also a render log's."""
    attrs = {
        "trial_id": tr.trial_id,
        "user_id": tr.user_id,
        "kind": tr.kind,
        "sample_rate": tr.rate,
        "n_samples": tr.n,
    }
    for key in ("theta0", "dtheta0"):
        if getattr(tr, key) is not None:
            attrs[key] = float(getattr(tr, key))
    attrs.update(source=tr.source, sensors=tr.sensors, meta=tr.meta, data_digest=tr.digest())
    node = {ATTRS: attrs}
    for name in ("t", "force", *RESPONSE_CHANNELS):
        values = getattr(tr, name)
        if values is None:
            continue
        info = tr.sensor(name)
        node[name] = Dataset(values, {"unit": UNITS[name], **({"sensor": info} if info else {})})
    if tr.truth:
        node["truth"] = attrs_tree(jsonable(tr.truth))
    return node
