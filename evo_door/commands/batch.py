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

import itertools
import re
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


# -- the command ------------------------------------------------------------------------
def run(args) -> int:
    from datetime import datetime

    from evo_door.errors import UserError
    from evo_door.experiment import load_experiment
    from evo_door.experiment.pipeline import is_pipeline
    from evo_door.optim.executors import open_executor, preflight

    executor = open_executor(preflight(args.executor or "local"))
    out_dir = Path(args.out or f"results/batch-{datetime.now():%Y%m%d-%H%M%S}")
    tasks = plan(args.experiments, args.assignments, out_dir)
    rows = {t["name"]: {"status": "not started"} for t in tasks}
    runnable = []
    for task in tasks:  # what can be checked here fails here, without a worker
        try:
            if is_pipeline(task["path"]):
                raise UserError(f"{task['path']}: a pipeline; run it with evo-door run")
            load_experiment(task["path"], task["overrides"])
            runnable.append(task)
        except UserError as exc:
            rows[task["name"]] = {"status": "failed", "error": _one_line(exc)}
    if runnable:
        out_dir.mkdir(parents=True, exist_ok=True)
    quiet = args.quiet
    if not quiet:
        print(
            f"batch: {len(tasks)} experiment(s) on executor {executor.name}; results in {out_dir}/",
            flush=True,
        )
    bar = _bar(len(tasks), show_progress(args))
    failed = sum(r["status"] == "failed" for r in rows.values())
    bar.update(failed)
    bar.set_postfix_str(f"failed {failed}")
    t0 = time.perf_counter()
    interrupted = False
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
        interrupted = True
        interrupt = getattr(executor, "interrupt", None)
        if interrupt is not None:
            try:
                interrupt()
            except KeyboardInterrupt:  # a second Ctrl-C: stop waiting
                pass
    finally:
        bar.close()
    for task in tasks:
        row = rows[task["name"]]
        row["file"] = task["out"] if Path(task["out"]).exists() else ""
        if interrupted and row["status"] == "not started" and row["file"]:
            row["status"] = "interrupted"
    if not quiet:
        print(format_summary(tasks, rows))
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


def _bar(total: int, show: bool):
    from tqdm import tqdm

    return tqdm(total=total, unit="exp", desc="batch", file=sys.stderr, disable=not show)


def _one_line(error) -> str:
    from evo_door.cli import error_line
    from evo_door.errors import UserError

    text = str(error) if isinstance(error, UserError) else f"{type(error).__name__}: {error}"
    return error_line(text)[len("evo-door: error: ") :]


def format_summary(tasks: list[dict], rows: dict) -> str:
    """The summary table: experiment, status, best fitness, parameters, time, file
    (a failed experiment's error under its row)."""
    from evo_door.experiment.format_text import text_table

    body, errors = [], []
    for task in tasks:
        r = rows[task["name"]]
        seconds = f"{r['seconds']:.1f}" if "seconds" in r else ""
        body.append(
            [
                task["name"],
                r["status"],
                r.get("fitness", ""),
                r.get("params", ""),
                seconds,
                r.get("file", ""),
            ]
        )
        if r.get("error"):
            errors.append(f"  {task['name']}: {r['error']}")
    header = ["experiment", "status", "best fitness", "best parameters", "time (s)", "file"]
    lines = text_table(header, body)
    if errors:
        lines += ["failed:", *errors]
    return "\n".join(lines)
