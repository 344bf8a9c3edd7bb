"""The layers of docs/architecture.md hold: every import of every module of evo_door
(those inside functions and under ``TYPE_CHECKING`` included, read with ``ast``, the
code is not run) goes down the layers or stays in its own package; no two packages
import each other, directly or round a circle; no private name (``_x``, or a name in a
private module) is imported from another package.

A failure names the module and line of each offending import.
"""

from __future__ import annotations

import ast
import re
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "evo_door"

#: The layers, bottom first: a unit (a package of evo_door, or a module at its top) may
#: import its own unit and the units of lower layers, never a higher layer's nor another
#: unit of its own layer. ``evo_door`` is the package's own ``__init__`` (the version).
#: docs/architecture.md gives the same table, with each unit's purpose and place.
LAYERS: list[set[str]] = [
    {"evo_door", "errors", "channels", "yaml_numbers", "kernel_cache"},
    {"files", "sim_settings"},
    {"params"},
    {"sim"},
    {"models"},
    {"data", "perception"},
    {"optim", "render"},
    {"plugins"},
    {"experiment"},
    {"reporting"},
    {"commands"},
    {"cli"},
    {"__main__"},
    {"api"},
]

#: The one import that goes up: the package's own ``__init__`` (the bottom unit
#: ``evo_door``) offers the public face's names, ``evo_door.Experiment`` and the like, by
#: importing the module ``evo_door.api`` (nothing else, not ``evo_door.api.build``)
#: inside its PEP 562 ``__getattr__`` only, so that ``import evo_door`` imports none of
#: the layers above (:func:`test_the_facade_reaches_up_only_lazily_and_only_to_api`).
FACADE = ("evo_door", "evo_door.api")


@dataclass(frozen=True)
class Import:
    module: str  # the importing module, dotted
    path: str  # its file, relative to the repository
    line: int
    target: str  # the imported module, dotted
    name: str  # the name imported from it ("" for ``import target``)

    def where(self) -> str:
        what = f"{self.target}.{self.name}" if self.name else self.target
        return f"{self.path}:{self.line}: {self.module} imports {what}"


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def is_package(module: str) -> bool:
    return (ROOT / Path(*module.split(".")) / "__init__.py").is_file()


