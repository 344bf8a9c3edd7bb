"""``evo-door draw MECHANISM.yaml``: a mechanism file's block diagram (SVG).

The examples draw as valid SVG holding every body's and element's name, the hand and
the ground, the same bytes twice, without compiling anything; a kind the drawer has no
symbol for is a labelled box; free text is escaped; the command writes, refuses to
replace without --force and refuses bad input in one line; the report of a fitted
mechanism shows the diagram inline (slow: a tiny fit), and says where it cannot.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from evo_door.cli import main
from evo_door.files.claims import HDF5_SIGNATURE
from evo_door.models.blocks import CACHE_ENV, components
from evo_door.models.blocks.drawing import SYMBOLS, body_order, element_label, mechanism_svg
from evo_door.models.blocks.mechanism import Element, read_mechanism
from evo_door.reporting.page import ReportPage
from evo_door.reporting.report_mechanism import mechanism_section

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "blocks"
SVG = "{http://www.w3.org/2000/svg}"


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    """Generated mechanisms (the slow test's fit) in a tmp folder of the session."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path_factory.getbasetemp() / "mechanisms"))


def texts(svg: str) -> list[str]:
    """Every text of the drawing: its <text> elements and the <title>s (tooltips)."""
    root = ET.fromstring(svg)
    return [t.text or "" for t in root.iter() if t.tag in (f"{SVG}text", f"{SVG}title")]


def groups(svg: str, cls: str) -> list[ET.Element]:
    return [g for g in ET.fromstring(svg).iter(f"{SVG}g") if g.get("class") == cls]


@pytest.mark.parametrize("name", ["soft_close_drawer", "two_carts"])
def test_the_examples_draw_every_body_element_the_hand_and_the_ground(name):
    mech = read_mechanism(EXAMPLES / f"{name}.yaml")
    svg = mechanism_svg(mech)
    root = ET.fromstring(svg)  # valid XML
    assert root.tag == f"{SVG}svg"
    assert root.find(f"{SVG}title").text.startswith(mech.name)
    shown = texts(svg)
    for body in mech.bodies:
        assert body in shown, body
    for element in mech.elements:
        assert element in shown, element
    assert "hand" in shown and "+ toward closed" in shown and "ground" in shown
    assert len(groups(svg, "element")) == len(mech.elements)
    assert len(groups(svg, "body")) == len(mech.bodies)
    assert len(groups(svg, "hand")) == 1
    assert mechanism_svg(read_mechanism(EXAMPLES / f"{name}.yaml")) == svg  # same bytes


def test_labels_carry_the_parameters_with_units_and_leave_out_numerics():
    mech = read_mechanism(EXAMPLES / "soft_close_drawer.yaml")
    stop = element_label(mech, mech.elements["stop"])
    assert stop == ["stop", "end stop, side above", "at 0.45 m"]  # k and c: numerics
    assert element_label(mech, mech.elements["softie"])[2:] == [
        "engage 0.35 m",
        "c_fluid 80 N s/m",
        "pull 0 N",
    ]
    shown = texts(mechanism_svg(mech))
    assert "mass 3 kg" in shown and "level 1.2 N" in shown and "c 3 N s/m" in shown


def test_bodies_go_left_to_right_as_their_connections_reach_them(tmp_path):
    (tmp_path / "chain.yaml").write_text(textwrap.dedent("""
        mechanism:
          name: chain
          handle: b
          bodies:
            a: {kind: linear, mass: 1.0}
            c: {kind: linear, mass: 1.0}
            b: {kind: linear, mass: 1.0}
          elements:
            bc: {kind: spring, between: [b, c], k: 10.0}
            ca: {kind: damper, between: [c, a], c: 1.0}
            ba: {kind: cable, between: [a, b], k: 10.0}
            ab: {kind: spring, between: [a, b], k: 20.0}
    """))  # fmt: skip
    mech = read_mechanism(tmp_path / "chain.yaml")
    assert body_order(mech) == ["b", "c", "a"]  # from the handle, the file's order
    svg = mechanism_svg(mech)
    boxes = {
        g.find(f"{SVG}title").text.split(":")[0]: g.find(f"{SVG}rect") for g in groups(svg, "body")
    }
    x = {name: float(r.get("x")) for name, r in boxes.items()}
    assert x["b"] < x["c"] < x["a"]
    # ba and ab join b and a, not neighbours: over the row, in two lanes one above the other
    ys = {}
    for g in groups(svg, "element"):
        name = g.find(f"{SVG}title").text.split(":")[0]
        ys[name] = float(g.find(f"{SVG}g").get("transform").split()[1].rstrip(")"))
    top = float(boxes["b"].get("y"))
    assert ys["ba"] < top and ys["ab"] < top and ys["ba"] != ys["ab"]
    assert ys["bc"] > top and ys["ca"] > top  # in the gaps between neighbours


def test_a_kind_without_a_symbol_is_a_labelled_box(monkeypatch):
    """A component the library gains later (a transmission, say) draws with no change
    to the drawer: a box with its kind in it, its title as the tooltip."""

    class Crank(components.Component):
        kind, title = "slider_crank", "slider-crank <transmission> & co"

    assert "slider_crank" not in SYMBOLS
    monkeypatch.setitem(components.COMPONENTS, "slider_crank", Crank())
    mech = read_mechanism(EXAMPLES / "soft_close_drawer.yaml")
    mech.elements["crank"] = Element("crank", "slider_crank", None, "box", {}, {})
    svg = mechanism_svg(mech)
    assert "slider_crank" in texts(svg) and "crank" in texts(svg)
    (crank,) = [g for g in groups(svg, "element") if g.find(f"{SVG}title").text.startswith("crank")]
    assert crank.find(f"{SVG}title").text == "crank: slider-crank <transmission> & co"
    assert crank.find(f".//{SVG}rect") is not None  # the box
    assert "&lt;transmission&gt; &amp; co" in svg  # escaped in the file


def test_free_text_is_escaped(tmp_path):
    (tmp_path / "odd.yaml").write_text(textwrap.dedent("""
        mechanism:
          name: odd
          title: a <b>bold</b> & "quoted" title
          handle: lid
          bodies:
            lid: {kind: rotary, inertia: 0.05}
          elements:
            oil: {kind: damper, on: lid, c: 0.02}
    """))  # fmt: skip
    svg = mechanism_svg(read_mechanism(tmp_path / "odd.yaml"))
    root = ET.fromstring(svg)
    assert root.find(f"{SVG}title").text == 'odd: a <b>bold</b> & "quoted" title'
    assert "<b>" not in svg
    assert "c 0.02 N m s/rad" in texts(svg)  # a rotary body's units
    assert "inertia 0.05 kg m^2" in texts(svg)


def _draw(*args, cwd: Path):
    """``evo-door draw ARGS`` in a fresh process: what it prints, and whether drawing
    compiled (imported numba or the code generator)."""
    probe = (
        "import sys; from evo_door.cli import main; rc = main(sys.argv[1:]); "
        "print('compiled' if {'numba', 'evo_door.models.blocks.codegen'} & set(sys.modules) "
        "else 'not compiled'); sys.exit(rc)"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-c", probe, "draw", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)  # fmt: skip


def test_the_command_writes_refuses_to_replace_and_compiles_nothing(tmp_path):
    shutil.copy(EXAMPLES / "two_carts.yaml", tmp_path)
    made = _draw("two_carts.yaml", cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    lines = made.stdout.splitlines()
    assert lines[0] == (
        "wrote two_carts.svg: mechanism two-carts, 2 bodies (a, b), 3 elements "
        "(coupling, rub_a, rub_b); the hand on a"
    )
    assert lines[1] == "not compiled"
    first = (tmp_path / "two_carts.svg").read_bytes()
    ET.fromstring(first)
    (tmp_path / "two_carts.svg").write_text("mine")
    forced = _draw("two_carts.yaml", cwd=tmp_path)  # a figure: replaced, with a note
    assert forced.returncode == 0, forced.stderr
    assert forced.stderr == "evo-door: replaced two_carts.svg\n"
    assert (tmp_path / "two_carts.svg").read_bytes() == first  # the same bytes
    data = HDF5_SIGNATURE + b"trials"
    (tmp_path / "data.svg").write_bytes(data)  # an HDF5 file, whatever its name
    kept = _draw("two_carts.yaml", "--out", "data.svg", cwd=tmp_path)
    assert kept.returncode == 2 and "an evo-door data file is there" in kept.stderr
    assert (tmp_path / "data.svg").read_bytes() == data


@pytest.mark.parametrize(
    "args, message",
    [
        (["missing.yaml"], "missing.yaml: mechanism file not found"),
        (["bad.yaml"], "mechanism bad.yaml: element 'rub': unknown kind 'frction'"),
        (["good.yaml", "--out", "good.png"], "a mechanism's diagram is SVG"),
        (["good.yaml", "--out", "good.yaml"], "a mechanism's diagram is SVG"),
        (["good.yaml", "--out", "sub/good.svg"], "sub"),
        (["good.yaml", "--set", "cart.mass=2"], "--set: for the door"),
        (["good.yaml", "--angles", "0,90"], "--angles: for the door"),
        (["haptic"], "draw takes a mechanism file"),
    ],
)
def test_bad_input_is_one_line_and_status_2(tmp_path, monkeypatch, capsys, args, message):
    good = "mechanism: {name: g, handle: cart, bodies: {cart: {kind: linear, mass: 1.0}}}\n"
    (tmp_path / "good.yaml").write_text(good)
    (tmp_path / "bad.yaml").write_text(
        good.replace("}}}", "}}, elements: {rub: {kind: frction, on: cart}}}")
    )
    monkeypatch.chdir(tmp_path)
    assert main(["draw", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("evo-door: error: ") and err.count("\n") == 1 and message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.yaml", "good.yaml"]


def test_the_door_draws_as_svg_by_default(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["draw", "door"]) == 0
    assert capsys.readouterr().out == "wrote door.svg\n"
    ET.parse(tmp_path / "door.svg")
    assert main(["draw", "door"]) == 0  # a figure: replaced, with a note
    assert capsys.readouterr().err == "evo-door: replaced door.svg\n"


def test_the_report_section_draws_the_file_or_says_why_not(tmp_path):
    page = ReportPage(tmp_path)
    drawer = EXAMPLES / "soft_close_drawer.yaml"
    mechanism_section(page, str(drawer), "run", "fit")
    (figure,) = page.parts
    assert figure.startswith('<figure class="diagram"><svg ') and "</svg><figcaption>" in figure
    assert (tmp_path / "run-mechanism.svg").read_text() == mechanism_svg(read_mechanism(drawer))
    gone = tmp_path / "elsewhere" / "drawer.yaml"
    mechanism_section(page, str(gone), "run", "fit")
    assert "is not on this machine" in page.parts[1] and "<svg" not in page.parts[1]
    mechanism_section(page, "door", "run", "fit")  # not a mechanism file: nothing
    assert len(page.parts) == 2


@pytest.mark.slow
def test_the_report_of_a_fitted_mechanism_embeds_its_diagram(tmp_path, monkeypatch, capsys):
    """A tiny fit of the drawer (2 trials, a GA of 8 x 2, no polish), then report."""
    work = tmp_path / "blocks"
    work.mkdir()
    shutil.copy(EXAMPLES / "soft_close_drawer.yaml", work)
    fit = (EXAMPLES / "fit.yaml").read_text()
    fit = fit.replace("  validate: [T08]\n", "").replace(
        "population: 30, generations: 10, seed: 1, polish: slsqp, ftol: 1.0e-9",
        "population: 8, generations: 2, seed: 1, polish: none",
    )
    (work / "fit.yaml").write_text(fit)
    monkeypatch.chdir(work)
    rig = ["rig", "generate", "--model", "soft_close_drawer.yaml", "--trials", "2"]
    assert main([*rig, "--out", "trials.h5"]) == 0
    assert main(["run", "fit.yaml", "--out", "fit.h5", "--quiet"]) == 0
    assert main(["report", "fit.h5", "--out", "page"]) == 0
    capsys.readouterr()
    page = (work / "page" / "report.html").read_text()
    svg = (work / "page" / "run-mechanism.svg").read_text()
    assert svg.rstrip() in page  # inlined as it is written beside the page
    assert "box" in texts(svg) and "softie" in texts(svg)
    (work / "soft_close_drawer.yaml").unlink()  # the results file opened elsewhere
    assert main(["report", "fit.h5", "--out", "moved"]) == 0
    moved = (work / "moved" / "report.html").read_text()
    assert "<svg" not in moved and "is not on this machine" in moved


def test_the_figure_in_the_docs_is_what_the_command_draws_now():
    """docs/figures/soft_close_drawer.svg: remade by the command docs/blocks.md names."""
    figure = ROOT / "docs" / "figures" / "soft_close_drawer.svg"
    drawn = mechanism_svg(read_mechanism(EXAMPLES / "soft_close_drawer.yaml"))
    assert figure.read_text(encoding="utf-8") == drawn, (
        "remake it: cd docs/figures && evo-door draw ../../examples/blocks/soft_close_drawer.yaml"
    )
    assert "(figures/soft_close_drawer.svg)" in (ROOT / "docs" / "blocks.md").read_text()
