"""The fuzz suite (issue 37, "files are data"): damaged and hostile files through every
command that reads them.

Every file kind evo-door reads (a run's and a pipeline's results files, a run fitted to a
chosen feel, an interrupted run, trial files in HDF5 and CSV, a render log, a JND file,
parameter files in YAML, an experiment and a pipeline in YAML) is damaged and given to
each command that reads it
(``show``, ``compare``, ``runs``, ``export-spec``, ``report``, ``resume``, ``data show``,
``data import``, ``simulate --input``, ``params --params``, ``render --params``,
``render-check``, ``push``, ``run``). A command must either do its work (exit 0; the
damage changed nothing it reads, or a value it takes as it is) or refuse the file in
one line ``evo-door: error: ...`` with exit status 2: never a traceback, never more
than 10 s, never more than 1 GB of memory.

The damage comes two ways:

- *corpus*: seeded byte damage (flipped bits, cuts, zeroed or random ranges, bytes
  removed or inserted) and text damage (a value, a line, an indent, a character), and
  *hostile* files: a file changed with h5py and sealed again (``evo_door.files.reseal``),
  its checksums right but its content wrong (a text where a number belongs, a 2-D array
  where a 1-D one does, a group missing, NaN, huge or negative sizes, JSON that does not
  parse or is not what it should be). They run in one fresh process, whose peak memory
  and per-case time are measured (:func:`run_cases`);
- *properties* (hypothesis): hostile edits, JSON edits and text damage drawn and shrunk,
  run in this process. With ``CI`` set (``.ci/run``) the draws are the same every run.

``EVO_DOOR_FUZZ_EXAMPLES`` (default 15 a property) and ``EVO_DOOR_FUZZ_CASES`` (the
corpus cases a kind, default 12) search deeper; ``EVO_DOOR_FUZZ_SEED`` draws another
corpus: ``EVO_DOOR_FUZZ_EXAMPLES=500 EVO_DOOR_FUZZ_CASES=200 pytest tests/test_fuzz.py``.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import subprocess
import sys
import time
import traceback
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from evo_door.cli import main
from evo_door.files import reseal
from tests.helpers import DATA, TINY_EXPERIMENT
from tests.test_cli import plain_warnings

ROOT = Path(__file__).resolve().parents[1]

EXAMPLES = int(os.environ.get("EVO_DOOR_FUZZ_EXAMPLES", 15))
CASES = int(os.environ.get("EVO_DOOR_FUZZ_CASES", 12))
SEED = int(os.environ.get("EVO_DOOR_FUZZ_SEED", 37))
#: what a command may take on a damaged file: seconds, and bytes of memory (peak RSS)
TIME_LIMIT = 10.0
MEMORY_LIMIT = 2**30

FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=bool(os.environ.get("CI")),
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

# -- the corpus ------------------------------------------------------------------------
PIPELINE = f"""\
name: pipe
stages:
  first:
    model: door
    target: {{data: {DATA}, trials: [T01, T03]}}
    free: {{F_atD: [5.0, 70.0]}}
    objective: {{kind: ise, derivative: 1}}
    algorithm: {{population: 4, generations: 1, seed: 1}}
  second:
    model: door
    params: {{from: first}}
    target: {{data: {DATA}, trials: [T01]}}
    free: {{K: [300, 500]}}
    objective: {{kind: ise, derivative: 1}}
    algorithm: {{population: 4, generations: 1, seed: 2}}
