"""A run's checkpoint written, and what its results file keeps when the disk refuses it.

A run (and a pipeline) rewrites its whole results file at each checkpoint
(:func:`write_checkpoint`, atomically): after a generation once the last write is
:data:`CHECKPOINT_EVERY` seconds old, after every job, and when Ctrl-C or SIGTERM
(:class:`TermAsInterrupt`) stops it. When the file system refuses one (a full disk,
a quota, a folder made read-only meanwhile), the file on disk is the previous
checkpoint, whole: the error says where that one stands (:func:`position`, recorded
after every write) and that ``evo-door resume`` continues from it, ending as an
uninterrupted run would. A run that never got its first checkpoint on disk wrote
nothing, and says so.
"""

from __future__ import annotations

import signal

from evo_door.errors import WriteError
from evo_door.experiment import store
from evo_door.files import write_h5

#: Least seconds between two of a GA's checkpoints: a generation ending sooner after the
#: last write is not written (a results file is rewritten whole, its checksums too). The
#: end of a job, Ctrl-C, SIGTERM and a checkpoint hook always write, so a kill loses at
#: most this much of the GA's work, which a resume repeats exactly.
CHECKPOINT_EVERY = 5.0


class TermAsInterrupt:
    """While a run runs, SIGTERM stops it as Ctrl-C does, at the next checkpoint.

    A batch system's time limit or a plain ``kill`` sends SIGTERM; the handler only
    notes it (an exception raised inside a signal handler can land in a place that
    swallows it, such as a weakref callback), and the run raises KeyboardInterrupt once
    the current generation is on disk. A second SIGTERM gets the previous handler (by
    default: die at once; the last checkpoint is whole either way).
    """

    def __init__(self):
        self.requested = False
        self._previous = None

    def __enter__(self) -> TermAsInterrupt:
        try:
            self._previous = signal.signal(signal.SIGTERM, self._handle)
        except ValueError:  # not the main thread: signals are not ours to take
            self._previous = None
        return self

    def _handle(self, signum, frame) -> None:
        self.requested = True
        signal.signal(signal.SIGTERM, self._previous or signal.SIG_DFL)

    def __exit__(self, *exc) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGTERM, self._previous)


def write_checkpoint(path, tree: dict, on_disk: str | None) -> None:
    """Write ``tree`` as the results file ``path``; ``on_disk`` is where the checkpoint
    already in ``path`` stands (:func:`position`), None if there is none of this run.

    A refused write is a :class:`~evo_door.errors.WriteError` that says, beside the
    file and the reason, that this last checkpoint is kept and how to resume from it.
    """
    try:
        write_h5(path, tree, compression=store.COMPRESSION, make_folder=True)
    except WriteError as exc:
        if on_disk is None:
            raise
        raise exc.leaving(
            f"the last checkpoint ({on_disk}) is kept: resume with `evo-door resume {path}`"
        ) from None


def finished(jobs) -> frozenset[int]:
    """The indices of the finished ones among ``jobs`` (what a checkpoint written now
    holds finished: :func:`evo_door.experiment.store.run_tree` copies them after)."""
    return frozenset(k for k, job in enumerate(jobs) if job.done)


def position(jobs) -> str:
    """Where a run of ``jobs`` stands, in words: ``generation 12``, ``job t3, the
    start``, ``every fit done`` (what a checkpoint written now holds)."""
    pending = [j for j in jobs if not j.done]
    if not pending:
        return "every fit done"
    job = pending[0]
    where = "the start" if job.ga is None else f"generation {job.ga.generation}"
    return f"job {job.name}, {where}" if len(jobs) > 1 else where


def stage_position(stages: list[str], done: list[str], current) -> str:
    """Where a pipeline stands: ``stage fit, generation 3``, ``1 of 2 stages done``
    (``current``: the run of the stage under way, or None)."""
    if current is not None:
        stage = next(name for name in stages if name not in done)
        return f"stage {stage}, {position(current.jobs)}"
    return f"{len(done)} of {len(stages)} stages done"
