"""The PathSim side-by-side benchmark (``benchmarks/bench_pathsim.py``): the section
skips with its reason without PathSim; with it, the PathSim diagram is the drawer's
equations (it agrees with the reference and the workbench on the trial, at the
defaults and at another candidate), so its timing compares like with like."""

import sys

import numpy as np
import pytest

from benchmarks import bench_pathsim as bp
from evo_door.models.blocks import CACHE_ENV


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    """Generated mechanisms in a tmp folder of the session (not the user's cache)."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path_factory.getbasetemp() / "mechanisms"))


def test_without_pathsim_the_section_says_why_and_measures_nothing(monkeypatch):
    from benchmarks.suite import Suite, section_pathsim

    monkeypatch.setitem(sys.modules, "pathsim", None)  # import pathsim raises ImportError
    reason = bp.available()
    assert reason and "\n" not in reason and "'.[bench]'" in reason
    suite = Suite(quick=True)
    section_pathsim(suite)
    (m,) = suite.metrics
    assert m.name == "pathsim.trial.speedup" and m.value is None and m.met is None
    assert m.note == f"skipped: {reason}"
    assert suite.tables["pathsim"] == f"Skipped: {reason}."


@pytest.mark.slow
def test_the_pathsim_diagram_is_the_drawer_of_the_workbench():
    pytest.importorskip("pathsim")
    model = bp.drawer()
    defaults = model.load_params()
    other = defaults.replace(
        {"box.mass": 2.5, "runners.level": 1.8, "grease.c": 2.0, "softie.c_fluid": 150.0}
    )
    t, force = bp.trial()
    for params in (defaults, other):
        p = params.as_dict()
        ref = bp.reference(p, t, force)
        x, v = bp.workbench_run(model, params, force, 1e-9, 1)
        xs, vs = bp.PathSimDrawer(p, t, force, "RKDP54", 1e-6).run()
        for pair in ((x, v), (xs, vs)):
            ex, ev = bp.errors(*pair, ref)
            assert ex <= bp.ACCURACY[0] and ev <= bp.ACCURACY[1], (p, ex, ev)
        # the trial goes through every switch: into the soft-close and out of it, stuck
        # twice (exactly at rest), slipping both ways
        assert ref[0].max() > p["softie.engage"] > ref[0][-1] > 0.0
        assert v.max() > 0.1 and v.min() < -0.1
        stuck = np.flatnonzero(v == 0.0)
        assert np.any(np.diff(stuck) > 1), "stuck once only"
        assert vs[-1] == 0.0 and xs[-1] == xs[-50]
    # a re-parameterised diagram is the one built at those parameters
    d = bp.PathSimDrawer(defaults.as_dict(), t, force, "RKDP54", 1e-6)
    again = d.run(other.as_dict())
    np.testing.assert_array_equal(again[1], vs)
