"""benchmarks/history.py: the headline figures of every committed suite page."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from benchmarks import history

ROOT = Path(__file__).resolve().parent.parent

PAGE = """# Benchmark suite (`python -m benchmarks`)

Machine: Linux-x, 2 CPUs (AMD EPYC), numba threads 2. Measured 2026-11-30 15:34, one run. Commit 23ddfac.

| door smooth: default dopri5 x1, tol 1e-07: <= 2.68 ms (the earlier suite) | 939 us | met |
| door smooth: default dopri5 x1, tol 1e-07, max |theta error|: <= 2.52e-08 rad | 8.17e-11 rad | met |

| model | workbench GA 100 x 20 | evaluations | plain GA | plain per evaluation | on | speed-up |
|---|---:|---:|---:|---:|---|---:|
| door | 772 ms | 1465 | 176 s | 120 ms | population 100, generations 0-1 (166 evaluations) | 228x |
| haptic | 1.36 s | 1474 | 140 s | 95.3 ms | population 100, generations 0-1 (168 evaluations) | 103x |

| `evo-door compile` (every kernel), cold | 51.1 s |  |  |  |

Wall time of `evo-door run experiments/case_study.yaml` in a fresh process: **31 s** (the pipeline's own time 30 s)
"""


def test_a_page_gives_each_figure_as_it_printed_it():
    page = history.parse(PAGE)
    assert page is not None
    assert (page.measured, page.commit) == ("2026-11-30 15:34", "23ddfac")
    assert page.machine == "Linux-x, 2 CPUs (AMD EPYC)"
    assert page.ga_door == ("772 ms", "228x") and page.ga_haptic == ("1.36 s", "103x")
    assert page.smooth_door == "939 us"  # the time, not the error rows after it
    assert (page.main_job, page.cold_compile) == ("31 s", "51.1 s")


def test_a_figure_the_page_did_not_measure_is_a_dash_and_a_non_page_nothing():
    old = "\n".join(
        line for line in PAGE.splitlines() if "compile" not in line and "smooth" not in line
    )
    page = history.parse(old)
    assert page.cold_compile is None and page.smooth_door is None and page.ga_door is not None
    assert "| - | 31 s | - |" in history.table([page])
    assert history.parse("# a page with no measured date and commit") is None


def test_the_host_probe_is_read_where_the_page_states_it():
    from benchmarks.probe import probe_sentence

    page = history.parse(
        PAGE.replace("Commit 23ddfac.", "Commit 23ddfac." + probe_sentence([0.351, 0.4]))
    )
    assert page.probe == "0.35 / 0.40 s"
    assert "| 51.1 s | 0.35 / 0.40 s | Linux-x" in history.table([page])
    assert history.parse(PAGE).probe is None  # an earlier page: a dash
    assert "| 51.1 s | - | Linux-x" in history.table([history.parse(PAGE)])


def test_the_committed_suite_page_gives_every_figure():
    """The page of the latest full run: a change of its layout that the history no
    longer reads fails here, not silently as dashes."""
    page = history.parse((ROOT / "benchmarks" / "suite.md").read_text(encoding="utf-8"))
    assert page is not None
    assert None not in (page.ga_door, page.ga_haptic, page.smooth_door, page.main_job)
    assert page.cold_compile is not None and page.probe is not None


@pytest.mark.skipif(
    shutil.which("git") is None or not (ROOT / ".git").exists(), reason="not a git checkout"
)
def test_the_history_lists_each_committed_page_once_oldest_first():
    found = history.pages()
    assert found, "no committed suite page"
    commits = [p.commit for p in found]
    assert len(commits) == len(set(commits))
    assert [p.measured for p in found] == sorted(p.measured for p in found)
