"""A specification a supplier can build: nominal values that doors made to the supplier's
tolerances feel like the chosen feel, and how many of them will.

A specification stage ends with one door that feels like the chosen feel (the
perceptual objective, :class:`~evo_door.perception.FeelTarget`). A supplier cannot
build one value; it builds within the tolerances of its process (a spring's rate to
+-10 %, a friction to +-25 %: :mod:`evo_door.optim.process`). What the supplier needs
is a nominal that most doors built to those tolerances still pass the perceptual check
with, and the share that will: the **yield**.

:func:`specify` does it in five steps:

1. **The check, for many doors at once** (:class:`BatchFeelCheck`): every door's margins,
   its differences from the chosen feel in units of their JNDs, signed: each point of
   both strokes outside the latch zone, both latch peaks, both peaks' angles, and the
   felt inertia and damping where the chosen feel has dynamics. A door passes when
   every margin is within +-1, as :func:`~evo_door.perception.check_verdict` judges one
   door (tests compare the two). One compiled call a batch of doors, across threads.
2. **Sensitivities**: each specification's secant slope of every margin over its own
   tolerance (JND per unit of the specification): a specification the check does not
   see has none, and the table says "not judged" instead of giving it a band.
3. **Design centring**: the free specifications' nominal that maximises the yield,
   not the one on the boundary of the check. The doors are the margins' secant model
   about the nominal with one set of standardised draws (common random numbers,
   :data:`DESIGN_SAMPLES` doors, seed ``design_seed``), the yield smoothed, maximised by
   Nelder-Mead within a trust box of :data:`TRUST` tolerances, the model made again at
   the new nominal (:data:`ROUNDS` rounds). The centred nominal is kept where more of
   those doors pass with it, by the compiled check itself, than with the
   smallest-change door the stage started from; that door stays in the results as the
   alternative, with its own yield.
4. **The yield**: a fresh sample of doors drawn after the design is fixed, with a seed
   of its own (``yield_seed``), at least 2000 doors, each through the compiled check:
   the share that passes with its 95 % Clopper-Pearson interval. Each specification's
   **contribution to the yield loss** is the yield the sample would gain were that
   specification built exactly (its deviation taken off every door's margins through
   its secant slopes).
5. **Reachable or not**: where the yield is below the target (95 %), the stage says so
   and gives (a) the **allocation**: the fewest tolerances, tightened by the least
   common factor, that reach the target, searched on the yield sample's draws through
   the secant model about the most *robust* nominal (the door with the most room: the
   least worst margin of its own, Nelder-Mead on the compiled check; tight tolerances
   want room, not a centre on the process's spread), and verified by the compiled
   check on another fresh sample (``allocation_seed``), aimed a little above the
   target and higher while that sample misses it (:data:`ALLOCATION_AIMS`); none where
   even that door is beyond the JND; and (b) the **nearest feel** the process can hold
   (:func:`nearest_feel`): a set of the chosen feel's model (a haptic set) whose feel
   the sampled doors pass at the target, as near the chosen feel as it can be, for a
   participant to confirm on the renderer.

Everything is in the specifications' own units; margins are in JND.
"""

from __future__ import annotations

import functools
import itertools
import math
import sys
import time

import numpy as np

from evo_door.errors import UserError
from evo_door.optim.feel_doors import (
    BLOWN,
    BatchFeelCheck,
    Reference,
    band_text,
    passing,
    passing_moved,
    smoothed_share,
    soft_yield,
)
from evo_door.optim.specification import (
    DESIGN_SEED,
    NearestFeel,
    Specification,
    YieldEstimate,
    clopper_pearson,
)
from evo_door.perception import FeelTarget
from evo_door.perception.feel import DIRECTIONS

__all__ = [
    "BatchFeelCheck",
    "NearestFeel",
    "Reference",
    "Specification",
    "YieldEstimate",
    "band_text",
    "clopper_pearson",
    "full_nominal",
    "nearest_feel",
    "passing",
    "soft_yield",
    "specify",
    "standard_draws",
]

