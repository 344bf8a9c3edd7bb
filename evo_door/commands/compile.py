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

numba compiles on one core. Where there are two or more (``--jobs``, default: two where
the process may use two cores), a second process compiles what does not depend on the
one-coordinate integrators at the same time: the FMU runners and the emulator's physics
at once, then, as soon as this process has the integrators in the cache, the
state-vector integrators (:mod:`evo_door.sim.states` imports them), and, once this
process has the haptic model and the objective in the cache too, the render of the
haptic model and the modules that import only what is in the cache by then
(:data:`LATER`: the state-vector objective, the equilibrium, the mechanisms'
renderer, the yield's kernels). This process goes on meanwhile with the door, the GA
and its objectives, and imports the rest once the second has ended, so that no kernel
is compiled twice: a shorter wait on two cores (``python -m benchmarks --only
startup`` times it cold and warm; the render and :data:`LATER` are the second's
because it used to end long before the first). Both write numba's cache, each its own
kernels.
"""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import subprocess
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
    p.add_argument(
        "--jobs",
        type=_jobs,
        default=None,
        metavar="N",
        help="processes that compile at once: 1 or 2 (the work splits in two; default: 2 "
        "where this process may use two cores or more)",
    )
    # the second process of --jobs 2 (internal): its part, then its kernels as JSON
    p.add_argument("--second-part", action="store_true", help=argparse.SUPPRESS)
    p.set_defaults(func=run)


def _jobs(text: str) -> int:
    """``--jobs``: a whole number of at least 1; more than 2 is 2 (two parts)."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"at least 1 process, not {n}")
    return min(n, 2)


def default_jobs() -> int:
    """2 where this process may run on two cores or more, else 1."""
    from evo_door.optim.executors import cores

    return min(cores(), 2)


def modules() -> list[str]:
    """Every module of the package but the entry point."""
    import evo_door

    names = [
        info.name
        for info in pkgutil.walk_packages(evo_door.__path__, "evo_door.")
        if not info.name.endswith("__main__")
    ]
    return sorted(names)


def steps(second: SecondProcess | None = None):
    """``(what, callable)``: the work that compiles every kernel the commands use; with
    ``second``, the part the second process does is left to it, and waited for before
    the modules that import what it compiles."""
    from evo_door.sim_settings import KINDS

    def integrators():
        importlib.import_module("evo_door.sim.integrators")
        if second is not None:
            second.go()  # the state-vector integrators load these from the cache
        return ""

    def haptic():
        _simulating("haptic")
        if second is not None:
            second.more()  # its render and LATER load the haptic model from the cache
        return ""

    # first what needs neither the state-vector integrators nor the FMU runners (none
    # of these steps imports them, nor what the second process compiles once told
    # "more"), then, the second process's part done, the rest
    rendering = "a render of the haptic model on the simulated device"
    yield "the one-coordinate integrators", integrators
    yield "simulating the haptic model", haptic
    yield "simulating the door model", lambda: _simulating("door")
    with tempfile.TemporaryDirectory() as tmp:
        for kind in KINDS:
            yield f"a GA generation, objective {kind}", lambda kind=kind: _fitting(kind, Path(tmp))
    if second is None:
        yield rendering, _rendering
    else:
        yield f"waiting for the second process ({SECOND_PART})", second.wait
        if second.failure:  # its render is left to this process (LATER: imported below)
            yield rendering, _rendering
    yield "importing every module", _importing
    yield "the FMU runners (FMI 2 and 3, model exchange and co-simulation)", _fmu_runners
    yield "the HapticMaster emulator's physics", _emulator


def _importing() -> str:
    """Every module of the package (kernels with a declared signature compile there)."""
    skipped = []
    for name in modules():
        try:
            importlib.import_module(name)
        except ImportError as exc:  # an optional extra not installed (fmpy, dask...)
            skipped.append(f"{name} ({exc.name or exc})")
    return f"skipped {', '.join(skipped)}" if skipped else ""


def _simulating(name: str) -> str:
    """A built-in model by every integration scheme, by a batch, and its force-angle curve."""
    import numpy as np

    from evo_door.models import get_model
    from evo_door.sim import METHODS, simulate, simulate_batch
    from evo_door.sim.simulate import force_angle_curve

    model = get_model(name)
    params = model.load_params()
    dt = 1 / 1024
    force = np.where(np.arange(512) * dt < 0.1, 20.0, 0.0)
    for method in sorted(METHODS):
        simulate(model, params, force, dt, method=method)
    simulate_batch(model, np.array([params.vector] * 2), force, dt)
    force_angle_curve(model, params)
    return ""


def _fitting(kind: str, folder: Path) -> str:
    """A GA generation and its polish by the objective ``kind``, on two impulses of the
    virtual rig (no repository needed), made in ``folder`` the first time."""
    import evo_door
    from evo_door.models import get_model

    trials = folder / "trials.h5"
    if not trials.exists():
        from evo_door.data.io import write_trials
        from evo_door.data.rig.campaign import Campaign, generate_trials

        door = get_model("door")
        campaign = Campaign(users=1, trials=2, kinds=("impulse",))
        write_trials(trials, generate_trials(door, door.load_params(), campaign, progress=False))
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


def _rendering() -> str:
    """The haptic model rendered on the simulated device, in simulated time, with a log
    (written to a temporary folder, removed after)."""
    from evo_door.models import get_model
    from evo_door.render.device import SimDevice
    from evo_door.render.loop import ServoLoop

    params = get_model("haptic").load_params()
    loop = ServoLoop(SimDevice("open", radius=params["radius"]), params)
    loop.run(0.05)  # s of simulated time: 125 cycles at the default 2500 Hz
    with tempfile.TemporaryDirectory() as tmp:
        loop.write_log(Path(tmp) / "render.h5")
    return ""


def _fmu_runners() -> str:
    from evo_door.models.fmu.instance import compile_runners

    compile_runners()
    return ""


def _emulator() -> str:
    from evo_door.render.emulator_physics import compile_kernel

    compile_kernel()
    return ""


#: what the second process compiles, in its order
SECOND_PART = (
    "the FMU runners, the emulator's physics, the state-vector integrators, "
    "a render, the state-vector objective and the mechanisms' renderer"
)
#: the modules the second process imports last, once told "more" (each imports only
#: what the first has in the cache by then, the one-coordinate integrators, the haptic
#: model and the objective, and what the second compiled itself)
LATER = (
    "evo_door.render.mechanism_kernels",
    "evo_door.optim.yield_kernel",
    "evo_door.sim.equilibrium",
    "evo_door.sim.state_objective",
)


class SecondProcess:
    """``evo-door compile --second-part`` beside this process: it compiles the FMU
    runners and the emulator's physics at once, the state-vector integrators once told
    (:meth:`go`: the one-coordinate ones, which they import, are in the cache), a
    render and :data:`LATER` once told more (:meth:`more`: the haptic model and the
    objective are in the cache), and ends by printing what it compiled. Its progress
    lines are said when it is waited for (:meth:`wait`), after this process's own. A
    failed or missing second process costs time, never a kernel: this process's own
    steps then compile what it left."""

    def __init__(self, quiet: bool):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "evo_door", "compile", "--second-part"]
            + (["--quiet"] if quiet else []),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.compiled: list[str] = []
        self.failure = ""

    def go(self) -> None:
        self._say("go", last=False)

    def more(self) -> None:
        self._say("more", last=True)

    def _say(self, word: str, last: bool) -> None:
        """Write ``word`` to its stdin (closed after the last word, or on an error)."""
        stdin = self.proc.stdin
        if stdin is None:  # closed already
            return
        try:
            stdin.write(word + "\n")
            stdin.flush()
        except OSError:  # it has ended already: wait() says how
            last = True
        if last:
            self.proc.stdin = None  # communicate() then leaves it
            try:
                stdin.close()
            except OSError:
                pass

    def wait(self) -> str:
        from evo_door.kernel_cache import kernels

        self.more()  # said after the haptic model already (then a no-op); else now
        out, err = self.proc.communicate()
        sys.stderr.write(err)
        if self.proc.returncode != 0:
            self.failure = f"the second process failed (exit {self.proc.returncode})"
            return f"{self.failure}; what it left compiles here"
        try:
            self.compiled = json.loads(out.strip().splitlines()[-1])["compiled"]
        except (ValueError, IndexError, KeyError, TypeError):
            self.failure = "the second process said nothing readable"
            return f"{self.failure}; what it left compiles here"
        return f"it compiled {kernels(len(self.compiled))}"

    def stop(self) -> None:
        """End it if it still runs (this process failed or was interrupted)."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


def _second_part(args) -> int:
    """The second process's part (:class:`SecondProcess`); its kernels as JSON on stdout."""
    from evo_door import kernel_cache
    from evo_door.errors import UserError

    if sys.stdin.isatty():  # a person, not the first process: it would wait for "go"
        raise UserError(
            "--second-part is evo-door compile's own second process: run evo-door compile"
        )

    def report(name, count, seconds):
        print(
            f"evo-door: compiling {name} (second process, kernel {count}, {seconds:.0f} s so far)",
            file=sys.stderr,
        )

    say = (lambda line: None) if args.quiet else (lambda line: print(line, file=sys.stderr))
    kernel_cache.COMPILES.report = None if args.quiet else report
    kernel_cache.COMPILES.clear()
    say("compile (second process): the FMU runners")
    _fmu_runners()
    say("compile (second process): the HapticMaster emulator's physics")
    _emulator()
    if sys.stdin.readline().strip() != "go":  # the first process ended or failed
        return 1
    say("compile (second process): the state-vector integrators")
    importlib.import_module("evo_door.sim.states")
    if sys.stdin.readline().strip() == "more":  # else the first does the rest
        say("compile (second process): a render of the haptic model on the simulated device")
        _rendering()
        say("compile (second process): " + ", ".join(LATER))
        for name in LATER:
            importlib.import_module(name)
    kernel_cache.COMPILES.report = None
    print(json.dumps({"compiled": kernel_cache.COMPILES.compiled}))
    return 0