def resolve(module: str, node: ast.ImportFrom) -> str:
    """The absolute module of ``from ... import`` (relative imports resolved)."""
    if not node.level:
        return node.module or ""
    base = module.split(".") if is_package(module) else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports_of(path: Path) -> list[Import]:
    """Every import of evo_door in a file, wherever it stands in the file."""
    module, rel = module_name(path), str(path.relative_to(ROOT))
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [Import(module, rel, node.lineno, a.name, "") for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            target = resolve(module, node)
            for a in node.names:
                # ``from evo_door.x import y`` where y is a module imports the module
                sub = f"{target}.{a.name}"
                if (ROOT / Path(*sub.split("."))).with_suffix(".py").is_file() or is_package(sub):
                    out.append(Import(module, rel, node.lineno, sub, ""))
                else:
                    out.append(Import(module, rel, node.lineno, target, a.name))
    return [i for i in out if i.target.split(".")[0] == "evo_door"]


def all_imports() -> list[Import]:
    return [i for path in sorted(PACKAGE.rglob("*.py")) for i in imports_of(path)]


def unit(module: str) -> str:
    """The unit of the layer map a module belongs to."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "evo_door"


def owner(module: str) -> str:
    """The package that owns a module's private names: its innermost package; a module
    at the top of evo_door owns its own."""
    if is_package(module):
        return module
    parent = module.rsplit(".", 1)[0]
    return module if parent == "evo_door" else parent


def is_private(word: str) -> bool:
    return word.startswith("_") and not word.startswith("__")


def rank() -> dict[str, int]:
    return {u: k for k, layer in enumerate(LAYERS) for u in layer}


# -- the checks, each a function of the imports (tested below on made-up imports too) --
def unplaced(imports: list[Import]) -> list[str]:
    ranks = rank()
    units = {unit(module_name(p)) for p in PACKAGE.rglob("*.py")}
    units |= {unit(i.target) for i in imports}
    return sorted(u for u in units if u not in ranks)


def upward(imports: list[Import]) -> list[Import]:
    """Imports of a higher layer's unit, or of another unit of the same layer."""
    ranks = rank()
    bad = []
    for i in imports:
        a, b = unit(i.module), unit(i.target)
        if (i.module, i.target) == FACADE:
            continue  # the root's lazy facade, checked on its own below
        if a != b and ranks.get(b, -1) >= ranks.get(a, -1):
            bad.append(i)
    return bad


def cycles(imports: list[Import]) -> list[list[Import]]:
    """The circles of imports between units: for each group of units that reach one
    another (a strongly connected component), one shortest circle through its first
    unit, as the import that makes each step."""
    edges: dict[str, dict[str, Import]] = defaultdict(dict)
    for i in imports:
        a, b = unit(i.module), unit(i.target)
        if a != b and (i.module, i.target) != FACADE:  # the facade is run-time only
            edges[a].setdefault(b, i)
    return [shortest_circle(sorted(g)[0], g, edges) for g in components(edges)]


def components(edges: dict[str, dict[str, Import]]) -> list[set[str]]:
    """The groups of more than one unit that reach one another (Tarjan's algorithm;
    a few dozen units, so recursion is fine)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups: list[set[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(edges.get(v, {})):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = set()
            while True:
                w = stack.pop()
                group.add(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(group)

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return groups


def shortest_circle(start: str, group: set[str], edges) -> list[Import]:
    """The imports of a shortest circle from ``start`` back to it within ``group``."""
    came: dict[str, tuple[str, Import]] = {}
    frontier = [start]
    while frontier:  # breadth first: the first way back is a shortest one
        nxt = []
        for v in frontier:
            for w, imp in sorted(edges.get(v, {}).items()):
                if w not in group or w in came:
                    continue
                came[w] = (v, imp)
                if w == start:
                    path, at = [], start
                    while True:
                        prev, step = came[at]
                        path.append(step)
                        at = prev
                        if at == start:
                            return path[::-1]
                nxt.append(w)
        frontier = nxt
    raise AssertionError(f"{start} is in a component without a circle")  # cannot happen


def private_crossings(imports: list[Import]) -> list[Import]:
    """A private name, or a name from a private module, imported from another package."""
    bad = []
    for i in imports:
        private = (i.name and is_private(i.name)) or any(is_private(p) for p in i.target.split("."))
        if private and owner(i.module) != owner(i.target):
            bad.append(i)
    return bad


def offenders(found: list[Import]) -> list[str]:
    """Offending imports as ``file:line: ...`` lines."""
    return [i.where() for i in found]


# -- the package as it is ------------------------------------------------------------
def test_every_unit_has_its_place_in_the_layers():
    missing = unplaced(all_imports())
    assert not missing, (
        f"not in the layer map: {', '.join(missing)}; give each its layer in "
        "tests/test_architecture.py (LAYERS) and docs/architecture.md"
    )


def test_no_import_goes_up_or_sideways():
    bad = offenders(upward(all_imports()))
    assert not bad, (
        "imports of a higher layer (or of another unit of the same layer; "
        "docs/architecture.md):\n" + "\n".join(bad)
    )


def test_no_circle_of_imports_between_packages():
    found = cycles(all_imports())
    text = "\n\n".join("\n".join(i.where() for i in circle) for circle in found)
    assert not found, f"packages that import each other round a circle:\n{text}"


def test_no_private_name_crosses_a_package():
    bad = offenders(private_crossings(all_imports()))
    assert not bad, (
        "private names imported from another package (make them public, or move the "
        "code):\n" + "\n".join(bad)
    )


def test_the_documented_layers_are_the_tested_ones():
    """docs/architecture.md's table of layers lists the units of LAYERS, bottom first."""
    doc = (ROOT / "docs" / "architecture.md").read_text()
    rows = re.findall(r"^\| (\d+) \| ([^|]+) \|", doc, re.M)
    documented = [set(re.findall(r"`([\w.]+)`", units)) for _, units in rows]
    assert [int(k) for k, _ in rows] == list(range(len(rows)))
    assert documented == LAYERS


def test_the_facade_reaches_up_only_lazily_and_only_to_api():
    """The root ``__init__`` imports ``evo_door.api`` inside ``__getattr__`` and nowhere
    else: at its top it would make ``import evo_door`` import every layer."""
    path = PACKAGE / "__init__.py"
    tree = ast.parse(path.read_text(), str(path))
    lazy = [f for f in tree.body if isinstance(f, ast.FunctionDef) and f.name == "__getattr__"]
    inside = {id(n) for f in lazy for n in ast.walk(f)}
    found = [i for i in imports_of(path) if i.target == "evo_door.api"]
    assert found, "evo_door/__init__.py no longer offers the API: update FACADE"
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)) and id(node) not in inside:
            names = [a.name for a in node.names]
            module = getattr(node, "module", None) or ""
            assert not any(n.startswith("evo_door") for n in [module, *names]), (
                f"evo_door/__init__.py:{node.lineno}: imports evo_door outside __getattr__"
            )


