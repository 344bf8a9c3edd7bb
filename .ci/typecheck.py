"""The type check of the library against its baseline, which only shrinks.

    python .ci/typecheck.py            # CI and `tox -e typecheck`
    python .ci/typecheck.py --shrink   # after fixing errors: drop them from the baseline

mypy checks ``evo_door`` as ``[tool.mypy]`` in pyproject.toml says. The errors it found
when the check was introduced are in ``.ci/mypy-baseline.txt``, one a line, without
line numbers (``file: error: message  [code]``), so that an edit elsewhere in a file
does not move them. The check fails when mypy finds an error the baseline does not
hold (each printed with its line), and when the baseline holds one mypy no longer
finds: that one was fixed, and ``--shrink`` removes it. ``--shrink`` never adds.

``--write`` records mypy's errors as they are, new ones included: only for errors that
a move of code carried to another file, with the diff of the baseline reviewed.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASELINE = ROOT / ".ci" / "mypy-baseline.txt"

_ERROR = re.compile(r"^(?P<file>[^:\s]+\.pyi?):(?P<line>\d+):(?:\d+:)? error: (?P<text>.*)$")


def normalise(output: str) -> list[tuple[str, str]]:
    """``(baseline line, mypy's line)`` for each error in mypy's output (notes and the
    summary skipped); the baseline line has no line numbers, also none in the text.

    >>> normalise('a/b.py:12: error: "None" has no attribute "x"  [attr-defined]\\n'
    ...           "a/b.py:12: note: a note\\nFound 1 error in 1 file")[0][0]
    'a/b.py: error: "None" has no attribute "x"  [attr-defined]'
    >>> normalise("a.py:3: error: Name \\"f\\" already defined on line 1  [no-redef]")[0][0]
    'a.py: error: Name "f" already defined on line N  [no-redef]'
    """
    out = []
    for line in output.splitlines():
        m = _ERROR.match(line.strip())
        if m:
            text = re.sub(r"\bline \d+", "line N", m["text"])
            out.append((f"{m['file']}: error: {text}", line.strip()))
    return out


def compare(found: list[tuple[str, str]], baseline: list[str]) -> tuple[list[str], list[str]]:
    """(new errors as mypy printed them, baseline lines no longer found), counting
    repeats: a file with the same error twice in the baseline may have it twice.

    >>> compare([("f.py: error: x", "f.py:3: error: x"), ("f.py: error: x", "f.py:9: error: x")],
    ...         ["f.py: error: x", "g.py: error: y"])
    (['f.py:9: error: x'], ['g.py: error: y'])
    """
    allowed = Counter(baseline)
    new = []
    for key, line in found:
        if allowed[key] > 0:
            allowed[key] -= 1
        else:
            new.append(line)
    fixed = sorted(allowed.elements())
    return new, fixed


def read_baseline() -> list[str]:
    if not BASELINE.exists():
        return []
    return [line for line in BASELINE.read_text().splitlines() if line.strip()]


def write_baseline(lines: list[str]) -> None:
    BASELINE.write_text("".join(f"{line}\n" for line in sorted(lines)))


def run_mypy() -> str:
    # without PYTHONPATH: mypy reads it as a search path, and a checkout on it (a
    # developer's, a test's) makes the modules it names "installed" and unchecked
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(
        [sys.executable, "-m", "mypy", "--no-error-summary", "--hide-error-context"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
    )
    if done.returncode not in (0, 1):  # 2: mypy itself failed (configuration, crash)
        sys.exit(f"typecheck: mypy failed:\n{done.stdout}{done.stderr}")
    return done.stdout


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--shrink", action="store_true", help="drop fixed errors from the baseline")
    group.add_argument("--write", action="store_true", help="record mypy's errors as they are")
    args = parser.parse_args(argv)
    found = normalise(run_mypy())
    baseline = read_baseline()
    if args.write:
        write_baseline([key for key, _ in found])
        print(f"typecheck: {len(found)} errors written to {BASELINE.relative_to(ROOT)}")
        return 0
    new, fixed = compare(found, baseline)
    if args.shrink and not new:
        remaining = Counter(baseline) - Counter(fixed)
        write_baseline(list(remaining.elements()))
        print(f"typecheck: {len(fixed)} fixed errors removed; {len(found)} remain")
        return 0
    for line in new:
        print(line)
    if new:
        print(
            f"typecheck: {len(new)} new type errors (above); fix them (the baseline only shrinks)"
        )
    if fixed:
        print(f"typecheck: {len(fixed)} errors of the baseline are fixed:")
        print("\n".join(f"  {line}" for line in fixed))
        print("  remove them from the baseline: python .ci/typecheck.py --shrink")
    if not new and not fixed:
        print(f"typecheck: no new type errors ({len(found)} in the baseline)")
    return 1 if new or fixed else 0


if __name__ == "__main__":
    sys.exit(main())
