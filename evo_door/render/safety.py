"""Safety rules of the renderer.

- :func:`limit_force` (compiled, every cycle): a non-finite force (NaN, inf) becomes
  zero and is reported as a fault; a force above the device limit is scaled down to
  it along its own direction.
- :func:`passivity` / :func:`check_passive`: Colgate and Schenkel's condition for a
  sampled virtual wall to be passive, ``b > K T / 2 + |B|``, with ``b`` the device's
  physical damping (N s/m), ``K`` the stiffest virtual spring of the parameter set in
  device units (N/m), ``B`` its most negative virtual damping (N s/m) and ``T`` the
  loop period (s). A set that fails is refused with the reason, or, when asked,
  clamped (its stiffnesses scaled down) and the clamp reported.
- :func:`~evo_door.render.hands_off.check_hands_off` (its own module, light enough
  for the command line's flags): the door a set describes, released from rest
  anywhere in its stroke with no hand on it, must not move faster than a limit.
- :class:`Watchdog`: after ``misses`` consecutive late cycles, or when the device
  connection drops, the force ramps to zero within ``ramp_time`` (10 ms) and the
  device is stopped.
"""

from __future__ import annotations

import math

from numba import njit

from evo_door.errors import UserError
from evo_door.models.haptic import PARAMS

#: fault codes returned by :func:`limit_force`
OK = 0
SATURATED = 1
NON_FINITE = 2

#: Stiffnesses of the haptic model: (name, divide by radius?) -> N/m on the device.
#: Tangential laws F (N) = k theta (N/rad) are k / R per metre of arc.
_STIFFNESSES = (
    ("latch_stiffness", True),
    ("stop_stiffness", True),
    ("gasket_stiffness", True),
    ("return_stiffness", True),
    ("k_radial", False),
    ("k_plane", False),
)
#: Negative dampings: transition_damping (N s/rad, tangential) and c_energy (N s/m).
_NEGATIVE_DAMPINGS = (("transition_damping", True), ("c_energy", False))


@njit(cache=True)
def limit_force(f, limit):
    """Make ``f`` (3-vector, N, in place) safe: finite and of norm <= ``limit``.

    Returns :data:`OK`, :data:`SATURATED` (scaled down to the limit) or
    :data:`NON_FINITE` (set to zero).
    """
    n2 = f[0] * f[0] + f[1] * f[1] + f[2] * f[2]
    if not math.isfinite(n2):
        f[0] = 0.0
        f[1] = 0.0
        f[2] = 0.0
        return NON_FINITE
    if n2 > limit * limit:
        # a hair under the limit so rounding cannot leave it above
        scale = limit / math.sqrt(n2) * (1.0 - 1e-12)
        f[0] *= scale
        f[1] *= scale
        f[2] *= scale
        return SATURATED
    return OK


def _values(params) -> dict[str, float]:
    return params.as_dict() if hasattr(params, "as_dict") else PARAMS.as_dict(params)


#: What the loop's implicit law renders (:func:`~evo_door.render.kernels.compute_command_implicit`):
#: the door's tangential springs and its snap-zone damping, solved over the step on
#: the device's mass, stable and dissipative at any stiffness; left out of the check.
IMPLICIT = frozenset(
    (
        "latch_stiffness",
        "stop_stiffness",
        "gasket_stiffness",
        "return_stiffness",
        "transition_damping",
    )
)


def passivity(params, damping: float, period: float, exclude=frozenset()) -> dict:
    """The Colgate-Schenkel check of a haptic parameter set.

    ``exclude`` names the springs and dampings not rendered by a sampled explicit law
    (solved implicitly by the loop, :data:`IMPLICIT`, or rendered by the device itself
    at its own rate): they are left out of K and B.

    Returns ``{"ok", "K", "K_name", "B", "b", "T", "margin", "reason"}``: K (N/m) the
    stiffest virtual spring and which parameter it is, B (N s/m) the size of the most
    negative virtual damping, b (N s/m) the device's damping, T (s) the loop period,
    margin = b - (K T / 2 + |B|) (N s/m), and a one-line reason when not ok.
    """
    v = _values(params)
    radius = v["radius"]
    springs = {n: v[n] / radius if r else v[n] for n, r in _STIFFNESSES if n not in exclude}
    k_name = max(springs, key=springs.get) if springs else "none"
    k = springs.get(k_name, 0.0)
    b_neg = sum(v[n] / radius if r else v[n] for n, r in _NEGATIVE_DAMPINGS if n not in exclude)
    need = k * period / 2.0 + abs(b_neg)
    margin = damping - need
    ok = margin > 0.0
    reason = ""
    if not ok:
        reason = (
            f"not passive at a {period * 1e3:.3g} ms loop period: {k_name} gives "
            f"K = {k:.4g} N/m, negative damping |B| = {b_neg:.4g} N s/m, and the device "
            f"damping b = {damping:.4g} N s/m is not above K T / 2 + |B| = {need:.4g} N s/m"
        )
    return dict(
        ok=ok, K=k, K_name=k_name, B=b_neg, b=damping, T=period, margin=margin, reason=reason
    )


