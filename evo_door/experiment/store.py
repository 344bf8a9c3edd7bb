"""Results files: a nested dict written to HDF5 atomically, and read back.

A run is checkpointed by writing the *whole* results file under a temporary name in
the same folder, flushing it to disk and renaming it over the previous version
(``os.replace``, atomic on POSIX and Windows). A run killed at any moment therefore
leaves either the previous complete checkpoint or the new one, never a half-written
HDF5 file (HDF5 itself is not crash-safe while a file is open for writing).

The in-memory form is a nested dict: a dict is a group, a key ``"@attrs"`` holds the
group's attributes (str, int, float, bool; dicts and lists are stored as JSON text),
``numpy`` arrays and lists of numbers are datasets, a str is a scalar string dataset
(for texts too long for an attribute).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

ATTRS = "@attrs"
FORMAT = "evo-door run"
FORMAT_VERSION = 1
#: Datasets at least this large are gzip-compressed.
_COMPRESS_ABOVE = 4096


def _h5py():
    import h5py

    return h5py


def _jsonable(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, bytes):
        return value.decode()
    raise TypeError(f"cannot store {type(value).__name__} as JSON")


def _attr_value(value):
    if isinstance(value, (dict, list, tuple)) or value is None:
        return "json:" + json.dumps(value, default=_jsonable)
    if isinstance(value, (np.integer, np.floating, np.bool_)):
        return value.item()
    return value


def _read_attr(value):
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, str) and value.startswith("json:"):
        return json.loads(value[5:])
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def _write_group(group, tree: dict) -> None:
    h5py = _h5py()
    for key, value in tree.items():
        if key == ATTRS:
            for name, v in value.items():
                group.attrs[name] = _attr_value(v)
        elif isinstance(value, dict):
            _write_group(group.create_group(key), value)
        elif isinstance(value, str):
            group.create_dataset(key, data=value, dtype=h5py.string_dtype())
        else:
            data = np.asarray(value)
            if data.dtype == object:
                raise TypeError(f"cannot store {key!r}: object array")
            opts = {"compression": "gzip", "compression_opts": 1, "shuffle": True} \
                if data.size >= _COMPRESS_ABOVE and data.ndim >= 1 else {}
            group.create_dataset(key, data=data, **opts)


class Keep:
    """Placeholder in a tree: copy this group unchanged from the file being replaced.

    Checkpoints rewrite the whole file; large groups that never change (the trials)
    are copied from the previous version with HDF5's object copy, which moves the
    stored (compressed) bytes instead of compressing them again.
    """

    def __init__(self, build):
        self.build = build  # () -> dict, used when there is nothing to copy from


def write_atomic(path, tree: dict) -> None:
    """Write ``tree`` to ``path`` through a temporary file and an atomic rename."""
    h5py = _h5py()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temporary_name(path, os.getpid())
    keep = {k: v for k, v in tree.items() if isinstance(v, Keep)}
    tree = {k: v for k, v in tree.items() if not isinstance(v, Keep)}
    try:
        with h5py.File(tmp, "w") as f:
            _write_group(f, tree)
            old = None
            if keep and path.is_file():
                try:
                    old = h5py.File(path, "r")
                except OSError:
                    old = None
            try:
                for key, placeholder in keep.items():
                    if old is not None and key in old:
                        old.copy(old[key], f, name=key)
                    else:
                        _write_group(f.create_group(key), placeholder.build())
            finally:
                if old is not None:
                    old.close()
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _temporary_name(path: Path, pid: int) -> Path:
    return path.with_name(f".{path.name}.tmp-{pid}")


def remove_stale_temporaries(path) -> list[Path]:
    """Delete temporaries a killed writer of ``path`` left behind (see :func:`write_atomic`)."""
    path = Path(path)
    removed = []
    for tmp in path.parent.glob(f".{path.name}.tmp-*"):
        try:
            tmp.unlink()
            removed.append(tmp)
        except OSError:  # pragma: no cover - gone already, or not ours to remove
            pass
    return removed


def _read_group(group) -> dict:
    h5py = _h5py()
    out = {ATTRS: {k: _read_attr(v) for k, v in group.attrs.items()}}
    for key, item in group.items():
        if isinstance(item, h5py.Group):
            out[key] = _read_group(item)
        elif h5py.check_string_dtype(item.dtype) is not None and item.shape == ():
            v = item[()]
            out[key] = v.decode() if isinstance(v, bytes) else str(v)
        else:
            out[key] = item[()]
    return out


def read_tree(path) -> dict:
    """The whole results file as a nested dict (see the module docstring)."""
    from evo_door.errors import UserError

    h5py = _h5py()
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: results file not found")
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT:
                raise UserError(f"{path}: not an evo-door results file "
                                f"(format {f.attrs.get('format')!r})")
            return _read_group(f)
    except OSError as exc:
        raise UserError(f"{path}: not a readable HDF5 file ({exc})") from None


def peek(path) -> dict:
    """Root attributes, the resolved configuration and each job's GA attributes, cheaply."""
    from evo_door.errors import UserError

    h5py = _h5py()
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT:
                raise UserError(f"{path}: not an evo-door results file")
            out = {ATTRS: {k: _read_attr(v) for k, v in f.attrs.items()}}
            out["resolved"] = json.loads(f["experiment/resolved"][()])
            out["jobs"] = {k: {k2: _read_attr(v) for k2, v in f[f"jobs/{k}/ga"].attrs.items()}
                           if f"jobs/{k}/ga" in f else {} for k in f["jobs"]}
            out["best"] = ({k: _read_attr(v) for k, v in f["best"].attrs.items()}
                           if "best" in f else None)
            return out
    except OSError as exc:
        raise UserError(f"{path}: not a readable HDF5 file ({exc})") from None


def versions() -> dict:
    """Versions of the packages that decide a run's numbers."""
    import platform
    from importlib import metadata

    from evo_door import __version__

    out = {"python": platform.python_version(), "evo_door": __version__,
           "platform": platform.platform(), "cpus": os.cpu_count() or 0}
    for dist in ("numpy", "scipy", "numba", "deap", "h5py", "pyyaml"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:  # pragma: no cover
            out[dist] = "not installed"
    try:
        import numba

        out["numba_threads"] = int(numba.get_num_threads())
    except Exception:  # pragma: no cover
        pass
    return out
