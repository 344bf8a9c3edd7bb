"""The check every model passes before anything is simulated: :func:`check_model`.

A model from a user's file is refused with one line when the workbench could not run
it: its declaration, its rig kinds and range, and its compiled functions (``accel``, or
``rhs`` for a model on a state vector, and ``switches``), each compiled here for the
exact type the integrators call it with.
"""

from __future__ import annotations

import inspect
import math
import re

from evo_door.errors import UserError
from evo_door.params import ParamTable
from evo_door.params.declaration import suggest

#: Trial kinds of the virtual rig (:mod:`evo_door.data.rig`).
RIG_KINDS = ("unlock", "lock", "impulse", "slow")


def check_model(model, source: str = ""):
    """Refuse, with one line, a model the workbench could not use; return it otherwise.

    Checks that it is a :class:`Model`, that ``params`` is a ParamTable declared for
    it, and that ``accel`` is a numba function that compiles for the exact type the
    integrators call it with (``ACCEL_SIGNATURE`` of :mod:`evo_door.sim.integrators`,
    a first-class function ``float64(float64, float64, float64, float64[::1])``). An
    ``@njit`` without a signature is compiled for it here (or loaded from numba's disk
    cache), as the first simulation would do anyway.
    """
    from evo_door.models.base import Model

    where = source or getattr(model, "name", "?")
    if not isinstance(model, Model):
        raise UserError(f"{where!r} is a {type(model).__name__}, not an evo_door Model")
    name = f"model {model.name!r}"
    if not isinstance(model.params, ParamTable):
        raise UserError(
            f"{name}: params must be a ParamTable (evo_door.params), "
            f"got {type(model.params).__name__}"
        )
    if model.params.model != model.name:
        raise UserError(
            f"{name}: its ParamTable is declared for model "
            f"{model.params.model!r}; give both the same name"
        )
    bad = [k for k in model.rig_kinds if k not in RIG_KINDS]
    if bad:
        raise UserError(
            f"{name}: unknown rig kind {bad[0]!r}"
            + suggest(bad[0], RIG_KINDS)
            + f"; kinds: {', '.join(RIG_KINDS)}"
        )
    lo, hi = model.theta_range
    if not lo < hi:
        raise UserError(
            f"{name}: theta_range {model.theta_range} must go from open (lower) to closed (upper)"
        )
    if model.rhs is not None:
        _check_states(model)
        return model
    _check_accel(model)
    _check_switches(model)
    return model


_WANT_RHS = "a numba @njit function rhs(x, force, p, dx) writing dx"
_WANT_START = "a numba @njit function start(x, p) completing the initial state x"
_WANT_STATE_SWITCHES = "a numba @njit function switches(x, force, p, g) writing g"


def _check_states(model) -> None:
    """A model on a state vector: its states, handle, contacts and compiled functions."""
    # long: one check after the other, each a line of its own; read top to bottom
    name = f"model {model.name!r}"
    states = model.states
    if not (isinstance(states, tuple) and len(states) >= 2 and all(
        isinstance(s, str) and s.isidentifier() for s in states
    )):  # fmt: skip
        raise UserError(f"{name}: states must be a tuple of at least two names, got {states!r}")
    if len(set(states)) != len(states):
        raise UserError(f"{name}: states {states!r} name one state twice")
    n = len(states)

    def index(value, what) -> int:
        if not (isinstance(value, int) and 0 <= value < n):
            raise UserError(
                f"{name}: {what} must be an index into states (0 to {n - 1}), got {value!r}"
            )
        return value

    if not (isinstance(model.handle, tuple) and len(model.handle) == 2):
        raise UserError(f"{name}: handle must be (position, speed) indices, got {model.handle!r}")
    position = index(model.handle[0], "handle's position")
    speed = index(model.handle[1], "handle's speed")
    if position == speed:
        raise UserError(f"{name}: the handle's position and speed must be two states")
    for k in model.contacts:
        if index(k, "a contact") == position:
            raise UserError(f"{name}: contact {k} is the handle's position, not a speed")
    if model.x0 and len(model.x0) != n:
        raise UserError(f"{name}: x0 has {len(model.x0)} values for {n} states")
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in model.x0):
        raise UserError(f"{name}: x0 must be finite numbers, got {model.x0!r}")
    _check_settings(model)
    from evo_door.sim.states import RHS_SIGNATURE, START_SIGNATURE, STATE_SWITCHES_SIGNATURE

    _check_compiled(name, "rhs", model.rhs, RHS_SIGNATURE, _WANT_RHS)
    if model.start is not None:
        _check_compiled(name, "start", model.start, START_SIGNATURE, _WANT_START)
    if model.switches is not None:
        _check_compiled(
            name, "switches", model.switches, STATE_SWITCHES_SIGNATURE, _WANT_STATE_SWITCHES
        )


