"""Which process owns a file while it works on it (:class:`FileLock`)."""

from __future__ import annotations

import contextlib
import errno
import os
from pathlib import Path

from evo_door.errors import UserError, WriteError
from evo_door.files.atomic import check_folder, write_reason

#: lock file -> [descriptor, holders]: the locks this process holds (see FileLock).
#: Module-level on purpose: ``flock`` locks belong to the process, so every FileLock of
#: one file in this process must share one descriptor and count its holders; the
#: entries go when their last holder releases, so it holds only the locks in use.
_HELD: dict[str, list] = {}


class _Busy(Exception):
    """Another process holds the lock (the message says which)."""


class FileLock:
    """An advisory, exclusive lock on ``path`` for as long as this object holds it.

    The lock lives on a companion file ``.NAME.lock`` next to ``path`` (``path`` itself is
    replaced at every atomic write, so it cannot carry a lock), taken with ``flock``:
    the system releases it when the process dies, however it dies, so a killed run never
    leaves a file locked. :meth:`acquire` does not wait: a file locked by another
    process raises :class:`~evo_door.errors.UserError` saying which process holds it.
    Within one process the lock is shared (counted): a run that opens its own file
    again is not locked out by itself.

    >>> import tempfile
    >>> target = Path(tempfile.mkdtemp()) / "run.h5"
    >>> with FileLock(target) as lock:
    ...     FileLock.holder(target) == os.getpid()
    True
    >>> FileLock.holder(target) is None
    True
    """

    def __init__(self, path):
        self.path = Path(path)
        self.lock_path = self.path.with_name(f".{self.path.name}.lock")
        self._key: str | None = None

    @property
    def held(self) -> bool:
        return self._key is not None

    def acquire(self, what: str = "in use", wait: float = 0.0) -> FileLock:
        """Take the lock, or raise ``PATH: WHAT (process N); wait for it ...``; with
        ``wait`` (s), another holder is waited for that long first (polled)."""
        import time

        deadline = time.monotonic() + wait
        while True:
            try:
                return self._acquire(what)
            except _Busy as busy:
                if time.monotonic() >= deadline:
                    raise UserError(str(busy)) from None
                time.sleep(0.02)

    def _acquire(self, what: str) -> FileLock:
        import fcntl

        if self._key is not None:
            return self
        check_folder(self.path)
        key = str(self.lock_path.parent.resolve() / self.lock_path.name)
        if key in _HELD:
            _HELD[key][1] += 1
            self._key = key
            return self
        while True:
            try:  # never through a link: a lock file that points elsewhere is refused
                fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o666)
            except OSError as exc:
                if exc.errno == errno.ELOOP:
                    raise UserError(
                        f"{self.lock_path}: a symbolic link where evo-door keeps the lock of "
                        f"{self.path.name}; evo-door never writes through it: remove it"
                    ) from None
                raise WriteError(self.path, write_reason(exc) or str(exc)) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                os.close(fd)
                if exc.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                    raise
                pid = self.holder(self.path)
                by = f"process {pid}" if pid and pid > 0 else "another process"
                raise _Busy(
                    f"{self.path}: {what} ({by}); wait for it to finish or stop it first"
                ) from None
            # the holder before us may have removed the lock file after we opened it:
            # then we hold a lock on a file nobody else can see; take the new one
            try:
                same = os.lstat(self.lock_path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError as exc:  # a full disk: no room even for the process id
            with contextlib.suppress(OSError):
                os.unlink(self.lock_path)
            os.close(fd)
            raise WriteError(self.path, write_reason(exc) or str(exc)) from None
        _HELD[key] = [fd, 1]
        self._key = key
        return self

    def release(self) -> None:
        """Let the lock go (the last holder in this process removes the lock file)."""
        if self._key is None:
            return
        entry = _HELD[self._key]
        entry[1] -= 1
        if entry[1] == 0:
            del _HELD[self._key]
            try:
                os.unlink(self.lock_path)
            except FileNotFoundError:  # pragma: no cover
                pass
            os.close(entry[0])  # closing releases the flock
        self._key = None

    @staticmethod
    def holder(path) -> int | None:
        """The process id holding the lock on ``path``, or None when it is free."""
        import fcntl

        path = Path(path)
        lock_path = path.with_name(f".{path.name}.lock")
        try:
            fd = os.open(lock_path, os.O_RDONLY | os.O_NOFOLLOW)
        except OSError:
            return None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except OSError:
                text = os.pread(fd, 32, 0).decode(errors="replace").strip()
                return int(text) if text.isdigit() else -1
            fcntl.flock(fd, fcntl.LOCK_UN)
            return None
        finally:
            os.close(fd)

    def __enter__(self) -> FileLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()

    def __del__(self):  # a forgotten release
        try:
            self.release()
        except Exception:  # pragma: no cover - interpreter shutting down
            pass
