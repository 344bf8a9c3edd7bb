"""``evo-door compile``: compile the kernels once, ahead of the first real command.

numba compiles a kernel the first time it runs and keeps it in its disk cache
(:mod:`evo_door.kernel_cache`, which also drops an entry whose sources changed). A first
command after an install therefore waits for its kernels; this command pays that wait at
a time of the user's choosing: for a cluster image, a CI job, a lab machine before a
session. It imports every module of the package (kernels with a declared signature
compile there) and runs each built-in model through what the commands use, briefly:
a simulation by every integration scheme, one by a batch, a force-angle curve, and a
GA generation with its polish by every objective, on two impulses of the virtual rig (no
repository data needed), a render of the haptic model on the simulated device, in
simulated time, the FMU runners for FMI 2 and 3 (compiled for the types of any FMU's
functions: no FMU needed) and the HapticMaster emulator's physics. ``evo-door
simulate``, ``evo-door run``, ``evo-door render`` and ``evo-door emulate`` then compile
nothing (``tests/test_kernel_cache.py``), nor an FMU's first run (``tests/test_fmu.py``).
A mechanism file's module (the user's own) compiles at its first use, named by the notes.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
import tempfile
import time
from pathlib import Path

ORDER = 95


def register(sub) -> None:
    p = sub.add_parser(
        "compile",
        help="compile numba's kernels once (a cluster image, CI, a lab machine before a "
        "session); later commands start at once",
    )
    p.add_argument(
        "--quiet", action="store_true", help="no line per step or kernel, only the summary"
    )
    p.set_defaults(func=run)


def modules() -> list[str]:
    """Every module of the package but the entry point."""
    import evo_door

    names = [
        info.name
        for info in pkgutil.walk_packages(evo_door.__path__, "evo_door.")
        if not info.name.endswith("__main__")
    ]
    return sorted(names)


def steps():
    """``(what, callable)``: the work that compiles every kernel the commands use."""
    import numpy as np

    from evo_door.models import get_model
    from evo_door.sim import METHODS, simulate, simulate_batch
    from evo_door.sim.simulate import force_angle_curve
    from evo_door.sim_settings import KINDS

    def importing():
        skipped = []
        for name in modules():
            try:
                importlib.import_module(name)
            except ImportError as exc:  # an optional extra not installed (fmpy, dask...)
                skipped.append(f"{name} ({exc.name or exc})")
        return f"skipped {', '.join(skipped)}" if skipped else ""

    def simulating(name):
        model = get_model(name)
        params = model.load_params()
        dt = 1 / 1024
        force = np.where(np.arange(512) * dt < 0.1, 20.0, 0.0)
        for method in sorted(METHODS):
            simulate(model, params, force, dt, method=method)
        simulate_batch(model, np.array([params.vector] * 2), force, dt)
        force_angle_curve(model, params)
        return ""

    def fitting(kind, folder):
        import evo_door

        trials = folder / "trials.h5"
        if not trials.exists():  # two impulses of the virtual rig (no repository needed)
            from evo_door.data.io import write_trials
            from evo_door.data.rig.campaign import Campaign, generate_trials

            door = get_model("door")
            campaign = Campaign(users=1, trials=2, kinds=("impulse",))
            write_trials(
                trials, generate_trials(door, door.load_params(), campaign, progress=False)
            )
        evo_door.Experiment(
            name="compile",
            model="door",
            params="default",
            target=evo_door.trial_file(trials, preprocess={"rate_bias": "start"}),
            free={"M": [0.3, 2.5]},
            objective={"kind": kind, "derivative": 1},
            algorithm={"population": 4, "generations": 1, "seed": 1},  # and its polish
        ).run(folder / f"{kind}.h5")
        return ""

    def rendering(folder):
        from evo_door.render.device import SimDevice
        from evo_door.render.loop import ServoLoop

        params = get_model("haptic").load_params()
        loop = ServoLoop(SimDevice("open", radius=params["radius"]), params)
        loop.run(0.05)  # s of simulated time: 125 cycles at the default 2500 Hz
        loop.write_log(folder / "render.h5")
        return ""

    yield "importing every module", importing
    for name in ("haptic", "door"):
        yield f"simulating the {name} model", lambda name=name: simulating(name)
    with tempfile.TemporaryDirectory() as tmp:
        for kind in KINDS:
            yield f"a GA generation, objective {kind}", lambda kind=kind: fitting(kind, Path(tmp))
        yield "a render of the haptic model on the simulated device", lambda: rendering(Path(tmp))
    yield "the FMU runners (FMI 2 and 3, model exchange and co-simulation)", _fmu_runners
    yield "the HapticMaster emulator's physics", _emulator


def _fmu_runners() -> str:
    from evo_door.models.fmu.instance import compile_runners

    compile_runners()
    return ""


def _emulator() -> str:
    from evo_door.render.emulator_physics import compile_kernel

    compile_kernel()
    return ""


def run(args) -> int:
    from evo_door import kernel_cache

    if args.quiet:
        kernel_cache.finish_announce(summary=False)
    kernel_cache.COMPILES.count = 0
    start = time.perf_counter()
    say = (lambda line: None) if args.quiet else (lambda line: print(line, file=sys.stderr))
    for what, work in steps():
        say(f"compile: {what}")
        note = work()
        if note:
            say(f"compile: {note}")
    n = kernel_cache.COMPILES.count
    kernel_cache.finish_announce(summary=False)
    print(
        f"compiled {kernel_cache.kernels(n)} in {time.perf_counter() - start:.1f} s"
        if n
        else "nothing to compile: every kernel was in numba's cache"
    )
    return 0