#: doors of the yield's fresh sample (the issue's floor: 2000)
SAMPLES = 2000
#: doors of the common-random-number sample the nominal is centred on
DESIGN_SAMPLES = 400
#: the seeds: the centring's draws (DESIGN_SEED, 1), the yield's fresh sample, the
#: allocation's check
YIELD_SEED = 2
ALLOCATION_SEED = 3
#: the yield a specification must reach to be called reachable
TARGET = 0.95
#: centring: rounds of (secant model, Nelder-Mead), the trust box in tolerances and the
#: Nelder-Mead's evaluations per free parameter (the yield smoothed by SMOOTHING)
ROUNDS = 2
TRUST = 2.0
EVALUATIONS_PER_FREE = 60
#: allocation: every subset of up to this many of the largest contributors is tried
#: (more are added one at a time, largest first); a tightened tolerance is never below
#: this share of the process's
CANDIDATES = 6
LEAST_SHARE = 0.05
#: the yield's draws the allocation is searched on (all of a fresh sample verify it)
ALLOCATION_DOORS = 1000
#: how far above the target the allocation's search aims, tried in turn until the fresh
#: sample verifies the target: the search is first order on a thousand doors, and one
#: aim missed its verification by a door in 2000 (the main job, on one CPU)
ALLOCATION_AIMS = (0.005, 0.01, 0.02, 0.04)


# -- the computation ------------------------------------------------------------------
def standard_draws(distributions: list[str], n: int, rng) -> np.ndarray:
    """Deviations of ``n`` doors in units of each tolerance: normal with 3 sigma = 1, or
    uniform on [-1, 1]; one column per specification, drawn in that order.

    >>> u = standard_draws(["normal", "uniform"], 20000, np.random.default_rng(1))
    >>> round(float(u[:, 0].std()), 2), bool(np.abs(u[:, 1]).max() <= 1.0)
    (0.33, True)
    """
    out = np.empty((n, len(distributions)))
    for j, kind in enumerate(distributions):
        if kind == "uniform":
            out[:, j] = rng.uniform(-1.0, 1.0, n)
        else:
            out[:, j] = rng.standard_normal(n) / 3.0
    return out


