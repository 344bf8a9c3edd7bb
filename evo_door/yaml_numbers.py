"""YAML as engineers write it: ``1e-3`` and ``5e8`` are numbers.

PyYAML follows YAML 1.1, where a float needs a dot (``1.0e-3``) and ``1e-3`` is a
string. Every YAML file of the workbench (parameter sets, experiments) is read with
:class:`Loader`, which accepts the YAML 1.2 form too, and numbers are written with
:func:`format_float`, which YAML 1.1 readers also take as floats.
"""

from __future__ import annotations

import re

import yaml


class Loader(yaml.SafeLoader):
    """PyYAML's safe loader, reading ``1e-3`` and ``5e8`` as numbers."""


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
