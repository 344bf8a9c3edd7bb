"""How ``pytest -n`` shares the suite among its workers: the hooks of pytest-xdist that
``tests/conftest.py`` takes from here.

**A worker more than the cores** (``-n auto``). About a sixth of the suite's time on 2
cores is spent waiting on the wall clock, not computing: renders paced at their loop
rate, the emulated HapticMaster, the browser, watchdogs that must see a stall. With a
worker per core those seconds leave a core idle; a third worker on two cores fills them.
``PYTEST_XDIST_AUTO_NUM_WORKERS`` still sets the number, as xdist documents.

**A file is a unit of work**, handed whole to one worker: what a file's tests share (a
module's fixture: a fit, a server, a browser session whose tests run in file order) is
made once. Units are handed out costliest first, so that the last ones are short: a
test that ``tests/tiers.txt`` lists (measured at 0.5 s or more) counts as
:data:`MEASURED_WEIGHT` of the others.

**With more workers than cores, the paced files run one at a time**: the files whose
tests pace a loop on the wall clock and judge its timing (:data:`PACED`: the renders,
the console, the emulated HapticMaster and its stalls, the JND sessions on a device)
form one unit together, run one after another on one worker, so that two real-time
loops never compete for the cores with a third worker's kernels beside them. With many
cores they are split into several such units (one per three workers), each still one
file after another. With a worker per core (``.ci/run``, where the checks beside the
suite take the idle CPU) each is a file like the others: the paced unit left one
worker mostly waiting for 200 s, and CI took longer (ci116: the suite 396 s against
358 s for ci114, with xdist's ``load``).

Measured on 2 cores (AMD EPYC, by hand, warm cache, the same hour, probe 0.43 s): the
suite in 336 s with two workers and xdist's ``load``, in 289 s with three and these units
(the paced unit 208 s of it, on one worker). With three workers and ``load`` another
worker's real-time render met ``test_render_priority``'s busy-machine test and made it
miss its bound.

Why not xdist's ``loadgroup`` and ``xdist_group`` marks: xdist adds the group to
``item._nodeid``, which pytest 9's ``nodeid`` no longer reads; every test stayed a unit
of its own, and the browser's session was split between workers.
"""

from __future__ import annotations

import os
import re
import zlib

import pytest
from xdist.scheduler import LoadScopeScheduling

from tests.helpers import measured_tiers

#: The test files whose tests pace a loop on the wall clock and judge its timing (by
#: the file's name, which is all the scheduler sees of a test: xdist's controller
#: collects nothing).
PACED = re.compile(r"(^|/)test_(render_|console_|hapticmaster|jnd_device)[^/]*\.py$")

#: What a test measured at 0.5 s or more (``tests/tiers.txt``) weighs in a unit's cost,
#: a test under that weighing 1 (most take 0.02-0.2 s; those listed, 0.5-20 s)
MEASURED_WEIGHT = 20

#: Workers per unit of paced files (one such unit on up to five workers).
WORKERS_PER_PACED_UNIT = 3


def paced_units(workers: int, cores: int) -> int:
    """How many units the paced files are split into, for ``workers`` workers on
    ``cores`` cores; 0: none, each paced file is a unit of its own (no more workers
    than cores)."""
    if workers <= cores:
        return 0
    return max(1, (workers + 1) // WORKERS_PER_PACED_UNIT)


def unit_of(nodeid: str, units: int) -> str:
    """The unit of work of the test ``nodeid``: its file, or ``paced-K`` for a paced
    file where there are ``units`` paced units (the same K for every test of a file,
    whatever the run)."""
    path = nodeid.split("::", 1)[0]
    if units and PACED.search(path):
        return f"paced-{zlib.crc32(path.encode()) % units}"
    return path


def unit_cost(nodeids, measured: frozenset[str]) -> int:
    """The cost of a unit of work by its tests: :data:`MEASURED_WEIGHT` for a test in
    ``measured`` (the ids ``tests/tiers.txt`` lists), 1 for another."""
    return sum(MEASURED_WEIGHT if nodeid in measured else 1 for nodeid in nodeids)


class FileScheduling(LoadScopeScheduling):
    """xdist's ``loadscope`` with a test file as the scope and the paced files together
    (:func:`unit_of`), the units handed out costliest first (:func:`unit_cost`)."""

    def __init__(self, config, log=None):
        super().__init__(config, log)
        self.units = paced_units(self.numnodes, cores())
        self._ordered = False

    def _split_scope(self, nodeid: str) -> str:
        return unit_of(nodeid, self.units)

    def _assign_work_unit(self, node) -> None:
        if not self._ordered:  # the queue is whole at the first assignment
            measured = measured_tiers()
            costs = {scope: unit_cost(unit, measured) for scope, unit in self.workqueue.items()}
            for scope in sorted(costs, key=costs.__getitem__, reverse=True):
                self.workqueue.move_to_end(scope)
            self._ordered = True
        super()._assign_work_unit(node)


def cores() -> int:
    """The cores this process may use."""
    return len(os.sched_getaffinity(0))


@pytest.hookimpl(tryfirst=True, optionalhook=True)  # before xdist's; none without it
def pytest_xdist_make_scheduler(config, log):
    """:class:`FileScheduling` for xdist's default distribution (``-n`` without
    ``--dist``); a ``--dist`` given on the command line or in ``PYTEST_ADDOPTS`` is
    xdist's own."""
    given = [*config.invocation_params.args, *os.environ.get("PYTEST_ADDOPTS", "").split()]
    if config.getoption("dist") != "load" or any(a.startswith("--dist") for a in given):
        return None
    return FileScheduling(config, log)


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_auto_num_workers(config):
    """``-n auto``: one worker more than the cores this process may use, unless
    ``PYTEST_XDIST_AUTO_NUM_WORKERS`` says how many (xdist reads it then)."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    return cores() + 1
