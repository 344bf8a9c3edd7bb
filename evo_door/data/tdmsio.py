"""National Instruments TDMS files (LabVIEW, SignalExpress) through npTDMS (extra ``tdms``).

Each TDMS group holding channels is one trial (its name is the trial id); each
channel is a column, mapped to trial channels like CSV columns
(``--map force="Load cell:N"``). A channel's unit comes from its ``unit_string``
property unless the mapping gives one; the time axis from a mapped / ``t`` / ``time``
channel or else from the waveform properties ``wf_increment`` and
``wf_start_offset`` that NI software writes.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evo_door.data.columns import Column, trial_from_columns
from evo_door.data.trial import RESPONSE_CHANNELS, UNITS, Trial
from evo_door.errors import UserError
from evo_door.files import atomic_write, to_json

INSTALL_HINT = "reading NI TDMS files needs the npTDMS package: pip install 'evo-door[tdms]'"


def _nptdms():
    try:
        import nptdms
    except ImportError:
        raise UserError(INSTALL_HINT) from None
    return nptdms


def _column(channel) -> Column:
    props = channel.properties
    data = channel[:]
    if data.dtype.kind == "M":  # absolute time stamps -> seconds from the first one
        data = (data - data[0]) / np.timedelta64(1, "s") if data.size else data.astype(float)
    try:
        values = np.asarray(data, dtype=np.float64)
    except (TypeError, ValueError):
        values = np.full(len(data), np.nan)
    unit = props.get("unit_string") or None
    dt = props.get("wf_increment")
    t0 = props.get("wf_start_offset", 0.0)
    return Column(
        channel.name,
        values,
        str(unit) if unit else None,
        float(dt) if dt else None,
        float(t0 or 0.0),
    )


def read_tdms(path, trials="all", mapping=None, rate=None, fields=None) -> list[Trial]:
    """Read one trial per TDMS group (``trials`` selects groups by name or number)."""
    from evo_door.data.h5io import _select

    nptdms = _nptdms()
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: file not found")
    if path.stat().st_size == 0:
        raise UserError(f"{path}: empty file")
    try:
        tdms = nptdms.TdmsFile.read(path)
    except Exception as exc:  # npTDMS raises ValueError, KeyError, struct.error...
        raise UserError(f"{path}: not a readable TDMS file ({type(exc).__name__}: {exc})") from None
    groups = {g.name: g for g in tdms.groups() if g.channels()}
    if not groups:
        raise UserError(f"{path}: empty: no group holds any channel")
    out = []
    for name in _select(path, list(groups), trials):
        g = groups[name]
        where = f"{path}:{name}"
        columns = {ch.name: _column(ch) for ch in g.channels()}
        props = g.properties
        flds = {
            "trial_id": name,
            "user_id": props.get("user_id"),
            "kind": props.get("kind"),
            "theta0": props.get("theta0"),
            "dtheta0": props.get("dtheta0"),
        }
        for key in ("sensors", "truth", "meta"):
            if key in props:
                flds[key] = json.loads(props[key])
        flds = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in flds.items()}
        flds.update({k: v for k, v in (fields or {}).items() if v is not None})
        out.append(
            trial_from_columns(
                columns,
                where,
                mapping,
                rate,
                flds,
                record_import="meta" not in props or bool(mapping),
            )
        )
    return out


def write_tdms(path, trials) -> None:
    """Write trials as TDMS, one group per trial, SI channels with waveform properties."""
    nptdms = _nptdms()
    objects = [nptdms.RootObject({"software": "evo-door"})]
    for tr in trials:
        props = {
            "trial_id": tr.trial_id,
            "user_id": tr.user_id,
            "kind": tr.kind,
            "sensors": to_json(tr.sensors),
            "meta": to_json(tr.meta),
        }
        if tr.truth:
            props["truth"] = to_json(tr.truth)
        for key in ("theta0", "dtheta0"):
            if getattr(tr, key) is not None:
                props[key] = float(getattr(tr, key))
        objects.append(nptdms.GroupObject(tr.trial_id, properties=props))
        for name in ("force", *RESPONSE_CHANNELS):
            values = getattr(tr, name)
            if values is None:
                continue
            objects.append(
                nptdms.ChannelObject(
                    tr.trial_id,
                    name,
                    values,
                    properties={
                        "unit_string": UNITS[name],
                        "wf_increment": tr.dt,
                        "wf_start_offset": float(tr.t[0]),
                        "wf_samples": tr.n,
                    },
                )
            )
    with atomic_write(path) as tmp:
        with nptdms.TdmsWriter(str(tmp)) as writer:
            writer.write_segment(objects)
