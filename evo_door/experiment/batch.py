"""Batches: many experiments side by side, one task each on an executor.

The library half of ``evo-door batch`` (:mod:`evo_door.commands.batch` is its command
line): the sweeps of ``--set`` lists (:func:`expand_sweeps`), the tasks with their
results files (:func:`plan`) and one task as a worker runs it (:func:`run_task`); the
summary table is :func:`evo_door.reporting.format_tables.format_batch`.

:func:`run_task` is what an executor ships to its workers (pickled by name), so it lives
in this layer: a worker imports the experiment layer and what lies below it, never the
command line.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path


# -- sweeps -------------------------------------------------------------------------
def split_values(text: str) -> list[str]:
    """The values of a ``--set`` value: split at commas outside brackets and quotes.

    >>> split_values("1,2,3")
    ['1', '2', '3']
    >>> split_values("[0.3, 2.5],[0.5, 3.0]")
    ['[0.3, 2.5]', '[0.5, 3.0]']
    >>> split_values("'a,b'")
    ["'a,b'"]
    """
    out, depth, quote, start = [], 0, None, 0
    for i, ch in enumerate(text):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{(":
            depth += 1
        elif ch in "]})":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(text[start:i].strip())
            start = i + 1
    out.append(text[start:].strip())
    return out


def expand_sweeps(assignments) -> list[tuple[str, list[str]]]:
    """Every combination of the ``--set`` lists: ``(suffix, assignments)`` per
    experiment, the suffix naming the swept values (empty without a sweep).

    >>> for suffix, sets in expand_sweeps(["algorithm.seed=1,2", "algorithm.population=20"]):
    ...     print(suffix, sets)
    seed1 ['algorithm.seed=1', 'algorithm.population=20']
    seed2 ['algorithm.seed=2', 'algorithm.population=20']
    """
    from evo_door.errors import UserError

    axes = []
    for item in assignments:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UserError(f"--set {item!r}: expected KEY.PATH=VALUE (or V1,V2,... for a sweep)")
        values = split_values(value)
        if any(not v for v in values):
            raise UserError(f"--set {item!r}: an empty value in the list")
        axes.append([(key.strip(), v, len(values) > 1) for v in values])
    out = []
    for combo in itertools.product(*axes):
        suffix = "-".join(f"{k.split('.')[-1]}{_slug(v)}" for k, v, swept in combo if swept)
        out.append((suffix, [f"{k}={v}" for k, v, _ in combo]))
    return out


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.]+", "_", text).strip("_")


def plan(experiments, assignments, out_dir: Path) -> list[dict]:
    """The batch's tasks: one per experiment file and sweep combination, each with its
    name and results file in ``out_dir`` (absolute paths: workers may run elsewhere)."""
    tasks, used = [], set()
    for path in experiments:
        stem = Path(path).stem
        for suffix, overrides in expand_sweeps(assignments):
            name = f"{stem}-{suffix}" if suffix else stem
            base, k = name, 1
            while name in used:
                k += 1
                name = f"{base}-{k}"
            used.add(name)
            tasks.append(
                {
                    "name": name,
                    "path": str(Path(path).resolve()),
                    "overrides": overrides,
                    "out": str((out_dir / f"{name}.h5").resolve()),
                }
            )
    return tasks


# -- one task (runs in a worker) ----------------------------------------------------------
def run_task(task: dict) -> dict:
    """Run (or continue, or read back) one experiment of a batch; its summary row."""
    from evo_door.errors import UserError
    from evo_door.experiment import load_experiment
    from evo_door.experiment.runner import ExperimentRun

    exp = load_experiment(task["path"], task["overrides"])
    exp.executor = "local"  # the batch is the parallelism: one experiment per task
    out = Path(task["out"])
    if out.exists():  # run before (a worker died, or the batch was stopped): go on
        run = ExperimentRun.open(out)
        if run.experiment["text"] != exp.text or list(run.experiment["overrides"]) != list(
            exp.overrides
        ):
            run.release()
            raise UserError(f"{out}: holds another experiment's run; give another --out")
        if run.status != "complete":
            run.run(executor="local")
    else:
        run = ExperimentRun.create(exp, out)
        run.run()
    return _summary(run)


def _summary(run) -> dict:
    """A finished run's row of the summary table, read from its file."""
    from evo_door.experiment import Results
    from evo_door.files import ATTRS

    res = Results(run.path)
    units = res.units()
    return {
        "status": "complete",
        "fitness": f"{res.fitness():.4g} {res.fitness_unit}",
        "params": ", ".join(
            f"{n} = {v:.4g} {units.get(n, '')}".rstrip() for n, v in res.best().items()
        ),
        "seconds": float(res.tree["timings"][ATTRS].get("total_s", 0.0)),
    }
