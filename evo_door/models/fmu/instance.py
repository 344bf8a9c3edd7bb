"""One loaded FMU in this process: extracted once, instantiated once, reset per run.

:class:`Instance` holds the FMU's shared library and one instance of it, made through
FMPy's classes (``FMU2Model``, ``FMU2Slave``, ``FMU3Model``, ``FMU3Slave``). Before each
run (a trial of one candidate) it is reset and initialised with the run's parameters
and initial state, through FMPy; the run itself is a compiled kernel calling the
library (:mod:`evo_door.models.fmu.kernels`). A process keeps one instance per FMU
(:func:`instance`): a worker of an executor extracts and instantiates once, however
many candidates it evaluates.

Loading an FMU runs its code: load only FMUs you trust.
"""

from __future__ import annotations

import atexit
import math
import shutil
import warnings
from pathlib import Path

import numpy as np
from numba.core.errors import NumbaExperimentalFeatureWarning

from evo_door.errors import UserError
from evo_door.models.fmu import kernels
from evo_door.models.fmu.calls import api, stub_api
from evo_door.models.fmu.description import FmuInfo

#: the trial's channels the kernels write, in this order, where the FMU has them
OUTPUT_KEYS = ("theta", "dtheta", "ddtheta")

_INSTANCES: dict = {}


class FmuRunError(Exception):
    """The FMU refused a call while it was being set up for a run."""


