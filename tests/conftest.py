"""Shared fixtures: small analytic test models that need no door physics; the bundled
models' usual parameter sets; the HapticMaster emulator. What tests share that is not a
fixture is in ``helpers.py``."""

import os

import pytest
from numba import njit

from evo_door.models import get_model
from evo_door.models.base import Model
from evo_door.params import Param, ParamTable
from tests.helpers import measured_tiers, tier

#: The command line's notes of what numba compiles (evo_door.kernel_cache) would land in
#: the stderr that tests compare, whenever a test happens to compile first; quiet here
#: (tests/test_kernel_cache.py turns them on).
os.environ["EVO_DOOR_COMPILE_NOTES"] = "0"


@pytest.hookimpl(tryfirst=True)  # before -m selects by marker
def pytest_collection_modifyitems(config, items):
    """The tiers (docs/testing.md): a test not marked ``slow`` is ``integration`` if
    ``tests/tiers.txt`` lists it (measured at 0.5 s or more) or if it asks for a fixture
    of its file's, shared by its module or the session, that a test of another tier asks
    for too (whichever test asks first pays for it: most are a fit, a run or a corpus);
    else ``unit``."""
    measured = measured_tiers()
    kinds = [tier(i.nodeid, i.get_closest_marker("slow") is not None, measured) for i in items]
    shared = {f for item, kind in zip(items, kinds) if kind != "unit" for f in _own_shared(item)}
    for item, kind in zip(items, kinds):
        if kind == "unit" and shared.intersection(_own_shared(item)):
            kind = "integration"
        if kind != "slow":
            item.add_marker(kind)


def _own_shared(item) -> set[tuple[str, str]]:
    """``(file, name)`` of the module- or session-scoped fixtures a test asks for that its
    own file defines."""
    info = getattr(item, "_fixtureinfo", None)  # a docstring example has none
    here = item.nodeid.split("::")[0]
    return {
        (here, name)
        for name, defs in (info.name2fixturedefs.items() if info else ())
        if defs[-1].scope in ("module", "session") and defs[-1].baseid == here
    }


@njit(cache=True)
def oscillator_accel(theta, dtheta, force, p):
    """I ddtheta = -k (theta - theta_eq) - c dtheta + force."""
    return (-p[0] * (theta - p[3]) - p[1] * dtheta + force) / p[2]


OSCILLATOR_PARAMS = ParamTable(
    "oscillator",
    [
        Param("k", "N/rad", 100.0, 0.0, 1e7, "specification", "spring stiffness"),
        Param("c", "N s/rad", 1.0, 0.0, 1e4, "specification", "viscous damping"),
        Param("inertia", "kg m", 1.0, 1e-3, 100.0, "specification", "inertia"),
        Param("theta_eq", "rad", 0.0, -10.0, 10.0, "geometry", "equilibrium angle"),
    ],
)


@pytest.fixture(scope="session")
def door():
    """The physical door model."""
    return get_model("door")


@pytest.fixture(scope="session")
def default(door):
    """The door's ``default`` preset (parameter sets are read-only)."""
    return door.load_params("default")


@pytest.fixture(scope="session")
def seed_trial():
    """The haptic model's ``seed_trial`` preset."""
    return get_model("haptic").load_params("seed_trial")


@pytest.fixture(scope="session")
def oscillator():
    return Model(
        "oscillator",
        "linear oscillator",
        OSCILLATOR_PARAMS,
        oscillator_accel,
        method="rk4",
        substeps=1,
    )


#: Importable as "tests.conftest:OSCILLATOR_MODEL" wherever a model name is accepted.
OSCILLATOR_MODEL = Model(
    "oscillator", "linear oscillator", OSCILLATOR_PARAMS, oscillator_accel, method="rk4", substeps=1
)


# -- the HapticMaster emulator (tests/test_hapticmaster.py, test_render_native.py) ----
@pytest.fixture
def emulator():
    """An emulated HapticMaster on 127.0.0.1 that advances only when told (tests)."""
    from evo_door.render.emulator import HapticMasterEmulator

    emu = HapticMasterEmulator(port=0, clock="query", steps_per_query=0)
    yield emu
    emu.close()