def clamp_passive(params, damping: float, period: float, safety: float = 0.9, exclude=frozenset()):
    """A copy of ``params`` made passive by scaling down what breaks the condition.

    Negative dampings are scaled to at most half the device damping, then every
    stiffness above ``K_max = safety * 2 (b - |B|) / T`` down to it. Returns
    ``(params, changes)`` with ``changes`` {name: (old, new)}; raises a UserError when
    a declared lower bound forbids it.
    """
    v = _values(params)
    radius = v["radius"]
    changes: dict[str, tuple[float, float]] = {}
    negative = [(n, r) for n, r in _NEGATIVE_DAMPINGS if n not in exclude]
    b_neg = sum(v[n] / radius if r else v[n] for n, r in negative)
    scale_b = 1.0 if b_neg <= 0.5 * damping else 0.5 * damping / b_neg
    if scale_b < 1.0:
        for name, _ in negative:
            changes[name] = (v[name], v[name] * scale_b)
        b_neg *= scale_b
    k_max = safety * 2.0 * (damping - b_neg) / period
    for name, per_r in _STIFFNESSES:
        k = v[name] / radius if per_r else v[name]
        if name not in exclude and k > k_max:
            new = k_max * radius if per_r else k_max
            if new < PARAMS[name].lower:
                raise UserError(
                    f"cannot clamp {name} to a passive {new:.4g} {PARAMS[name].unit}: below "
                    f"its declared minimum {PARAMS[name].lower:g}; raise the loop rate or "
                    "the device damping"
                )
            changes[name] = (v[name], new)
    new_params = params.replace({n: c[1] for n, c in changes.items()}) if changes else params
    return new_params, changes


def check_passive(params, damping: float, period: float, clamp: bool = False, exclude=frozenset()):
    """``params`` if passive; else clamped (``clamp``) or a UserError with the reason.

    ``exclude`` as in :func:`passivity`. Returns ``(params, changes)``; ``changes`` is
    empty unless clamped.
    """
    check = passivity(params, damping, period, exclude)
    if check["ok"]:
        return params, {}
    if not clamp:
        hint = "; --device-damping states the device's own" if damping <= 0.0 else ""
        raise UserError(f"parameter set refused: {check['reason']} (--clamp scales it down{hint})")
    return clamp_passive(params, damping, period, exclude=exclude)


class Watchdog:
    """Counts late cycles; once tripped, gives the ramp factor of the force (1 -> 0).

    ``misses`` consecutive late cycles, or :meth:`trip` (a dropped connection), start
    a linear ramp of the commanded force to zero over ``ramp_time`` (s).
    """

    def __init__(self, misses: int = 10, ramp_time: float = 0.008):
        if misses < 1:
            raise UserError(f"watchdog: misses must be >= 1, got {misses}")
        self.misses = int(misses)
        self.ramp_time = float(ramp_time)
        self.late = 0
        self.tripped_at: float | None = None
        self.reason = ""

    def cycle(self, t: float, late: bool) -> None:
        """Record one cycle at time ``t`` (s), late or not."""
        self.late = self.late + 1 if late else 0
        if self.late >= self.misses and self.tripped_at is None:
            self.trip(t, f"{self.late} consecutive cycles missed their deadline")

    def trip(self, t: float, reason: str) -> None:
        if self.tripped_at is None:
            self.tripped_at = float(t)
            self.reason = reason

    @property
    def tripped(self) -> bool:
        return self.tripped_at is not None

    def factor(self, t: float) -> float:
        """Scale of the force at time ``t``: 1 before the trip, down to 0 at the ramp's end."""
        if self.tripped_at is None:
            return 1.0
        return max(0.0, 1.0 - (t - self.tripped_at) / self.ramp_time)