def test_the_facade_is_no_licence_for_other_upward_imports():
    made = [
        _imp("evo_door", "evo_door.api", ""),  # the facade: fine
        _imp("evo_door", "evo_door.api.build", "Experiment", 9),
        _imp("evo_door", "evo_door.experiment", "load_experiment", 11),
        _imp("evo_door.experiment.config", "evo_door.api", "", 13),
    ]
    assert [i.line for i in upward(made)] == [9, 11, 13]


def test_the_scan_sees_lazy_imports_and_the_offenders_it_should():
    """The reader finds imports inside functions and resolves relative ones (the test
    above would pass vacuously if it did not)."""
    found = {(i.module, i.target, i.name) for i in all_imports()}
    # commands/batch.py imports the experiment layer inside a function
    assert ("evo_door.commands.batch", "evo_door.experiment.batch", "plan") in found
    # render/log_file.py imports the trial's writer inside a function
    assert ("evo_door.render.log_file", "evo_door.data.h5io", "trial_tree") in found
    assert ("evo_door.cli", "evo_door.commands", "") in found


# -- the checks on made-up imports (each would catch what it is for) -------------------
def _imp(module: str, target: str, name: str = "x", line: int = 7) -> Import:
    return Import(module, module.replace(".", "/") + ".py", line, target, name)


def test_an_upward_and_a_sideways_import_are_caught_with_their_line():
    made = [
        _imp("evo_door.params.sets", "evo_door.render.log", "session_params", 268),
        _imp("evo_door.optim.executors", "evo_door.render.loop", "ServoLoop"),
        _imp("evo_door.commands.batch", "evo_door.experiment.batch", "plan"),  # fine
        _imp("evo_door.render.log", "evo_door.render.keys", "shown"),  # its own package
    ]
    got = [i.where() for i in upward(made)]
    assert got == [
        "evo_door/params/sets.py:268: evo_door.params.sets imports "
        "evo_door.render.log.session_params",
        "evo_door/optim/executors.py:7: evo_door.optim.executors imports "
        "evo_door.render.loop.ServoLoop",
    ]


def test_a_circle_between_packages_is_caught_with_each_import():
    made = [
        _imp("evo_door.params.sets", "evo_door.render.log", "session_params", 268),
        _imp("evo_door.render.keys", "evo_door.models.haptic", "PARAMS", 23),
        _imp("evo_door.models.haptic", "evo_door.params", "param_vector", 40),
        _imp("evo_door.data.io", "evo_door.files", "read_text"),  # not in the circle
    ]
    (circle,) = cycles(made)  # from the first unit, models: models -> params -> render
    assert [i.line for i in circle] == [40, 268, 23]


def test_a_private_name_from_another_package_is_caught():
    made = [
        _imp("evo_door.render.log", "evo_door.data.h5io", "_trial_tree", 301),
        _imp("evo_door.cli", "evo_door.commands._common", "add_progress_arguments"),
        _imp("evo_door.experiment.batch", "evo_door.experiment.results", "_table"),  # fine
        _imp("evo_door.commands.batch", "evo_door.commands._common", "show_progress"),  # fine
        _imp("evo_door.cli", "evo_door", "__version__"),  # a dunder is not private
    ]
    got = [i.where() for i in private_crossings(made)]
    assert got == [
        "evo_door/render/log.py:301: evo_door.render.log imports evo_door.data.h5io._trial_tree",
        "evo_door/cli.py:7: evo_door.cli imports evo_door.commands._common.add_progress_arguments",
    ]


