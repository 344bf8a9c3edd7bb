"""Constitutive laws shared by the door's blocks (compiled).

Kept apart from the blocks so that every block uses the same friction law and the
same smooth window, and a test can check the law on its own.
"""

from __future__ import annotations

import math
from fractions import Fraction

from numba import njit


def _lambert_rational(levels):
    """Numerator and denominator coefficients (rising powers of ``z = x^2``) of the
    ``levels``-th convergent of Lambert's continued fraction
    ``tanh x = x / (1 + z / (3 + z / (5 + ...)))``, exactly, as floats."""
    num, den = [Fraction(2 * levels + 1)], [Fraction(1)]
    for k in range(levels - 1, -1, -1):
        # (2k+1) + z / (num / den) = ((2k+1) num + z den) / num
        new = [Fraction(0)] * max(len(num), len(den) + 1)
        for i, c in enumerate(num):
            new[i] += (2 * k + 1) * c
        for i, c in enumerate(den):
            new[i + 1] += c
        num, den = new, num
    return tuple(float(c) for c in den), tuple(float(c) for c in num)


# Below |x| = 0.625 the 7th convergent is tanh to 6e-18 relative (below half an ulp);
# above, (1 - e^-2x) / (1 + e^-2x) has no cancellation.
(_P0, _P1, _P2, _P3), (_Q0, _Q1, _Q2, _Q3, _Q4) = _lambert_rational(7)
_SMALL = 0.625


# error_model="numpy": no zero test before the division (its denominator is >= 1)
@njit(cache=True, nogil=True, error_model="numpy")
def tanh(u):
    """``tanh(u)`` within 6e-16 (3 ulp) of ``math.tanh``, at a fraction of its cost.

    The C library's tanh goes through ``expm1``; the friction laws call it six times
    per evaluation of the door's right-hand side. Here: a rational function (Lambert's
    continued fraction, cut where it is exact to double precision) for small ``|u|``,
    one ``exp`` above, +-1 beyond 20 (tanh(20) is 1 to double precision).
    ``tests/test_door_fast.py`` compares it with ``math.tanh`` over 1e-300 .. 1e300.
    """
    x = abs(u)
    if x < _SMALL:
        z = u * u
        return (
            u
            * (_P0 + z * (_P1 + z * (_P2 + z * _P3)))
            / (_Q0 + z * (_Q1 + z * (_Q2 + z * (_Q3 + z * _Q4))))
        )
    if x > 20.0:
        return 1.0 if u > 0.0 else -1.0
    e = math.exp(-2.0 * x)
    r = (1.0 - e) / (1.0 + e)
    return r if u > 0.0 else -r


@njit(cache=True, nogil=True)
def dry_friction(f_mag, a, v_rel):
    """Dry friction of eq. 3.1, ``f_mag * tanh(a * v_rel)``.

    Inputs: ``f_mag`` friction magnitude (N or N m), ``a`` sensitivity factor (s/m or
    s/rad, the inverse of the slip speed at which friction reaches 76 % of ``f_mag``),
    ``v_rel`` relative speed (m/s or rad/s). Output: the friction magnitude *along*
    ``v_rel``; a block applies it with a minus sign (friction opposes slip). Static and
    kinetic friction are the same (the seed's hypothesis).
    """
    u = a * v_rel
    if u > 20.0:  # tanh(20) = 1 - 8e-18: skip the call while sliding
        return f_mag
    if u < -20.0:
        return -f_mag
    return f_mag * tanh(u)


@njit(cache=True, nogil=True)
def dry_friction_2d(f_mag, a, vx, vy):
    """Planar dry friction: magnitude ``f_mag * tanh(a |v|)`` along ``v = (vx, vy)``.

    Outputs ``(fx, fy)``, the vector *along* the slip velocity (apply with a minus
    sign). ``tanh(a s) / s`` tends to ``a`` as the slip speed ``s`` tends to 0, so the
    law is smooth through rest.
    """
    ratio = a * tanh_ratio(a * a * (vx * vx + vy * vy))
    return f_mag * ratio * vx, f_mag * ratio * vy


@njit(cache=True, nogil=True, error_model="numpy")
def tanh_ratio(x2):
    """``tanh(x) / x`` for ``x = sqrt(x2) >= 0`` (1 at 0).

    Below |x| = 0.625 it is the rational function of :func:`tanh` without its factor
    x: no square root and no second division where a slip is slow.
    """
    if x2 < _SMALL * _SMALL:
        return (_P0 + x2 * (_P1 + x2 * (_P2 + x2 * _P3))) / (
            _Q0 + x2 * (_Q1 + x2 * (_Q2 + x2 * (_Q3 + x2 * _Q4)))
        )
    x = math.sqrt(x2)
    return tanh(x) / x


@njit(cache=True, nogil=True)
def activation(x, x0, a):
    """Activation function of eq. 4.36, ``S(x, x0, a) = (tanh(a (x - x0)) + 1) / 2``."""
    return 0.5 * (tanh(a * (x - x0)) + 1.0)
