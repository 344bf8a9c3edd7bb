"""A run's checkpoint written, and what its results file keeps when the disk refuses it.

A run (and a pipeline) rewrites its whole results file after every generation
(:func:`write_checkpoint`, atomically). When the file system refuses one (a full disk,
a quota, a folder made read-only meanwhile), the file on disk is the previous
checkpoint, whole: the error says where that one stands (:func:`position`, recorded
after every write) and that ``evo-door resume`` continues from it, ending as an
uninterrupted run would. A run that never got its first checkpoint on disk wrote
nothing, and says so.
"""

from __future__ import annotations

from evo_door.errors import WriteError
from evo_door.experiment import store
from evo_door.files import write_h5


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
