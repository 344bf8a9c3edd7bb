"""The smallest change within the JND: from a front of doors to one specification.

The specification stage starts from the AS-IS door (the stage's base values) and must
change it as little as the chosen feel needs. NSGA-II (:mod:`.nsga2`) searches two
objectives at once (:class:`ChangeObjectives`):

1. the **perceptual error**, the perceptual objective of the problem's chosen feel
   (JND^2, :class:`~evo_door.perception.FeelTarget`);
2. the **change**, the mean over the free specifications of ``|x - x_asis|`` divided
   by the specification's search range (a pure number, 0 for the AS-IS door, 1 when
   every specification moves across its whole range). Normalising by the search range
   makes newtons and kilograms comparable, and a sum of absolute values (not of
   squares) prefers moving a few specifications over moving all of them a little,
   which is what "change as little as needed" means to the engineer who has to make
   the change. How many specifications change is settled afterwards (below).

:func:`choose_smallest_change` then turns the front into the answer:

- **the smallest change within the JND**: of the front's points whose perceptual
  check passes (:func:`~evo_door.perception.perceptual_check`: every point of both
  strokes, the latch peaks and their angles, the felt dynamics within their JNDs;
  :func:`~evo_door.perception.check_verdict`), the one of least change.
  With none, the point of least perceptual error is polished (SLSQP on the perceptual
  objective) and checked again;
- **kept specifications**: each changed specification, smallest change first, is set
  back to its AS-IS value where the check still passes; a specification the feel does
  not determine (its verdict from :mod:`.feel_identifiability` is not identifiable)
  is also tried with the other changed specifications following it (an SLSQP polish
  of those alone). A reset the check refuses is undone: the answer always passes.
  The specifications left at their AS-IS values are the *kept* ones;
- **polish**: the changed specifications alone are polished on the perceptual
  objective (with ``polish``), and the polished door is taken if its check passes;
- **an unreachable feel**: no point passes, even polished. The answer is then the
  closest door (least perceptual error, polished), reported with ``reachable`` False
  and, per stroke, where and by how much it misses (the check's worst difference and
  the failing angle bands).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace

import numpy as np

from evo_door.errors import UserError
from evo_door.optim.local import LocalSettings, slsqp

#: the change measures an experiment may name (``algorithm.change``)
CHANGE_MEASURES = ("normalised",)
#: a free specification within this fraction of its search range from its AS-IS value
#: counts as unchanged
UNCHANGED = 1e-9


def change_size(X, asis, lower, upper) -> np.ndarray:
    """The normalised change of each row of ``X`` from ``asis``: the mean over columns
    of ``|x - x_asis| / (upper - lower)``.

    >>> change_size([[1.0, 5.0], [0.0, 10.0]], [0.0, 5.0], [0.0, 0.0], [2.0, 10.0])
    array([0.25, 0.25])
    """
    X = np.atleast_2d(np.asarray(X, dtype=np.float64))
    width = np.asarray(upper, dtype=np.float64) - np.asarray(lower, dtype=np.float64)
    return np.mean(np.abs(X - np.asarray(asis, dtype=np.float64)) / width, axis=1)


class ChangeObjectives:
    """The two objectives of the smallest change: ``evaluate(X) -> (F, blown)`` with
    ``F[:, 0]`` the perceptual error (JND^2) of ``problem`` (a
    :class:`~evo_door.optim.problem.Problem`, or an executor's stand-in for one) and
    ``F[:, 1]`` :func:`change_size` from ``asis`` (the AS-IS free values, ``start``)."""

    def __init__(self, problem, asis):
        self.problem = problem
        self.lower = np.asarray(problem.lower, dtype=np.float64)
        self.upper = np.asarray(problem.upper, dtype=np.float64)
        self.start = np.asarray(asis, dtype=np.float64)

    @classmethod
    def around(cls, problem, evaluator) -> ChangeObjectives:
        """The objectives of ``problem`` from its AS-IS door, evaluated by ``evaluator``
        (the problem itself, or an executor's stand-in for it)."""
        return cls(evaluator, asis_vector(problem))

    def evaluate(self, X):
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        error, blown = self.problem.evaluate(X)
        change = change_size(X, self.start, self.lower, self.upper)
        return np.c_[error, change], blown


def asis_vector(problem) -> np.ndarray:
    """The AS-IS values of ``problem``'s free specifications (its base vector), clipped
    to their search ranges."""
    return np.clip(problem.base[problem.index], problem.lower, problem.upper)


@dataclass
class SmallestChange:
    """What :func:`choose_smallest_change` decided (module docstring).

    ``front_x`` / ``front_f`` are the front (free values; perceptual error JND^2 and
    change 1, one row a point, least error first); ``chosen`` the front point the
    answer started from (-1: none passed, the closest door); ``x`` the answer;
    ``kept`` the free specifications left at their AS-IS values; ``check`` the answer's
    :func:`~evo_door.perception.check_verdict`; ``reachable`` whether it passes.
    """

    front_x: np.ndarray
    front_f: np.ndarray
    asis: np.ndarray
    chosen: int
    closest: int
    x: np.ndarray
    error: float
    change: float
    kept: list[str]
    reachable: bool
    check: dict
    measure: str = "normalised"
    #: the share of the JND the answer was chosen within (1: the check's own JND)
    margin: float = 1.0
    polished: bool = False
    checks: int = 0
    seconds: float = 0.0
    steps: list[str] = field(default_factory=list)

    def miss(self) -> dict:
        """Where an unreachable feel is missed, per stroke: the worst difference (angle
        deg, difference N, JND N) and the failing angle bands (deg); {} when reached."""
        if self.reachable:
            return {}
        return {
            d: {
                "verdict": self.check[d]["verdict"],
                "fraction_beyond_jnd": self.check[d]["fraction_beyond_jnd"],
                "worst": dict(self.check[d]["worst"]),
                "bands_deg": [list(b) for b in self.check[d]["bands_deg"]],
            }
            for d in ("opening", "closing")
        }

    def to_tree(self, free) -> dict:
        """The results file's group (``jobs/<k>/front``)."""
        from evo_door.files import ATTRS

        return {
            ATTRS: {
                "measure": self.measure,
                "margin": float(self.margin),
                "free": list(free),
                "chosen": int(self.chosen),
                "closest": int(self.closest),
                "error": float(self.error),
                "change": float(self.change),
                "kept": list(self.kept),
                "reachable": bool(self.reachable),
                "polished": bool(self.polished),
                "check": json.dumps(_plain(self.check)),
                "checks": int(self.checks),
                "seconds": float(self.seconds),
                "steps": list(self.steps),
                "columns": ["perceptual error JND^2", "change 1"],
            },
            "front_x": np.asarray(self.front_x, dtype=np.float64),
            "front_f": np.asarray(self.front_f, dtype=np.float64),
            "asis": np.asarray(self.asis, dtype=np.float64),
            "x": np.asarray(self.x, dtype=np.float64),
        }

    @classmethod
    def from_tree(cls, node: dict) -> SmallestChange:
        """The inverse of :meth:`to_tree`, each value checked (a results file is data:
        :mod:`evo_door.files.fields`)."""
        from evo_door.files import ATTRS, DamagedFile, Node, fields

        a = node[ATTRS]
        where = fields.place_of(a, "check")
        check = fields.as_mapping(fields.json_value(a, "check"), where)
        for d in ("opening", "closing"):
            if d in check:
                at = f"{where}: {d}"
                stroke = Node(fields.as_mapping(check[d], at), place=at, style="key")
                fields.text(stroke, "verdict", "")
                fields.number(stroke, "fraction_beyond_jnd", None)
                fields.mapping(stroke, "worst", {})
                bands = stroke.get("bands_deg") or []
                if not isinstance(bands, list):
                    raise DamagedFile(f"{at}.bands_deg: expected a list of [from, to] angles")
                for band in bands:
                    fields.as_numbers(band, f"{at}.bands_deg")
        front_x = fields.array(node, "front_x", shape=(None, None))
        k, n = front_x.shape
        out = fields.stored(
            cls,
            a,
            node,
            shapes={"front_f": (k, 2), "asis": (n,), "x": (n,)},
            check=check,
            front_x=front_x,
        )
        if not (-1 <= out.chosen < k and 0 <= out.closest < max(k, 1)):
            raise DamagedFile(f"{fields.node_place(node)}: chosen or closest not on the front")
        return out


def _plain(value):
    """``value`` with numpy numbers and tuples made JSON's."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


class _Judge:
    """The perceptual check of free vectors of ``problem`` against its chosen feel,
    counted, on the mechanism's curve sampled where the objective samples it; with a
    ``margin`` below 1, every JND (force fraction and floor, position, felt inertia and
    damping) taken at that share."""

    def __init__(self, problem, margin: float = 1.0):
        self.problem = problem
        self.feel = problem.feel
        self.jnd = scaled_jnd(self.feel.jnd, margin)
        self.count = 0

    def verdict(self, x) -> dict:
        self.count += 1
        p = self.problem.full(x)[0]
        return self.feel.verdict(self.problem.model, p, self.jnd)

    def passes(self, x) -> bool:
        return bool(self.verdict(x)["passes"])


def scaled_jnd(jnd, margin: float):
    """``jnd`` with every difference threshold taken at ``margin`` of itself."""
    if margin == 1.0:
        return jnd
    names = ("force", "force_floor", "position", "inertia", "viscosity")
    return replace(jnd, **{n: getattr(jnd, n) * margin for n in names})


def _polish_some(problem, x, names, settings: LocalSettings):
    """SLSQP on the perceptual objective over the free specifications ``names`` only,
    the others held at their values in ``x``; the full free vector it ends at."""
    from evo_door.optim.problem import Problem

    if not names:
        return np.array(x, dtype=np.float64), float(problem.evaluate(x)[0][0])
    cols = [problem.free.index(n) for n in names]
    base = problem.full(x)[0]
    sub = Problem(
        problem.model,
        names,
        problem.lower[cols],
        problem.upper[cols],
        base,
        (),
        problem.objective,
        method=problem.method,
        substeps=problem.substeps,
        model_name=problem.model_name,
        tolerance=problem.tolerance,
        feel=problem.feel,
    )
    res = slsqp(sub, np.asarray(x, dtype=np.float64)[cols], settings)
    out = np.array(x, dtype=np.float64)
    out[cols] = res.x
    return out, float(res.fitness)


def choose_smallest_change(
    problem,
    front_x,
    front_f,
    identifiable: dict[str, bool] | None = None,
    polish: bool = True,
    settings: LocalSettings | None = None,
    margin: float = 1.0,
) -> SmallestChange:
    """The answer of a smallest-change search from its front (module docstring).

    ``identifiable`` maps a free specification to whether the feel determines it
    (:func:`~evo_door.optim.feel_identifiability.feel_identifiability` at the front's
    point of least error; None: taken as determined). ``margin`` (in (0, 1]): the answer
    is chosen to pass the check at that share of the JND, leaving the rest of it to the
    tolerances a supplier builds to; where no door passes at it, the smallest change
    within the whole JND is the answer, and its steps say so. Its ``check`` and
    ``reachable`` are always the check's at the whole JND.
    """
    t0 = time.perf_counter()
    settings = settings or LocalSettings()
    front_x = np.atleast_2d(np.asarray(front_x, dtype=np.float64))
    front_f = np.atleast_2d(np.asarray(front_f, dtype=np.float64))
    asis = asis_vector(problem)
    judge = _Judge(problem, margin)
    steps: list[str] = []
    closest = int(np.argmin(front_f[:, 0]))
    chosen = -1
    for k in np.argsort(front_f[:, 1], kind="stable"):
        if judge.passes(front_x[k]):
            chosen = int(k)
            break
    polished = False
    if chosen >= 0:
        x = front_x[chosen].copy()
        steps.append(f"front point {chosen} passes the check with the least change")
    else:
        x = front_x[closest].copy()
        if polish:
            x, _ = _polish_some(problem, x, list(problem.free), settings)
            polished = True
        steps.append(
            "no front point passes the check; the point of least error"
            + (" polished" if polish else "")
        )
    reachable = judge.passes(x)
    if margin < 1.0 and not reachable:  # not within the margin: within the whole JND
        out = choose_smallest_change(problem, front_x, front_f, identifiable, polish, settings)
        out.steps.insert(0, f"no door passes within {margin:g} of the JND: the whole JND taken")
        out.seconds = time.perf_counter() - t0
        return out
    if reachable:
        x = _keep_asis(problem, judge, x, asis, identifiable or {}, settings, steps)
        changed = _changed(problem, x, asis)
        if polish and changed:
            y, _ = _polish_some(problem, x, changed, settings)
            if judge.passes(y):
                x, polished = y, True
                steps.append(f"polished {', '.join(changed)} within the JND")
            else:
                steps.append("the polished door fails the check: kept the unpolished one")
    check = _Judge(problem).verdict(x)  # the check's own JND, whatever the margin
    kept = [n for n in problem.free if n not in _changed(problem, x, asis)]
    return SmallestChange(
        front_x=front_x,
        front_f=front_f,
        asis=asis,
        chosen=chosen,
        closest=closest,
        x=x,
        error=float(problem.evaluate(x)[0][0]),
        change=float(change_size(x, asis, problem.lower, problem.upper)[0]),
        kept=kept,
        reachable=bool(check["passes"]),
        check=check,
        margin=float(margin),
        polished=polished,
        checks=judge.count,
        seconds=time.perf_counter() - t0,
        steps=steps,
    )


def _changed(problem, x, asis) -> list[str]:
    """The free specifications of ``x`` away from their AS-IS values."""
    width = problem.upper - problem.lower
    moved = np.abs(np.asarray(x) - asis) > UNCHANGED * width
    return [n for n, m in zip(problem.free, moved) if m]


def _keep_asis(problem, judge, x, asis, identifiable, settings, steps) -> np.ndarray:
    """Set back to AS-IS every changed specification the check lets go (module docstring)."""
    x = np.array(x, dtype=np.float64)
    width = problem.upper - problem.lower
    order = np.argsort(np.abs(x - asis) / width, kind="stable")
    for j in order:  # alone, smallest change first
        name = problem.free[j]
        if name not in _changed(problem, x, asis):
            continue
        y = x.copy()
        y[j] = asis[j]
        if judge.passes(y):
            x = y
            steps.append(f"{name} kept at its AS-IS value")
    for j in order:  # not determined by the feel: the other changed ones follow it
        name = problem.free[j]
        changed = _changed(problem, x, asis)
        if name not in changed or identifiable.get(name, True) or len(changed) < 2:
            continue
        y = x.copy()
        y[j] = asis[j]
        y, _ = _polish_some(problem, y, [n for n in changed if n != name], settings)
        if judge.passes(y):
            x = y
            steps.append(f"{name} kept at its AS-IS value, the other changes following")
    return x


def miss_text(miss: dict) -> list[str]:
    """Lines for a person: where an unreachable feel is missed, per stroke."""
    lines = []
    for d, m in miss.items():
        w = m["worst"]
        bands = ", ".join(f"{a:.1f}-{b:.1f} deg" for a, b in m["bands_deg"][:6])
        more = len(m["bands_deg"]) - 6
        lines.append(
            f"  {d}: {m['verdict']}, {100 * m['fraction_beyond_jnd']:.1f} % of the stroke "
            f"beyond the JND; worst {w['difference_N']:+.3g} N (JND {w['jnd_N']:.3g} N) "
            f"at {w['angle_deg']:.2f} deg"
            + (f"; failing {bands}" + (f" and {more} more" if more > 0 else "") if bands else "")
        )
    return lines


def smallest_change_of(
    problem, state, polish: bool, settings: LocalSettings | None = None, margin: float = 1.0
):
    """:func:`choose_smallest_change` on an NSGA-II state's archive, the feel's verdicts
    (:func:`~.feel_identifiability.feel_identifiability`) taken at its point of least
    error (none where they cannot be made: every specification counts as determined)."""
    from evo_door.optim.feel_identifiability import feel_identifiability

    front_x, front_f = state.front_x, state.front_f
    try:
        ident = feel_identifiability(problem, front_x[int(np.argmin(front_f[:, 0]))])
        identifiable = {n: v == "identifiable" for n, v in zip(ident.names, ident.verdicts)}
    except (UserError, ValueError, np.linalg.LinAlgError):
        identifiable = None
    return choose_smallest_change(problem, front_x, front_f, identifiable, polish, settings, margin)