def _check_compiled(name: str, what: str, func, sig, want: str) -> None:
    """Refuse ``func`` unless it is an @njit function that compiles for ``sig``."""
    from numba import config
    from numba.core.dispatcher import Dispatcher

    if getattr(config, "DISABLE_JIT", False):
        if not callable(func):
            raise UserError(f"{name}: {what} must be {want}; got {_describe(func)}")
        return
    if not isinstance(func, Dispatcher):
        raise UserError(f"{name}: {what} must be {want}; got {_describe(func)}")
    try:
        func.get_compile_result(sig)
    except Exception as exc:  # numba raises TypingError, TypeError, NameError...
        raise UserError(
            f"{name}: {what} must be {want}; it does not compile for "
            f"{_signature_text(sig)}: {_numba_reason(exc)}"
        ) from None


def _check_settings(model) -> None:
    """The switching functions' count and the tolerance, of either kind of model."""
    name = f"model {model.name!r}"
    if not (isinstance(model.n_switches, int) and 0 <= model.n_switches <= 64):
        raise UserError(f"{name}: n_switches must be a whole number from 0 to 64")
    if (model.switches is None) != (model.n_switches == 0):
        raise UserError(f"{name}: give switches and n_switches together (or neither)")
    if not (isinstance(model.tolerance, float) and 0.0 < model.tolerance < 1.0):
        raise UserError(f"{name}: tolerance must be a number in (0, 1), got {model.tolerance!r}")


def _check_switches(model) -> None:
    _check_settings(model)
    if model.switches is None:
        return
    from evo_door.sim.located import SWITCHES_SIGNATURE

    want = "a numba @njit function switches(theta, dtheta, force, p, g) writing g"
    _check_compiled(f"model {model.name!r}", "switches", model.switches, SWITCHES_SIGNATURE, want)


_WANT = "a numba @njit function accel(theta, dtheta, force, p) -> float"


def _check_accel(model) -> None:
    from numba import config
    from numba.core.dispatcher import Dispatcher

    from evo_door.sim.integrators import ACCEL_SIGNATURE

    name, accel = f"model {model.name!r}", model.accel
    if config.DISABLE_JIT:
        # NUMBA_DISABLE_JIT=1 turns every @njit into its Python function: check the
        # arguments only
        if not callable(accel):
            raise UserError(f"{name}: accel must be {_WANT}; got {_describe(accel)}")
        if not _takes_four(accel):
            raise UserError(
                f"{name}: accel must be {_WANT}; it does not take the four "
                "arguments (theta, dtheta, force, p)"
            )
        return
    if not isinstance(accel, Dispatcher):
        raise UserError(f"{name}: accel must be {_WANT}; got {_describe(accel)}")
    try:
        result = accel.get_compile_result(ACCEL_SIGNATURE)
    except Exception as exc:  # numba raises TypingError, TypeError, NameError...
        raise UserError(
            f"{name}: accel must be {_WANT}; it does not compile for "
            f"{_signature_text(ACCEL_SIGNATURE)}: {_numba_reason(exc)}"
        ) from None
    if result.signature.return_type != ACCEL_SIGNATURE.return_type:
        raise UserError(f"{name}: accel must be {_WANT}; it returns {result.signature.return_type}")


def _takes_four(func) -> bool:
    try:
        inspect.signature(func).bind(0.0, 0.0, 0.0, None)
    except (TypeError, ValueError):
        return False
    return True


def _describe(obj) -> str:
    if inspect.isfunction(obj):
        return "a plain Python function (decorate it with @njit(cache=True))"
    if obj is None:
        return "None"
    return f"a {type(obj).__name__}"


def _signature_text(sig) -> str:
    return (
        "("
        + ", ".join("float64[::1]" if str(a).startswith("array") else str(a) for a in sig.args)
        + ")"
    )


_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _numba_reason(exc: Exception) -> str:
    """The line of a (multi-line, coloured) numba error that says what is wrong."""
    text = _ANSI.sub("", str(exc))
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith(("Failed in", "During:", "File ", "^")):
            continue
        if "not available and compilation disabled" in line:
            return "its explicit @njit signature does not include it"
        # "No conversion from UniTuple(float64 x 2) to float64 for '$10return_value.3'"
        return re.sub(r" for '\$[^']*'.*$", "", line)
    return type(exc).__name__