def specify(
    model,
    p0,
    feel: FeelTarget,
    names: list[str],
    process,
    free: list[str],
    lower,
    upper,
    asis=None,
    target: float = TARGET,
    samples: int = SAMPLES,
    design_seed: int = DESIGN_SEED,
    yield_seed: int = YIELD_SEED,
    allocation_seed: int = ALLOCATION_SEED,
    centre: bool = True,
    feel_model=None,
    feel_params=None,
    progress: bool = False,
) -> Specification:
    """The specification of ``names`` from the door ``p0`` (a full kernel vector of
    ``model``, the smallest change that reaches the chosen ``feel``), built to
    ``process`` (an :class:`~evo_door.optim.process.Process` of ``names``); ``free``
    are the specifications the nominal may move (within ``lower``..``upper``, their
    search ranges), ``asis`` the AS-IS door's full vector (the "changed" column);
    ``feel_model`` and ``feel_params`` the chosen feel's model and set (a haptic set:
    where the target is out of reach, the nearest feel is one of that model). See the
    module docstring."""
    # long: the five steps in order (module docstring), each a few lines; the order is the point
    t0 = time.perf_counter()
    p0 = _check_inputs(model, p0, feel, names, samples, target)
    idx = np.array([model.params.index(n) for n in names], dtype=np.int64)
    lo_decl = np.array([model.params[n].lower for n in names])
    hi_decl = np.array([model.params[n].upper for n in names])
    dist = [process.distribution[process.names.index(n)] for n in names]
    source = [process.source[process.names.index(n)] for n in names]
    check = BatchFeelCheck(model, feel)
    bar = _bar(ROUNDS + 4, progress)

    def widths(p):
        return np.asarray(process.half_widths(p[idx]), dtype=np.float64)

    def doors(p, U, t):
        P = np.repeat(p[None, :], len(U), axis=0)
        P[:, idx] = np.clip(p[idx] + U * t, lo_decl, hi_decl)
        return P

    design_draws = standard_draws(dist, DESIGN_SAMPLES, np.random.default_rng(design_seed))
    cols = np.array([names.index(n) for n in free if n in names], dtype=np.int64)
    search_lo = np.asarray(lower, dtype=np.float64)
    search_hi = np.asarray(upper, dtype=np.float64)
    start = p0.copy()
    p = p0.copy()
    if centre and cols.size:
        for _ in range(ROUNDS):
            p = _centre_round(check, p, idx, cols, widths(p), design_draws, search_lo, search_hi)
            bar.update(1)
    else:
        bar.update(ROUNDS)
    # the centred nominal where more of the design doors pass with it (the compiled
    # check, not the secant model); a tie keeps the smallest change, the method's answer
    y_start = passing(check.margins(doors(start, design_draws, widths(start)))).sum()
    y_centred = passing(check.margins(doors(p, design_draws, widths(p)))).sum()
    bar.update(1)
    if centre and y_centred > y_start and check.passes(p):
        design, other, other_name = "centred", start, "smallest change"
    else:
        p, design, other, other_name = start, "smallest change", None, ""
    # the yield: a fresh sample, drawn now that the design is fixed
    t = widths(p)
    U = standard_draws(dist, samples, np.random.default_rng(yield_seed))
    forces: dict = {}
    measured: list = []
    M = check.margins(doors(p, U, t), forces, measured)
    ok = passing(M)
    estimate = YieldEstimate(int(ok.sum()), samples, yield_seed)
    bar.update(1)
    J = _secants(check, p, idx, t, lo_decl, hi_decl)
    sensitivity = np.max(np.abs(J), axis=0) if J.size else np.zeros(len(names))
    loss = np.array(
        [
            passing_moved(M, U[:, j] * t[j], J[:, j]).mean() - ok.mean() if t[j] else 0.0
            for j in range(len(names))
        ]
    )
    fails = np.abs(M) > 1.0
    worst = check.labels[int(np.argmax(fails.sum(axis=0)))] if fails.any() else ""
    alternative = {}
    if other is not None:
        Ua = standard_draws(dist, samples, np.random.default_rng(yield_seed))
        ya = passing(check.margins(doors(other, Ua, widths(other)))).mean()
        alternative = {
            "design": other_name,
            "nominal": other[idx].copy(),
            "yield": YieldEstimate(int(round(ya * samples)), samples, yield_seed),
        }
    bar.update(1)
    allocation, allocation_yield, allocation_nominal = {}, None, None
    nearest, note, room = None, "", 0.0
    if estimate.estimate < target and feel_model is not None:
        nearest = nearest_feel(
            check, _joined(measured), feel_model, feel_params, target, yield_seed
        )
    if estimate.estimate < target:
        # tightened tolerances want the door with the most room, not the one centred
        # on the process's spread: the allocation is made about the robust nominal
        # (from the design and from the smallest change: Nelder-Mead is a local search)
        tries = [_robust_nominal(check, q, idx, cols, search_lo, search_hi) for q in (p, start)]
        rooms = [float(np.max(np.abs(check.margins(q)[0]))) for q in tries]
        robust, room = tries[int(np.argmin(rooms))], min(rooms)
    if estimate.estimate < target and room > 1.0:
        note = (
            f"no tightening reaches the target: the door itself, at its most robust "
            f"nominal, is {room:.2f} JND from the chosen feel"
        )
    elif estimate.estimate < target:
        tr = widths(robust)
        Jr = _secants(check, robust, idx, tr, lo_decl, hi_decl)
        some = U[:ALLOCATION_DOORS]  # the search on some of the yield's draws
        Ml = check.margins(robust)[0] + (some * tr) @ Jr.T  # first order
        swing = np.max(np.abs(Jr), axis=0) * tr
        Uv = standard_draws(dist, samples, np.random.default_rng(allocation_seed))
        for aim in ALLOCATION_AIMS:  # higher while the fresh sample misses the target
            tighter = _allocate(Ml, some, tr, Jr, names, loss, swing, target, aim)
            if not tighter:  # none reaches this aim: the last one found stands
                break
            allocation = tighter
            tightened = tr.copy()
            for n, w in allocation.items():
                tightened[names.index(n)] = w
            okv = passing(check.margins(doors(robust, Uv, tightened)))
            allocation_yield = YieldEstimate(int(okv.sum()), samples, allocation_seed)
            allocation_nominal = robust[idx].copy()
            if allocation_yield.estimate >= target:
                break
    bar.update(1)
    bar.close()
    nominal_margin = float(np.max(np.abs(check.margins(p))))
    return Specification(
        names=list(names),
        units=[model.params[n].unit for n in names],
        nominal=p[idx].copy(),
        asis=(np.asarray(asis, dtype=np.float64)[idx] if asis is not None else start[idx]).copy(),
        half_width=t,
        distribution=dist,
        source=source,
        sensitivity=sensitivity,
        loss=loss,
        free=[names[c] for c in cols],
        design=design,
        yield_=estimate,
        target=target,
        worst=worst,
        alternative=alternative,
        allocation=allocation,
        allocation_yield=allocation_yield,
        allocation_nominal=allocation_nominal,
        nearest=nearest,
        nominal_margin=nominal_margin,
        design_seed=design_seed,
        evaluations=check.evaluations,
        seconds=time.perf_counter() - t0,
        note=note,
        curves=_curves(check, forces),
    )


