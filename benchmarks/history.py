"""The headline figures of every committed suite page, before and after, in one table.

``benchmarks/suite.md`` holds the latest full run of ``python -m benchmarks``; each
earlier run is in git, as the page committed then. This reads every version of that
page from the history of this checkout (``git log`` and ``git show``, nothing measured
here) and writes ``benchmarks/history.md``: for each, when it was measured and at which
commit, the GA 100 x 20 on one 5 s trial (door and haptic) with its ratio to the plain
scipy + DEAP loop of the same run, the door's smooth 5 s trial, the main job in a fresh
process and a cold ``evo-door compile``, where the page measured them, and the host
probe at the run's start and end (the host's speed at the hour: the same work takes
markedly longer in a slow hour of a shared machine). Each row is what that page
says, on the machine it names: rerun the suite at a row's commit to measure it again.

    python -m benchmarks.history            # print the table
    python -m benchmarks.history --write    # and write benchmarks/history.md
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
PAGE = "benchmarks/suite.md"
OUT = HERE / "history.md"

_MEASURED = re.compile(r"Measured (\d{4}-\d\d-\d\d \d\d:\d\d)[^\n]*?Commit ([0-9a-f]{7,40})")
_MACHINE = re.compile(r"^Machine: ([^,]+), (\d+ CPUs[^,]*)", re.M)
# a row of the GA section's table: model | time | evaluations | plain | per eval | on | ratio
_GA = r"^\| {model} \| ([^|]+?) \| \d+ \| [^|]+ \| [^|]+ \| [^|]+ \| ([^|]+?) \|$"
_SMOOTH = re.compile(r"^\| door smooth: default [^|]*?: <= [^|]+ \| ([^|]+?) \|", re.M)
_MAIN_JOB = re.compile(r"experiments/case_study\.yaml` in a fresh process: \*\*([^*]+)\*\*")
_COMPILE = re.compile(r"^\| `evo-door compile` \(every kernel\), cold \| ([^|]+?) \|", re.M)
_PROBE = re.compile(r"Host probe \([^)]*\): (\d+\.\d+) s(?: at the start and (\d+\.\d+) s)?")


@dataclass
class Page:
    """What one version of the suite page says (None: the page did not measure it)."""

    measured: str
    commit: str
    machine: str
    ga_door: tuple[str, str] | None
    ga_haptic: tuple[str, str] | None
    smooth_door: str | None
    main_job: str | None
    cold_compile: str | None
    probe: str | None = None


def _ga(text: str, model: str) -> tuple[str, str] | None:
    found = re.search(_GA.format(model=model), text, re.M)
    return (found.group(1).strip(), found.group(2).strip()) if found else None


def _first(pattern: re.Pattern, text: str) -> str | None:
    found = pattern.search(text)
    return found.group(1).strip() if found else None


def parse(text: str) -> Page | None:
    """The figures of one suite page's text; None for a text that is not one (no
    measured date and commit)."""
    measured = _MEASURED.search(text)
    if measured is None:
        return None
    machine = _MACHINE.search(text)
    return Page(
        measured=measured.group(1),
        commit=measured.group(2)[:7],
        machine=f"{machine.group(1)}, {machine.group(2)}" if machine else "",
        ga_door=_ga(text, "door"),
        ga_haptic=_ga(text, "haptic"),
        smooth_door=_first(_SMOOTH, text),
        main_job=_first(_MAIN_JOB, text),
        cold_compile=_first(_COMPILE, text),
        probe=_probe(text),
    )


def _probe(text: str) -> str | None:
    """The host probe's times as the page gives them, start and end ("0.35 / 0.38 s")."""
    found = _PROBE.search(text)
    if found is None:
        return None
    return " / ".join(t for t in found.groups() if t) + " s"


def _git(*args: str) -> str:
    done = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"benchmarks.history: git {' '.join(args)}: {done.stderr.strip()}")
    return done.stdout


def pages() -> list[Page]:
    """Every committed version of the suite page that parses, oldest first (a run
    committed twice is listed once)."""
    out: list[Page] = []
    for commit in reversed(_git("log", "--format=%H", "--", PAGE).split()):
        page = parse(_git("show", f"{commit}:{PAGE}"))
        if page is not None and not any(p.commit == page.commit for p in out):
            out.append(page)
    return out


def _cell(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, tuple):
        return f"{value[0]} ({value[1]})"
    return value


def table(found: list[Page]) -> str:
    """The markdown page: a row a committed suite page."""
    lines = [
        "# Earlier suite pages (`python -m benchmarks.history`)",
        "",
        "Every committed version of `benchmarks/suite.md`, read from git: when it was "
        "measured, the commit it measured, and its headline figures as it printed them. "
        "GA: the suite's GA 100 x 20 on one 5 s trial (its `ga` section), and in brackets "
        "how many times faster it was than the plain scipy + DEAP loop of the same run "
        "(the haptic rows run the seed's tanh friction). The smooth trial: the door "
        "pushed from open, 5 s at 1024 Hz, at the default integrator. Main job: "
        "`evo-door run experiments/case_study.yaml` in a fresh process, warm. Cold "
        "compile: `evo-door compile` on an empty numba cache. Each row was measured on "
        "the machine it names, at its own load (its page says it); '-' where the page "
        "did not measure it. Host probe: the seconds of a fixed plain Python loop "
        "(`benchmarks/probe.py`) at the run's start and end, the host's speed at that "
        "hour: compare rows by it before reading a change as the code's. Rerun "
        "`python -m benchmarks` at a row's commit to measure it again.",
        "",
        "| measured | commit | GA door | GA haptic | door smooth trial | main job | "
        "cold compile | host probe | machine |",
        "|---|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for p in found:
        cells = (p.ga_door, p.ga_haptic, p.smooth_door, p.main_job, p.cold_compile, p.probe)
        lines.append(
            f"| {p.measured} | {p.commit} | "
            + " | ".join(_cell(c) for c in cells)
            + f" | {p.machine} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.history", description=__doc__)
    ap.add_argument("--write", action="store_true", help=f"write {OUT.relative_to(ROOT)}")
    args = ap.parse_args(argv)
    text = table(pages())
    print(text, end="")
    if args.write:
        OUT.write_text(text, encoding="utf-8")
        print(f"wrote {OUT}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
