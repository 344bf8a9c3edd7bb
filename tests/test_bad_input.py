"""Every command against every kind of bad input: one line, exit 2, nothing left behind.

Each case runs ``evo-door ARGS`` in-process on a workspace of good and bad files and
checks what a user sees: exit status 2, exactly one line on stderr that starts with
``evo-door: error:`` and names the file or option at fault, no traceback, and the
workspace unchanged, byte for byte (no new file, no temporary, no lock file, no
half-written output).
"""

import hashlib
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from evo_door.data import write_trials
from evo_door.experiment import load_experiment, run_experiment
from tests.test_cli import cli
from tests.test_experiment import EXPERIMENT
from tests.test_optim import make_trial

PNG = b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4

#: an experiment fitted to another model driven by the rig's trials, written inline
RIG_EXPERIMENT = """\
name: rig
model: tests.conftest:OSCILLATOR_MODEL
target:
  model: tests.conftest:OSCILLATOR_MODEL
  inputs:
    model: tests.conftest:OSCILLATOR_MODEL
    users: 2
    trials: 2
    seed: 1
free: {k: [20, 500]}
algorithm: {population: 4, generations: 1}
"""


def _readonly_folder(tmp: Path) -> Path:
    """A folder nobody may write in: chmod 555, or, for root (who ignores modes), /sys."""
    if os.geteuid() != 0:
        folder = tmp / "ro"
        folder.mkdir()
        folder.chmod(0o555)
        return folder
    folder = Path("/sys")
    if not folder.is_dir() or os.access(folder, os.W_OK) and _writable(folder):
        pytest.skip("no read-only folder on this machine")
    return folder


