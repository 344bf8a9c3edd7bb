"""The session record of a render log: a participant's session in the web console.

The console's session events (:data:`SESSION_KINDS`: who the participant is, the A/B
comparisons, the set chosen) are events of the render log; the final log gathers them
in its ``/session`` group (:func:`session_tree`). :func:`read_session` reads a log's
session back, :func:`format_session` says it for people (``evo-door show LOG.h5``) and
:func:`session_params` gives the set a log stands for (``--params LOG.h5``).
"""

from __future__ import annotations

import numpy as np

from evo_door.errors import UserError
from evo_door.files import ATTRS, Dataset

#: the event kinds that belong to a participant's session
SESSION_KINDS: tuple[str, ...] = ("participant", "ab_store", "ab_switch", "ab_choice", "undo")
SESSION_KINDS += ("reset", "save", "chosen", "note")
#: and a JND session's (the console's, evo_door.render.console.jnd_mode, and
#: ``evo-door jnd``'s, evo_door.render.jnd: jnd_switch for each phase)
SESSION_KINDS += ("jnd_start", "jnd_trial", "jnd_switch", "jnd_answer", "jnd_end", "jnd_save")


def session_tree(events, names, units) -> dict | None:
    """The ``/session`` group of a log from its events; None without session events.

    Layout::

        /session               participant (str, the last one given), events (json:
                               every session event, time-stamped), choices (json: the
                               A/B preferences), chosen_t (s, -1 without a choice)
            chosen             the participant's final set (SI, in ``names`` order),
                               attributes names, units; absent without a choice
    """
    mine = [e for e in events if e.get("kind") in SESSION_KINDS]
    if not mine:
        return None
    participant = ""
    for e in mine:
        if e["kind"] == "participant":
            participant = str(e.get("id", ""))
    chosen = [e for e in mine if e["kind"] == "chosen"]
    tree = {
        ATTRS: {
            "participant": participant,
            "events": mine,
            "choices": [e for e in mine if e["kind"] == "ab_choice"],
            "chosen_t": chosen[-1]["t"] if chosen else -1.0,
        }
    }
    values = chosen[-1].get("params", {}) if chosen else {}
    if chosen and all(n in values for n in names):  # the control port completes it
        vector = np.array([values[n] for n in names], dtype=np.float64)
        tree["chosen"] = Dataset(vector, {"names": list(names), "units": list(units)})
    return tree


def read_session(path) -> dict:
    """A render log's session: participant, duration, parameter sets, the choice.

    Returns ``{"participant", "duration_s", "device", "sets": [(t, {name: value})],
    "changes", "choices", "chosen": {name: value} or None, "chosen_t", "events",
    "statistics", "stopped", "changes_not_kept", "not_kept_span", "events_not_kept"}``
    (``stopped``: who ended the render, as its ``stopped`` event says, e.g. "stopped by
    the operator"; else ""; ``changes_not_kept``: the parameter changes in force but
    not kept, past the log's cap of sets, ``not_kept_span`` [first, last] (s) when
    they came into force, else None; ``events_not_kept``: the session events and
    refused changes past the log's cap); a log without a session record has an empty
    participant, no choice and the session events list empty. A file that is not a
    render log is a UserError.
    """
    from evo_door.files import fields, open_h5, read_attrs

    with open_h5(path) as f:
        if "render" not in f:
            raise UserError(f"{path}: not a render log (no /render group)")
        log = read_log(f, path)
        session = read_attrs(f["session"]) if "session" in f else {}
        chosen = None
        if "session/chosen" in f:
            ds = f["session/chosen"]
            names = fields.texts(read_attrs(ds), "names")
            chosen = dict(zip(names, fields.as_array(ds[()], ds.name, (len(names),)).tolist()))
    events = log["events"]
    ended = [e.get("message", "") for e in events if e.get("kind") == "stopped"]
    counting = {e.get("kind"): e for e in events if e.get("kind") in ("dropped", "changes_dropped")}
    unkept = counting.get("changes_dropped")
    return {
        "participant": fields.text(session, "participant", ""),
        "duration_s": log["duration"],
        "device": log["device"],
        "sets": log["sets"],
        "changes": [e for e in events if e.get("kind") == "change"],
        "choices": events_of(session.get("choices", []), fields.place_of(session, "choices")),
        "chosen": chosen,
        "chosen_t": fields.number(session, "chosen_t", -1.0),
        "events": events_of(session.get("events", []), fields.place_of(session, "events")),
        "statistics": log["statistics"],
        "stopped": ended[-1] if ended else "",
        "changes_not_kept": int(unkept.get("count", 0)) if unkept else 0,
        "not_kept_span": [unkept.get("t"), unkept.get("last_t")] if unkept else None,
        "events_not_kept": int(counting.get("dropped", {}).get("count", 0)),
    }