# -- sizes: a module answers one question, a function does one step --------------------
#: a module longer than this says why in a docstring line starting with "Size:"
MAX_MODULE_LINES = 600
#: a function with more lines of code than this (its docstring not counted) says why in
#: a comment "# long: <reason>" on its first body line (after the docstring)
MAX_FUNCTION_LINES = 80


def module_size_offenders(path: Path) -> list[str]:
    """``path`` if it is longer than MAX_MODULE_LINES without a "Size:" line in its
    docstring."""
    text = path.read_text()
    lines = text.count("\n") + (not text.endswith("\n"))
    doc = ast.get_docstring(ast.parse(text)) or ""
    said = any(line.startswith("Size:") for line in doc.splitlines())
    return (
        [] if lines <= MAX_MODULE_LINES or said else [f"{path.relative_to(ROOT)} ({lines} lines)"]
    )


def long_functions(path: Path) -> list[str]:
    """``FILE:NAME`` of the functions in ``path`` with more than MAX_FUNCTION_LINES lines
    of code (docstring left out) and no "# long:" comment as their first body line."""
    text = path.read_text()
    lines = text.splitlines()
    out = []
    for node in ast.walk(ast.parse(text)):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        body = node.body
        has_doc = (
            isinstance(body[0], ast.Expr)
            and isinstance(body[0].value, ast.Constant)
            and isinstance(body[0].value.value, str)
        )
        code = body[1:] if has_doc else body
        if not code:
            continue
        first = code[0].lineno  # its first statement, 1-based
        if node.end_lineno - first + 1 <= MAX_FUNCTION_LINES:
            continue
        # the comment lines right above the first statement (after the docstring, or
        # after the signature, however many lines it takes): the first says why
        top = first - 1
        while top > (body[0].end_lineno if has_doc else node.lineno) and lines[
            top - 1
        ].strip().startswith("#"):
            top -= 1
        if not (top < first - 1 and lines[top].strip().startswith("# long:")):
            out.append(f"{path.relative_to(ROOT)}:{node.name}")
    return out


def test_every_module_is_short_or_says_why():
    """A module over 600 lines answers more than one question: cut it by responsibility,
    or give the reason in a docstring line starting with "Size:"."""
    bad = [o for p in sorted(PACKAGE.rglob("*.py")) for o in module_size_offenders(p)]
    assert not bad, "modules over 600 lines without a 'Size:' line in the docstring:\n" + "\n".join(
        bad
    )


def test_every_long_function_says_why():
    """A function of more than 80 lines of code is cut into named steps, or its first
    body line says why not: ``# long: <reason>``."""
    bad = [o for p in sorted(PACKAGE.rglob("*.py")) for o in long_functions(p)]
    assert not bad, "functions over 80 lines without '# long: <reason>':\n" + "\n".join(bad)


def test_the_size_checks_catch_what_they_are_for(tmp_path, monkeypatch):
    """On made-up files: a long module without its reason, a long function without its
    comment are found; with them, they are not."""
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    body = "".join(f"    x{i} = {i}\n" for i in range(81))
    long_module = tmp_path / "big.py"
    long_module.write_text('"""A module."""\n' + "y = 1\n" * 600)
    assert module_size_offenders(long_module) == ["big.py (601 lines)"]
    long_module.write_text('"""A module.\n\nSize: one table.\n"""\n' + "y = 1\n" * 600)
    assert module_size_offenders(long_module) == []
    f = tmp_path / "f.py"
    f.write_text('def f(a=1):\n    """Doc."""\n' + body)
    assert long_functions(f) == ["f.py:f"]
    f.write_text('def f(a=1):\n    """Doc."""\n    # long: one table\n' + body)
    assert long_functions(f) == []
    f.write_text("def f(\n    a=1,\n):\n    # long: one table\n" + body)
    assert long_functions(f) == []
    f.write_text("def f(\n    a=1,\n):\n    # one table\n" + body)  # not the reason's form
    assert long_functions(f) == ["f.py:f"]
    f.write_text("def f(\n    a=1,\n):\n" + body[: -len("    x80 = 80\n")])  # 80 lines: fine
    assert long_functions(f) == []


