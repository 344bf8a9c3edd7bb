"""The integrators' settings as plain data, for code that reads them without integrating.

A command that only reads a results file (``show``, ``export-spec``, ``runs``) checks a
stored method's name, its tolerance and the objective's kind; importing the compiled
integrators for that cost it numba and the loading of their machine code, most of its
start-up. The compiled modules (:mod:`evo_door.sim`) take their codes from here; it sits
below them, outside the package, because importing any module of ``evo_door.sim`` loads
the integrators (its ``__init__``).
"""

from __future__ import annotations

import math

from evo_door.errors import UserError

#: ``method`` codes of the compiled integrators (:mod:`evo_door.sim.located`)
RK4 = 0
SEMI_IMPLICIT = 1
DOPRI5 = 2
#: a method's name in a file or on the command line -> its code
METHODS = {"rk4": RK4, "semi_implicit": SEMI_IMPLICIT, "dopri5": DOPRI5}
#: Default tolerance of ``dopri5`` (per step, ``tol (1 + |x|)`` in rad and rad/s).
DEFAULT_TOLERANCE = 1e-7

#: objective kernel codes (:mod:`evo_door.sim.objective`)
MAX_SQUARE = 0
ISE = 1
#: objective.kind in an experiment -> kernel code
KINDS = {"max_square": MAX_SQUARE, "ise": ISE}


def tolerance_of(model, tolerance=None) -> float:
    """The ``dopri5`` tolerance: ``tolerance`` if given (checked), else the model's.

    >>> tolerance_of(object(), "1e-6")
    1e-06
    """
    tol = getattr(model, "tolerance", DEFAULT_TOLERANCE) if tolerance is None else tolerance
    tol = float(tol)
    if not (math.isfinite(tol) and 0.0 < tol < 1.0):
        raise UserError(f"integration tolerance must be a number in (0, 1), got {tolerance!r}")
    return tol


def refined(method: str, substeps: int, tolerance: float) -> tuple[str, int, float]:
    """The settings of the a-posteriori error check: the same method at half the step
    (and, for ``dopri5``, a 32 times tighter tolerance: its error goes as h^5)."""
    return method, 2 * int(substeps), float(tolerance) / 32.0