def read_log(f, path) -> dict:
    """What every reader of a render log takes from its open file ``f``, each value
    checked (a log is data: :mod:`evo_door.files.fields`): the sets in force
    (``sets``: [(t, {name: value})]), ``events``, ``statistics``, ``device`` and the
    ``duration`` (s)."""
    from evo_door.files import DamagedFile, fields, read_attrs

    if not hasattr(f["render"], "keys") or "params" not in f["render"]:
        raise UserError(f"{path}: not a render log (no /render group with its sets)")
    render = read_attrs(f["render"])
    group = f["render/params"]
    if not hasattr(group, "keys"):
        raise DamagedFile(f"{path}: /render/params: expected a group, got a dataset")
    names = fields.texts(read_attrs(group), "names")
    times = fields.as_array(
        _dataset(f, "render/params/t", path), f"{path}: /render/params/t", (None,)
    )
    values = fields.as_array(
        _dataset(f, "render/params/values", path),
        f"{path}: /render/params/values",
        (times.size, len(names)),
    )
    t = fields.as_array(_dataset(f, "render/t", path), f"{path}: /render/t", (None,))
    stored = fields.mapping(render, "statistics", {})
    statistics = dict(stored)
    # the numbers the readers print: each a number (else one line naming it), or left
    # out where the file holds none (a null read as a number would be a traceback)
    for key in ("rate_hz", "faults", "on_time_fraction", "period_mean_s", "missed_cycles", "gaps"):
        if fields.number(stored, key, None) is None:
            statistics.pop(key, None)
    fields.text(statistics, "status", "")
    fields.flag(statistics, "realtime", True)
    return {
        "sets": [(float(ti), dict(zip(names, v.tolist()))) for ti, v in zip(times, values)],
        "events": events_of(render.get("events", []), fields.place_of(render, "events")),
        "statistics": statistics,
        "device": fields.text(render, "device", ""),
        "duration": float(t[-1]) if t.size else 0.0,
    }


def _dataset(f, name: str, path):
    from evo_door.files import DamagedFile

    if name not in f or not hasattr(f[name], "dtype"):
        raise DamagedFile(f"{path}: /{name}: missing, or not a dataset")
    return f[name][()]


#: the numbers of an event a reader takes, by kind
_EVENT_NUMBERS = {
    "device": ("damping", "friction", "max_force"),
    "jnd_end": ("weber",),
    "changes_dropped": ("last_t",),
    "gap": ("from_t",),
}
#: the counts of an event a reader takes, by kind
_EVENT_COUNTS = {
    "jnd_end": ("answers",),
    "dropped": ("count",),
    "changes_dropped": ("count",),
    "gap": ("count",),
}


def events_of(value, where: str) -> list[dict]:
    """A log's events (a list of mappings, each with a time ``t`` and a ``kind``), each
    value a reader formats checked; or one line naming ``where``."""
    from evo_door.files import DamagedFile, Node, fields

    if not isinstance(value, list):
        raise DamagedFile(f"{where}: expected a list of events, got {fields.show(value)}")
    out = []
    for i, e in enumerate(value):
        e = Node(fields.as_mapping(e, f"{where}[{i}]"), place=f"{where}[{i}]:", style="key")
        fields.number(e, "t", None)
        kind = fields.text(e, "kind", "")
        for key in _EVENT_NUMBERS.get(kind, ()):
            fields.number(e, key, None)
        for key in _EVENT_COUNTS.get(kind, ()):
            fields.integer(e, key, None, lo=0)
        if kind == "changes_dropped":  # when the sets not kept began
            fields.number(e, "t")
        for key in ("message", "slot", "param", "status"):
            fields.text(e, key, None)
        ci = e.get("ci95")
        if ci is not None and len(fields.as_numbers(ci, e.name("ci95"))) != 2:
            raise DamagedFile(f"{e.name('ci95')}: expected [low, high]")
        if "params" in e:
            fields.mapping(e, "params", None, fields.as_number)
        out.append(dict(e))
    return out