def run(args) -> int:
    from evo_door import kernel_cache

    if args.second_part:
        return _second_part(args)
    jobs = args.jobs if args.jobs is not None else default_jobs()
    if args.quiet:
        kernel_cache.finish_announce(summary=False)
    kernel_cache.COMPILES.clear()
    start = time.perf_counter()
    say = (lambda line: None) if args.quiet else (lambda line: print(line, file=sys.stderr))
    second = SecondProcess(args.quiet) if jobs > 1 else None
    try:
        for what, work in steps(second):
            say(f"compile: {what}")
            note = work()
            if note:
                say(f"compile: {note}")
    finally:
        if second is not None:
            second.stop()
    mine = kernel_cache.COMPILES.compiled
    theirs = second.compiled if second is not None else []
    twice = sorted(set(mine) & set(theirs))
    n = len(mine) + len(theirs)
    kernel_cache.finish_announce(summary=False)
    took = time.perf_counter() - start
    where = " in 2 processes" if second is not None and not second.failure else ""
    print(
        f"compiled {kernel_cache.kernels(n)}{where} in {took:.1f} s"
        if n
        else "nothing to compile: every kernel was in numba's cache"
    )
    if twice:  # the split is meant to keep them apart: time lost, nothing wrong
        print(f"evo-door: compiled in both processes: {', '.join(twice)}", file=sys.stderr)
    return 0
