"""A mechanism file drawn as a 1-D mechanical block diagram, in SVG (``evo-door draw``).

:func:`mechanism_svg` lays a :class:`~evo_door.models.blocks.mechanism.Mechanism` out
the way a 1-D system simulation tool sketches a mechanism: the ground a hatched line
along the bottom, the bodies in a row above it (a box for a linear body, a disc for a
rotary one), left to right in the order their connections reach them from the handle;
each element a symbol between its two ends, those on one body standing between the
ground and the body, those between two neighbours across the gap between them, those
between two bodies farther apart routed over the row. Several elements between the same
two ends stand side by side in lanes. The hand is an arrow on the handle, its positive
direction toward closed. Each element is labelled with its name, its kind and words and
its parameters (the file's values) with their units; numerics (a stop's stiffness) are
left out.

The symbols are a table by kind (:data:`SYMBOLS`); a kind the table does not know, a
component added to the library later, is drawn as a box with its kind in it, so every
mechanism the reader accepts draws. Drawing reads the file only (no code generation,
no compilation) and is plain text: the same mechanism gives the same bytes. The page
needs no ids or definitions, so it can be inlined into an HTML page more than once.
"""

from __future__ import annotations

import html
from dataclasses import dataclass, field

from evo_door.models.blocks.components import COMPONENTS, ROTARY
from evo_door.models.blocks.mechanism import Element, Mechanism

FONT = 11  # px
LINE = 13  # px between two lines of a label
CHAR = 6.3  # px, a character's width at FONT, estimated (sans-serif)
MARGIN = 20
GROUND_LANE = 130  # px from the ground line to a body's bottom
HALF = 9  # px, half the height of a symbol across its axis
INK = "#222"
#: parameter groups left out of the labels (how stiff a stop is: not what it means)
HIDDEN_GROUPS = ("numerics",)


def mechanism_svg(mech: Mechanism) -> str:
    """The diagram of ``mech`` as an SVG document (text, no XML declaration)."""
    sketch = _Sketch(mech)
    return sketch.render()


# -- labels --------------------------------------------------------------------------
def _num(v: float) -> str:
    """A number as it is written in a file: 3, 0.45, 1e+05."""
    return f"{v:g}"


def _xy(v: float) -> str:
    """A coordinate: one decimal at most."""
    text = f"{v:.1f}"
    return text[:-2] if text.endswith(".0") else text


def _esc(text: str) -> str:
    return html.escape(str(text), quote=True)


def _width(lines: list[str]) -> float:
    return max((len(line) for line in lines), default=0) * CHAR


def element_label(mech: Mechanism, e: Element) -> list[str]:
    """The lines of an element's label: name, kind and words, key parameters."""
    kind = e.kind.replace("_", " ")
    words = ", ".join(f"{k} {v}" for k, v in sorted(e.words.items()))
    lines = [e.name, f"{kind}, {words}" if words else kind]
    prefix = f"{e.name}."
    for p in mech.params:
        if p.name.startswith(prefix) and p.group not in HIDDEN_GROUPS:
            unit = f" {p.unit}" if p.unit and p.unit != "1" else ""
            lines.append(f"{p.name[len(prefix) :]} {_num(p.default)}{unit}")
    return lines


def body_label(mech: Mechanism, name: str) -> list[str]:
    """The lines of a body's label: name, kind, its first parameter (mass, inertia)."""
    body = mech.bodies[name]
    lines = [name, f"{body.kind} body"]
    first = next((p for p in mech.params if p.name.startswith(f"{name}.")), None)
    if first is not None:
        lines.append(f"{first.name.split('.', 1)[1]} {_num(first.default)} {first.unit}")
    return lines


def body_order(mech: Mechanism) -> list[str]:
    """The bodies left to right: the handle, then as the elements between two bodies
    reach them (breadth first, in the file's order)."""
    order, k = [mech.handle], 0
    while k < len(order):
        here = order[k]
        for e in mech.elements.values():
            if e.a is not None and here in (e.a, e.b):
                other = e.b if here == e.a else e.a
                if other not in order:
                    order.append(other)
        k += 1
    return order + [b for b in mech.bodies if b not in order]


