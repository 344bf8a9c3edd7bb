"""The FMU's C functions as numba first-class functions.

The compiled integrators of :mod:`evo_door.models.fmu.kernels` call the FMU's shared
library directly, with no Python between the steps. They receive the functions as a
tuple (:func:`api`), each element an object that tells numba the function's address
and its C signature (numba's ``WrapperAddressProtocol``). The kernels are compiled for
the *types* of the tuple, not for the addresses, so they are cached on disk once and
serve every FMU of one FMI version in every process.

Arguments cross as plain machine words: the instance and every array as its address
(``uintp``), counts as ``int64`` (``size_t`` on the 64-bit platforms evo-door runs on),
FMI 2 booleans as ``int32`` and FMI 3 booleans as ``uint8``.

A function an FMU does not export for the interface in use (``fmi2DoStep`` of a
model-exchange-only FMU) is replaced by a compiled stub that returns ``fmi2Error``;
the kernels never call it.
"""

from __future__ import annotations

import ctypes
import warnings

from numba import cfunc, types
from numba.core.errors import NumbaExperimentalFeatureWarning
from numba.core.types.function_type import WrapperAddressProtocol

# numba calls first-class functions "experimental"; they are what the kernels are for
warnings.filterwarnings(
    "ignore", category=NumbaExperimentalFeatureWarning, message="First-class function type"
)

_u, _i64, _f, _i32, _u8 = types.uintp, types.int64, types.float64, types.int32, types.uint8

#: positions in the tuple :func:`api` returns
(
    SET_TIME,
    SET_STATES,
    GET_DERIVATIVES,
    SET_REAL,
    GET_REAL,
    COMPLETED_STEP,
    DO_STEP,
    GET_EVENT_INDICATORS,
    ENTER_EVENT_MODE,
    DISCRETE_STATES,
    ENTER_CONTINUOUS_MODE,
    GET_STATES,
) = range(12)

_ARRAY_CALL = _i32(_u, _u, _i64)  # (instance, double*, size_t)
_INSTANCE_CALL = _i32(_u)

#: name and signature of each function, per FMI version, in the order above
SIGNATURES = {
    2: (
        ("fmi2SetTime", _i32(_u, _f)),
        ("fmi2SetContinuousStates", _ARRAY_CALL),
        ("fmi2GetDerivatives", _ARRAY_CALL),
        ("fmi2SetReal", _i32(_u, _u, _i64, _u)),
        ("fmi2GetReal", _i32(_u, _u, _i64, _u)),
        ("fmi2CompletedIntegratorStep", _i32(_u, _i32, _u, _u)),
        ("fmi2DoStep", _i32(_u, _f, _f, _i32)),
        ("fmi2GetEventIndicators", _ARRAY_CALL),
        ("fmi2EnterEventMode", _INSTANCE_CALL),
        ("fmi2NewDiscreteStates", _i32(_u, _u)),
        ("fmi2EnterContinuousTimeMode", _INSTANCE_CALL),
        ("fmi2GetContinuousStates", _ARRAY_CALL),
    ),
    3: (
        ("fmi3SetTime", _i32(_u, _f)),
        ("fmi3SetContinuousStates", _ARRAY_CALL),
        ("fmi3GetContinuousStateDerivatives", _ARRAY_CALL),
        ("fmi3SetFloat64", _i32(_u, _u, _i64, _u, _i64)),
        ("fmi3GetFloat64", _i32(_u, _u, _i64, _u, _i64)),
        ("fmi3CompletedIntegratorStep", _i32(_u, _u8, _u, _u)),
        ("fmi3DoStep", _i32(_u, _f, _f, _u8, _u, _u, _u, _u)),
        ("fmi3GetEventIndicators", _ARRAY_CALL),
        ("fmi3EnterEventMode", _INSTANCE_CALL),
        ("fmi3UpdateDiscreteStates", _i32(_u, _u, _u, _u, _u, _u, _u)),
        ("fmi3EnterContinuousTimeMode", _INSTANCE_CALL),
        ("fmi3GetContinuousStates", _ARRAY_CALL),
    ),
}

#: the status FMI 2 and 3 call "error" (what a stub returns)
ERROR = 3


class CFunction(WrapperAddressProtocol):
    """A C function at ``address`` with numba signature ``sig`` (a first-class value)."""

    def __init__(self, address: int, sig):
        self.address = int(address)
        self.sig = sig

    def __wrapper_address__(self) -> int:
        return self.address

    def signature(self):
        return self.sig


_STUBS: dict = {}


def _stub(sig):
    """A compiled function of signature ``sig`` that returns ``ERROR``."""
    if sig not in _STUBS:
        n = len(sig.args)
        names = ", ".join(f"a{i}" for i in range(n))
        scope: dict = {}
        exec(f"def stub({names}):\n    return {ERROR}\n", scope)  # one body per arity
        _STUBS[sig] = cfunc(sig, cache=False)(scope["stub"])
    return _STUBS[sig]


def api(dll, version: int) -> tuple:
    """The tuple of :class:`CFunction` the kernels take, from a loaded library."""
    out = []
    for name, sig in SIGNATURES[version]:
        try:
            address = ctypes.cast(getattr(dll, name), ctypes.c_void_p).value
        except AttributeError:
            address = None
        if not address:
            address = _stub(sig).address
        out.append(CFunction(address, sig))
    return tuple(out)


def stub_api(version: int) -> tuple:
    """A tuple of :class:`CFunction` of FMI ``version`` that are all stubs: of the types
    :func:`api` gives for any FMU of that version, so the kernels compile for it (and
    are cached) without an FMU (``evo-door compile``)."""
    return tuple(CFunction(_stub(sig).address, sig) for _, sig in SIGNATURES[version])
