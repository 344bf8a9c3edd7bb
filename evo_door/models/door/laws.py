"""Constitutive laws shared by the door's blocks (compiled).

Kept apart from the blocks so that every block uses the same friction law and the
same smooth window, and a test can check the law on its own.
"""

from __future__ import annotations

import math

from numba import njit


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
    return f_mag * math.tanh(u)


@njit(cache=True, nogil=True)
def dry_friction_2d(f_mag, a, vx, vy):
    """Planar dry friction: magnitude ``f_mag * tanh(a |v|)`` along ``v = (vx, vy)``.

    Outputs ``(fx, fy)``, the vector *along* the slip velocity (apply with a minus
    sign). ``tanh(a s) / s`` tends to ``a`` as the slip speed ``s`` tends to 0, so the
    law is smooth through rest.
    """
    s = math.sqrt(vx * vx + vy * vy)
    if s * a < 1e-8:
        ratio = a
    else:
        ratio = math.tanh(a * s) / s
    return f_mag * ratio * vx, f_mag * ratio * vy


@njit(cache=True, nogil=True)
def activation(x, x0, a):
    """Activation function of eq. 4.36, ``S(x, x0, a) = (tanh(a (x - x0)) + 1) / 2``."""
    return 0.5 * (math.tanh(a * (x - x0)) + 1.0)
