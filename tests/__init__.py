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

OpenBLAS (numpy's and scipy's) keeps a thread per core that spins for a while after
every call it spreads over them, waiting for the next: the same contest. The suite runs
it on one thread (``OPENBLAS_NUM_THREADS=1``, unless the environment sets a number),
for the workers and the commands alike. Measured on 2 cores: a 300 x 300 product three
times, then 0.3 s of sleep, took 44-49 ms of CPU in that sleep on OpenBLAS's default,
0.06-0.09 ms on one thread; ``tests/test_jnd.py`` alone (its fits, by scipy's L-BFGS-B,
call the library's triangular solves) 8.7-12.1 s of CPU against 5.3-5.6 s; the whole
suite (``pytest -n auto``, a warm cache, back to back in one hour, host probe 0.45-0.51
s) 400 s of wall time and 767 s of CPU on the default, 381 s and 724 s on one thread.
The numbers the tests compare are the same either way (the suite passes both ways).
"""

import os

#: set (to "1") where the suite chose the policy, for the workers and the commands too
SUITE_SET_POLICY = "EVO_DOOR_TESTS_SET_OMP_POLICY"
if "OMP_WAIT_POLICY" not in os.environ:
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    os.environ[SUITE_SET_POLICY] = "1"
#: set (to "1") where the suite chose OpenBLAS's number of threads
SUITE_SET_BLAS = "EVO_DOOR_TESTS_SET_BLAS_THREADS"
if "OPENBLAS_NUM_THREADS" not in os.environ:
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    os.environ[SUITE_SET_BLAS] = "1"
