"""benchmarks/slowest_tests.py: the slowest tests of a run, with their reasons."""

import pytest

from benchmarks import slowest_tests as st

JUNIT = """<?xml version="1.0" encoding="utf-8"?>
<testsuites><testsuite name="pytest" tests="4" time="12.5" timestamp="2026-11-29T05:00:00">
<testcase classname="tests.test_latch_fitness" name="test_latch_forces_are_the_same_whatever_the_ga_seed" time="9.0"/>
<testcase classname="tests.test_fuzz"
  name="test_damaged_files_are_refused_in_one_line_in_bounded_time_and_memory[run]" time="11.0"/>
<testcase classname="tests.test_new" name="test_something_slow" time="10.0"/>
<testcase classname="tests.test_quick" name="test_quick" time="0.01"/>
</testsuite></testsuites>
"""


def test_the_slowest_first_each_with_its_reason_parameters_left_out(tmp_path):
    path = tmp_path / "run.xml"
    path.write_text(JUNIT)
    rows, totals = st.slowest(path, 3)
    assert [r[1] for r in rows] == [
        "test_fuzz::test_damaged_files_are_refused_in_one_line_in_bounded_time_and_memory[run]",
        "test_new::test_something_slow",
        "test_latch_fitness::test_latch_forces_are_the_same_whatever_the_ga_seed",
    ]
    assert rows[0][2].startswith("every damaged file")  # the reason of the unparametrised id
    assert rows[1][2] == "no reason recorded"
    assert totals["tests"] == 4 and totals["under_1s"] == 1 and totals["wall"] == 12.5
    text = st.table(rows, totals, "abc1234")
    assert "commit abc1234, started 2026-11-29 05:00" in text
    assert "| 1 | `test_fuzz::" in text and "| 11.0 |" in text


def test_write_replaces_only_the_generated_block(tmp_path, monkeypatch, capsys):
    path = tmp_path / "run.xml"
    path.write_text(JUNIT)
    doc = tmp_path / "testing.md"
    doc.write_text(f"# Testing\n\nbefore\n{st.BEGIN}\nold table\n{st.END}\nafter\n")
    monkeypatch.setattr(st, "DOC", doc)
    monkeypatch.setattr(st, "ROOT", tmp_path)
    assert st.main([str(path), "-n", "2", "--commit", "abc1234", "--write"]) == 0
    text = doc.read_text()
    assert text.startswith("# Testing\n\nbefore\n") and text.endswith(f"{st.END}\nafter\n")
    assert "old table" not in text and "test_something_slow" in text


@pytest.mark.parametrize("content", ["not xml", "<testsuites/>"])
def test_a_file_that_is_not_a_run_is_one_line(tmp_path, content):
    path = tmp_path / "run.xml"
    path.write_text(content)
    with pytest.raises(SystemExit, match=r"^slowest_tests: error: .*run\.xml: "):
        st.slowest(path, 20)


def test_every_reason_names_a_test_that_exists():
    from tests.helpers import ROOT

    for name in st.REASONS:
        module, test = name.split("::")
        source = (ROOT / "tests" / f"{module}.py").read_text()
        assert f"def {test}(" in source, name