"""

#: a run fitted to a chosen feel (NSGA-II, a sharp judge): its file holds a front, a
#: perceptual check and the specification's tolerances
FEEL = """\
name: feel
model: door
params: default
target: {curve: feel.csv}
perception: {force: 0.01, force_floor: 0.02}
free: {K: [200, 800], F_atD: [0, 100]}
algorithm: {kind: nsga2, population: 8, generations: 1, seed: 1}
"""

#: a JND session on the simulated device, short (10 trials of 0.2 s intervals)
JND = [
    "jnd", "--param", "friction_closing", "--participant", "sim:0.1", "--trials", "10",
    "--interval", "0.2", "--pause", "0.05", "--ramp", "0.02", "--rate", "1000", "--seed", "1",
]  # fmt: skip


class _Stop(Exception):
    pass


def build_corpus(folder: Path) -> Path:
    """One good file of each kind in ``folder`` (about 8 s)."""
    from evo_door.experiment import load_experiment, run_experiment

    (folder / "exp.yaml").write_text(TINY_EXPERIMENT)
    (folder / "pipe.yaml").write_text(PIPELINE)
    (folder / "feel.yaml").write_text(FEEL)
    quiet = ["--quiet"]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["run", str(folder / "exp.yaml"), "--out", str(folder / "run.h5"), *quiet]) == 0

        def stop(run, job):  # an interrupted run: killed after its first generation
            if job.ga is not None and job.ga.generation == 1:
                raise _Stop()

        with pytest.raises(_Stop):
            exp = load_experiment(folder / "exp.yaml", ["algorithm.generations=3"])
            run_experiment(exp, folder / "cut.h5", on_checkpoint=stop)
        assert (
            main(["run", str(folder / "pipe.yaml"), "--out", str(folder / "pipe.h5"), *quiet]) == 0
        )
        curve = ["curve", "door", "--set", "K=350", "--set", "F_atD=12", "--points", "31"]
        assert main([*curve, "--out", str(folder / "feel.csv")]) == 0
        assert (
            main(["run", str(folder / "feel.yaml"), "--out", str(folder / "feel.h5"), *quiet]) == 0
        )
        trials = ["--trial", "T01", "--trial", "T02"]
        assert main(["data", "import", str(DATA), *trials, "--out", str(folder / "trials.h5")]) == 0
        csv = str(folder / "trial.csv")
        assert main(["rig", "generate", "--model", "door", "--trials", "1", "--out", csv]) == 0
        log = ["--user", "swing", "--duration", "0.3", "--log", str(folder / "log.h5")]
        assert main(["render", "--params", "seed_trial", *log]) == 0
        assert main([*JND, "--out", str(folder / "jnd.h5")]) == 0
        hp = ["--params", "seed_trial", "--write", str(folder / "hp.yaml")]
        assert main(["params", "haptic", *hp]) == 0
        assert main(["params", "door", "--write", str(folder / "dp.yaml")]) == 0
    return folder


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    return build_corpus(tmp_path_factory.mktemp("corpus"))


#: kind -> (its file in the corpus, the commands that read it). {f}: the damaged file,
#: {d}: its folder, {c}: the corpus, {o}: a fresh output folder
KINDS = {
    "run": ("run.h5", [
        "show {f}", "show {f} --json", "compare {c}/run.h5 {f}", "compare {f} {c}/run.h5 --json",
        "runs {d}", "runs {d} --json", "export-spec {f}", "export-spec {f} --format yaml",
        "resume {f} --quiet", "params door --params {f}",
    ]),
    "run-figures": ("run.h5", [
        "report {f} --out {o}/rep", "show {f} --plot {o}/fit.png --convergence {o}/c.png",
    ]),
    "cut": ("cut.h5", ["resume {f} --quiet", "show {f} --json", "runs {d}"]),
    "feel": ("feel.h5", [
        "show {f}", "show {f} --json", "export-spec {f}", "resume {f} --quiet",
        "compare {c}/feel.h5 {f}", "export-spec {f} --format yaml",
    ]),
    "pipe": ("pipe.h5", [
        "show {f}", "show {f} --stage second", "show {f} --json", "compare {f}:first {c}/run.h5",
        "export-spec {f} --stage second", "runs {d} --json", "resume {f} --quiet",
    ]),
    "trials": ("trials.h5", [
        "data show {f}", "data import {f} --out {o}/x.h5",
        "simulate door --input {f} --trial T01 --out {o}/o.csv", "show {f}", "render-check {f}",
    ]),
    "csv": ("trial.csv", [
        "data show {f}", "data import {f} --out {o}/x.h5",
        "simulate door --input {f} --out {o}/o.csv",
    ]),
    "log": ("log.h5", [
        "show {f}", "show {f} --json", "render-check {f}", "data show {f}",
        "render --params {f} --user hold --duration 0.05", "params haptic --params {f}",
        "simulate haptic --input {f} --out {o}/o.csv", "data import {f} --out {o}/x.h5",
    ]),
    "jnd": ("jnd.h5", [
        "show {f}", "show {f} --json", "report {f} --out {o}/rep",
        "report {c}/run.h5 --jnd-file {f} --out {o}/rep",
    ]),
    "hp": ("hp.yaml", [
        "params haptic --params {f}", "render --params {f} --user hold --duration 0.05",
        "push {f} --to 127.0.0.1:1 --timeout 0.2", "render-check {c}/log.h5 --params {f}",
        "rig generate --model haptic --params {f} --trials 1 --out {o}/t.h5",
    ]),
    "dp": ("dp.yaml", [
        "params door --params {f}", "curve door --params {f} --points 5 --out {o}/c.csv",
        "simulate door --params {f} --input {c}/trial.csv --out {o}/o.csv",
    ]),
    "exp": ("exp.yaml", [
        "run {f} --out {o}/r.h5 --quiet --set algorithm.generations=0",
    ]),
    "pipe-yaml": ("pipe.yaml", [
        "run {f} --out {o}/r.h5 --quiet --set stages.first.algorithm.generations=0",
    ]),
}  # fmt: skip


# -- damage ----------------------------------------------------------------------------
#: values a damaged YAML file may hold in place of one of its own
HOSTILE_YAML = [
    "nan", ".nan", ".inf", "-.inf", "-1", "0", "1e999", "99999999999999999999999", "-1e-320",
    "''", "[]", "{}", "null", "~", "true", "x", "[1, 2]", "{a: 1}", "&a x", "*a", "!!binary AA==",
    "!!python/object/apply:os.system [ls]", "!!set {a}", "2001-12-14", "0x1F", "1_000", ":",
    "- x", "'open", '"\\x00"', '"\\ud800"', "[" * 40 + "]" * 40, "-0", "1e-400", "5.", "|",
]  # fmt: skip
#: cells a damaged CSV file may hold
HOSTILE_CELLS = [
    "", "nan", "inf", "-inf", "1e999", "x", '"', ",,,", "1e308", "-1", "0", "\x00", "1,2", "  ",
    "NaN", "1e-320", "99999999999999999999", "\u00e9", "1;2",
]  # fmt: skip


def byte_damage(data: bytes, rng) -> tuple[str, bytes]:
    """One kind of byte damage at a random place."""
    n = len(data)
    kind = str(rng.choice(["flip", "flips", "cut", "zero", "random", "delete", "insert"]))
    at, size = int(rng.integers(0, n)), int(rng.integers(1, 64))
    b = bytearray(data)
    if kind == "flip":
        b[at] ^= 1 << int(rng.integers(0, 8))
    elif kind == "flips":
        for i in rng.integers(0, n, 16):
            b[int(i)] ^= 1 << int(rng.integers(0, 8))
    elif kind == "cut":
        del b[at:]
    elif kind == "zero":
        b[at : at + size] = bytes(len(b[at : at + size]))
    elif kind == "random":
        b[at : at + size] = rng.integers(0, 256, len(b[at : at + size]), dtype=np.uint8).tobytes()
    elif kind == "delete":
        del b[at : at + size]
    else:
        b[at:at] = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
    return f"{kind} at byte {at}", bytes(b)


def text_damage(text: str, pick) -> tuple[str, str]:
    """One change of a YAML text; ``pick(n)`` chooses among ``n``."""
    lines = text.split("\n")
    kind = ["value", "value", "value", "delete", "repeat", "indent", "key", "char"][pick(8)]
    i = pick(len(lines))
    if kind == "value":
        tokens = list(re.finditer(r"[^\s,:\[\]{}]+", text))
        m = tokens[pick(len(tokens))]
        new = HOSTILE_YAML[pick(len(HOSTILE_YAML))]
        return f"{m.group()!r} -> {new!r}", text[: m.start()] + new + text[m.end() :]
    if kind == "char":
        j = pick(len(text))
        c = ":[]{}&*!|>'\"#%@`,-\t\x00\u00e9"[pick(18)]
        return f"{c!r} at {j}", text[:j] + c + text[j + 1 :]
    if kind == "delete":
        del lines[i]
    elif kind == "repeat":
        lines.insert(i, lines[i])
    elif kind == "indent":
        lines[i] = "   " + lines[i]
    else:
        lines[i] = lines[i].replace(":", "x:", 1)
    return f"{kind} line {i + 1}", "\n".join(lines)


def csv_damage(text: str, pick) -> tuple[str, str]:
    """One change of a CSV text; ``pick(n)`` chooses among ``n``."""
    lines = text.split("\n")
    kind = ["cell", "cell", "delete", "repeat", "header", "swap", "column", "char", "crlf"][pick(9)]
    i = pick(len(lines))
    if kind == "cell":
        cells = lines[i].split(",")
        cells[pick(len(cells))] = HOSTILE_CELLS[pick(len(HOSTILE_CELLS))]
        lines[i] = ",".join(cells)
    elif kind == "delete":
        del lines[i]
    elif kind == "repeat":
        lines.insert(i, lines[i])
    elif kind == "swap":
        j = pick(len(lines))
        lines[i], lines[j] = lines[j], lines[i]
    elif kind == "header":
        k = 1 if lines[0].startswith("#") else 0
        lines[k] = ["", "t", "force", "t,t", "t,force,force", "a,b,c", "t [x],force [y]"][pick(7)]
    elif kind == "column":
        lines = [line.rsplit(",", 1)[0] for line in lines]
    elif kind == "char":
        j = pick(len(text))
        c = ",;\t\"'#\x00e-+.\n"[pick(12)]
        return f"{c!r} at {j}", text[:j] + c + text[j + 1 :]
    else:
        return kind, text.replace("\n", "\r\n")
    return f"{kind} line {i + 1}", "\n".join(lines)


def hostile_targets(path: Path) -> list[tuple[str, str, str | None]]:
    """Every object of an HDF5 file an edit can aim at: (kind, name, attribute)."""
    out = []
    with h5py.File(path, "r") as f:

        def visit(name, obj):
            out.append(("group" if isinstance(obj, h5py.Group) else "dataset", "/" + name, None))
            out.extend(("attr", "/" + name, a) for a in obj.attrs if a != "_digest")

        out.extend(("attr", "/", a) for a in f.attrs if a != "_digest")
        f.visititems(visit)
    return out


#: what an attribute may be replaced with ("DEL": removed)
ATTR_VALUES = [
    "DEL", "x", "", -1, 0, 2**62, -(2**62), float("nan"), float("inf"), -1e308, 1e308,
    np.array([1.0, 2.0]), np.array([[1, 2], [3, 4]]), True, "json:{", "json:null", "json:[]",
    "json:{}", 'json:"x"', "json:1e999", "json:" + "[" * 3000 + "]" * 3000, 'json:{"a": 1}',
    "json:[1,2,3]", "json:[null]", 'json:{"":{}}', "json:-1", "json:NaN", np.zeros(0),
    b"\xff\xfe", "json:" + "9" * 400, 'json:"\\ud800"', "a\x00b",
]  # fmt: skip
#: what a dataset may be replaced with
DATASET_VALUES = [
    "DEL", "text", "2d", "3d", "empty", "scalar", "nan", "inf", "negative", "huge", "half",
    "double", "bool", "int8", "complex", "zeros", "compound", "bytes",
]  # fmt: skip
#: what a group may be replaced with
GROUP_VALUES = ["DEL", "dataset", "empty", "extra", "extra_group"]


def _dataset_value(kind: str, old):
    arr = np.asarray(old)
    numeric = arr.dtype.kind in "biuf"
    return {
        "text": lambda: "x",
        "bytes": lambda: np.void(b"\x00\x01"),
        "2d": lambda: np.stack([arr, arr]) if numeric else np.array([[1.0, 2.0]]),
        "3d": lambda: np.zeros((2, 2, 2)),
        "empty": lambda: np.zeros((0,)),
        "scalar": lambda: 1.0,
        "nan": lambda: np.full(arr.shape, np.nan),
        "inf": lambda: np.full(arr.shape, np.inf),
        "negative": lambda: -np.abs(arr.astype(float)) - 1 if numeric else -1.0,
        "huge": lambda: np.full(arr.shape, 2**62, dtype=np.int64),
        "half": lambda: arr[: arr.shape[0] // 2] if arr.ndim else arr,
        "double": lambda: np.concatenate([arr, arr]) if arr.ndim and numeric else arr,
        "bool": lambda: np.ones(arr.shape, dtype=bool),
        "int8": lambda: np.ones(arr.shape, dtype=np.int8),
        "complex": lambda: np.ones(arr.shape, dtype=complex),
        "zeros": lambda: np.zeros(arr.shape) if numeric else "",
        "compound": lambda: np.zeros(3, dtype=[("a", "f8"), ("b", "i4")]),
    }[kind]()


def hostile_edit(path: Path, target, value) -> bool:
    """Change one object of ``path`` as a hostile sender would (:data:`ATTR_VALUES`...),
    then seal the file again: its checksums right, its content wrong. False where the
    edit cannot be made (the root group cannot go)."""
    kind, name, attr = target
    with h5py.File(path, "r+") as f:
        obj = f[name]
        if kind == "attr":
            if isinstance(value, str) and value == "DEL":
                del obj.attrs[attr]
            else:
                obj.attrs[attr] = value
        elif kind == "dataset":
            old, parent, key = obj[()], obj.parent, name.rsplit("/", 1)[1]
            del parent[key]
            if value != "DEL":
                parent[key] = _dataset_value(value, old)
        else:
            if name == "/":
                return False
            parent, key = obj.parent, name.rsplit("/", 1)[1]
            if value in ("DEL", "dataset"):
                del parent[key]
                if value == "dataset":
                    parent[key] = 0.0
            elif value == "empty":
                for k in list(obj.keys()):
                    del obj[k]
            else:
                obj.create_group("zz") if value == "extra_group" else obj.create_dataset(
                    "zz", data=np.arange(3.0)
                )
        reseal(f)
    return True


def json_places(path: Path) -> list[tuple[str, str | None]]:
    """Every JSON text of an HDF5 file: ``json:`` attributes (name, attribute) and the
    resolved configurations (name of the dataset, None)."""
    out = []
    with h5py.File(path, "r") as f:

        def visit(name, obj):
            for a, v in obj.attrs.items():
                if isinstance(v, str) and v.startswith("json:"):
                    out.append(("/" + name, a))
            if isinstance(obj, h5py.Dataset) and name.endswith("resolved"):
                out.append(("/" + name, None))

        visit("", f)
        f.visititems(visit)
    return [("/" + n.strip("/"), a) for n, a in out]


def json_paths(value, prefix=()) -> list[tuple]:
    """Every place in a decoded JSON value: a tuple of keys and indices."""
    out = [prefix]
    if isinstance(value, dict):
        for k, v in value.items():
            out += json_paths(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            out += json_paths(v, (*prefix, i))
    return out


#: what a JSON value may be replaced with ("DEL": removed from its mapping or list)
JSON_VALUES = [
    "DEL", None, "x", "", -1, 0, 1.5, 10**30, -(10**30), 10**400, float("nan"), float("inf"),
    True, [], {}, [1, 2], {"a": 1}, [[[[[[]]]]]], "\ud800", ["x", None],
]  # fmt: skip


def edited(doc, where: tuple, value):
    """``doc`` with the value at the path ``where`` replaced by ``value`` ("DEL":
    removed; the whole document where ``where`` is empty, None for "DEL")."""
    if not where:
        return None if value == "DEL" else value
    parent = doc
    for k in where[:-1]:
        parent = parent[k]
    if value == "DEL":
        del parent[where[-1]]
    else:
        parent[where[-1]] = value
    return doc


def json_edit(path: Path, place, where: tuple, value) -> None:
    """Replace the JSON value at ``where`` of the JSON text at ``place`` and reseal."""
    name, attr = place
    with h5py.File(path, "r+") as f:
        obj = f[name]
        raw = obj.attrs[attr] if attr else obj[()]
        raw = raw.decode() if isinstance(raw, bytes) else str(raw)
        doc = edited(json.loads(raw[5:] if attr else raw), where, value)
        text = json.dumps(doc, allow_nan=True)  # ASCII: a lone surrogate as its escape
        if attr:
            obj.attrs[attr] = "json:" + text
        else:
            parent, key = obj.parent, name.rsplit("/", 1)[1]
            del parent[key]
            parent.create_dataset(key, data=text, dtype=h5py.string_dtype())
        reseal(f)


# -- running a command -----------------------------------------------------------------
def run_command(argv: list[str]) -> dict:
    """``evo-door ARGV`` in this process: exit code, output, time, the traceback of
    anything but a clean exit, and the warnings a plain interpreter would have printed
    (a user reads each as more lines on stderr)."""
    out, err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    code, tb = None, ""
    with plain_warnings() as caught:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse
                code = exc.code
            except BaseException:  # noqa: BLE001 - a traceback is what the suite looks for
                tb = traceback.format_exc()
    return {
        "argv": argv,
        "code": code,
        "stdout": out.getvalue()[-2000:],
        "stderr": err.getvalue(),
        "traceback": tb,
        "warnings": [
            f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})" for w in caught
        ],
        "seconds": time.perf_counter() - t0,
    }


def problem(result: dict) -> str | None:
    """What is wrong with how a command met a damaged file, or None."""
    if result["traceback"]:
        return "traceback:\n" + result["traceback"]
    err = result["stderr"]
    if "Traceback" in err or "Traceback" in result["stdout"]:
        return "a traceback in the output:\n" + err
    if result.get("warnings"):
        return "a warning a user would read as more lines:\n" + "\n".join(result["warnings"])
    if result["code"] == 2:
        lines = err.splitlines()
        if len(lines) != 1 or not lines[0].startswith("evo-door: error: "):
            return f"exit 2 without exactly one error line: {err!r}"
    elif result["code"] != 0:
        return f"exit status {result['code']}: {err!r}"
    if result["seconds"] > TIME_LIMIT:
        return f"took {result['seconds']:.1f} s"
    return None


def test_a_warning_a_command_prints_counts_as_a_problem(monkeypatch):
    """The check itself: a command that warns (a RuntimeWarning from numpy's overflow,
    as an RMS of a damaged file's huge numbers once did) is found, though it exits 0
    with its output clean; one that does not is not."""

    def warns(argv):
        np.square(np.array([1e200]))  # overflow encountered in square
        return 0

    monkeypatch.setattr(sys.modules[__name__], "main", warns)
    found = problem(run_command(["show", "x.h5"]))
    assert found is not None and "RuntimeWarning" in found and "overflow" in found
    monkeypatch.setattr(sys.modules[__name__], "main", lambda argv: 0)
    assert problem(run_command(["show", "x.h5"])) is None


def fill(template: str, damaged: Path, corpus: Path, out: Path) -> list[str]:
    return template.format(f=damaged, d=damaged.parent, c=corpus, o=out).split()


# -- the corpus in a fresh process -------------------------------------------------------
#: the corpus cases of the slower kinds (figures, a run's start) for 8 of the others
SLOWER = {"run-figures": 2, "jnd": 4, "exp": 4, "pipe-yaml": 2, "cut": 6}


def cases_of(kind: str) -> int:
    return max(1, CASES * SLOWER.get(kind, 8) // 8)


def corpus_cases(corpus: Path, folder: Path, kinds=KINDS) -> list[dict]:
    """:func:`cases_of` damaged files of each kind, seeded: byte damage (or text
    damage), a hostile edit for HDF5 files; each with one of its kind's commands."""
    rng = np.random.default_rng(SEED)
    cases = []
    for kind, (name, commands) in kinds.items():
        n = cases_of(kind)
        source = corpus / name
        targets = hostile_targets(source) if name.endswith(".h5") else []
        for k in range(n):
            case = folder / f"{kind}-{k}"
            (case / "in").mkdir(parents=True)
            damaged = case / "in" / name
            pick = lambda m: int(rng.integers(0, m))  # noqa: E731
            if targets and k % 2:
                target = targets[pick(len(targets))]
                values = {"attr": ATTR_VALUES, "dataset": DATASET_VALUES}.get(
                    target[0], GROUP_VALUES
                )
                value = values[pick(len(values))]
                shutil.copy(source, damaged)
                try:
                    made = hostile_edit(damaged, target, value)
                except (TypeError, ValueError, OSError):  # h5py cannot store it
                    made = False
                if not made:
                    shutil.copy(source, damaged)
                label = f"hostile {target} <- {str(value)[:40]!r}"
            elif name.endswith((".yaml", ".csv")) and k % 4:
                damage = csv_damage if name.endswith(".csv") else text_damage
                label, text = damage(source.read_text(), pick)
                damaged.write_bytes(text.encode("utf-8", "surrogatepass"))
            else:
                label, data = byte_damage(source.read_bytes(), rng)
                damaged.write_bytes(data)
            command = commands[k % len(commands)]
            cases.append(
                {
                    "label": f"{kind} #{k}: {label}",
                    "argv": fill(command, damaged, corpus, case / "out"),
                    "out": str(case / "out"),
                }
            )
    return cases


def _peak_rss() -> int:
    """This process's peak resident memory since the last :func:`_reset_peak`, bytes."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024


def _reset_peak() -> None:
    with contextlib.suppress(OSError):  # Linux: 5 resets the peak (VmHWM)
        Path("/proc/self/clear_refs").write_text("5")


#: a case that has not ended after this many seconds ends the worker (HDF5 can loop in
#: C, where no signal reaches): the suite names the case it died in
HANG = 60


def run_cases(cases_file: str, results_file: str) -> None:
    """The worker: each case of ``cases_file`` through ``main`` in this (fresh) process,
    its result appended to ``results_file`` as one JSON line (a crash or a hang leaves
    the cases before it, and names the one it died in: its ``start`` line has no
    result)."""
    import resource
    import threading

    limit = 2 * 2**30  # a guard against a runaway allocation; the suite checks 1 GB
    with contextlib.suppress(ValueError, OSError):
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    cases = json.loads(Path(cases_file).read_text())
    with open(results_file, "a") as out:
        for case in cases:
            out.write(json.dumps({"start": case["label"]}) + "\n")
            out.flush()
            Path(case["out"]).mkdir(parents=True, exist_ok=True)
            _reset_peak()
            watchdog = threading.Timer(HANG, os._exit, (124,))
            watchdog.start()
            result = run_command(case["argv"])
            watchdog.cancel()
            result.update(label=case["label"], peak=_peak_rss())
            out.write(json.dumps(result) + "\n")
            out.flush()


def in_fresh_process(cases: list[dict], folder: Path) -> list[dict]:
    """Run ``cases`` in one fresh process (:func:`run_cases`); their results."""
    (folder / "cases.json").write_text(json.dumps(cases))
    results = folder / "results.jsonl"
    env = {
        **os.environ,
        "PYTHONPATH": str(ROOT),
        "MPLBACKEND": "Agg",
        # few threads and malloc arenas: the address-space guard holds on any machine
        "NUMBA_NUM_THREADS": "2",
        "MALLOC_ARENA_MAX": "2",
    }
    code = "import sys; from tests.test_fuzz import run_cases; run_cases(*sys.argv[1:])"
    proc = subprocess.run(
        [sys.executable, "-c", code, str(folder / "cases.json"), str(results)],
        capture_output=True,
        text=True,
        cwd=folder,
        env=env,
        timeout=60 + HANG * len(cases),
    )
    lines = [json.loads(line) for line in results.read_text().splitlines()]
    done = [r for r in lines if "start" not in r]
    if len(done) < len(cases):
        died = [r["start"] for r in lines if "start" in r][len(done)]
        how = f"did not end within {HANG} s" if proc.returncode == 124 else "crashed"
        raise AssertionError(
            f"case {died} {how} (status {proc.returncode}):\n{proc.stderr[-3000:]}"
        )
    return done


@pytest.fixture(scope="module")
def corpus_results(corpus, tmp_path_factory) -> list[dict]:
    folder = tmp_path_factory.mktemp("cases")
    return in_fresh_process(corpus_cases(corpus, folder), folder)


@pytest.mark.parametrize("kind", list(KINDS))
def test_damaged_files_are_refused_in_one_line_in_bounded_time_and_memory(kind, corpus_results):
    results = [r for r in corpus_results if r["label"].startswith(f"{kind} #")]
    assert len(results) == cases_of(kind)
    bad = [f"{r['label']}\n  {' '.join(r['argv'])}\n  {problem(r)}" for r in results if problem(r)]
    assert not bad, "\n".join(bad)
    peak = max(r["peak"] for r in results)
    assert peak < MEMORY_LIMIT, f"{kind}: {peak / 2**20:.0f} MiB"
    # the damage reaches the readers: some of it is refused
    assert len(results) < 4 or any(r["code"] == 2 for r in results), [r["stderr"] for r in results]


# -- properties ------------------------------------------------------------------------
def _check(result: dict, what: str) -> None:
    found = problem(result)
    assert found is None, f"{what}\n  evo-door {' '.join(result['argv'])}\n  {found}"


def _fresh(tmp_path: Path, name: str) -> Path:
    """A fresh folder for one example (a new file each time: no cached check applies)."""
    folder = tmp_path / f"ex-{time.perf_counter_ns()}"
    (folder / "out").mkdir(parents=True)
    return folder / name


#: hostile edits: the kinds whose HDF5 file is edited, and the commands run on it here
HOSTILE = {
    "run": ["show {f}", "show {f} --json", "export-spec {f}", "compare {c}/run.h5 {f}",
            "runs {d} --json", "resume {f} --quiet"],
    "pipe": ["show {f}", "show {f} --stage second --json", "compare {f}:first {c}/run.h5",
             "resume {f} --quiet"],
    "cut": ["resume {f} --quiet", "show {f}"],
    "feel": ["show {f} --json", "export-spec {f}", "resume {f} --quiet"],
    "trials": ["data show {f}", "data import {f} --out {o}/x.h5",
               "simulate door --input {f} --trial T01 --out {o}/o.csv"],
    "log": ["show {f}", "render-check {f}", "params haptic --params {f}", "data show {f}"],
    "jnd": ["show {f}", "show {f} --json"],
}  # fmt: skip


@pytest.mark.parametrize("kind", list(HOSTILE))
@FUZZ
@given(data=st.data())
def test_a_hostile_file_with_right_checksums_is_one_line(kind, data, corpus, tmp_path):
    """A file changed with h5py and sealed again: whatever the change, one line or the
    command's work; never a traceback."""
    name = KINDS[kind][0]
    targets = _targets(corpus / name)
    target = data.draw(st.sampled_from(targets), label="target")
    values = {"attr": ATTR_VALUES, "dataset": DATASET_VALUES}.get(target[0], GROUP_VALUES)
    value = data.draw(st.sampled_from(values), label="value")
    command = data.draw(st.sampled_from(HOSTILE[kind]), label="command")
    damaged = _fresh(tmp_path, name)
    shutil.copy(corpus / name, damaged)
    try:
        assume(hostile_edit(damaged, target, value))
    except (TypeError, ValueError, OSError):  # h5py cannot store it
        assume(False)
    result = run_command(fill(command, damaged, corpus, damaged.parent / "out"))
    _check(result, f"{target} <- {value!r}")


_TARGETS: dict = {}


def _targets(path: Path) -> list:
    if path not in _TARGETS:
        _TARGETS[path] = hostile_targets(path)
    return _TARGETS[path]


@pytest.mark.parametrize("kind", ["run", "pipe", "feel", "log", "trials"])
@FUZZ
@given(data=st.data())
def test_hostile_json_in_a_file_is_one_line(kind, data, corpus, tmp_path):
    """Any value of any JSON text a file holds (``json:`` attributes, the resolved
    configuration) replaced, its checksums right."""
    name = KINDS[kind][0]
    places = _json_places(corpus / name)
    place = data.draw(st.sampled_from(places), label="place")
    paths = _json_paths_of(corpus / name, place)
    where = data.draw(st.sampled_from(paths), label="where")
    value = data.draw(st.sampled_from(JSON_VALUES), label="value")
    assume(not (value == "DEL" and not where))
    command = data.draw(st.sampled_from(HOSTILE[kind]), label="command")
    damaged = _fresh(tmp_path, name)
    shutil.copy(corpus / name, damaged)
    json_edit(damaged, place, where, value)
    result = run_command(fill(command, damaged, corpus, damaged.parent / "out"))
    _check(result, f"{place} {where} <- {value!r}")


@pytest.mark.parametrize("key", ["period_mean_s", "missed_cycles", "rate_hz", "on_time_fraction"])
@pytest.mark.parametrize("command", HOSTILE["log"])
def test_a_render_log_whose_loop_statistics_are_null_reads_without_them(
    key, command, corpus, tmp_path
):
    """A render log's loop statistics with a number replaced by null (found by the test
    above: ``render-check`` printed a traceback for a null mean period): each command
    reads the log as if the number were not there, or says in one line what is wrong."""
    damaged = _fresh(tmp_path, "log.h5")
    shutil.copy(corpus / "log.h5", damaged)
    json_edit(damaged, ("/render", "statistics"), (key,), None)
    result = run_command(fill(command, damaged, corpus, damaged.parent / "out"))
    _check(result, f"/render statistics {key} <- None")


def _json_places(path: Path) -> list:
    key = ("places", path)
    if key not in _TARGETS:
        _TARGETS[key] = json_places(path)
    return _TARGETS[key]


def _json_paths_of(path: Path, place) -> list:
    key = ("paths", path, place)
    if key not in _TARGETS:
        name, attr = place
        with h5py.File(path, "r") as f:
            raw = f[name].attrs[attr] if attr else f[name][()]
        raw = raw.decode() if isinstance(raw, bytes) else str(raw)
        _TARGETS[key] = json_paths(json.loads(raw[5:] if attr else raw))
    return _TARGETS[key]


@FUZZ
@given(data=st.data())
def test_hostile_metadata_of_a_csv_trial_is_one_line(data, corpus, tmp_path):
    """Any value of a CSV trial's metadata line (``# evo-door trial: {...}``) replaced."""
    head, _, rest = (corpus / "trial.csv").read_text().partition("\n")
    prefix, _, text = head.partition(": ")
    doc = json.loads(text)
    where = data.draw(st.sampled_from(json_paths(doc)), label="where")
    value = data.draw(st.sampled_from(JSON_VALUES), label="value")
    assume(where or value != "DEL")
    doc = edited(doc, where, value)
    damaged = _fresh(tmp_path, "trial.csv")
    damaged.write_text(f"{prefix}: {json.dumps(doc, allow_nan=True)}\n{rest}")
    command = data.draw(st.sampled_from(TEXT["csv"]), label="command")
    result = run_command(fill(command, damaged, corpus, damaged.parent / "out"))
    _check(result, f"{where} <- {value!r}")


#: text damage: the kinds of text file, and the commands run on them here (fast ones)
TEXT = {
    "hp": ["params haptic --params {f}", "render --params {f} --user hold --duration 0.05",
           "push {f} --to 127.0.0.1:1 --timeout 0.2"],
    "dp": ["params door --params {f}", "curve door --params {f} --points 5 --out {o}/c.csv"],
    "csv": ["data show {f}", "data import {f} --out {o}/x.h5",
            "simulate door --input {f} --out {o}/o.csv"],
}  # fmt: skip


@pytest.mark.parametrize("kind", list(TEXT))
@FUZZ
@given(data=st.data())
def test_a_damaged_text_file_is_one_line(kind, data, corpus, tmp_path):
    name = KINDS[kind][0]
    damage = csv_damage if name.endswith(".csv") else text_damage
    label, text = damage(
        (corpus / name).read_text(), lambda n: data.draw(st.integers(0, n - 1), label="pick")
    )
    command = data.draw(st.sampled_from(TEXT[kind]), label="command")
    damaged = _fresh(tmp_path, name)
    damaged.write_bytes(text.encode("utf-8", "surrogatepass"))
    result = run_command(fill(command, damaged, corpus, damaged.parent / "out"))
    _check(result, label)


def test_a_global_heap_that_would_loop_for_ever_is_one_line(corpus, tmp_path):
    """Zeroed bytes where a global heap's first object begins (index 0, size 0): HDF5's
    reader walks that collection for ever (found by this suite: ``data import`` hung);
    checked before HDF5 reads it. In a fresh process, under a timeout."""
    from tests.helpers import cli_process

    data = bytearray((corpus / "trials.h5").read_bytes())
    at = data.find(b"GCOL\x01\x00\x00\x00")
    assert at > 0
    data[at + 16 : at + 32] = bytes(16)  # the first object's header: index 0, size 0
    damaged = tmp_path / "trials.h5"
    damaged.write_bytes(bytes(data))
    res = cli_process("data", "import", damaged, "--out", tmp_path / "x.h5", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert f"{damaged}: damaged HDF5 file (the global heap at byte {at}" in res.stderr