def _writable(folder: Path) -> bool:
    try:
        (folder / ".evo-door-probe").touch()
    except OSError:
        return False
    (folder / ".evo-door-probe").unlink()
    return True


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    """The workspace: an experiment, trials, a complete run and assorted bad files."""
    w = tmp_path_factory.mktemp("ws")
    trials = [make_trial(s, 0.75, tid=f"t{s}") for s in (1, 2, 3)] + [make_trial(4, 0.75, tid="v1")]
    write_trials(w / "trials.h5", trials)
    (w / "exp.yaml").write_text(EXPERIMENT)
    (w / "rig.yaml").write_text(RIG_EXPERIMENT)
    (w / "rig-bad.yaml").write_text(RIG_EXPERIMENT.replace("users: 2", "users: abc"))
    # a bad JND setting on its own line, below the perception: key
    (w / "perception.yaml").write_text(
        EXPERIMENT + "perception:\n  force_floor: 0.5\n  force: 1.5\n"
    )
    exp = load_experiment(w / "exp.yaml", ["algorithm.generations=2", "algorithm.polish=none"])
    run_experiment(exp, out=w / "run.h5")
    t = np.arange(64) / 1024
    (w / "force.csv").write_text("t,force\n" + "".join(f"{a:.8f},1.0\n" for a in t))
    (w / "picture.png").write_bytes(PNG)
    (w / "afile").write_text("a file, not a folder\n")
    (w / "folder").mkdir()
    data = (w / "run.h5").read_bytes()
    (w / "truncated.h5").write_bytes(data[: len(data) // 2])
    (w / "truncated.yaml").write_text("model: door\nvalues:\n  M: [1.0,\n")
    (w / "truncated.csv").write_text("t,force\n0.0,1.0\n0.0009765625,")
    # a damaged compressed chunk inside an otherwise sound trial file
    shutil.copy(w / "trials.h5", w / "corrupt.h5")
    with h5py.File(w / "corrupt.h5") as f:
        ds = f["trials/t1/dtheta"]
        info = ds.id.get_chunk_info(0)
    with open(w / "corrupt.h5", "r+b") as fh:
        fh.seek(info.byte_offset + 16)
        fh.write(b"\xff" * 64)
    (w / "ro").mkdir()  # replaced by a truly read-only folder per test when not root
    # parameter files, for outputs named like an input (p.csv: YAML all the same)
    from evo_door.models import get_model

    get_model("door").load_params(None).to_yaml(w / "p.yaml")
    shutil.copy(w / "p.yaml", w / "p.csv")
    get_model("haptic").load_params("seed_trial").to_yaml(w / "hp.yaml")
    (w / "side.partial").write_bytes(b"a render's side file\n")
    # NaN in a parameter file and in a render log taken as parameters
    (w / "nan.yaml").write_text("model: haptic\nvalues:\n  open_force: .nan\n")
    _nan_render_log(w / "nanlog.h5")
    return w


def _nan_render_log(path: Path) -> None:
    """A render log whose parameter set holds a NaN (as a damaged file could)."""
    from evo_door.models.haptic import PARAMS
    from evo_door.render.log import N_COLUMNS, RenderLog

    log = RenderLog(1000.0, PARAMS)
    vector = PARAMS.defaults.copy()
    vector[PARAMS.index("open_force")] = np.nan
    log.params(0.0, vector)
    for k in range(10):
        log.add(k * 0.001, np.zeros(N_COLUMNS))
    log.write(path, loop_rate=2500.0, device="sim", statistics={})


def snapshot(folder: Path) -> dict:
    return {
        str(p.relative_to(folder)): hashlib.sha1(p.read_bytes()).hexdigest()
        if p.is_file()
        else "dir"
        for p in sorted(folder.rglob("*"))
    }


#: what the error says when an output is one of the command's inputs
IN = "is also an input of this command"

#: a headless render on the simulated device with a log (a bad flag leaves no side file)
_RENDER = "render --params seed_trial --user hold --log {w}/new.h5 "

#: (command line, what the error must name). {w}: the workspace; {ro}: a read-only folder.
CASES = {
    # params
    "params: missing file": ("params door --params {w}/missing.yaml", "missing.yaml"),
    "params: a results file": (
        "params door --params {w}/run.h5",
        "run.h5: a results file, not a parameter file",
    ),
    "params: binary (picture)": ("params door --params {w}/picture.png", "picture.png: binary"),
    "params: truncated YAML": ("params door --params {w}/truncated.yaml", "truncated.yaml"),
    "params: out of range": ("params door --set M=1e9", "'M'"),
    "params: read-only target": ("params door --write {ro}/p.yaml", "p.yaml"),
    "params: file as folder": ("params door --write {w}/afile/p.yaml", "afile"),
    # simulate
    "simulate: missing input": (
        "simulate door --input {w}/missing.csv --out {w}/o.csv",
        "missing.csv",
    ),
    "simulate: results file as input": (
        "simulate door --input {w}/run.h5 --out {w}/o.csv",
        "run.h5",
    ),
    "simulate: binary input": ("simulate door --input {w}/picture.png --out {w}/o.csv", "png"),
    "simulate: truncated input": (
        "simulate door --input {w}/truncated.csv --out {w}/o.csv",
        "truncated.csv",
    ),
    "simulate: read-only target": (
        "simulate door --input {w}/force.csv --out {ro}/o.csv",
        "o.csv",
    ),
    "simulate: file as folder": (
        "simulate door --input {w}/force.csv --out {w}/afile/o.csv",
        "afile",
    ),
    "simulate: theta0 out of range": (
        "simulate door --input {w}/force.csv --theta0 10 --out {w}/o.csv",
        "--theta0",
    ),
    "simulate: substeps 0": (
        "simulate door --input {w}/force.csv --substeps 0 --out {w}/o.csv",
        "--substeps",
    ),
    "simulate: tolerance out of range": (
        "simulate door --input {w}/force.csv --tolerance 2 --out {w}/o.csv",
        "--tolerance",
    ),
    "simulate: tolerance not a number": (
        "simulate door --input {w}/force.csv --tolerance tight --out {w}/o.csv",
        "--tolerance",
    ),
    # curve
    "curve: unsupported image": (
        "curve door --out {w}/c.csv --plot {w}/c.jpg2",
        "c.jpg2",
    ),
    "curve: read-only target": ("curve door --out {ro}/c.csv", "c.csv"),
    "curve: file as folder": ("curve door --out {w}/afile/c.csv", "afile"),
    "curve: no points": ("curve door --points 0 --out {w}/c.csv", "--points"),
    "curve: speed not above 0": ("curve door --speed -0.02 --out {w}/c.csv", "--speed"),
    "curve: coulomb and a speed": (
        "curve door --coulomb --speed 0.02 --out {w}/c.csv",
        "--coulomb and --speed",
    ),
    # draw
    "draw: not an image": ("draw door --out {w}/d.txt", "d.txt"),
    "draw: read-only target": ("draw door --out {ro}/d.png", "d.png"),
    "draw: bad angles": ("draw door --angles 0,abc --out {w}/d.png", "--angles"),
    # rig
    "rig: read-only target": ("rig generate --model door --trials 1 --out {ro}/t.h5", "t.h5"),
    "rig: file as folder": (
        "rig generate --model door --trials 1 --out {w}/afile/t.h5",
        "afile",
    ),
    "rig: no trials": ("rig generate --model door --trials 0 --out {w}/t.h5", "--trials"),
    "rig: binary parameter file": (
        "rig generate --model door --params {w}/run.h5 --out {w}/t.h5",
        "run.h5",
    ),
    # data import
    "data import: results file": ("data import {w}/run.h5 --out {w}/x.h5", "run.h5"),
    "data import: missing": ("data import {w}/missing.csv --out {w}/x.h5", "missing.csv"),
    "data import: picture": ("data import {w}/picture.png --out {w}/x.h5", "picture.png"),
    "data import: truncated HDF5": ("data import {w}/truncated.h5 --out {w}/x.h5", "truncated.h5"),
    "data import: corrupt chunk": ("data import {w}/corrupt.h5 --out {w}/x.h5", "corrupt.h5"),
    "data import: read-only target": ("data import {w}/trials.h5 --out {ro}/x.h5", "x.h5"),
    "data import: file as folder": ("data import {w}/trials.h5 --out {w}/afile/x.h5", "afile"),
    # data show
    "data show: results file": ("data show {w}/run.h5", "run.h5"),
    "data show: corrupt chunk": ("data show {w}/corrupt.h5", "corrupt.h5"),
    "data show: truncated": ("data show {w}/truncated.h5", "truncated.h5"),
    "data show: unsupported image": ("data show {w}/trials.h5 --plot {w}/x.jpg2", "x.jpg2"),
    "data show: read-only plot": ("data show {w}/trials.h5 --plot {ro}/x.png", "x.png"),
    # run
    "run: missing experiment": ("run {w}/missing.yaml --out {w}/r.h5", "missing.yaml"),
    "run: results file as experiment": ("run {w}/run.h5 --out {w}/r.h5", "run.h5: binary"),
    "run: picture as experiment": ("run {w}/picture.png --out {w}/r.h5", "picture.png"),
    "run: file as folder": ("run {w}/exp.yaml --out {w}/afile/r.h5", "afile"),
    "run: read-only target": ("run {w}/exp.yaml --out {ro}/r.h5", "r.h5"),
    "run: /proc target": ("run {w}/exp.yaml --out /proc/r.h5", "/proc/r.h5"),
    "run: complete run at --out": ("run {w}/exp.yaml --out {w}/run.h5", "--force"),
    "run: results file as target data": (
        "run {w}/exp.yaml --set target.data={w}/run.h5 --out {w}/r.h5",
        "run.h5",
    ),
    "run: corrupt target data": (
        "run {w}/exp.yaml --set target.data={w}/corrupt.h5 --out {w}/r.h5",
        "corrupt.h5",
    ),
    "run: simulation tolerance 0": (
        "run {w}/exp.yaml --set simulation.tolerance=0 --out {w}/r.h5",
        "--set simulation.tolerance=0: simulation.tolerance: must be a number in [1e-13, 1)",
    ),
    "run: simulation tolerance 1e-300 (would never end)": (
        "run {w}/exp.yaml --set simulation.tolerance=1e-300 --out {w}/r.h5",
        "simulation.tolerance: must be a number in [1e-13, 1)",
    ),
    "simulate: tolerance 1e-300": (
        "simulate door --input {w}/force.csv --out {w}/o.csv --tolerance 1e-300",
        "--tolerance",
    ),
    "simulate: a billion substeps": (
        "simulate door --input {w}/force.csv --out {w}/o.csv --substeps 1000000000",
        "--substeps",
    ),
    "curve: a billion points": ("curve door --out {w}/c.csv --points 1000000000", "--points"),
    "rig: a billion users": (
        "rig generate --model door --users 1000000000 --out {w}/t.h5",
        "--users",
    ),
    "run: simulation tolerance 1": (
        "run {w}/exp.yaml --set simulation.tolerance=1 --out {w}/r.h5",
        "simulation.tolerance: must be a number in [1e-13, 1) (dopri5's per step",
    ),
    "run: simulation tolerance not a number": (
        "run {w}/exp.yaml --set simulation.tolerance=tight --out {w}/r.h5",
        "simulation.tolerance: expected a finite number, got 'tight'",
    ),
    "run: perception, a Weber fraction of 1.5": (
        "run {w}/perception.yaml --out {w}/r.h5",
        "perception.yaml:{line}: perception.force: a Weber fraction below 1 (0.1 is 10 %), got 1.5",
    ),
    "run: perception, a force floor of 0": (
        "run {w}/exp.yaml --set perception.force_floor=0 --out {w}/r.h5",
        "perception.force_floor: must be > 0, got 0",
    ),
    "run: perception, an unknown setting": (
        "run {w}/exp.yaml --set perception.forse=0.1 --out {w}/r.h5",
        "perception.forse: unknown key (did you mean 'force'",
    ),
    "run: perception, not a mapping": (
        "run {w}/exp.yaml --set perception=3 --out {w}/r.h5",
        "perception: expected a mapping of JND settings",
    ),
    "run: population beyond memory": (
        "run {w}/exp.yaml --set algorithm.population=1e9 --out {w}/r.h5",
        "algorithm.population",
    ),
    # run: an inline rig specification (target.inputs), each entry as rig generate's flags
    "run: rig users not a number": (
        "run {w}/rig-bad.yaml --out {w}/r.h5",
        "rig-bad.yaml:7: target.inputs.users: expected a whole number, got 'abc'",
    ),
    "run: rig no users": ("run {w}/rig.yaml --set target.inputs.users=0", "inputs.users: must be"),
    "run: rig trials not whole": (
        "run {w}/rig.yaml --set target.inputs.trials=2.5",
        "target.inputs.trials: expected a whole number, got 2.5",
    ),
    "run: rig negative seed": ("run {w}/rig.yaml --set target.inputs.seed=-1", "inputs.seed"),
    "run: rig seed not a number": (
        "run {w}/rig.yaml --set target.inputs.seed=x",
        "target.inputs.seed: expected a whole number",
    ),
    "run: rig rate 0": ("run {w}/rig.yaml --set target.inputs.rate=0", "inputs.rate: must be"),
    "run: rig rate not a number": ("run {w}/rig.yaml --set target.inputs.rate=abc", "inputs.rate"),
    "run: rig unknown kind": (
        "run {w}/rig.yaml --set target.inputs.kinds=[imuplse]",
        "target.inputs.kinds: unknown trial kind 'imuplse' (did you mean 'impulse'?)",
    ),
    "run: rig kind the model cannot make": (
        "run {w}/rig.yaml --set target.inputs.kinds=lock",
        "cannot make lock trials",
    ),
    "run: rig all_sensors not a boolean": (
        "run {w}/rig.yaml --set target.inputs.all_sensors=3",
        "target.inputs.all_sensors: expected true or false",
    ),
    "run: rig set not a mapping": ("run {w}/rig.yaml --set target.inputs.set=3", "inputs.set"),
    "run: rig set of an unknown parameter": (
        "run {w}/rig.yaml --set target.inputs.set.kk=3",
        "no parameter 'kk' (did you mean 'k'?)",
    ),
    "run: rig unknown key": (
        "run {w}/rig.yaml --set target.inputs.usres=3",
        "target.inputs.usres: unknown key (did you mean 'users'",
    ),
    "run: rig unknown model": ("run {w}/rig.yaml --set target.inputs.model=nope", "'nope'"),
    "run: rig unknown preset": ("run {w}/rig.yaml --set target.inputs.params=nope", "'nope'"),
    "rig: negative seed": ("rig generate --model door --seed -1 --out {w}/t.h5", "--seed"),
    # compare-objectives
    "compare-objectives: missing experiment": (
        "compare-objectives {w}/missing.yaml --out {w}/cmp",
        "missing.yaml",
    ),
    "compare-objectives: results file as experiment": (
        "compare-objectives {w}/run.h5 --out {w}/cmp",
        "run.h5: binary",
    ),
    "compare-objectives: unknown kind": (
        "compare-objectives {w}/exp.yaml --kinds ise,msq --out {w}/cmp",
        "--kinds",
    ),
    "compare-objectives: derivative 3": (
        "compare-objectives {w}/exp.yaml --derivatives 0,3 --out {w}/cmp",
        "--derivatives",
    ),
    "compare-objectives: no seeds": (
        "compare-objectives {w}/exp.yaml --seeds 0 --out {w}/cmp",
        "--seeds",
    ),
    "compare-objectives: read-only target": (
        "compare-objectives {w}/exp.yaml --out {ro}/cmp",
        "cmp",
    ),
    "compare-objectives: file as folder": (
        "compare-objectives {w}/exp.yaml --out {w}/afile/cmp",
        "afile",
    ),
    # export-spec, report
    "export-spec: missing": ("export-spec {w}/missing.h5", "missing.h5"),
    "export-spec: trials, not a run": ("export-spec {w}/trials.h5", "trials.h5"),
    "export-spec: unknown format": ("export-spec {w}/run.h5 --format xls", "--format 'xls'"),
    "export-spec: a stage of a run": ("export-spec {w}/run.h5 --stage physical", "run.h5"),
    "export-spec: read-only target": ("export-spec {w}/run.h5 --out {ro}/s.md", "s.md"),
    "export-spec: file as folder": ("export-spec {w}/run.h5 --out {w}/afile/s.md", "afile"),
    "report: missing": ("report {w}/missing.h5", "missing.h5"),
    "report: a picture": ("report {w}/picture.png --out {w}/rep", "picture.png"),
    "report: truncated": ("report {w}/truncated.h5 --out {w}/rep", "truncated.h5"),
    "report: JND out of range": ("report {w}/run.h5 --jnd 1.5 --out {w}/rep", "--jnd"),
    "report: a file as folder": ("report {w}/run.h5 --out {w}/afile", "afile"),
    "report: read-only target": ("report {w}/run.h5 --out {ro}/rep", "rep"),
    # show, runs, resume
    "show: missing": ("show {w}/missing.h5", "missing.h5"),
    "show: trials, not a run": ("show {w}/trials.h5", "trials.h5"),
    "show: picture": ("show {w}/picture.png", "picture.png"),
    "show: truncated": ("show {w}/truncated.h5", "truncated.h5"),
    "show: plot to a folder": ("show {w}/run.h5 --plot {w}/folder", "folder"),
    "show: unsupported image": ("show {w}/run.h5 --plot {w}/f.jpg2", "f.jpg2"),
    "show: read-only plot": ("show {w}/run.h5 --plot {ro}/f.png", "f.png"),
    "show: a good plot and a bad convergence image": (
        "show {w}/run.h5 --plot {w}/f.png --convergence {w}/c.jpg2",
        "c.jpg2",
    ),
    "show: convergence to an unsupported image": (
        "show {w}/run.h5 --convergence {w}/c.jpg2",
        "c.jpg2",
    ),
    "compare: one run only": ("compare {w}/run.h5", "compare"),
    "compare: a missing run": ("compare {w}/run.h5 {w}/missing.h5", "missing.h5"),
    "compare: trials, not a run": ("compare {w}/run.h5 {w}/trials.h5", "trials.h5"),
    "compare: a picture": ("compare {w}/run.h5 {w}/picture.png", "picture.png"),
    "compare: --stage, no pipeline": ("compare {w}/run.h5 {w}/run.h5 --stage latch", "--stage"),
    "compare: a stage of a run": ("compare {w}/run.h5 {w}/run.h5:latch", "run.h5: holds one run"),
    "runs: missing folder": ("runs {w}/nowhere", "nowhere"),
    "runs: a file": ("runs {w}/afile", "afile"),
    "resume: missing": ("resume {w}/missing.h5", "missing.h5"),
    "resume: trials, not a run": ("resume {w}/trials.h5", "trials.h5"),
    "resume: truncated": ("resume {w}/truncated.h5", "truncated.h5"),
    "resume: picture": ("resume {w}/picture.png", "picture.png"),
    "resume: unknown executor": ("resume {w}/run.h5 --executor gpu", "'gpu'"),
    "run: unknown executor": ("run {w}/exp.yaml --executor gpu --out {w}/r.h5", "'gpu'"),
    "run: no workers in a pool": (
        "run {w}/exp.yaml --executor processes:0 --out {w}/r.h5",
        "processes:0",
    ),
    "batch: read-only target": ("batch {w}/exp.yaml --out {ro}/b", "b"),
    "batch: file as folder": ("batch {w}/exp.yaml --out {w}/afile/b", "afile"),
    "batch: bad --set": ("batch {w}/exp.yaml --set =3 --out {w}/b", "--set"),
    "batch: unknown executor": ("batch {w}/exp.yaml --executor gpu --out {w}/b", "'gpu'"),
    "bench: unknown section": ("bench --only nope --out {w}/bench", "nope"),
    # every numeric flag of render, push, console and emulate has a declared range
    # (evo_door.commands._common.Range); a render's --log is refused before a side file
    "render: duration 0": (_RENDER + "--duration 0", "--duration"),
    "render: duration inf": (_RENDER + "--duration inf", "--duration inf: must be finite"),
    "render: duration beyond a day": (_RENDER + "--duration 1e6", "--duration"),
    "render: rate nan": (_RENDER + "--duration 1 --rate nan", "--rate nan"),
    "render: rate beyond the loop": (_RENDER + "--duration 1 --rate 1e6", "--rate"),
    "render: rate not a number": (_RENDER + "--duration 1 --rate fast", "--rate 'fast'"),
    "render: log rate above the loop rate": (
        _RENDER + "--duration 1 --log-rate 1e8",
        "--log-rate 100000000: must be in 1..2500 Hz (up to --rate)",
    ),
    "render: log rate 0": (_RENDER + "--duration 1 --log-rate 0", "--log-rate"),
    "render: device damping inf": (_RENDER + "--duration 1 --device-damping inf", "N s/m"),
    "render: device damping negative": (_RENDER + "--duration 1 --device-damping -1", "N s/m"),
    "render: device damping absurd": (_RENDER + "--duration 1 --device-damping 1e300", "N s/m"),
    "render: watchdog misses 0": (_RENDER + "--duration 1 --watchdog-misses 0", "--watchdog"),
    "render: watchdog misses a fraction": (
        _RENDER + "--duration 1 --watchdog-misses 1.5",
        "--watchdog-misses",
    ),
    "render: console port beyond 65535": (
        _RENDER + "--duration 1 --console-port 70000",
        "--console-port",
    ),
    "render: seed negative": (_RENDER + "--duration 1 --seed -1", "--seed"),
    "render: token too long": (
        _RENDER + "--duration 1 --control 0 --token " + "t" * 300,
        "--token",
    ),
    "render: NaN in a parameter file": (
        "render --params {w}/nan.yaml --user hold --duration 1 --log {w}/new.h5",
        "nan.yaml: parameter 'open_force' is nan",
    ),
    "render: NaN in a log as parameters": (
        "render --params {w}/nanlog.h5 --user hold --duration 1 --log {w}/new.h5",
        "'open_force' is nan",
    ),
    "push: NaN in a parameter file": ("push {w}/nan.yaml --to 1", "nan.yaml"),
    "push: NaN in --set": ("push --set open_force=nan --to 1", "'open_force' is nan"),
    "push: timeout inf": ("push --set open_force=3 --to 1 --timeout inf", "--timeout"),
    "push: timeout 0": ("push --set open_force=3 --to 1 --timeout 0", "--timeout"),
    "push: token too long": ("push --set open_force=3 --to 1 --token " + "t" * 300, "--token"),
    "console: port beyond 65535": ("console --control 1 --port 70000", "--port"),
    "console: port not a number": ("console --control 1 --port http", "--port"),
    "console: token too long": ("console --control 1 --token " + "t" * 300, "--token"),
    "render-check: missing log": (
        "render-check {w}/missing.h5",
        "missing.h5: render log not found",
    ),
    "render-check: a trial file, no render log": ("render-check {w}/trials.h5", "not a render log"),
    "render-check: a picture": ("render-check {w}/picture.png", "picture.png"),
    "render-check: a truncated file": ("render-check {w}/truncated.h5", "truncated.h5"),
    "render-check: NaN in the log's set": ("render-check {w}/nanlog.h5", "open_force"),
    "render-check: window inf": ("render-check {w}/nanlog.h5 --window inf", "--window"),
    "render-check: device friction beyond the force": (
        "render-check {w}/nanlog.h5 --device-friction 1e9",
        "--device-friction",
    ),
    "emulate: port beyond 65535": ("emulate hapticmaster --port 70000", "--port"),
    "emulate: no mass": ("emulate hapticmaster --inertia 0", "--inertia"),
    "emulate: damping inf": ("emulate hapticmaster --damping inf", "--damping"),
    "emulate: friction beyond the force": ("emulate hapticmaster --coulomb 1e9", "--coulomb"),
    "emulate: noise nan": ("emulate hapticmaster --noise nan", "--noise"),
    "emulate: seconds inf": ("emulate hapticmaster --seconds inf", "--seconds"),
    "emulate: seconds 0": ("emulate hapticmaster --seconds 0", "--seconds"),
    # a trial file is replaced only with --force (data import: or extended, --append)
    "data import: trial file at --out": (
        "data import {w}/force.csv --out {w}/trials.h5",
        "--force to replace it or --append",
    ),
    "rig: trial file at --out": (
        "rig generate --model door --trials 1 --out {w}/trials.h5",
        "--force to replace it",
    ),
    # the supervisor's flags go with a real device, and not together
    "render: --no-supervisor on the simulated device": (
        "render --params seed_trial --user hold --duration 0.1 --no-supervisor",
        "--no-supervisor goes with a hapticmaster:// device",
    ),
    "render: --supervisor-budget out of range": (
        "render --device hapticmaster://127.0.0.1:1 --duration 0.1 --supervisor-budget 1",
        "--supervisor-budget 1: must be in 5..1000 ms",
    ),
    "run: --checkpoint-every negative": (
        "run experiments/default.yaml --checkpoint-every -1",
        "--checkpoint-every -1: must be in 0..86400 s",
    ),
    "resume: --checkpoint-every not a number": (
        "resume missing.h5 --checkpoint-every often",
        "--checkpoint-every 'often': expected a number",
    ),
    "render: --supervisor-budget nan": (
        "render --device hapticmaster://127.0.0.1:1 --duration 0.1 --supervisor-budget nan",
        "--supervisor-budget nan",
    ),
    "render: --supervisor-budget with --no-supervisor": (
        "render --device hapticmaster://127.0.0.1:1 --duration 0.1 --supervisor-budget 30 "
        "--no-supervisor",
        "--supervisor-budget goes without --no-supervisor",
    ),
    "render: trial file at --log": (
        "render --params seed_trial --user hold --duration 0.1 --log {w}/trials.h5",
        "--force to replace it",
    ),
    # no command writes over one of its inputs, --force or not
    "params: --write onto --params": ("params door --params {w}/p.yaml --write {w}/p.yaml", IN),
    "simulate: --out onto --input": ("simulate door --input {w}/force.csv --out {w}/force.csv", IN),
    "simulate: --out onto --params": (
        "simulate door --params {w}/p.csv --input {w}/force.csv --out {w}/p.csv",
        IN,
    ),
    "curve: --out onto --params": ("curve door --params {w}/p.csv --out {w}/p.csv", IN),
    "curve: --plot onto --out": ("curve door --out {w}/c.png --plot {w}/c.png", "both --out"),
    "draw: --out onto --params": ("draw door --params {w}/p.yaml --out {w}/p.yaml", IN),
    "rig: --out onto --params": (
        "rig generate --model door --params {w}/p.csv --trials 1 --out {w}/p.csv",
        IN,
    ),
    "rig: --out onto --params, --force": (
        "rig generate --model door --params {w}/p.csv --trials 1 --out {w}/p.csv --force",
        IN,
    ),
    "data import: --out onto an input": ("data import {w}/trials.h5 --out {w}/trials.h5", IN),
    "data import: --out onto an input, --force": (
        "data import {w}/trials.h5 --out {w}/trials.h5 --force",
        IN,
    ),
    "data import: --out onto an input, --append": (
        "data import {w}/trials.h5 --out {w}/trials.h5 --append",
        IN,
    ),
    "data import: --out onto an input by another name": (
        "data import {w}/folder/../trials.h5 --out {w}/trials.h5 --force",
        IN,
    ),
    "data show: --plot onto the trials": ("data show {w}/trials.h5 --plot {w}/trials.h5", IN),
    "show: --plot onto the results": ("show {w}/run.h5 --plot {w}/run.h5", IN),
    "show: --convergence onto the results": ("show {w}/run.h5 --convergence {w}/run.h5", IN),
    "show: --plot and --convergence one file": (
        "show {w}/run.h5 --plot {w}/f.png --convergence {w}/f.png",
        "both --plot",
    ),
    "export-spec: --out onto the results": ("export-spec {w}/run.h5 --out {w}/run.h5", IN),
    "export-spec: --out onto the results, yaml": (
        "export-spec {w}/run.h5 --format yaml --out {w}/run.h5",
        IN,
    ),
    "report: --out onto the results": ("report {w}/run.h5 --out {w}/run.h5", IN),
    "render: --log onto --params, --force": (
        "render --params {w}/hp.yaml --user hold --duration 0.1 --log {w}/hp.yaml --force",
        IN,
    ),
    "render: --recover onto its side file": (
        "render --recover {w}/side.partial --log {w}/side.partial --force",
        IN,
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_every_command_refuses_bad_input_in_one_line(case, ws, tmp_path, capsys):
    command, names = CASES[case]
    ro = _readonly_folder(tmp_path)
    before = snapshot(ws)
    line = (ws / "perception.yaml").read_text().splitlines().index("  force: 1.5") + 1
    names = names.format(line=line) if "{line}" in names else names
    args = command.format(w=ws, ro=ro).split()
    res = cli(capsys, *args)
    assert res.returncode == 2, (res.returncode, res.stderr)
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("evo-door: error: "), res.stderr
    assert "Traceback" not in res.stderr
    assert names in lines[0], lines[0]
    assert len(lines[0]) <= 400
    assert snapshot(ws) == before
    if ro.is_relative_to(tmp_path):
        assert list(ro.iterdir()) == []


def test_evo_door_alone_shows_the_usage_and_exits_2(capsys):
    res = cli(capsys)
    assert res.returncode == 2 and "usage: evo-door" in res.stderr and res.stdout == ""


def test_a_complete_run_is_replaced_only_with_force(ws, tmp_path, capsys):
    out = tmp_path / "r.h5"
    shutil.copy(ws / "run.h5", out)
    before = out.read_bytes()
    assert cli(capsys, "run", ws / "exp.yaml", "--out", out, "--quiet").returncode == 2
    assert out.read_bytes() == before
    forced = cli(capsys, "run", ws / "exp.yaml", "--out", out, "--quiet", "--force")
    assert forced.returncode == 0, forced.stderr
    assert out.read_bytes() != before
    # never a file that is not a results file, --force or not
    (tmp_path / "trials.h5").write_bytes((ws / "trials.h5").read_bytes())
    res = cli(capsys, "run", ws / "exp.yaml", "--out", tmp_path / "trials.h5", "--force")
    assert res.returncode == 2 and "not an evo-door results file" in res.stderr


def test_one_writer_per_results_file_and_sigterm_leaves_a_resumable_run(ws, tmp_path, capsys):
    """A run owns its file: a second run or a resume is refused while it runs; SIGTERM
    stops it like Ctrl-C, with the last generation on disk and the lock gone."""
    import signal
    import subprocess
    import sys
    import time

    from evo_door.experiment import Results
    from evo_door.files import FileLock

    out = tmp_path / "long.h5"
    cmd = [sys.executable, "-m", "evo_door", "run", str(ws / "exp.yaml"), "--out", str(out)]
    cmd += ["--set", "algorithm.generations=100000", "--set", "algorithm.polish=none"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while FileLock.holder(out) != proc.pid or not out.exists():
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
            time.sleep(0.05)
        second = cli(capsys, "run", ws / "exp.yaml", "--out", out, "--force")
        assert second.returncode == 2
        assert f"a run is writing it (process {proc.pid})" in second.stderr
        resumed = cli(capsys, "resume", out)
        assert resumed.returncode == 2 and f"process {proc.pid}" in resumed.stderr
        proc.send_signal(signal.SIGTERM)
        try:
            _, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise AssertionError(proc.communicate()) from None
    finally:
        proc.kill()
    assert proc.returncode == 130 and f"evo-door resume {out}" in err
    assert FileLock.holder(out) is None and not any(
        p.name.startswith(".") for p in tmp_path.iterdir()
    )
    # the last finished generation is on disk, whole, ready for `evo-door resume`
    res = Results(out)
    assert res.attrs["status"] == "running" and res.attrs["generations_done"][0] >= 0


def test_a_run_that_cannot_start_leaves_no_folder_it_made(ws, tmp_path, capsys):
    out = tmp_path / "new" / "deeper" / "r.h5"
    res = cli(capsys, "run", ws / "exp.yaml", "--set", f"target.data={ws}/corrupt.h5", "--out", out)
    assert res.returncode == 2 and "corrupt.h5" in res.stderr
    assert list(tmp_path.iterdir()) == []
    # a folder that was there stays, with what it held
    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "notes.txt").write_text("mine")
    res = cli(
        capsys,
        "run",
        ws / "exp.yaml",
        "--set",
        f"target.data={ws}/corrupt.h5",
        "--out",
        tmp_path / "kept" / "r.h5",
    )
    assert res.returncode == 2 and sorted(p.name for p in (tmp_path / "kept").iterdir()) == [
        "notes.txt"
    ]
