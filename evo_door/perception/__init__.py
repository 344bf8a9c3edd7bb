"""What a hand can tell apart: just-noticeable differences and the feel compared in them.

A product's feel is compared with a chosen feel the way a user would: over the
force-angle curve of each stroke (opening, closing), in units of the force JND, and
for the felt inertia and damping against their own JNDs. Three modules:

- :mod:`.jnd`: the JND settings (Weber fractions and floors) with their sources;
- :mod:`.feel`: a feel as data (a force-angle curve from a model, a CSV file or a
  render log's parameters) and the **perceptual check** of one feel against another;
- :mod:`.target`: the chosen feel as a fitting target, the **perceptual objective**
  that the specification stage minimises, fast enough for a genetic algorithm.

docs/perception.md gives the definitions and the literature behind the defaults.
"""

from evo_door.perception.feel import (
    FeelCurve,
    check_verdict,
    model_curve,
    perceptual_check,
    read_curve_csv,
    verdict_text,
)
from evo_door.perception.jnd import JND
from evo_door.perception.target import FeelTarget

__all__ = [
    "JND",
    "FeelCurve",
    "FeelTarget",
    "check_verdict",
    "verdict_text",
    "model_curve",
    "perceptual_check",
    "read_curve_csv",
]
