"""Bounded GA operators that draw from a generator the run owns.

DEAP's own operators (``deap.tools.cxSimulatedBinaryBounded``, ``mutGaussian``,
``selTournament``...) draw from the interpreter-wide ``random`` module, so two runs
in one process, a library that also uses ``random``, or a resumed run would not
reproduce. These operators have DEAP's calling convention (they modify individuals
in place and return them as a tuple; selection returns a list of references) and
take the run's :class:`random.Random` as the keyword ``rng``; they are registered in a
:class:`deap.base.Toolbox` with ``rng`` bound (see :mod:`evo_door.optim.ga`).

Every operator keeps genes inside ``[low, up]``: crossover by construction, mutation by
drawing from a Gaussian truncated to the bounds.
"""

from __future__ import annotations

import random
from collections.abc import Sequence


def cx_sbx_bounded(
    ind1,
    ind2,
    *,
    eta: float,
    low: Sequence[float],
    up: Sequence[float],
    rng: random.Random,
    gene_probability: float = 0.5,
):
    """Simulated binary crossover restricted to the bounds (Deb and Agrawal, 1995).

    Each gene is recombined with probability ``gene_probability``. For parents
    ``y1 <= y2`` the spread factor is drawn from the SBX polynomial density whose tail
    is cut so that both children fall inside ``[low, up]``; a large ``eta`` keeps the
    children near their parents. The two children are then assigned to the two
    individuals at random.
    """
    for i in range(len(ind1)):
        if rng.random() >= gene_probability:
            continue
        x1, x2 = ind1[i], ind2[i]
        if abs(x1 - x2) <= 1e-14 * (abs(x1) + abs(x2) + 1e-300):
            continue
        y1, y2 = (x1, x2) if x1 < x2 else (x2, x1)
        lo, hi = low[i], up[i]
        u = rng.random()
        span = y2 - y1
        c1 = _sbx_child(y1, y2, span, 1.0 + 2.0 * (y1 - lo) / span, eta, u, -1.0)
        c2 = _sbx_child(y1, y2, span, 1.0 + 2.0 * (hi - y2) / span, eta, u, +1.0)
        c1 = min(max(c1, lo), hi)
        c2 = min(max(c2, lo), hi)
        if rng.random() < 0.5:
            c1, c2 = c2, c1
        ind1[i], ind2[i] = c1, c2
    return ind1, ind2


def _sbx_child(y1, y2, span, beta, eta, u, side):
    """One SBX child: ``(y1 + y2)/2 + side * betaq * span / 2``, ``betaq`` cut at ``beta``."""
    alpha = 2.0 - beta ** -(eta + 1.0)
    if u <= 1.0 / alpha:
        betaq = (u * alpha) ** (1.0 / (eta + 1.0))
    else:
        betaq = (1.0 / (2.0 - u * alpha)) ** (1.0 / (eta + 1.0))
    return 0.5 * (y1 + y2) + side * 0.5 * betaq * span


def mut_gaussian_bounded(
    individual,
    *,
    sigma: Sequence[float],
    low: Sequence[float],
    up: Sequence[float],
    indpb: float,
    rng: random.Random,
    max_tries: int = 1000,
):
    """Gaussian mutation truncated to the bounds.

    Each gene mutates with probability ``indpb`` to a value drawn from a normal
    distribution centred on the current value with standard deviation ``sigma[i]``,
    conditioned on ``[low[i], up[i]]`` (rejection sampling; after ``max_tries``
    misses, which only a sigma far below the bound width could cause, the draw is
    clipped).
    """
    for i in range(len(individual)):
        if rng.random() >= indpb:
            continue
        x, lo, hi, s = individual[i], low[i], up[i], sigma[i]
        for _ in range(max_tries):
            y = rng.gauss(x, s)
            if lo <= y <= hi:
                break
        else:  # pragma: no cover - needs sigma << bounds and an unlucky stream
            y = min(max(y, lo), hi)
        individual[i] = y
    return (individual,)


def sel_tournament(individuals, k: int, *, tournsize: int, rng: random.Random):
    """``k`` tournament winners (best fitness of ``tournsize`` uniform draws, with replacement).

    Ties go to the first drawn, so the result depends on nothing but the stream.
    """
    chosen = []
    n = len(individuals)
    for _ in range(k):
        best = individuals[rng.randrange(n)]
        for _ in range(tournsize - 1):
            other = individuals[rng.randrange(n)]
            if other.fitness > best.fitness:
                best = other
        chosen.append(best)
    return chosen


def uniform_individual(low: Sequence[float], up: Sequence[float], rng: random.Random) -> list:
    """Genes drawn uniformly within the bounds."""
    return [lo + (hi - lo) * rng.random() for lo, hi in zip(low, up)]


def rng_state(rng: random.Random) -> list[int]:
    """The generator's state as a flat list of ints (version, 625 words, gauss flag, value).

    ``random.Random.getstate()`` is ``(version, tuple_of_625_ints, gauss_next)``;
    ``gauss_next`` (None or a float) is stored as a flag and the float's 64 bits.
    """
    version, words, gauss_next = rng.getstate()
    if gauss_next is None:
        flag, bits = 0, 0
    else:
        import struct

        flag, bits = 1, struct.unpack("<q", struct.pack("<d", gauss_next))[0]
    return [int(version), *map(int, words), flag, bits]


def rng_from_state(state: Sequence[int]) -> random.Random:
    """Inverse of :func:`rng_state`."""
    import struct

    state = [int(v) for v in state]
    version, words, flag, bits = state[0], tuple(state[1:-2]), state[-2], state[-1]
    gauss_next = struct.unpack("<d", struct.pack("<q", bits))[0] if flag else None
    rng = random.Random()
    rng.setstate((version, words, gauss_next))
    return rng


def sel_tournament_dcd(individuals, k: int, *, rng: random.Random):
    """``k`` winners of binary tournaments on Pareto dominance, then crowding distance.

    NSGA-II's parent selection (DEAP's ``selTournamentDCD``, on the run's generator and
    for any ``k``): of two uniform draws, one that dominates the other wins; otherwise
    the one of larger ``fitness.crowding_dist`` (set by ``deap.tools.selNSGA2``); a tie
    goes to the first drawn.
    """
    chosen = []
    n = len(individuals)
    for _ in range(k):
        a = individuals[rng.randrange(n)]
        b = individuals[rng.randrange(n)]
        if b.fitness.dominates(a.fitness):
            a = b
        elif (
            not a.fitness.dominates(b.fitness) and b.fitness.crowding_dist > a.fitness.crowding_dist
        ):
            a = b
        chosen.append(a)
    return chosen
