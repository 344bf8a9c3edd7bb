"""benchmarks/slowest_tests.py: the slowest tests of a run, with their reasons."""

import pytest

from benchmarks import slowest_tests as st
from tests import helpers

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
    for name in st.REASONS:
        module, test = name.split("::")
        source = (helpers.ROOT / "tests" / f"{module}.py").read_text()
        assert f"def {test}(" in source, name


UNIT_RUN = """<?xml version="1.0" encoding="utf-8"?>
<testsuites><testsuite name="pytest" tests="3" time="3.0">
<testcase classname="tests.test_quick" name="test_quick" time="0.7"/>
<testcase classname="tests.test_quick" name="test_other[a-b]" time="0.1"/>
<testcase classname="evo_door.sim.simulate" name="evo_door.sim.simulate.simulate" time="2.0"/>
</testsuite></testsuites>
"""


def test_tiers_list_every_test_at_the_limit_in_any_run_and_no_docstring_example(tmp_path):
    runs = [tmp_path / "run.xml", tmp_path / "unit.xml"]
    runs[0].write_text(JUNIT)
    runs[1].write_text(UNIT_RUN)  # test_quick pays a shared fixture here: 0.7 s
    text = st.tiers_text(runs, "abc1234")
    listed = [line for line in text.splitlines() if not line.startswith("#")]
    assert listed == [
        "tests/test_fuzz.py::"
        "test_damaged_files_are_refused_in_one_line_in_bounded_time_and_memory[run]",
        "tests/test_latch_fitness.py::test_latch_forces_are_the_same_whatever_the_ga_seed",
        "tests/test_new.py::test_something_slow",
        "tests/test_quick.py::test_quick",
    ]
    assert "at commit\n# abc1234)" in text
    assert helpers.measured_tiers(_written(tmp_path, text)) == frozenset(listed)


def _written(tmp_path, text):
    path = tmp_path / "tiers.txt"
    path.write_text(text)
    return path


def test_a_test_is_slow_as_marked_integration_as_measured_else_unit():
    measured = frozenset({"tests/test_a.py::test_b"})
    assert helpers.tier("tests/test_a.py::test_b", True, measured) == "slow"
    assert helpers.tier("tests/test_a.py::test_b", False, measured) == "integration"
    assert helpers.tier("tests/test_a.py::test_c", False, measured) == "unit"


def test_conftest_marks_this_quick_test_unit(request):
    assert request.node.get_closest_marker("unit") is not None
    assert request.node.get_closest_marker("integration") is None


def test_every_listed_tier_names_a_test_that_exists():
    listed = helpers.measured_tiers()
    assert len(listed) > 100  # the file is there and read
    for node in listed:
        path, *_, name = node.split("::")
        source = (helpers.ROOT / path).read_text()
        assert f"def {name.split('[')[0]}(" in source, node


FIXTURE_SHARING = """
import pytest

@pytest.fixture(scope="module")
def fit():
    return 1

@pytest.mark.slow
def test_slow(fit):
    pass

def test_shares_the_slow_ones_fixture(fit):
    pass

def test_alone():
    pass
"""


def test_a_quick_test_sharing_a_module_fixture_with_a_slow_one_is_integration(pytester):
    """Whichever test asks first for a shared fixture pays for it: not a unit test."""
    pytester.makeconftest("from tests.conftest import pytest_collection_modifyitems\n")
    pytester.makepyfile(test_tiers=FIXTURE_SHARING)
    for marker, names in (
        ("unit", ["test_alone"]),
        ("integration", ["test_shares_the_slow_ones_fixture"]),
    ):
        out = pytester.runpytest_inprocess("--collect-only", "-q", "-m", marker)
        ids = [line for line in out.outlines if "::" in line]
        assert [i.split("::")[1] for i in ids] == names, out.outlines


def _case(name, seconds, own=None, processes=None) -> str:
    props = ""
    if own is not None:
        props = (
            f'<properties><property name="{st.CPU_OWN}" value="{own}"/>'
            f'<property name="{st.CPU_PROCESSES}" value="{processes}"/></properties>'
        )
    return f'<testcase classname="tests.test_x" name="{name}" time="{seconds}">{props}</testcase>'