# -- symbols: drawn along the x axis from 0 (end a) to length (end b) ----------------
def _path(d: str, extra: str = "", width: float = 1.3) -> str:
    return f'<path d="{d}" fill="none" stroke="{INK}" stroke-width="{width}"{extra}/>'


def _lead(x0: float, x1: float, dashed: bool = False) -> str:
    extra = ' stroke-dasharray="2 3"' if dashed else ""
    return _path(f"M{_xy(x0)} 0H{_xy(x1)}", extra)


def _middle(length: float, size: float = 60.0) -> tuple[float, float]:
    """Where the symbol itself sits: ``size`` px (at most) in the middle, leads around."""
    size = min(size, max(length - 16.0, 10.0))
    return (length - size) / 2.0, (length + size) / 2.0


def _hatch(x: float, y0: float, y1: float, back: float) -> str:
    """A surface across the axis at ``x``, hatched on the side ``back`` (-1, +1)."""
    d = f"M{_xy(x)} {_xy(y0)}V{_xy(y1)}"
    y = y0 + 2.0
    while y < y1:
        d += f"M{_xy(x)} {_xy(y)}l{_xy(5.0 * back)} 4"
        y += 5.0
    return _path(d)


def spring(length: float, vertical: bool) -> str:
    m0, m1 = _middle(length)
    teeth = 8
    step = (m1 - m0) / teeth
    d = f"M0 0H{_xy(m0)}"
    for i in range(teeth):
        d += f"L{_xy(m0 + (i + 0.5) * step)} {_xy(HALF if i % 2 else -HALF)}"
    d += f"L{_xy(m1)} 0H{_xy(length)}"
    return _path(d)


def _dashpot(m0: float, m1: float) -> tuple[str, float]:
    """A cylinder open toward b and its piston; returns the parts and the piston's x."""
    top = m0 + 0.75 * (m1 - m0)
    cylinder = _path(f"M{_xy(top)} {-HALF}H{_xy(m0)}V{HALF}H{_xy(top)}")
    piston = m0 + 0.45 * (m1 - m0)
    plate = _path(f"M{_xy(piston)} {-HALF + 3}V{HALF - 3}", width=2.4)
    return cylinder + plate, piston


def damper(length: float, vertical: bool) -> str:
    m0, m1 = _middle(length, 44.0)
    parts, piston = _dashpot(m0, m1)
    return _lead(0.0, m0) + parts + _lead(piston, length)


def soft_close(length: float, vertical: bool) -> str:
    """A dashpot whose rod ends in a catch short of the body: it engages on the way."""
    m0, m1 = _middle(length, 60.0)
    parts, piston = _dashpot(m0, m0 + 0.7 * (m1 - m0))
    catch = _path(f"M{_xy(m1)} -6V6")
    return _lead(0.0, m0) + parts + _lead(piston, m1) + catch + _lead(m1 + 4, length, True)


def friction(length: float, vertical: bool) -> str:
    """A block on a hatched surface at end a, the rod to end b."""
    m0, m1 = _middle(length, 34.0)
    surface = _hatch(m0, -HALF - 5, HALF + 5, -1.0)
    block = (
        f'<rect x="{_xy(m0)}" y="{-HALF + 1}" width="{_xy(m1 - m0)}" height="{2 * HALF - 2}" '
        f'fill="#ddd" stroke="{INK}" stroke-width="1.3"/>'
    )
    return _lead(0.0, m0 - 6) + surface + block + _lead(m1, length)


def end_stop(length: float, vertical: bool) -> str:
    """A wall (hatched behind) facing end b, a gap to it: it pushes, never pulls."""
    m0, m1 = _middle(length, 30.0)
    return _lead(0.0, m1) + _hatch(m1, -HALF - 3, HALF + 3, -1.0) + _lead(m1 + 4, length, True)


