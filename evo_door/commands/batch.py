"""``evo-door batch EXP.yaml ...``: many experiments side by side, one results file each.

Each experiment is one task on the executor (``--executor``; ``local`` runs them one
after the other in this process), its GA on the compiled batch of the worker that runs
it. ``--set KEY=V1,V2`` makes a sweep: one experiment per value (several lists: every
combination). A failed experiment never stops the others; the summary table gives its
one-line error, and the exit status is 1 when any failed.

A task whose worker died is run again and goes on from its results file's last
checkpoint; so does a batch run again with the same ``--out`` (finished experiments are
only read back), which is how a batch stopped by Ctrl-C is continued.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from evo_door.commands._common import add_progress_arguments, show_progress
from evo_door.commands.run import add_executor_argument

ORDER = 42


def register(sub) -> None:
    p = sub.add_parser(
        "batch",
        help="run many experiments (or a --set sweep) in parallel, one results file each",
        description="Run many experiments side by side on an executor, each to its own "
        "results file in --out, with one progress display and a summary table. A failed "
        "experiment does not stop the others. Exit status: 0 if every experiment "
        "finished, 1 if any failed, 2 for a usage error, 130 when interrupted (finished "
        "files are complete; run the same command with the same --out to continue).",
    )
    p.add_argument("experiments", metavar="EXP.yaml", nargs="+", help="experiment files")
    add_executor_argument(
        p,
        "where the experiments run, one task each: local (default: one after the other "
        "in this process), processes[:N], dask[:N] or tcp://HOST:PORT (a Dask scheduler)",
    )
    p.add_argument(
        "--out",
        metavar="DIR",
        help="folder of the results files (default: results/batch-<date>-<time>/)",
    )
    p.add_argument(
        "--set",
        metavar="KEY.PATH=V1,V2,...",
        action="append",
        default=[],
        dest="assignments",
        help="override a setting of every experiment; a comma list makes a sweep, one "
        "experiment per value (several lists: every combination); repeatable",
    )
    add_progress_arguments(p)
    p.set_defaults(func=run)


# -- the command ------------------------------------------------------------------------
def run(args) -> int:
    from datetime import datetime

    from evo_door.experiment.batch import plan
    from evo_door.optim.executors import open_executor, preflight
    from evo_door.reporting.format_tables import format_batch

    executor = open_executor(preflight(args.executor or "local"))
    out_dir = Path(args.out or f"results/batch-{datetime.now():%Y%m%d-%H%M%S}")
    tasks = plan(args.experiments, args.assignments, out_dir)
    rows = {t["name"]: {"status": "not started"} for t in tasks}
    runnable = _check(tasks, rows)
    if runnable:
        out_dir.mkdir(parents=True, exist_ok=True)
    if not args.quiet:
        print(
            f"batch: {len(tasks)} experiment(s) on executor {executor.name}; results in {out_dir}/",
            flush=True,
        )
    t0 = time.perf_counter()
    interrupted = _execute(executor, runnable, rows, len(tasks), show_progress(args))
    for task in tasks:
        row = rows[task["name"]]
        row["file"] = task["out"] if Path(task["out"]).exists() else ""
        if interrupted and row["status"] == "not started" and row["file"]:
            row["status"] = "interrupted"
    failed = sum(r["status"] == "failed" for r in rows.values())
    if not args.quiet:
        print(format_batch(tasks, rows))
        print(f"{len(tasks)} experiment(s), {failed} failed, {time.perf_counter() - t0:.1f} s")
    if interrupted:
        left = [
            t["name"] for t in tasks if rows[t["name"]]["status"] in ("not started", "interrupted")
        ]
        print(
            f"evo-door: interrupted; not finished: {', '.join(left) or 'none'}; the same "
            f"command with --out {out_dir} continues them",
            file=sys.stderr,
        )
        return 130
    return 1 if failed else 0


def _check(tasks: list[dict], rows: dict) -> list[dict]:
    """The tasks that load; the others' rows say why (what can be checked here fails
    here, without a worker)."""
    from evo_door.errors import UserError
    from evo_door.experiment import load_experiment
    from evo_door.experiment.pipeline import is_pipeline

    runnable = []
    for task in tasks:
        try:
            if is_pipeline(task["path"]):
                raise UserError(f"{task['path']}: a pipeline; run it with evo-door run")
            load_experiment(task["path"], task["overrides"])
            runnable.append(task)
        except UserError as exc:
            rows[task["name"]] = {"status": "failed", "error": _one_line(exc)}
    return runnable


def _execute(executor, runnable: list[dict], rows: dict, total: int, show: bool) -> bool:
    """Run the tasks on the executor, each one's row filled as it ends, under one
    progress bar; whether Ctrl-C stopped the batch."""
    from evo_door.experiment.batch import run_task

    bar = _bar(total, show)
    failed = sum(r["status"] == "failed" for r in rows.values())
    bar.update(failed)
    bar.set_postfix_str(f"failed {failed}")
    try:
        with executor:
            for i, result, error in executor.imap(run_task, runnable):
                name = runnable[i]["name"]
                if error is None:
                    rows[name] = result
                else:
                    failed += 1
                    rows[name] = {"status": "failed", "error": _one_line(error)}
                bar.update(1)
                bar.set_postfix_str(f"failed {failed}")
    except KeyboardInterrupt:
        interrupt = getattr(executor, "interrupt", None)
        if interrupt is not None:
            try:
                interrupt()
            except KeyboardInterrupt:  # a second Ctrl-C: stop waiting
                pass
        return True
    finally:
        bar.close()
    return False


def _bar(total: int, show: bool):
    from tqdm import tqdm

    return tqdm(total=total, unit="exp", desc="batch", file=sys.stderr, disable=not show)


def _one_line(error) -> str:
    from evo_door.errors import PREFIX, UserError, error_line

    text = str(error) if isinstance(error, UserError) else f"{type(error).__name__}: {error}"
    return error_line(text)[len(PREFIX) :]