def is_render_log(path) -> bool:
    """Whether ``path`` is an HDF5 file holding a render log (never raises)."""
    from evo_door.files import open_h5

    try:
        with open_h5(path) as f:
            return "render" in f and "render/params" in f
    except (UserError, OSError):  # not a file, not HDF5: the caller's own reader says why
        return False


def format_session(s: dict, path="") -> str:
    """:func:`read_session`'s summary for people (angles in degrees, units)."""
    from evo_door.models.haptic import PARAMS
    from evo_door.render.keys import shown as shown_unit

    def shown(name, value):  # a mechanism's names are not the haptic model's: no unit
        return shown_unit(value, PARAMS[name].unit if name in PARAMS else "").strip()

    stats = s["statistics"]
    lines = [f"render log {path}".rstrip()]
    who = s["participant"] or "(no participant id)"
    unkept = s.get("changes_not_kept", 0)
    lines.append(
        f"  participant {who}, {s['duration_s']:.1f} s on {s['device'] or '?'}, "
        f"{len(s['changes']) + unkept} parameter changes, {len(s['choices'])} A/B choices"
    )
    if unkept:
        first, last = s["not_kept_span"]
        lines.append(
            f"  {unkept} of the changes not kept in the log (past its cap of sets), from "
            f"{first:.1f} to {last:.1f} s;\n    it keeps the set in force at each choice and "
            "at the end"
        )
    if s.get("events_not_kept"):
        lines.append(
            f"  {s['events_not_kept']} session events and refused changes not kept in the "
            "log (past its cap)"
        )
    status = s.get("stopped") or stats.get("status", "?")
    if stats.get("realtime") is False:  # simulated time: it kept no clock to be on time for
        lines.append(
            f"  loop {stats.get('rate_hz', 0):g} Hz unpaced (simulated time), "
            f"{stats.get('faults', 0)} faults, status {status}"
        )
    elif "on_time_fraction" in stats:
        lines.append(
            f"  loop {stats.get('rate_hz', 0):g} Hz, {100 * stats['on_time_fraction']:.3f} % of "
            f"cycles on time, {stats.get('faults', 0)} faults, status {status}"
        )
    for e in s["choices"]:
        lines.append(f"  at {e['t']:7.1f} s: prefers {e.get('slot', '?')}")
    for e in s["events"]:
        if e.get("kind") == "jnd_end":
            w, ci = e.get("weber"), e.get("ci95")
            fit = f", Weber fraction {w:.3g} (95 %: {ci[0]:.3g} to {ci[1]:.3g})" if w and ci else ""
            lines.append(
                f"  at {e['t']:7.1f} s: JND session on {e.get('param', '?')} "
                f"{e.get('status', '?')}, {e.get('answers', 0)} answers{fit}"
            )
    start = s["sets"][0][1] if s["sets"] else {}
    final = s["chosen"] if s["chosen"] is not None else (s["sets"][-1][1] if s["sets"] else {})
    title = f"chosen at {s['chosen_t']:.1f} s" if s["chosen"] is not None else "last set in force"
    differs = [n for n in final if final[n] != start.get(n)]
    lines.append(f"  {title} (differs from the starting set in {len(differs)} parameters):")
    for name in differs:
        lines.append(
            f"    {name:24s} {shown(name, start[name]):>14s} -> {shown(name, final[name])}"
        )
    if s["chosen"] is None:
        lines.append("  no final choice recorded: --params LOG.h5 takes the last set in force")
    return "\n".join(lines)


def session_params(path) -> tuple[dict, str]:
    """The parameter set a render log stands for, and what it is.

    The participant's chosen set when the session has one, else the last set in
    force. Returns ``({name: value}, description)``.
    """
    s = read_session(path)
    if s["chosen"] is not None:
        who = f" of participant {s['participant']}" if s["participant"] else ""
        return s["chosen"], f"{path}: the set chosen{who} at {s['chosen_t']:.1f} s"
    if not s["sets"]:
        raise UserError(f"{path}: the log holds no parameter set")
    t, values = s["sets"][-1]
    return values, f"{path}: the last set in force (from {t:.1f} s; no choice recorded)"