def cable(length: float, vertical: bool) -> str:
    """A rope: a wavy line end to end."""
    waves = max(int(length // 14), 2)
    step = length / waves
    d = "M0 0"
    for i in range(waves):
        d += f"Q{_xy((i + 0.5) * step)} {-5 if i % 2 else 5} {_xy((i + 1) * step)} 0"
    return _path(d)


def unknown(length: float, vertical: bool) -> str:
    """A kind without a symbol: a box (its kind is written in it by the caller)."""
    along, across = (28.0, 96.0) if vertical else (96.0, 28.0)
    along = min(along, max(length - 12.0, 10.0))
    m0 = (length - along) / 2.0
    box = (
        f'<rect x="{_xy(m0)}" y="{_xy(-across / 2)}" width="{_xy(along)}" '
        f'height="{_xy(across)}" fill="#fff" stroke="{INK}" stroke-width="1.3"/>'
    )
    return _lead(0.0, m0) + box + _lead(m0 + along, length)


def _across(kind: str) -> float:
    """How far a symbol reaches across its axis, each side (px)."""
    return 16.0 if kind in SYMBOLS else 50.0


#: kind -> symbol(length, vertical) -> SVG of the symbol along x from 0 to length
SYMBOLS = {
    "spring": spring,
    "damper": damper,
    "friction": friction,
    "end_stop": end_stop,
    "soft_close": soft_close,
    "cable": cable,
}


# -- the layout ----------------------------------------------------------------------
@dataclass
class _Column:
    """A body's place: its box, and the elements between it and the ground under it."""

    name: str
    x: float = 0.0
    width: float = 0.0
    ground: list[Element] = field(default_factory=list)
    lanes: list[float] = field(default_factory=list)  # each ground lane's width


class _Sketch:
    """The diagram of one mechanism: sizes first, then the parts in drawing order."""

    def __init__(self, mech: Mechanism):
        self.mech = mech
        self.order = body_order(mech)
        self.at = {b: i for i, b in enumerate(self.order)}
        self.columns = [_Column(b) for b in self.order]
        self.gaps: list[list[Element]] = [[] for _ in self.order[1:]]
        self.over: list[Element] = []
        for e in mech.elements.values():
            if e.a is None:
                self.columns[self.at[e.b]].ground.append(e)
            elif abs(self.at[e.a] - self.at[e.b]) == 1:
                self.gaps[min(self.at[e.a], self.at[e.b])].append(e)
            else:
                self.over.append(e)
        self.labels = {e.name: element_label(mech, e) for e in mech.elements.values()}
        self.title = f"{mech.name}: {mech.title}" if mech.title != mech.name else mech.name
        count = (
            f"{_many(len(mech.bodies), 'body', 'bodies')}, {_many(len(mech.elements), 'element')}"
        )
        self.note = f"{count}; positions and forces positive toward closed (to the right)"
        self.parts: list[str] = []
        self._measure()

    def _lines(self, e: Element) -> int:
        return len(self.labels[e.name])

    def _measure(self) -> None:
        """The columns', gaps' and rows' sizes, and the x of each column."""
        for col in self.columns:
            col.lanes = [
                max(96.0, 2 * _across(e.kind) + 24.0 + _width(self.labels[e.name]))
                for e in col.ground
            ]
            text = _width(body_label(self.mech, col.name)) + 24.0
            col.width = max(120.0, text, sum(col.lanes))
        self.gap_widths = [
            max([150.0] + [_width(self.labels[e.name]) + 40.0 for e in gap]) for gap in self.gaps
        ]
        self.gap_rows = [[self._lines(e) * LINE + 28.0 for e in gap] for gap in self.gaps]
        rotary = any(self.mech.bodies[b].kind == ROTARY for b in self.order)
        self.body_h = max([130.0 if rotary else 84.0] + [sum(r) + 16.0 for r in self.gap_rows])
        x = float(MARGIN)
        for col, gap in zip(self.columns, self.gap_widths + [0.0]):
            col.x = x
            x += col.width + gap
        first = self.columns[0]
        hand = first.x + first.width / 2 + 44.0 + _width(["+ toward closed"])
        title = _width([self.title]) * (FONT + 2) / FONT
        self.width = max(x, hand, MARGIN + title, MARGIN + _width([self.note])) + MARGIN
        self.over_rows = [self._lines(e) * LINE + 30.0 for e in self.over]
        self.top = MARGIN + 2 * LINE + 12.0  # the title
        self.hand_y = self.top + 22.0
        self.body_y = self.hand_y + 34.0 + sum(self.over_rows)
        self.ground_y = self.body_y + self.body_h + GROUND_LANE
        self.height = self.ground_y + 14.0 + LINE + MARGIN

    def render(self) -> str:
        title = self.title
        self._text(MARGIN, MARGIN + FONT, [title], bold=True, size=FONT + 2)
        self._text(MARGIN, MARGIN + FONT + LINE + 4, [self.note], fill="#555")
        self._ground()
        for col in self.columns:
            self._body(col)
            self._ground_lanes(col)
        for i, gap in enumerate(self.gaps):
            self._gap(i, gap)
        self._over()
        self._hand()
        w, h = _xy(self.width), _xy(self.height)
        head = (
            f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" '
            f'viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="{FONT}" '
            f'role="img" aria-label="{_esc(title)}">'
        )
        body = "\n".join(self.parts)
        return f'{head}\n<title>{_esc(title)}</title>\n<rect width="{w}" height="{h}" fill="#fff"/>\n{body}\n</svg>\n'

    # -- parts ---------------------------------------------------------------------
    def _text(self, x, y, lines, bold=False, size=FONT, fill=INK, anchor="start") -> None:
        for k, line in enumerate(lines):
            weight = ' font-weight="bold"' if bold and k == 0 else ""
            self.parts.append(
                f'<text x="{_xy(x)}" y="{_xy(y + k * LINE)}" font-size="{size}" fill="{fill}" '
                f'text-anchor="{anchor}"{weight}>{_esc(line)}</text>'
            )

    def _ground(self) -> None:
        y, x0, x1 = self.ground_y, MARGIN / 2, self.width - MARGIN / 2
        d = f"M{_xy(x0)} {_xy(y)}H{_xy(x1)}"
        x = x0 + 4.0
        while x < x1:
            d += f"M{_xy(x)} {_xy(y)}l-6 8"
            x += 8.0
        self.parts.append(f'<g class="ground"><title>ground</title>{_path(d)}</g>')
        self._text(x0, y + 8.0 + LINE + 2, ["ground"], fill="#555")

    def _body(self, col: _Column) -> None:
        body = self.mech.bodies[col.name]
        x, y, w, h = col.x, self.body_y, col.width, self.body_h
        lines = body_label(self.mech, col.name)
        shape = f'<rect x="{_xy(x)}" y="{_xy(y)}" width="{_xy(w)}" height="{_xy(h)}" '
        if body.kind == ROTARY:  # a wheel on its axis, in a rounded frame
            r = 28.0
            cx, cy = x + w / 2, y + 10.0 + r
            shape += f'rx="14" fill="#fff" stroke="{INK}" stroke-width="1" stroke-dasharray="4 3"/>'
            shape += (
                f'<circle cx="{_xy(cx)}" cy="{_xy(cy)}" r="{_xy(r)}" fill="#eef" '
                f'stroke="{INK}" stroke-width="1.6"/>'
                + _path(
                    f"M{_xy(cx - r)} {_xy(cy)}H{_xy(cx + r)}M{_xy(cx)} {_xy(cy - r)}V{_xy(cy + r)}"
                )
                + f'<circle cx="{_xy(cx)}" cy="{_xy(cy)}" r="3" fill="{INK}"/>'
            )
            text_y = cy + r + LINE + 2
        else:
            shape += f'fill="#eef" stroke="{INK}" stroke-width="1.6"/>'
            text_y = y + h / 2 - (len(lines) - 1) * LINE / 2 + 4
        self.parts.append(
            f'<g class="body"><title>{_esc(col.name)}: {body.kind} body</title>{shape}</g>'
        )
        self._text(x + w / 2, text_y, lines, bold=True, anchor="middle")

    def _element(self, e: Element, x0, y0, x1, y1) -> None:
        """The symbol of ``e`` from (x0, y0), its end a, to (x1, y1), its end b:
        horizontal, or vertical upward."""
        vertical = x0 == x1
        length = abs(y1 - y0) if vertical else x1 - x0
        draw = SYMBOLS.get(e.kind, unknown)
        turn = " rotate(-90)" if vertical else ""
        comp = COMPONENTS.get(e.kind)
        tip = f"{e.name}: {comp.title}" if comp is not None and comp.title else e.name
        self.parts.append(
            f'<g class="element"><title>{_esc(tip)}</title>'
            f'<g transform="translate({_xy(x0)} {_xy(y0)}){turn}">{draw(length, vertical)}</g></g>'
        )
        if e.kind not in SYMBOLS:
            mx, my = (x0 + x1) / 2, (y0 + y1) / 2
            self._text(mx, my + 4, [e.kind], anchor="middle")

    def _ground_lanes(self, col: _Column) -> None:
        x = col.x + (col.width - sum(col.lanes)) / 2
        bottom = self.body_y + self.body_h
        for e, lane in zip(col.ground, col.lanes):
            sx = x + _across(e.kind) + 6.0
            self._element(e, sx, self.ground_y, sx, bottom)
            lines = self.labels[e.name]
            ty = bottom + GROUND_LANE / 2 - (len(lines) - 1) * LINE / 2 + 4
            self._text(sx + _across(e.kind) + 8.0, ty, lines, bold=True)
            x += lane

    def _gap(self, i: int, gap: list[Element]) -> None:
        left, right = self.columns[i], self.columns[i + 1]
        x0, x1 = left.x + left.width, right.x
        y = self.body_y + 8.0
        for e, row in zip(gap, self.gap_rows[i]):
            lines = self.labels[e.name]
            self._text((x0 + x1) / 2, y + FONT, lines, bold=True, anchor="middle")
            sy = y + row - 12.0
            self._element(e, x0, sy, x1, sy)
            y += row

    def _over(self) -> None:
        """Elements between bodies that are not neighbours: over the row of bodies."""
        y = self.body_y - 12.0
        for k, (e, row) in enumerate(zip(self.over, self.over_rows)):
            assert e.a is not None  # between two bodies, as the constructor sorted them
            ends = (self.columns[self.at[e.a]], self.columns[self.at[e.b]])
            a, b = sorted(ends, key=lambda c: c.x)
            xa = a.x + a.width * (0.7 + 0.2 * ((k + 1) % 2))
            xb = b.x + b.width * (0.3 - 0.2 * ((k + 1) % 2))
            self.parts.append(
                _path(
                    f"M{_xy(xa)} {_xy(self.body_y)}V{_xy(y)}M{_xy(xb)} {_xy(self.body_y)}V{_xy(y)}"
                )
            )
            self._element(e, xa, y, xb, y)
            self._text(
                (xa + xb) / 2, y - row + 24.0, self.labels[e.name], bold=True, anchor="middle"
            )
            y -= row

    def _hand(self) -> None:
        """An arrow on the handle: the hand's force, positive toward closed."""
        col = self.columns[0]
        cx, y = col.x + col.width / 2, self.hand_y
        rotary = self.mech.bodies[col.name].kind == ROTARY
        reach = self.body_y + (10.0 if rotary else 0.0)
        arrow = (
            _path(f"M{_xy(cx - 36)} {_xy(y)}H{_xy(cx + 30)}", width=2)
            + f'<path d="M{_xy(cx + 38)} {_xy(y)}l-10 -5v10z" fill="{INK}"/>'
            + _path(f"M{_xy(cx)} {_xy(y)}V{_xy(reach)}", ' stroke-dasharray="3 2"')
            + f'<circle cx="{_xy(cx)}" cy="{_xy(reach)}" r="3.5" fill="{INK}"/>'
        )
        self.parts.append(
            f'<g class="hand"><title>the hand, on {_esc(col.name)}</title>{arrow}</g>'
        )
        self._text(cx - 42, y + 4, ["hand"], bold=True, anchor="end")
        self._text(cx + 44, y + 4, ["+ toward closed"], fill="#555")


def _many(n: int, one: str, more: str = "") -> str:
    return f"{n} {one if n == 1 else more or one + 's'}"