class Instance:
    """A loaded, instantiated FMU (see the module docstring)."""

    def __init__(self, info: FmuInfo):
        import fmpy

        info.check_channels()
        self.info = info
        md = info.description
        self.folder = Path(fmpy.extract(str(info.path)))
        atexit.register(shutil.rmtree, self.folder, True)
        cls = _fmpy_class(info.version, info.interface)
        token = md.guid if info.version == 2 else md.instantiationToken
        try:
            self.fmu = cls(
                guid=token,
                unzipDirectory=str(self.folder),
                modelIdentifier=info.identifier,
                instanceName="evo_door",
            )
            self.fmu.instantiate()
        except Exception as exc:
            raise UserError(f"FMU {info.path}: cannot load or instantiate it: {exc}") from None
        self.comp = np.uintp(self.fmu.component or 0)
        self.api = api(self.fmu.dll, info.version)
        ch = info.channels
        self.vr_in = np.array([ch["force"].vr], dtype=np.uint32)
        self.outputs = tuple(k for k in OUTPUT_KEYS if k in ch)
        self.vr_out = np.array([ch[k].vr for k in self.outputs], dtype=np.uint32)
        self.params = list(info.parameters.items())  # declaration order
        self._started = False
        self._entries: dict = {}  # kernel -> its compiled entry point for these types
        self._next_event = math.inf  # the time event the initialisation set

    # -- one run ------------------------------------------------------------------
    def _set(self, vrs, values) -> None:
        if not len(vrs):
            return
        if self.info.version == 2:
            self.fmu.setReal(list(vrs), list(values))
        else:
            self.fmu.setFloat64(list(vrs), list(values))

    def initialise(self, p, theta0: float | None, dtheta0: float | None, t0: float) -> None:
        """Reset, set the parameters ``p`` (declaration order) and the initial state
        (SI; None leaves the FMU's own start value), and initialise; raise
        :class:`FmuRunError` if the FMU refuses."""
        info, fmu = self.info, self.fmu
        ch = info.channels
        try:
            if self._started:
                fmu.reset()
            self._started = True
            if info.version == 2:
                fmu.setupExperiment(startTime=t0)
            self._set([vr for _, (vr, _) in self.params], np.asarray(p, dtype=np.float64))
            for key, value in (("theta0", theta0), ("dtheta0", dtheta0)):
                if key in ch and value is not None:
                    c = ch[key]
                    self._set([c.vr], [(value - c.offset) / c.factor])
            if info.version == 2:
                fmu.enterInitializationMode()
            else:
                fmu.enterInitializationMode(startTime=t0)
            fmu.exitInitializationMode()
            if info.interface == "me":
                self._next_event = self._settle_events()
                fmu.enterContinuousTimeMode()
        except Exception as exc:
            raise FmuRunError(" ".join(str(exc).split()) or type(exc).__name__) from None

    def _settle_events(self) -> float:
        """The initialisation's event iteration; the time event it sets (inf if none),
        which the run must stop at."""
        for _ in range(kernels.MAX_EVENT_ITERATIONS):
            if self.info.version == 2:
                needed, terminate, _, _, timed, at = self.fmu.newDiscreteStates()
            else:
                needed, terminate, _, _, timed, at = self.fmu.updateDiscreteStates()
            if terminate:
                raise FmuRunError("the FMU asked to terminate at initialisation")
            if not needed:
                return float(at) if timed else math.inf
        raise FmuRunError("the FMU's discrete states do not settle at initialisation")

    def run(self, p, force, dt, theta0, dtheta0, t0=0.0, substeps=4):
        """One run: ``(outputs, status)``, ``outputs`` (n, len(self.outputs)) in SI;
        ``theta0`` / ``dtheta0`` None start where the FMU starts by itself."""
        ch = self.info.channels
        f = (np.asarray(force, dtype=np.float64) - ch["force"].offset) / ch["force"].factor
        f = np.ascontiguousarray(f)
        out = np.empty((f.size, len(self.outputs)))
        try:
            self.initialise(p, theta0, dtheta0, t0)
        except FmuRunError:
            out[:] = np.nan
            return out, kernels.FMU_ERROR
        with warnings.catch_warnings():  # numba's "experimental" on the first compile
            warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
            status = self._run(f, out, t0, dt, substeps)
        for j, key in enumerate(self.outputs):
            out[:, j] = out[:, j] * ch[key].factor + ch[key].offset
        return out, int(status)

    def hold_forces(self, p, theta, dtheta, layout) -> np.ndarray:
        """The force (N) that holds the speed still at each angle ``theta`` and speed
        ``dtheta`` (rad, rad/s; arrays of one shape), at the parameters ``p``: the FMU
        initialised at its start, its states then set to each (angle, speed), the
        ``layout`` (:class:`~evo_door.models.fmu.description.StateLayout`) saying where
        they are. NaN where the FMU refuses."""
        ch = self.info.channels
        theta = np.ascontiguousarray(theta, dtype=np.float64)
        dtheta = np.ascontiguousarray(dtheta, dtype=np.float64)
        (fa, oa), (fs, os_) = layout.angle_si, layout.speed_si
        out = np.full(theta.size, np.nan)
        try:
            self.initialise(p, None, None, 0.0)
        except FmuRunError:
            return out
        x = np.zeros(self.info.n_states)
        self.fmu.getContinuousStates(x.ctypes.data_as(_double_p()), x.size)
        args = hold_arguments(
            self.api, self.comp, x, layout.angle, layout.speed,
            np.ascontiguousarray((theta.ravel() - oa) / fa),
            np.ascontiguousarray((dtheta.ravel() - os_) / fs), self.vr_in, out,
        )  # fmt: skip
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
            self._call(kernels.hold_me, args)
        return (out * ch["force"].factor + ch["force"].offset).reshape(theta.shape)

    def _run(self, f, out, t0, dt, substeps) -> int:
        if self.info.interface == "me":
            nx = self.info.n_states
            x = np.zeros(nx)
            if nx:
                self.fmu.getContinuousStates(x.ctypes.data_as(_double_p()), nx)
            args = me_arguments(
                self.api, self.comp, x, self.info.n_events, self._next_event, f, t0, dt,
                substeps, self.vr_in, self.vr_out, out,
            )  # fmt: skip
            return self._call(kernels.run_me, args)
        cs = cs_arguments(self.api, self.comp, f, t0, dt, self.vr_in, self.vr_out, out)
        return self._call(kernels.run_cs, cs)

    def _call(self, kernel, args) -> int:
        """``kernel(*args)``, through its compiled entry point once it is known: numba's
        dispatcher would type the tuple of C functions again on every call (0.2 ms)."""
        entry = self._entries.get(kernel)
        if entry is not None:
            return entry(*args)
        status = kernel(*args)
        import numba

        compiled = kernel.overloads.get(tuple(numba.typeof(a) for a in args))
        if compiled is not None:
            self._entries[kernel] = compiled.entry_point
        return status