# -- one model contract: no layer above the models asks which kind a model is ---------
#: Attributes that only one kind of model has (an FMU's runner and description, the
#: FMU model class): asking for them is asking which kind a model is.
KIND_MARKERS = {"runner", "info", "FmuModel", "FmuRunner", "FmuPlant", "StatePlant", "AccelPlant"}
#: The units where the kinds are made: the plants and the models.
KIND_HOME = {"sim", "models"}


def kind_tests(path: Path, root: Path = ROOT) -> list[str]:
    """Every place in a file that tests a model's kind: ``getattr`` / ``hasattr`` with
    a kind marker, ``isinstance`` with a kind class, ``x.runner`` / ``x.info``."""
    found = []
    rel = path.relative_to(root)
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            args = node.args
            if node.func.id in ("getattr", "hasattr") and len(args) >= 2:
                if isinstance(args[1], ast.Constant) and args[1].value in KIND_MARKERS:
                    found.append(f"{rel}:{node.lineno}: {node.func.id}(..., {args[1].value!r})")
            if node.func.id == "isinstance" and len(args) == 2:
                names = {n.id for n in ast.walk(args[1]) if isinstance(n, ast.Name)}
                names |= {n.attr for n in ast.walk(args[1]) if isinstance(n, ast.Attribute)}
                names.discard("model")
                if names & KIND_MARKERS:
                    found.append(f"{rel}:{node.lineno}: isinstance(..., {sorted(names)})")
        if isinstance(node, ast.Attribute) and node.attr in ("runner",):
            if isinstance(node.value, ast.Name) and node.value.id in ("model", "m"):
                found.append(f"{rel}:{node.lineno}: {node.value.id}.{node.attr}")
    return found


def test_no_layer_above_the_models_asks_which_kind_a_model_is():
    """The layers above ``sim`` and ``models`` ask a model's plant
    (:class:`evo_door.sim.plant.Plant`) and never test for an FMU's runner."""
    found = [
        f
        for path in sorted(PACKAGE.rglob("*.py"))
        if unit(module_name(path)) not in KIND_HOME
        for f in kind_tests(path)
    ]
    assert not found, "a model's kind tested above the models:\n" + "\n".join(found)


def test_the_kind_scan_catches_what_it_is_for(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(
        "def f(model):\n"
        "    if getattr(model, 'runner', None) is not None:\n"
        "        return model.runner\n"
        "    return isinstance(model, fmu.FmuModel) or hasattr(model, 'info')\n"
    )
    found = sorted(f.split(": ", 1)[1] for f in kind_tests(bad, tmp_path))
    assert found == [
        "getattr(..., 'runner')",
        "hasattr(..., 'info')",
        "isinstance(..., ['FmuModel', 'fmu'])",
        "model.runner",
    ]


# -- names: one class, one name ----------------------------------------------------------
def classes_of(path: Path) -> list[tuple[str, str]]:
    """``(class name, FILE:LINE)`` of every class defined in ``path``, nested ones too."""
    rel = path.relative_to(ROOT)
    tree = ast.parse(path.read_text(), str(path))
    return [(n.name, f"{rel}:{n.lineno}") for n in ast.walk(tree) if isinstance(n, ast.ClassDef)]


def shared_class_names(found: list[tuple[str, str]]) -> list[str]:
    """One line per class name defined more than once: the name and where each stands."""
    where: dict[str, list[str]] = defaultdict(list)
    for name, place in found:
        where[name].append(place)
    return [f"{n}: {', '.join(w)}" for n, w in sorted(where.items()) if len(w) > 1]


def test_no_two_classes_share_a_name():
    """A class's name says which it is: two ``Job``s (or two ``Page``s) make every reader
    of an import look twice."""
    found = [c for p in sorted(PACKAGE.rglob("*.py")) for c in classes_of(p)]
    bad = shared_class_names(found)
    assert not bad, "classes of evo_door that share a name (rename one):\n" + "\n".join(bad)


def test_a_shared_class_name_is_caught(tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    (tmp_path / "a.py").write_text("class Job:\n    class Step:\n        pass\n")
    (tmp_path / "b.py").write_text("x = 1\n\n\nclass Job:\n    pass\n\n\nclass Step:\n    pass\n")
    found = classes_of(tmp_path / "a.py") + classes_of(tmp_path / "b.py")
    assert shared_class_names(found) == ["Job: a.py:1, b.py:4", "Step: a.py:2, b.py:8"]
