"""Kinematic maps of the transmissions and the monotone table, compiled once.

Each map takes a body's coordinate ``q`` and returns the output ``s(q)`` and its ratio
``ds/dq`` in closed form. The generated mechanism module imports them (library code,
never the file's); the reader calls the same functions over the body's range to refuse
a transmission that folds (:mod:`evo_door.models.blocks.transmissions`). A map that
cannot be evaluated returns NaN for both.

- :func:`slider_crank`: a crank of radius ``r`` at angle ``q + phase`` drives, through a
  rod of length ``rod``, a slider on a line at distance ``offset`` from the crank's
  axis: ``s = r cos(phi) + sqrt(rod^2 - (r sin(phi) - offset)^2)``, the slider's
  distance from the axis along its line.
- :func:`four_bar`: ground link ``d`` between the pivots, input crank ``a`` at angle
  ``q + phase`` from the ground link, coupler ``b``, output rocker ``c``; ``s`` is the
  rocker's angle from the ground link (``branch`` +1 open, -1 crossed).
- :func:`pchip`: the monotone piecewise-cubic interpolant (Fritsch-Carlson slopes, the
  end slopes of the three-point formula, as scipy's ``PchipInterpolator``) of the
  points held in ``p`` from index ``i0``: ``n`` abscissas then ``n`` ordinates;
  beyond the end points a straight line with the end slope. :func:`pchip_integral`
  is its integral from the first point (the potential of a table spring).
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True)
def slider_crank(q, r, rod, offset, phase):  # pragma: no cover - compiled
    phi = q + phase
    sin, cos = math.sin(phi), math.cos(phi)
    h = r * sin - offset
    reach = rod * rod - h * h
    if not reach > 0.0:
        return math.nan, math.nan
    root = math.sqrt(reach)
    return r * cos + root, -r * sin - h * r * cos / root


@njit(cache=True)
def four_bar(q, a, b, c, d, phase, branch):  # pragma: no cover - compiled
    phi = q + phase
    sin, cos = math.sin(phi), math.cos(phi)
    px, py = d - a * cos, -a * sin  # from the crank's end to the rocker's pivot
    r2 = px * px + py * py
    r = math.sqrt(r2)
    k = (b * b - c * c - r2) / (2.0 * c)
    u = k / r
    if not (-1.0 < u < 1.0):
        return math.nan, math.nan
    alpha = math.atan2(py, px)
    s = alpha + branch * math.acos(u)
    # derivatives over phi
    dalpha = (a * a - a * d * cos) / r2
    dr = a * d * sin / r
    dk = -a * d * sin / c
    du = dk / r - k * dr / r2
    return s, dalpha - branch * du / math.sqrt(1.0 - u * u)


@njit(cache=True)
def _end_slope(h0, h1, m0, m1):  # pragma: no cover - compiled
    d = ((2.0 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
    if d * m0 <= 0.0:
        return 0.0
    if m0 * m1 < 0.0 and abs(d) > 3.0 * abs(m0):
        return 3.0 * m0
    return d


@njit(cache=True)
def _slope(p, i0, n, k):  # pragma: no cover - compiled
    """The interpolant's slope at point ``k``."""
    x, y = i0, i0 + n
    if n == 2:
        return (p[y + 1] - p[y]) / (p[x + 1] - p[x])
    if k == 0 or k == n - 1:
        j = 0 if k == 0 else n - 2
        step = 1 if k == 0 else -1
        h0 = p[x + j + 1] - p[x + j]
        m0 = (p[y + j + 1] - p[y + j]) / h0
        j1 = j + step
        h1 = p[x + j1 + 1] - p[x + j1]
        m1 = (p[y + j1 + 1] - p[y + j1]) / h1
        return _end_slope(h0, h1, m0, m1)
    h0 = p[x + k] - p[x + k - 1]
    h1 = p[x + k + 1] - p[x + k]
    m0 = (p[y + k] - p[y + k - 1]) / h0
    m1 = (p[y + k + 1] - p[y + k]) / h1
    if m0 * m1 <= 0.0:
        return 0.0
    w0, w1 = 2.0 * h1 + h0, h1 + 2.0 * h0
    return (w0 + w1) / (w0 / m0 + w1 / m1)


@njit(cache=True)
def pchip(q, p, i0, n):  # pragma: no cover - compiled
    x, y = i0, i0 + n
    if q <= p[x]:
        d = _slope(p, i0, n, 0)
        return p[y] + d * (q - p[x]), d
    if q >= p[x + n - 1]:
        d = _slope(p, i0, n, n - 1)
        return p[y + n - 1] + d * (q - p[x + n - 1]), d
    k = 0
    while q > p[x + k + 1]:
        k += 1
    h = p[x + k + 1] - p[x + k]
    t = (q - p[x + k]) / h
    y0, y1 = p[y + k], p[y + k + 1]
    d0, d1 = _slope(p, i0, n, k) * h, _slope(p, i0, n, k + 1) * h
    # cubic Hermite on t in [0, 1]
    t2, t3 = t * t, t * t * t
    s = (2 * t3 - 3 * t2 + 1) * y0 + (t3 - 2 * t2 + t) * d0 + (-2 * t3 + 3 * t2) * y1
    s += (t3 - t2) * d1
    ds = (6 * t2 - 6 * t) * y0 + (3 * t2 - 4 * t + 1) * d0 + (-6 * t2 + 6 * t) * y1
    ds += (3 * t2 - 2 * t) * d1
    return s, ds / h


@njit(cache=True)
def _segment_integral(p, i0, n, k, t):  # pragma: no cover - compiled
    """The integral of segment ``k`` of :func:`pchip` from its start to ``t`` (0..1)."""
    x, y = i0, i0 + n
    h = p[x + k + 1] - p[x + k]
    d0, d1 = _slope(p, i0, n, k) * h, _slope(p, i0, n, k + 1) * h
    t2 = t * t
    t3, t4 = t2 * t, t2 * t2
    out = (0.5 * t4 - t3 + t) * p[y + k] + (0.25 * t4 - 2.0 * t3 / 3.0 + 0.5 * t2) * d0
    out += (-0.5 * t4 + t3) * p[y + k + 1] + (0.25 * t4 - t3 / 3.0) * d1
    return out * h


@njit(cache=True)
def pchip_integral(q, p, i0, n):  # pragma: no cover - compiled
    x, y = i0, i0 + n
    if q <= p[x]:
        u = q - p[x]
        return p[y] * u + 0.5 * _slope(p, i0, n, 0) * u * u
    total = 0.0
    k = 0
    while k < n - 1 and q > p[x + k + 1]:
        total += _segment_integral(p, i0, n, k, 1.0)
        k += 1
    if k == n - 1:
        u = q - p[x + n - 1]
        return total + p[y + n - 1] * u + 0.5 * _slope(p, i0, n, n - 1) * u * u
    return total + _segment_integral(p, i0, n, k, (q - p[x + k]) / (p[x + k + 1] - p[x + k]))