def _junit(*cases) -> str:
    return (
        '<testsuites><testsuite name="pytest" time="30" timestamp="2026-12-01T18:00:00">'
        + "".join(cases)
        + "</testsuite></testsuites>"
    )


def test_the_cpu_time_a_run_recorded_is_tabled_and_can_order_the_list(tmp_path):
    """A test that waited for a core is slow but cheap; one whose processes work is not."""
    path = tmp_path / "run.xml"
    path.write_text(
        _junit(
            _case("test_waited", 9.0, "0.5", "0.0"),
            _case("test_spawns", 6.0, "0.2", "7.5"),
            _case("test_computes", 4.0, "3.9", "0.0"),
        )
    )
    rows, totals = st.slowest(path, 3)
    assert [r[1] for r in rows] == [
        "test_x::test_waited",
        "test_x::test_spawns",
        "test_x::test_computes",
    ]
    assert rows[1][3] == (0.2, 7.5) and totals["cpu"] == pytest.approx((4.6, 7.5))
    text = st.table(rows, totals, "abc1234")
    assert "CPU time: 12 s, 5 s in the workers and 8 s in the processes" in text
    assert "| 2 | `test_x::test_spawns` | 6.0 | 0.2 + 7.5 | no reason recorded |" in text
    rows, totals = st.slowest(path, 3, by="cpu")
    assert [r[1].split("::")[1] for r in rows] == ["test_spawns", "test_computes", "test_waited"]
    assert "Most CPU first." in st.table(rows, totals, "abc1234")


def test_a_run_without_cpu_times_keeps_the_old_table_and_marks_a_missing_one(tmp_path):
    path = tmp_path / "run.xml"
    path.write_text(_junit(_case("test_a", 2.0)))
    rows, totals = st.slowest(path, 5)
    text = st.table(rows, totals, "abc1234")
    assert totals["cpu"] is None and "CPU time" not in text and "CPU s" not in text
    path.write_text(_junit(_case("test_a", 2.0), _case("test_b", 1.0, "0.9", "0.1")))
    rows, totals = st.slowest(path, 5)
    assert "| 1 | `test_x::test_a` | 2.0 | - | no reason recorded |" in st.table(rows, totals, "x")


def test_the_docs_table_is_by_wall_time(tmp_path, capsys):
    path = tmp_path / "run.xml"
    path.write_text(_junit(_case("test_a", 2.0, "1", "1")))
    with pytest.raises(SystemExit):
        st.main([str(path), "--by", "cpu", "--write"])
    assert "the table of docs/testing.md is the slowest tests" in capsys.readouterr().err


CPU_SPENDING = """
import subprocess, sys, time

def _burn(seconds):
    end = time.process_time() + seconds
    while time.process_time() < end:
        pass

def test_burns_here():
    _burn(0.3)

def test_burns_in_a_process():
    code = "import time\\nend = time.process_time() + 0.3\\nwhile time.process_time() < end: pass"
    subprocess.run([sys.executable, "-c", code], check=True)

def test_idles():
    time.sleep(0.3)
"""


def test_the_suite_records_each_tests_cpu_time_and_its_processes(pytester):
    """tests/conftest.py's hooks: a test's own CPU and its processes', in the JUnit XML."""
    pytester.makeconftest(
        "from tests.conftest import pytest_runtest_makereport, pytest_runtest_setup\n"
    )
    pytester.makepyfile(test_cpu=CPU_SPENDING)
    out = pytester.runpytest_inprocess("-p", "no:xdist", "--junitxml=run.xml")
    out.assert_outcomes(passed=3)
    rows, totals = st.slowest(pytester.path / "run.xml", 3)
    cpu = {r[1].split("::")[1]: r[3] for r in rows}
    assert cpu["test_burns_here"][0] > 0.25 and cpu["test_burns_here"][1] < 0.05, cpu
    assert cpu["test_burns_in_a_process"][1] > 0.25, cpu  # and its own start-up, below
    assert cpu["test_burns_in_a_process"][0] < 0.2, cpu
    assert sum(cpu["test_idles"]) < 0.1, cpu
