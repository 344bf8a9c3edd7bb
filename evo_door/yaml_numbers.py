"""YAML as engineers write it: ``1e-3`` and ``5e8`` are numbers.

PyYAML follows YAML 1.1, where a float needs a dot (``1.0e-3``) and ``1e-3`` is a
string. Every YAML file of the workbench (parameter sets, experiments) is read with
:class:`Loader`, which accepts the YAML 1.2 form too, and numbers are written with
:func:`format_float`, which YAML 1.1 readers also take as floats.
"""

from __future__ import annotations

import re

import yaml

#: the bounds of a YAML document a file may hold: nesting, values, aliases (an alias is
#: a reference that expands where it is used: a few can make billions of values)
MAX_DEPTH = 64
MAX_NODES = 100_000
MAX_ALIASES = 100


class Loader(yaml.SafeLoader):
    """PyYAML's safe loader, reading ``1e-3`` and ``5e8`` as numbers, within bounds:
    at most :data:`MAX_DEPTH` levels of nesting, :data:`MAX_NODES` values and
    :data:`MAX_ALIASES` aliases, none of them recursive (a ``yaml.YAMLError`` with the
    line otherwise: the readers make it one line)."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0
        self._nodes = 0
        self._aliases = 0
        self._open: list = []  # the anchors of the nodes being composed

    def compose_node(self, parent, index):
        event = self.peek_event()
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_ALIASES:
                raise _bounds(event, f"more than {MAX_ALIASES} aliases")
            if event.anchor in self._open:
                raise _bounds(event, f"a recursive alias (*{event.anchor} inside &{event.anchor})")
            return super().compose_node(parent, index)
        self._nodes += 1
        if self._nodes > MAX_NODES:
            raise _bounds(event, f"more than {MAX_NODES} values")
        self._depth += 1
        if self._depth > MAX_DEPTH:
            raise _bounds(event, f"nested more than {MAX_DEPTH} levels deep")
        self._open.append(getattr(event, "anchor", None))
        try:
            return super().compose_node(parent, index)
        finally:
            self._open.pop()
            self._depth -= 1


def _bounds(event, problem: str) -> yaml.YAMLError:
    return yaml.composer.ComposerError(None, None, problem, event.start_mark)


Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def load(text: str):
    """A YAML document (or one value) with :class:`Loader`'s number rules."""
    return yaml.load(text, Loader=Loader)


def format_float(value: float) -> str:
    """The shortest text that reads back as exactly ``value``, with a dot in the mantissa.

    ``repr`` gives ``1e-05`` for 1e-5, which YAML 1.1 (PyYAML's safe loader) reads
    as a string; this gives ``1.0e-05``.
    """
    text = repr(float(value))
    mantissa, e, exponent = text.partition("e")
    if e and "." not in mantissa:
        text = f"{mantissa}.0e{exponent}"
    return text
