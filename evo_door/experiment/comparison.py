"""The same estimation under each objective: max-square or ISE, on derivative 0, 1 or 2.


The seed (section 5.1) says of eq. 5.3 (max-square) and eq. 5.4 (ISE) only that
"sometimes one works better than the other". :func:`plan_comparison` turns one
experiment into a grid of runs, one per objective kind x derivative x GA seed, all
else (model, free parameters and bounds, target, preprocessing, algorithm) as the file
says; :func:`run_comparison` runs them, each into a normal results file of one folder
(so ``evo-door show``, ``runs`` and ``compare`` work on each). Reading the runs back into
one row per (kind, derivative) is :mod:`.comparison_summary`; the tables and the figure
(``compare.csv``, ``compare.md``, ``compare.png``, ``runs.csv``) are
:mod:`evo_door.reporting.comparison_outputs`; the common yardstick every run is scored on is
:func:`evo_door.experiment.objectives.yardstick`.

The library call behind ``evo-door compare-objectives``::

    from evo_door.experiment.comparison import plan_comparison, run_comparison
    from evo_door.reporting.comparison_outputs import write_outputs
    from evo_door.experiment.comparison_summary import run_records, summarise

    comp = plan_comparison("experiments/default.yaml", seeds=3)
    run_comparison(comp, progress=True)
    records = run_records(comp)
    rows = summarise(records)
    write_outputs(comp, records, rows)
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from evo_door.channels import RESPONSE_CHANNELS
from evo_door.errors import MissingChannelError, UserError, WriteError
from evo_door.experiment.config import ExperimentConfig, load_experiment
from evo_door.experiment.objectives import DERIVATIVES, KINDS
from evo_door.experiment.results import Results
from evo_door.experiment.runner import ExperimentRun
from evo_door.experiment.yamltree import flatten
from evo_door.files import folder_reason
from evo_door.params.declaration import suggest


# -- options ---------------------------------------------------------------------------
def _items(text: str, option: str, example: str) -> list[str]:
    items = [s.strip() for s in str(text).split(",")]
    if not all(items):
        raise UserError(
            f"{option} {text!r}: expected a comma-separated list, e.g. {option} {example}"
        )
    return items


def parse_kinds(text: str) -> list[str]:
    """``--kinds max_square,ise`` -> ``["max_square", "ise"]`` (``max-square`` accepted).

    >>> parse_kinds("ise, max-square")
    ['ise', 'max_square']
    """
    out = []
    for item in _items(text, "--kinds", "max_square,ise"):
        kind = item.lower().replace("-", "_")
        if kind not in KINDS:
            raise UserError(
                f"--kinds {text}: {item!r} is not an objective kind"
                + suggest(kind, KINDS)
                + f"; kinds: {', '.join(KINDS)}"
            )
        if kind not in out:
            out.append(kind)
    return out


def parse_derivatives(text: str) -> list[int]:
    """``--derivatives 0,1,2`` -> ``[0, 1, 2]``; anything but 0, 1, 2 is refused.

    >>> parse_derivatives("1,0")
    [1, 0]
    """
    out = []
    for item in _items(text, "--derivatives", "0,1,2"):
        if item not in ("0", "1", "2"):
            raise UserError(
                f"--derivatives {text}: {item!r} is not a derivative: 0 (angle theta), "
                "1 (angular speed dtheta) or 2 (angular acceleration ddtheta)"
            )
        if int(item) not in out:
            out.append(int(item))
    return out


def parse_seeds(text) -> int:
    """``--seeds N``: a whole number of GA seeds, at least 1.

    >>> parse_seeds("3")
    3
    """
    try:
        n = int(str(text).strip())
    except ValueError:
        raise UserError(f"--seeds {text}: expected a whole number of GA seeds, e.g. 3") from None
    if not 1 <= n <= MAX_SEEDS:
        raise UserError(
            f"--seeds {n}: from 1 to {MAX_SEEDS} (the GA seeds are the experiment's "
            "algorithm.seed + 0 .. N-1, a results file each)"
        )
    return n


#: the most GA seeds a comparison runs (each a GA run and a results file per objective)
MAX_SEEDS = 100


# -- the plan --------------------------------------------------------------------------
@dataclass(frozen=True)
class Variant:
    """One run of a comparison: objective kind, derivative, GA seed."""

    kind: str
    derivative: int
    seed: int

    @property
    def channel(self) -> str:
        return RESPONSE_CHANNELS[self.derivative]

    @property
    def overrides(self) -> list[str]:
        """The ``--set`` assignments that make the experiment this variant."""
        return [
            f"objective.kind={self.kind}",
            f"objective.derivative={self.derivative}",
            f"algorithm.seed={self.seed}",
        ]

    def file_name(self, name: str) -> str:
        return f"{name}-{self.kind}-d{self.derivative}-s{self.seed}.h5"


@dataclass
class Comparison:
    """A checked plan: the runs to make and where (see :func:`plan_comparison`)."""

    source: str
    overrides: list
    name: str
    folder: Path
    kinds: list
    derivatives: list
    seeds: list
    #: derivatives left out because the trials lack their channel: derivative -> why
    skipped: dict = field(default_factory=dict)
    experiments: dict = field(default_factory=dict)  # Variant -> ExperimentConfig
    #: with ``resume``: complete runs already in the folder, kept as they are
    kept: set = field(default_factory=set)
    force: bool = False
    resume: bool = False

    @property
    def variants(self) -> list[Variant]:
        return [Variant(k, d, s) for k in self.kinds for d in self.derivatives for s in self.seeds]

    def path(self, variant: Variant) -> Path:
        return self.folder / variant.file_name(self.name)

    def notes(self) -> list[str]:
        return [
            f"derivative {d} ({RESPONSE_CHANNELS[d]}) left out: {why}"
            for d, why in self.skipped.items()
        ]


def default_folder(exp: ExperimentConfig) -> Path:
    """``<output>/<name>-objectives-<YYYYmmdd-HHMMSS>/``, not an existing one."""
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    base = Path(exp.output) / f"{exp.name}-objectives-{stamp}"
    folder, k = base, 1
    while folder.exists():
        k += 1
        folder = Path(f"{base}-{k}")
    return folder


def _check_folder(folder: Path) -> None:
    """The output folder can be made (or is there) and written in, else one line."""
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{folder}: is a file, not a folder; give --out a folder")
    existing = folder
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise UserError(f"{folder}: {existing} is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise WriteError(folder, folder_reason(existing))


def _provenance(key: str) -> bool:
    """Whether a flattened configuration key only says where a setting came from."""
    return key.startswith("perception_sources.") or (
        key.startswith("process.entries.") and key.endswith(".source")
    )


def _same_settings(path: Path, exp: ExperimentConfig) -> None:
    """A run kept by ``resume`` must have been made from the very same settings."""
    res = Results(path)
    old, new = flatten(res.config), flatten(exp.resolved())
    # the JNDs' and the tolerances' sources are provenance (a file moved, a line added):
    # their values count
    old = {k: v for k, v in old.items() if not _provenance(k)}
    new = {k: v for k, v in new.items() if not _provenance(k)}
    differ = [
        k for k in dict.fromkeys([*old, *new]) if json.dumps(old.get(k)) != json.dumps(new.get(k))
    ]
    if differ:
        key = differ[0]
        raise UserError(
            f"{path}: made with other settings ({key}: {old.get(key)!r}, now {new.get(key)!r}); "
            "give --force to run it again, or another --out"
        )


def plan_comparison(
    experiment,
    overrides=(),
    kinds=KINDS,
    derivatives=None,
    seeds: int = 1,
    out=None,
    force: bool = False,
    resume: bool = False,
    loader=None,
) -> Comparison:
    """Check everything a comparison needs before anything runs or is written.

    Parameters
    ----------
    experiment : str or Path
        The experiment file; ``overrides`` are its ``--set`` assignments.
    kinds : list of str
        Objective kinds (``max_square``, ``ise``).
    derivatives : list of int or None
        Derivatives compared. None: every derivative whose channel every fitted and
        validation trial carries, the others left out with a note
        (:attr:`Comparison.skipped`); a derivative asked for by name that the trials
        cannot serve is an error.
    seeds : int
        Number of GA seeds: the experiment's ``algorithm.seed`` + 0 .. seeds - 1.
    out : folder
        Where the runs and tables go (default :func:`default_folder`).
    force, resume :
        What to do with runs already in ``out``: replace them, or keep the complete
        ones made from the same settings and continue an interrupted one. Without
        either, a folder that already holds a run of the plan is refused.
    loader : callable, optional
        ``loader(overrides) -> ExperimentConfig`` in place of reading ``experiment`` as an
        experiment file (a pipeline's stage: :func:`evo_door.experiment.pipeline.stage_loader`).
    """
    if loader is None:

        def loader(assignments):
            return load_experiment(experiment, assignments)

    overrides = list(overrides)
    kinds, derivatives = _checked_choices(kinds, derivatives, seeds)
    base = loader(overrides)
    seed0 = base.algorithm.ga.seed
    folder = Path(out) if out is not None else default_folder(base)
    _check_folder(folder)
    comp = Comparison(
        source=str(experiment),
        overrides=overrides,
        name=base.name,
        folder=folder,
        kinds=kinds,
        derivatives=[],
        seeds=[seed0 + k for k in range(seeds)],
        force=force,
        resume=resume,
    )

    def variant_experiment(v: Variant) -> ExperimentConfig:
        return loader(overrides + v.overrides)

    comp.derivatives, comp.skipped = _served_derivatives(
        variant_experiment, Variant(kinds[0], 0, seed0), folder, derivatives
    )
    for v in comp.variants:
        comp.experiments[v] = variant_experiment(v)
    _check_runs_there(comp)
    return comp


def _checked_choices(kinds, derivatives, seeds) -> tuple[list, list | None]:
    """The objective kinds and derivatives asked for as lists, each checked, and the
    number of seeds checked."""
    kinds = list(kinds)
    for kind in kinds:
        if kind not in KINDS:
            raise UserError(
                f"objective kind {kind!r} is not one of {', '.join(KINDS)}" + suggest(kind, KINDS)
            )
    if derivatives is not None:
        derivatives = list(derivatives)
        if not derivatives or any(d not in DERIVATIVES for d in derivatives):
            raise UserError(f"derivatives {derivatives}: each is 0, 1 or 2")
    if not kinds:
        raise UserError("no objective kind to compare")
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise UserError(f"seeds {seeds!r}: at least 1")
    return kinds, derivatives


def _served_derivatives(
    variant_experiment, first: Variant, folder: Path, derivatives
) -> tuple[list, dict]:
    """The derivatives compared, and those left out with the reason (the channel the
    trials lack); ``derivatives`` None: every one the trials serve.

    The data are read and checked once per derivative as a run would (nothing is
    written), with ``first``'s kind and seed. Only the channel check depends on the
    derivative, so one that fails while another passes lacks its channel.
    """
    failed: dict[int, UserError] = {}
    why: dict[int, str] = {}
    for d in DERIVATIVES:
        exp = variant_experiment(Variant(first.kind, d, first.seed))
        try:
            ExperimentRun.new(exp, folder / "x.h5")
        except MissingChannelError as exc:
            failed[d] = exc
            # the channel is missing: said without the file's objective line, which
            # the comparison overrides
            why[d] = exc.reason
        except UserError as exc:
            failed[d] = exc
            why[d] = str(exc)
    wanted = list(DERIVATIVES) if derivatives is None else derivatives
    available = [d for d in DERIVATIVES if d not in failed]
    if not available:  # not a matter of channels: the experiment cannot run at all
        raise failed[wanted[0]]
    why = {d: text for d, text in why.items() if d in wanted}
    if derivatives is not None and why:
        d = next(d for d in wanted if d in why)
        raise UserError(
            f"--derivatives {d}: {why[d]}; these trials allow --derivatives "
            + ",".join(map(str, available))
        )
    return [d for d in wanted if d not in failed], why


def _check_runs_there(comp: Comparison) -> None:
    """Runs already in the folder: replaced (force), kept or continued (resume), or
    refused; with resume, the complete ones made from the same settings are kept."""
    there = [v for v in comp.variants if comp.path(v).exists()]
    if there and not (comp.force or comp.resume):
        first = comp.path(there[0])
        more = f" and {len(there) - 1} more run(s) of this comparison" if len(there) > 1 else ""
        raise UserError(
            f"{comp.folder}: already holds {first.name}{more}; give another --out, --force to "
            "replace them, or --resume to keep the complete ones and run the rest"
        )
    if comp.resume and not comp.force:
        for v in there:
            _same_settings(comp.path(v), comp.experiments[v])
            if Results(comp.path(v)).complete:
                comp.kept.add(v)


# -- running ---------------------------------------------------------------------------
def make_folder(comp: Comparison) -> None:
    """The comparison's folder, made if need be (one line if the system refuses)."""
    try:
        comp.folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{comp.folder}: cannot make the folder ({exc.strerror or exc})") from None


def run_comparison(comp: Comparison, progress: bool = False, on_run=None) -> list[Path]:
    """Make every run of ``comp`` (kept ones excepted); return the results files.

    ``progress`` shows a header line and the run's progress bar on stderr per run;
    ``on_run(variant, path)`` is called after each run is complete. Ctrl-C leaves the
    run at work resumable (``evo-door resume FILE``, or the comparison with ``resume``).
    """
    variants = comp.variants
    paths = []
    make_folder(comp)
    for i, v in enumerate(variants, 1):
        path = comp.path(v)
        head = f"[{i}/{len(variants)}] {v.kind} on {v.channel}, seed {v.seed}"
        if v in comp.kept:
            if progress:
                print(f"{head}: kept {path} (complete)", file=sys.stderr, flush=True)
        else:
            if comp.resume and not comp.force and path.exists():
                run = ExperimentRun.open(path)
                what = "continuing"
            else:
                run = ExperimentRun.create(comp.experiments[v], path, overwrite=comp.force)
                what = "writing"
            if progress:
                print(f"{head}: {what} {path}", file=sys.stderr, flush=True)
            run.label_prefix = f"[{i}/{len(variants)}] "
            run.run(progress=progress)
        paths.append(path)
        if on_run is not None:
            on_run(v, path)
    return paths