# -- the kernels' arguments, in the types they are compiled for -----------------------
# One place for the conversions: a run and `evo-door compile` (compile_runners) pass
# the same types, so what compile put in numba's cache is what a run finds there.
def me_arguments(api, comp, x, n_events, next_event, force, t0, dt, substeps, vr_in, vr_out, out):
    """The arguments of :func:`~evo_door.models.fmu.kernels.run_me`."""
    return (
        api, np.uintp(comp), x, int(n_events), float(next_event), force, float(t0),
        float(dt), int(substeps), vr_in, vr_out, out,
    )  # fmt: skip


def cs_arguments(api, comp, force, t0, dt, vr_in, vr_out, out):
    """The arguments of :func:`~evo_door.models.fmu.kernels.run_cs`."""
    return (api, np.uintp(comp), force, float(t0), float(dt), vr_in, vr_out, out)


def hold_arguments(api, comp, x, angle, speed, theta, dtheta, vr_in, out):
    """The arguments of :func:`~evo_door.models.fmu.kernels.hold_me` (at time 0)."""
    return (api, np.uintp(comp), x, int(angle), int(speed), 0.0, theta, dtheta, vr_in, out)


def runner_signatures() -> list[tuple]:
    """``(kernel, argument types)`` of every FMU kernel a run may call, for FMI 2 and
    3: the functions stubs (:func:`~evo_door.models.fmu.calls.stub_api`), the arrays
    of a run's dtypes and layouts, no FMU needed."""
    import numba

    x, f = np.zeros(1), np.zeros(1)
    vr, out = np.zeros(1, dtype=np.uint32), np.zeros((1, 1))
    found = []
    for version in (2, 3):
        fns = stub_api(version)
        for kernel, args in (
            (kernels.run_me, me_arguments(fns, 0, x, 0, math.inf, f, 0, 1, 1, vr, vr, out)),
            (kernels.run_cs, cs_arguments(fns, 0, f, 0, 1, vr, vr, out)),
            (kernels.hold_me, hold_arguments(fns, 0, x, 0, 1, x, x, vr, f)),
        ):
            with warnings.catch_warnings():  # typing the functions: "experimental"
                warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
                found.append((kernel, tuple(numba.typeof(a) for a in args)))
    return found


def compile_runners() -> None:
    """Compile (or load from numba's cache) every FMU kernel for FMI 2 and 3, without
    running one: what ``evo-door compile`` does, so that an FMU's first run compiles
    nothing."""
    with warnings.catch_warnings():  # numba's "experimental" first-class functions
        warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
        for kernel, types in runner_signatures():
            kernel.compile(types)


def _double_p():
    import ctypes

    return ctypes.POINTER(ctypes.c_double)


def _fmpy_class(version: int, interface: str):
    if version == 2:
        from fmpy.fmi2 import FMU2Model, FMU2Slave

        return FMU2Model if interface == "me" else FMU2Slave
    from fmpy.fmi3 import FMU3Model, FMU3Slave

    return FMU3Model if interface == "me" else FMU3Slave


def instance(info: FmuInfo) -> Instance:
    """This process's instance of the FMU ``info`` describes (made on first use)."""
    channels = tuple(sorted((k, c.name) for k, c in info.channels.items()))
    key = (str(info.path), info.interface, info.path.stat().st_mtime_ns, channels)
    inst = _INSTANCES.get(key)
    if inst is None:
        inst = _INSTANCES[key] = Instance(info)
    return inst
