"""Reading and writing trial files, whatever their format.

The one entry point for everything that accepts trials (experiments, ``evo-door data``,
the GA's targets)::

    from evo_door.data import read_trials
    trials = read_trials("experiments/data/default.h5")            # all trials
    trials = read_trials("run.csv")                                # evo-door simulate output
    trials = read_trials("log.tdms", map=["force=Fz:kN", "dtheta=Gyro:deg/s"])

Formats by extension: ``.h5`` / ``.hdf5`` (:mod:`.h5io`), ``.csv`` / ``.txt``
(:mod:`.csvio`), ``.tdms`` (:mod:`.tdmsio`, needs npTDMS). Every reader checks every
trial before returning any: a bad file raises one :class:`~evo_door.errors.UserError`
naming the file, the channel and the row, and nothing is half-imported.
"""

from __future__ import annotations

from pathlib import Path

from evo_door.data.trial import Trial
from evo_door.data.units import parse_maps
from evo_door.errors import UserError

H5_SUFFIXES = (".h5", ".hdf5", ".hdf")
CSV_SUFFIXES = (".csv", ".txt")
TDMS_SUFFIXES = (".tdms",)


def file_format(path) -> str:
    """``"h5"``, ``"csv"`` or ``"tdms"`` from the file name's extension."""
    suffix = Path(path).suffix.lower()
    if suffix in H5_SUFFIXES:
        return "h5"
    if suffix in CSV_SUFFIXES:
        return "csv"
    if suffix in TDMS_SUFFIXES:
        return "tdms"
    raise UserError(
        f"{path}: unknown trial file type {suffix or '(no extension)'!r}; "
        "use .h5/.hdf5, .csv or .tdms"
    )


def read_trials(path, trials="all", *, map=None, rate=None, channels=None, **fields) -> list[Trial]:
    """Read trials from a file, checked, in SI.

    Parameters
    ----------
    path : str or Path
        ``.h5``/``.hdf5`` (many trials), ``.csv`` (one trial), ``.tdms`` (one per group).
    trials : "all", str, int or list
        Which trials: ids (HDF5 group / TDMS group names) or positions in the file.
        A CSV file holds one trial, selected by its id or 0.
    map : list of str or dict, optional
        Channel mapping ``["force=Fz:kN", "theta=Incl:-1*deg+90"]``
        (see :mod:`evo_door.data.units`).
    rate : float, optional
        Expected sampling rate in Hz: a file at another rate is an error; builds the
        time axis for files without one.
    channels : sequence of str, optional
        Take only these channels of a CSV file (its other columns are not read, so
        they may hold anything); other formats read every channel.
    **fields
        Trial fields to set on every trial read (``user_id="U2"``, ``kind="impulse"``,
        ``theta0=1.5708``...), overriding the file's metadata.

    Returns
    -------
    list of Trial
    """
    mapping = map if isinstance(map, dict) else parse_maps(map)
    unknown = set(fields) - {"trial_id", "user_id", "kind", "theta0", "dtheta0"}
    if unknown:
        raise TypeError(f"read_trials: unexpected field(s) {sorted(unknown)}")
    fmt = file_format(path)
    if fmt == "h5":
        from evo_door.data.h5io import read_h5

        return read_h5(path, trials, mapping, rate, fields)
    if fmt == "tdms":
        from evo_door.data.tdmsio import read_tdms

        return read_tdms(path, trials, mapping, rate, fields)
    from evo_door.data.csvio import read_csv

    trial = read_csv(path, mapping, rate, fields, **({"channels": channels} if channels else {}))
    if trials not in (None, "all"):
        wanted = [trials] if isinstance(trials, (str, int)) else list(trials)
        for w in wanted:
            if w not in (trial.trial_id, 0, -1):
                raise UserError(
                    f"{path}: no trial {w!r}; a CSV file holds one trial ({trial.trial_id!r})"
                )
    return [trial]


def read_trial(path, trial=None, **kwargs) -> Trial:
    """Exactly one trial: ``trial`` (id or position) or the file's only one."""
    found = read_trials(path, "all" if trial is None else trial, **kwargs)
    if len(found) != 1:
        raise UserError(
            f"{path}: holds {len(found)} trials "
            f"({', '.join(t.trial_id for t in found)}); choose one"
        )
    return found[0]


def write_trials(path, trials, *, append: bool = False, description: str = "") -> None:
    """Write trials to ``path`` by extension (HDF5: many; CSV: one; TDMS: many).

    The file is written under a temporary name and renamed when complete, so a crash
    leaves either the old file or the new one, never half of one. With ``append``
    the trials already in an HDF5 file are kept (ids must stay unique).
    """
    trials = [trials] if isinstance(trials, Trial) else list(trials)
    if not trials:
        raise UserError(f"{path}: no trials to write")
    fmt = file_format(path)
    if append and Path(path).exists():
        if fmt != "h5":
            raise UserError(f"{path}: only HDF5 trial files can be appended to")
        trials = read_trials(path) + trials
    if fmt == "h5":
        from evo_door.data.h5io import write_h5_trials

        write_h5_trials(path, trials, description)
    elif fmt == "tdms":
        from evo_door.data.tdmsio import write_tdms

        write_tdms(path, trials)
    else:
        if len(trials) != 1:
            raise UserError(
                f"{path}: a CSV file holds one trial, got {len(trials)}; "
                "write HDF5 (.h5) or one CSV per trial"
            )
        from evo_door.data.csvio import write_csv

        write_csv(path, trials[0])