def full_nominal(spec: Specification, model, p0) -> np.ndarray:
    """The full kernel vector ``p0`` with the specification's nominal in it."""
    p = np.array(p0, dtype=np.float64)
    for n, v in zip(spec.names, spec.nominal):
        p[model.params.index(n)] = v
    return p


def _check_inputs(model, p0, feel, names, samples, target) -> np.ndarray:
    """``p0`` as a kernel vector; every bad argument a one-line error."""
    if not isinstance(feel, FeelTarget):
        raise UserError("specification: needs a chosen feel (a run with the perceptual objective)")
    p0 = np.array(p0, dtype=np.float64).ravel()
    if p0.shape != (len(model.params),) or not np.all(np.isfinite(p0)):
        raise UserError(
            f"specification: the door needs {len(model.params)} finite values of model "
            f"{model.name!r}, got shape {p0.shape}"
        )
    if not names:
        raise UserError("specification: no specification to build")
    for n in names:
        if n not in model.params.names:
            model.params[n]  # the declaration's own did-you-mean error
    if len(set(names)) != len(names):
        raise UserError("specification: a specification is named twice")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 100:
        raise UserError(f"specification: samples {samples!r}: a whole number of doors, >= 100")
    if not (isinstance(target, (int, float)) and 0.5 <= target < 1.0):
        raise UserError(f"specification: target {target!r}: a share in [0.5, 1) (0.95 is 95 %)")
    return p0


def _secants(check: BatchFeelCheck, p, idx, t, lo, hi) -> np.ndarray:
    """Each specification's secant slope of every margin over +-its tolerance (JND per
    unit), columns in ``idx``'s order; a step of 1e-6 of its value where the tolerance
    is 0 (a slope is still wanted for centring)."""
    steps = np.where(t > 0.0, t, 1e-6 * np.maximum(np.abs(p[idx]), 1e-6))
    P = np.repeat(p[None, :], 2 * len(idx), axis=0)
    for j, i in enumerate(idx):
        P[2 * j, i] = min(p[i] + steps[j], hi[j])
        P[2 * j + 1, i] = max(p[i] - steps[j], lo[j])
    M = check.margins(P)
    width = P[0::2, idx].diagonal() - P[1::2, idx].diagonal()
    with np.errstate(divide="ignore", invalid="ignore"):
        J = (M[0::2] - M[1::2]).T / np.where(width > 0.0, width, np.inf)
    J[np.abs(J) > 0.1 * BLOWN] = 0.0  # a blown door at an end: no slope to trust
    # a change the check cannot tell from rounding (a millionth of a JND over the step)
    # is no sensitivity: the check does not see that specification there
    J[np.abs(J) * steps[None, :] < 1e-6] = 0.0
    return J


