"""JND files: a measured session in HDF5, and the JND settings they replace.

``evo-door jnd`` writes one file per session (format ``evo-door jnd``)::

    /                 format, format_version, software, created, seed, configuration
                      (every setting of the session, JSON), versions, wall_s
    /jnd              param, unit, word, reference, method, trials, status,
                      participant, device, model, weber, ci95, open_ended, slope,
                      lapse, log_likelihood
    /jnd/trials       step (1), comparison (unit), order, answer, correct, time (s)
    /jnd/reference    attributes: the reference parameter set, name -> value

A file names the parameter it measured; the parameter's unit says which JND setting
it replaces (:data:`SETTING_BY_UNIT`: a force in N sets ``force``, a damping in
N s/rad ``viscosity``, an inertia in kg m ``inertia``, a stiffness in N/rad
``stiffness``). :func:`measured_jnd` turns files and a table of Weber fractions into
:class:`~evo_door.perception.jnd.JND` settings, with the source of each.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from evo_door import __version__
from evo_door.errors import UserError
from evo_door.files.h5tree import Dataset, open_h5, read_group, write_h5
from evo_door.files.metadata import ATTRS, read_attrs
from evo_door.perception.jnd import JND
from evo_door.perception.procedures import JndSession
from evo_door.perception.psychometric import Fit, Psychometric

FORMAT = "evo-door jnd"
FORMAT_VERSION = 1
#: the JND setting a measured parameter's Weber fraction replaces, by its unit
SETTING_BY_UNIT = {"N": "force", "N s/rad": "viscosity", "kg m": "inertia", "N/rad": "stiffness"}
#: the settings a measurement may replace (the others are floors and reference speeds)
WEBER_SETTINGS = ("force", "stiffness", "viscosity", "inertia")
#: the source of a setting nobody measured
LITERATURE = "default, from the literature (docs/perception.md)"
TRIAL_UNITS = {"step": "1", "order": "1", "answer": "1", "correct": "1", "time": "s"}


@dataclass
class JndRecord:
    """A JND file read back (see the module docstring for the fields)."""

    path: Path
    param: str
    unit: str
    word: str
    reference: float
    method: str
    status: str
    participant: str
    device: str
    model: str
    fit: Fit | None
    trials: dict = field(default_factory=dict)
    reference_params: dict = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)

    @property
    def setting(self) -> str | None:
        """The JND setting this measurement stands for, or None (a unit with none)."""
        return SETTING_BY_UNIT.get(self.unit)

    @property
    def complete(self) -> bool:
        return self.status == "complete"

    def summary(self) -> dict:
        """What ``jnd --json`` prints and ``show --json`` gives."""
        fit = self.fit
        return {
            "param": self.param,
            "unit": self.unit,
            "reference": self.reference,
            "weber": fit.weber if fit else None,
            "ci95": list(fit.ci95) if fit else None,
            "trials": int(len(self.trials.get("step", ()))),
            "method": self.method,
            "status": self.status,
            "participant": self.participant,
            "device": self.device,
            "setting": self.setting,
        }


def write_jnd_file(
    path,
    session: JndSession,
    fit: Fit | None,
    *,
    status: str,
    participant: str,
    device: str,
    model: str,
    reference_params: dict,
    settings: dict,
    seed,
    created: str,
    wall_s: float,
    versions: dict,
) -> None:
    """Write ``session`` (its every answered trial) and its ``fit`` (None: too few
    answers) as the JND file ``path``, atomically."""
    table = session.table()
    unit_of = {**TRIAL_UNITS, "comparison": session.unit}
    attrs = {
        "param": session.param,
        "unit": session.unit,
        "word": session.word,
        "reference": session.reference,
        "method": session.method,
        "trials_planned": session.trials,
        "status": status,
        "participant": participant,
        "device": device,
        "model": model,
    }
    if fit is not None:
        attrs.update(fit.as_dict())
        attrs["trials_fitted"] = attrs.pop("trials")
    tree = {
        ATTRS: {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "software": f"evo-door {__version__}",
            "description": f"JND session: {session.param} by {participant}",
            "created": created,
            "seed": seed,
            "configuration": settings,
            "versions": versions,
            "wall_s": float(wall_s),
        },
        "jnd": {
            ATTRS: attrs,
            "trials": {k: Dataset(v, {"unit": unit_of[k]}) for k, v in table.items()},
            "reference": {ATTRS: {k: float(v) for k, v in reference_params.items()}},
        },
    }
    write_h5(path, tree)


def is_jnd_file(path) -> bool:
    """Whether ``path`` is an HDF5 file of format ``evo-door jnd`` (False otherwise,
    unreadable files included)."""
    p = Path(path)
    if not p.is_file() or p.suffix.lower() not in (".h5", ".hdf5"):
        return False
    try:
        with open_h5(p) as f:
            return read_attrs(f).get("format") == FORMAT
    except UserError:
        return False


def read_jnd_file(path) -> JndRecord:
    """A JND file, or a one-line error saying why it is not one."""
    path = Path(path)
    with open_h5(path, "JND file") as f:
        top = read_attrs(f)
        if top.get("format") != FORMAT or "jnd" not in f:
            raise UserError(
                f"{path}: not a JND file (format {top.get('format')!r}; `evo-door jnd` writes them)"
            )
        if not hasattr(f["jnd"], "keys"):
            raise UserError(f"{path}: /jnd: expected a group, got a dataset")
        tree = read_group(f["jnd"])
    return _record(path, top, tree)


#: the trial table of a session: each column's name and how it is read (one row a trial)
_TRIAL_KINDS = {
    "step": "f",
    "comparison": "f",
    "order": "i",
    "answer": "i",
    "correct": "b",
    "time": "f",
}


def _record(path: Path, top: dict, tree: dict) -> JndRecord:
    """A JND file's record from its root attributes and ``/jnd`` group, each value
    checked (a file is data: :mod:`evo_door.files.fields`)."""
    from evo_door.files import fields

    a = tree[ATTRS]
    fit = None
    if "weber" in a:
        ci95 = fields.numbers(a, "ci95")
        ends = a["open_ended"]
        if len(ci95) != 2 or not isinstance(ends, list) or len(ends) != 2:
            raise UserError(f"{fields.place_of(a, 'ci95')}: expected [low, high] and two ends")
        fit = Fit(
            weber=fields.number(a, "weber", finite=True, lo=0.0),
            slope=fields.number(a, "slope"),
            lapse=fields.number(a, "lapse"),
            ci95=(ci95[0], ci95[1]),
            open_ended=(
                fields.as_flag(ends[0], fields.place_of(a, "open_ended")),
                fields.as_flag(ends[1], fields.place_of(a, "open_ended")),
            ),
            trials=fields.integer(a, "trials_fitted", lo=0),
            log_likelihood=fields.number(a, "log_likelihood"),
        )
    table = fields.group(tree, "trials")
    trials: dict[str, np.ndarray] = {}
    for k in table:
        if k != ATTRS:
            kind = _TRIAL_KINDS.get(k, "f")
            shape = (None,) if not trials else (next(iter(trials.values())).size,)
            trials[k] = fields.array(table, k, shape=shape, kind=kind)
    steps = trials.get("step", np.ones(0))
    if not np.all(np.isfinite(steps) & (steps > 0)):
        raise UserError(f"{fields.place_of(table, 'step')}: a step not a number above 0")
    for k in ("comparison", "time"):
        if k in trials and not np.all(np.isfinite(trials[k])):
            raise UserError(f"{fields.place_of(table, k)}: a value that is not finite")
    return JndRecord(
        path=path,
        param=fields.text(a, "param"),
        unit=fields.text(a, "unit"),
        word=fields.text(a, "word"),
        reference=fields.number(a, "reference", finite=True),
        method=fields.text(a, "method"),
        status=fields.text(a, "status"),
        participant=fields.text(a, "participant"),
        device=fields.text(a, "device"),
        model=fields.text(a, "model"),
        fit=fit,
        trials=trials,
        reference_params=fields.mapping(
            fields.group(tree, "reference"), ATTRS, None, fields.as_number
        ),
        attrs={**top, **a, "trials_planned": fields.integer(a, "trials_planned", len(steps), lo=0)},
    )


def usable_weber(record: JndRecord) -> float:
    """The Weber fraction of a JND file for the perceptual settings, or a one-line
    error: the session must be complete, its parameter's unit one of
    :data:`SETTING_BY_UNIT`, its interval closed and its estimate below 1."""
    where = f"{record.path}"
    if not record.complete or record.fit is None:
        raise UserError(f"{where}: the session is {record.status}; only a complete one sets a JND")
    if record.setting is None:
        units = ", ".join(f"{u} ({s})" for u, s in SETTING_BY_UNIT.items())
        raise UserError(
            f"{where}: {record.param} is in {record.unit}; a JND setting is measured on a "
            f"parameter in {units}"
        )
    if any(record.fit.open_ended):
        raise UserError(
            f"{where}: the answers do not bound the Weber fraction (its interval reaches "
            "the edge of the search); run more trials"
        )
    if not record.fit.weber < 1.0:
        raise UserError(f"{where}: Weber fraction {record.fit.weber:.3g} is not below 1")
    return record.fit.weber


def describe_source(record: JndRecord) -> str:
    """One line: where a measured JND came from."""
    fit = record.fit
    assert fit is not None
    return (
        f"{record.path.name}: {record.param} at {record.reference:g} {record.unit}, "
        f"{record.participant}, {record.method}, {fit.trials} trials, Weber "
        f"{fit.weber:.3g} [{fit.ci95[0]:.3g}, {fit.ci95[1]:.3g}]"
    )


def measured_jnd(base: JND, files=(), table: dict | None = None) -> tuple[JND, dict]:
    """``base`` with its Weber fractions replaced by measurements; and their sources.

    ``files`` are JND files; ``table`` maps a setting (``force``, ``stiffness``,
    ``viscosity``, ``inertia``) to ``{"weber": W, "source": TEXT}``. Several files
    on one setting (several participants) give the geometric mean of their Weber
    fractions; the table and the files may not both set one. Returns the settings and
    ``{setting: source}`` for every Weber setting (:data:`LITERATURE` where nothing
    was measured).
    """
    by_setting: dict[str, list[tuple[float, str]]] = {}
    for path in files:
        record = read_jnd_file(path)
        w = usable_weber(record)
        by_setting.setdefault(str(record.setting), []).append((w, describe_source(record)))
    for name, entry in (table or {}).items():
        if name not in WEBER_SETTINGS:
            raise UserError(
                f"Weber table: {name!r} is not a Weber fraction setting; settings: "
                f"{', '.join(WEBER_SETTINGS)}"
            )
        if name in by_setting:
            raise UserError(f"Weber table: {name} is also set by a JND file; give it once")
        if not isinstance(entry, dict) or set(entry) - {"weber", "source"} or "weber" not in entry:
            raise UserError(f"Weber table: {name}: expected {{weber: W, source: TEXT}}")
        w = entry["weber"]
        if not isinstance(w, (int, float)) or not (0.0 < w < 1.0) or not math.isfinite(w):
            raise UserError(f"Weber table: {name} {w!r}: a Weber fraction between 0 and 1")
        source = str(entry.get("source") or "a table without a source")
        by_setting[name] = [(float(w), source)]
    values = {}
    sources = {}
    for name in WEBER_SETTINGS:
        got = by_setting.get(name)
        if not got:
            sources[name] = LITERATURE
            continue
        values[name] = (
            got[0][0] if len(got) == 1 else math.exp(sum(math.log(w) for w, _ in got) / len(got))
        )
        lines = "; ".join(s for _, s in got)
        sources[name] = lines if len(got) == 1 else f"geometric mean of {len(got)}: {lines}"
    return replace(base, **values), sources


def curve_points(steps, fit: Fit | None, n: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """The fitted psychometric function from half the smallest step (or estimate) to
    twice the largest, ``n`` log-spaced points: (step, P(correct))."""
    steps = np.asarray(steps, dtype=float)
    lo = min(float(steps.min()), fit.weber if fit else 1.0) / 2.0
    hi = max(float(steps.max()), fit.weber if fit else 1.0) * 2.0
    x = np.geomspace(lo, hi, n)
    f = fit.function if fit else Psychometric(1.0)
    return x, f.p_correct(x)


def fitted_curve(record: JndRecord, n: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """The fitted psychometric function over a JND file's steps: (step, P(correct))."""
    return curve_points(record.trials["step"], record.fit, n)
