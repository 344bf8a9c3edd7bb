"""Shared fixtures: small analytic test models that need no door physics; the bundled
models' usual parameter sets; the HapticMaster emulator. What tests share that is not a
fixture is in ``helpers.py``."""

import os

import pytest
from numba import njit

from evo_door.models import get_model
from evo_door.models.base import Model
from evo_door.params import Param, ParamTable

#: The command line's notes of what numba compiles (evo_door.kernel_cache) would land in
#: the stderr that tests compare, whenever a test happens to compile first; quiet here
#: (tests/test_kernel_cache.py turns them on).
os.environ["EVO_DOOR_COMPILE_NOTES"] = "0"


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