def _centre_round(check, p, idx, cols, t, U, search_lo, search_hi) -> np.ndarray:
    """One round of centring (module docstring, step 3): the free specifications'
    nominal that maximises the smoothed yield of the secant model about ``p``."""
    from scipy.optimize import minimize

    from evo_door.optim.yield_kernel import worst_shifted

    lo = np.array([check.model.params[check.model.params.names[i]].lower for i in idx])
    hi = np.array([check.model.params[check.model.params.names[i]].upper for i in idx])
    J = _secants(check, p, idx, t, lo, hi)
    m0 = check.margins(p)[0]
    D = np.ascontiguousarray((U * t) @ J.T)  # every design door's deviation of its margins
    Jf = J[:, cols]
    ref = np.maximum(t[cols], 1e-3 * (search_hi - search_lo))
    box_lo = np.maximum(p[idx][cols] - TRUST * ref, search_lo)
    box_hi = np.minimum(p[idx][cols] + TRUST * ref, search_hi)
    if np.any(box_hi <= box_lo):
        return p

    def objective(z):
        return -smoothed_share(worst_shifted(D, m0 + Jf @ (z * ref)))

    z_lo = (box_lo - p[idx][cols]) / ref
    z_hi = (box_hi - p[idx][cols]) / ref
    res = minimize(
        objective,
        np.zeros(cols.size),
        method="Nelder-Mead",
        bounds=list(zip(z_lo, z_hi)),
        options={"maxfev": EVALUATIONS_PER_FREE * cols.size, "xatol": 1e-3, "fatol": 1e-5},
    )
    out = p.copy()
    out[idx[cols]] = p[idx][cols] + np.clip(res.x, z_lo, z_hi) * ref
    return out


def _joined(measured: list) -> dict:
    """One :meth:`BatchFeelCheck.measure` of the batches of a sample."""
    out: dict = {d: np.concatenate([m[d] for m in measured]) for d in DIRECTIONS}
    for key in ("peaks", "angles"):
        out[key] = {d: np.concatenate([m[key][d] for m in measured]) for d in DIRECTIONS}
    if "dynamics" in measured[0]:
        out["dynamics"] = np.concatenate([m["dynamics"] for m in measured])
    return out


def _subset(got: dict, rows) -> dict:
    out: dict = {d: got[d][rows] for d in DIRECTIONS}
    for key in ("peaks", "angles"):
        out[key] = {d: got[key][d][rows] for d in DIRECTIONS}
    if "dynamics" in got:
        out["dynamics"] = got["dynamics"][rows]
    return out


#: the units of the sensations the nearest feel moves: levels of force, dynamics
LEVEL_UNITS = ("N", "N s/rad", "kg m")
#: doors of the sample the nearest feel is searched on (all of them check it)
NEAREST_DOORS = 200


def nearest_feel(
    check: BatchFeelCheck, got: dict, model, params, target: float, seed: int = YIELD_SEED
) -> NearestFeel:
    """The set of ``model`` (the chosen feel's, at ``params``) nearest the chosen feel
    whose feel the measured doors ``got`` pass at ``target`` (module docstring, step 5).

    The sensations moved are the model's levels (group ``sensation``, a force, a
    damping or an inertia; each within its declared bounds); nearest is the perceptual
    objective of the chosen feel (:meth:`FeelTarget.value`, JND^2); the doors' smoothed
    yield must reach ``target``, a penalty otherwise. Nelder-Mead on the first
    :data:`NEAREST_DOORS` doors, the yield counted on all of them.
    """
    from scipy.optimize import minimize

    p0 = np.array(params, dtype=np.float64)
    cols = [
        i
        for i, q in enumerate(model.params)
        if q.group == "sensation" and q.unit in LEVEL_UNITS and q.lower < q.upper
    ]
    lo = np.array([model.params[model.params.names[i]].lower for i in cols])
    hi = np.array([model.params[model.params.names[i]].upper for i in cols])
    scale = np.maximum(np.abs(p0[cols]), 0.05 * (hi - lo))
    n = min(NEAREST_DOORS, len(got["peaks"]["opening"]))
    some = _subset(got, slice(0, n))
    aim = target + 0.01

    def feel_of(z):
        p = p0.copy()
        p[cols] = np.clip(p0[cols] + z * scale, lo, hi)
        return p

    def cost(z):
        p = feel_of(z)
        shortfall = max(0.0, aim - soft_yield(check.against(some, check.reference_of(model, p))))
        return check.feel.value(model, p) + 1e4 * shortfall**2

    res = minimize(
        cost,
        np.zeros(len(cols)),
        method="Nelder-Mead",
        options={"maxfev": 15 * len(cols), "xatol": 1e-3, "fatol": 1e-4},
    )
    p = feel_of(res.x)
    ok = passing(check.against(got, check.reference_of(model, p)))
    names = model.params.names
    moved = [names[i] for i in cols if abs(p[i] - p0[i]) > 1e-9 * max(abs(p0[i]), 1.0)]
    return NearestFeel(
        model=model.name,
        values={nm: float(v) for nm, v in zip(names, p)},
        moved=moved,
        distance=math.sqrt(max(check.feel.value(model, p), 0.0)),
        yield_=YieldEstimate(int(ok.sum()), len(ok), seed),
        target=target,
    )


