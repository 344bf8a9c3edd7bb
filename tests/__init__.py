"""The test suite (docs/testing.md).

numba's parallel kernels run their threads on GNU OpenMP, whose idle threads spin at
the end of every parallel region before they sleep. Under ``pytest -n auto`` a worker
per core each runs a team of a thread per core, and a team's spinning takes the core
from the other worker's kernels. Passive waiting here (set before any test module, or
numba's OpenMP, is loaded; the workers and every command a test starts inherit it),
unless the environment already says otherwise. Measured on 2 cores, five GA-heavy test
files (latch fitness, pipeline, objective comparison, smallest change, feel check) with
``pytest -n 2``, twice each: 58.9 and 62.2 s of wall time and 105 and 111 s of CPU
spinning, 46.0 and 45.7 s and 77 and 76 s passive; the whole suite once each way
(``pytest -n auto``, a warm cache): 481 s and 862 s of CPU spinning, 448 s and 795 s
passive. A command run on its own keeps
OpenMP's default: there nothing else wants the core, and the main job took 0.4-1.6 s
longer passive (its CPU 5 s less).
"""

import os

#: set (to "1") where the suite chose the policy, for the workers and the commands too
SUITE_SET_POLICY = "EVO_DOOR_TESTS_SET_OMP_POLICY"
if "OMP_WAIT_POLICY" not in os.environ:
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    os.environ[SUITE_SET_POLICY] = "1"
