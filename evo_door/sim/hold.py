"""A model's quasi-static force, where it has a faster way to it than ``accel``.

The force that holds a one-coordinate model still (``ddtheta = 0``) at a state follows
from ``accel`` being affine in the force: ``-a(0) / (a(1) - a(0))``, two calls
(:mod:`.accel_plant`). Both calls compute everything that does not depend on the force
(a door's mechanism, the haptic model's tangential force). A model may register a
compiled ``hold(theta, dtheta, p)`` (:data:`HOLD_SIGNATURE`) that computes it once: the
same numbers, to the last bit, for about one call's work instead of two. The perceptual objective measures
each door's force-angle curve on some 3000 angles, so this is much of its cost.

A registry, like :func:`~evo_door.sim.integrators.register_prepared`'s: a model's module
fills it when imported and nothing changes it afterwards. Its own module, light to
import, because the models that register import it.
"""

from __future__ import annotations

from collections.abc import Callable

from numba import types

#: Signature of a model's ``hold(theta, dtheta, p) -> force``: the force (N) that holds
#: ``ddtheta = 0`` at ``(theta, dtheta)``, as ``-a(0) / (a(1) - a(0))`` of ``accel``.
HOLD_SIGNATURE = types.float64(types.float64, types.float64, types.float64[::1])
#: The numba type of a ``hold`` function as a kernel argument.
HOLD_TYPE = types.FunctionType(HOLD_SIGNATURE)

#: Signature of a model's ``hold_rows(P, theta, dtheta, out) -> done``: ``hold`` of every
#: row of ``P`` (parameter vectors) at every angle of ``theta`` into ``out`` (rows,
#: angles), or False with nothing written where it has no faster way for these rows.
HOLD_ROWS_SIGNATURE = types.boolean(
    types.float64[:, ::1], types.float64[::1], types.float64, types.float64[:, ::1]
)

#: model accel -> its ``hold``, and its ``hold_rows``
_HOLDS: dict[object, Callable] = {}
_HOLD_ROWS: dict[object, Callable] = {}


def register_hold(accel, hold) -> None:
    """Declare the compiled ``hold`` (:data:`HOLD_SIGNATURE`) as the quasi-static force of
    the model right-hand side ``accel``: what two calls of ``accel`` give, to the last
    bit (the door and the haptic model do at import; their tests check it)."""
    _HOLDS[accel] = hold


def hold_form(accel) -> Callable | None:
    """The ``hold`` registered for ``accel`` (:func:`register_hold`), or None."""
    return _registered(_HOLDS, accel)


def register_hold_rows(accel, hold_rows) -> None:
    """Declare the compiled ``hold_rows`` (:data:`HOLD_ROWS_SIGNATURE`) as the model's
    ``hold`` of many parameter vectors at many angles where it can share work between
    rows (the door's pose, for doors of one geometry): faster than ``hold`` at each
    pair, the same numbers to the last bit (the door's tests check it), and False
    where it cannot (the caller then calls ``hold`` at each pair)."""
    _HOLD_ROWS[accel] = hold_rows


def hold_rows_form(accel) -> Callable | None:
    """The ``hold_rows`` registered for ``accel`` (:func:`register_hold_rows`), or None."""
    return _registered(_HOLD_ROWS, accel)


def _registered(table: dict, accel) -> Callable | None:
    try:
        return table.get(accel)
    except TypeError:  # an unhashable callable: none
        return None