def _robust_nominal(check, p, idx, cols, search_lo, search_hi) -> np.ndarray:
    """The free specifications' nominal with the most room: the least worst margin
    (JND) of the door itself, by Nelder-Mead on the compiled check from ``p``."""
    from scipy.optimize import minimize

    if not cols.size:
        return p
    width = search_hi - search_lo

    def door(z):
        q = p.copy()
        q[idx[cols]] = search_lo + np.clip(z, 0.0, 1.0) * width
        return q

    def worst(z):
        return float(np.max(np.abs(check.margins(door(z))[0])))

    z0 = (p[idx][cols] - search_lo) / width
    res = minimize(
        worst,
        z0,
        method="Nelder-Mead",
        bounds=[(0.0, 1.0)] * cols.size,
        options={"maxfev": 40 * cols.size, "xatol": 1e-4, "fatol": 1e-4},
    )
    return door(res.x) if res.fun < worst(z0) else p


def _allocate(M, U, t, J, names, loss, swing, target, above=ALLOCATION_AIMS[0]) -> dict:
    """The fewest tolerances, tightened by the least common factor, whose doors reach
    ``target`` and ``above`` it on the sample's margins (first order in each tightened
    deviation): every subset of up to :data:`CANDIDATES` of the largest contributors
    (yield loss, then swing: JND moved at the end of the tolerance), then more of them
    one at a time; {} when even all of them at :data:`LEAST_SHARE` cannot."""
    ranked = sorted(
        (j for j in range(len(names)) if t[j] > 0.0 and swing[j] > 0.0),
        key=lambda j: (-loss[j], -swing[j]),
    )
    aim = min(target + above, 1.0)  # above: the fresh sample that verifies it varies
    if not ranked:
        return {}
    # a margin that no tightening can take beyond 1 JND is left out of the search
    reach_of = np.abs(M) + sum(np.abs(np.outer(U[:, j] * t[j], J[:, j])) for j in ranked)
    keep = np.max(reach_of, axis=0) > 1.0
    M = np.ascontiguousarray(M[:, keep], dtype=np.float32)

    @functools.cache
    def shift(j):
        """Contributor ``j``'s shift of the margins, made when first tried."""
        return np.outer(U[:, j] * t[j], J[keep, j]).astype(np.float32)

    def reach(subset, share):
        m = M.copy()
        for j in subset:
            m -= (1.0 - share) * shift(j)
        return passing(m).mean()

    def least(subset):
        """The largest share of the process's tolerances kept that reaches ``aim``."""
        if reach(subset, LEAST_SHARE) < aim:
            return None
        lo, hi = LEAST_SHARE, 1.0
        for _ in range(10):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if reach(subset, mid) >= aim else (lo, mid)
        return lo

    top = ranked[:CANDIDATES]
    for k in range(1, len(ranked) + 1):
        subsets = itertools.combinations(top, k) if k <= len(top) else [tuple(ranked[:k])]
        found = [(share, sub) for sub in subsets if (share := least(sub)) is not None]
        if found:
            share, subset = max(found)
            return {names[j]: float(share * t[j]) for j in subset}
    return {}


def _curves(check: BatchFeelCheck, forces: dict) -> dict:
    """The figure's arrays: the chosen curve, its JND, the sampled doors' low and high."""
    if not forces:
        return {}
    out = {"theta": check.theta}
    for d in DIRECTIONS:
        f = np.concatenate(forces[d], axis=0)
        out[f"{d}_chosen"] = check.chosen[d]
        out[f"{d}_jnd"] = check.threshold[d]
        out[f"{d}_low"] = np.percentile(f, 2.5, axis=0)
        out[f"{d}_high"] = np.percentile(f, 97.5, axis=0)
    return out


class _NoBar:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def _bar(total: int, progress: bool):
    if not progress:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc="specification", unit="step", file=sys.stderr, dynamic_ncols=True)
