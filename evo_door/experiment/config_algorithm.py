"""The ``objective`` and ``algorithm`` sections of an experiment: how the fit searches.

The objective (max-square or ISE, on which derivative, how trials combine) and the
algorithm: the GA's settings, the local method (SLSQP) as polish or alone (``nlpql``),
a start point, a scan along each parameter before a polish from several starts
(``scan``, ``starts``: :mod:`evo_door.optim.multistart`), or NSGA-II on the GA's settings
(``nsga2``: the smallest change within the JND, :mod:`evo_door.optim.smallest_change`)
with its measure of change.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields

from evo_door.experiment.config_reader import KeyReader
from evo_door.optim.ga import GASettings
from evo_door.optim.local import LocalSettings
from evo_door.optim.multistart import ScanSettings
from evo_door.optim.problem import COMBINE, OBJECTIVE_KINDS, PERCEPTUAL, Objective
from evo_door.optim.smallest_change import CHANGE_MEASURES
from evo_door.params.declaration import suggest

OBJECTIVE_KEYS = ("kind", "derivative", "combine")
GA_KEYS = tuple(f.name for f in fields(GASettings))
#: the SLSQP settings an experiment may set (the finite-difference step stays internal)
LOCAL_KEYS = ("max_iterations", "ftol")
#: the scan before a multi-start polish: points a parameter (0: none), starts polished
SCAN_KEYS = ("scan", "starts")
ALGORITHM_KEYS = (
    "kind",
    *GA_KEYS,
    "polish",
    *LOCAL_KEYS,
    *SCAN_KEYS,
    "start",
    "change",
    "margin",
)
#: ``nsga2``: the perceptual error and the change from the AS-IS door, as a front
ALGORITHM_KINDS = ("ga", "nlpql", "nsga2")
#: the algorithms that breed a population (a GA's settings, checkpoints, executors)
POPULATION_KINDS = ("ga", "nsga2")
POLISH = ("none", "slsqp")


@dataclass
class AlgorithmSpec:
    """The ``algorithm`` section: GA settings, local method, polish and start point."""

    kind: str = "ga"
    ga: GASettings = field(default_factory=GASettings)
    polish: str = "none"
    local: LocalSettings = field(default_factory=LocalSettings)
    start: dict = field(default_factory=dict)
    scan: ScanSettings = field(default_factory=ScanSettings)
    #: how ``nsga2`` measures the change from the AS-IS door (``CHANGE_MEASURES``)
    change: str = "normalised"
    #: ``nsga2``: the share of the JND the answer is chosen within (the rest is left to
    #: the tolerances)
    margin: float = 1.0

    @property
    def population_based(self) -> bool:
        """Whether a population is bred (GA or NSGA-II), with its checkpoints."""
        return self.kind in POPULATION_KINDS

    def search(self):
        """The population search of this section: NSGA-II or the GA."""
        from evo_door.optim.ga import GeneticAlgorithm
        from evo_door.optim.nsga2 import NSGA2

        return NSGA2(self.ga) if self.kind == "nsga2" else GeneticAlgorithm(self.ga)

    def resolved(self) -> dict:
        """The section as plain data, every default filled in (as results files store it)."""
        return {
            "kind": self.kind,
            **asdict(self.ga),
            "polish": self.polish,
            **asdict(self.local),
            "scan": self.scan.points,
            "starts": self.scan.starts,
            "start": dict(self.start),
            "change": self.change,
            "margin": self.margin,
        }

    @classmethod
    def from_resolved(cls, data: dict) -> AlgorithmSpec:
        """The inverse of :meth:`resolved` (keys added since a file was written take
        their defaults); each setting checked for its type (a results file is data:
        :mod:`evo_door.files.fields`), out of range a ValueError."""
        from evo_door.files import fields as f

        return cls(
            kind=f.text(data, "kind", choices=ALGORITHM_KINDS),
            ga=f.stored(GASettings, data),
            polish=f.text(data, "polish", choices=POLISH),
            local=f.stored(LocalSettings, data),
            start=f.mapping(data, "start", {}, f.as_number),
            change=f.text(data, "change", "normalised", choices=CHANGE_MEASURES),
            margin=f.number(data, "margin", 1.0),
            scan=ScanSettings(
                points=f.integer(data, "scan", 0, lo=0), starts=f.integer(data, "starts", STARTS)
            ),
        )


def _objective(reader: KeyReader, curve_target: bool = False) -> Objective:
    """The ``objective`` section; a curve target (a chosen feel) is scored by the
    perceptual objective, which is then its default and its only kind."""
    o = KeyReader(reader.get("objective"), "objective", reader.node.where("objective"))
    o.check_keys(OBJECTIVE_KEYS)
    kind = o.choice("kind", PERCEPTUAL if curve_target else "max_square", OBJECTIVE_KINDS)
    if curve_target and kind != PERCEPTUAL:
        raise o.fail(
            "kind",
            f"{kind}: a curve target has no trials to score; it is fitted by the "
            "perceptual objective (leave kind out)",
        )
    return Objective(
        kind=kind,
        derivative=o.choice("derivative", 1, (0, 1, 2)),
        combine=o.choice("combine", "sum", COMBINE),
    )


def _algorithm(reader: KeyReader) -> AlgorithmSpec:
    a = KeyReader(reader.get("algorithm"), "algorithm", reader.node.where("algorithm"))
    a.check_keys(ALGORITHM_KEYS)
    ga = _ga_settings(a)
    ld = LocalSettings()
    local = LocalSettings(
        max_iterations=a.integer("max_iterations", ld.max_iterations, lo=1),
        ftol=a.number("ftol", ld.ftol, 0.0, open_lo=True),
    )
    kind = a.choice("kind", "ga", ALGORITHM_KINDS)
    polish = _polish(a, kind)
    start = a.get("start") or {}
    if not isinstance(start, dict):
        raise a.fail("start", "expected a mapping of free parameter names to start values")
    for key in ("change", "margin"):
        if key in a.node and kind != "nsga2":
            raise a.fail(key, f"belongs to kind nsga2 (the smallest change), not to kind {kind}")
    return AlgorithmSpec(
        kind=kind,
        ga=ga,
        polish=polish,
        local=local,
        start={str(k): v for k, v in start.items()},
        change=a.choice("change", CHANGE_MEASURES[0], CHANGE_MEASURES),
        margin=a.number("margin", 1.0, lo=0.0, hi=1.0, open_lo=True),
        scan=_scan(a, kind, polish),
    )


#: polishes after a scan when ``starts`` is not given
STARTS = ScanSettings().starts


def _scan(a: KeyReader, kind: str, polish: str) -> ScanSettings:
    """``scan`` (points a parameter, 0 / false / empty: none) and ``starts``, checked: a
    scan hands its points to SLSQP, so it needs ``polish: slsqp`` or ``kind: nlpql``."""
    raw = a.get("scan")
    points = 0 if raw is None or raw is False else a.integer("scan", 0, lo=0)
    if 0 < points < 3:
        raise a.fail("scan", f"{points} points cannot bracket a minimum: give 3 or more (0: none)")
    if a.get("starts") is not None and not points:
        raise a.fail("starts", "polishes the scan's best points: give scan: N too")
    starts = a.integer("starts", STARTS, lo=1)
    if points and kind == "ga" and polish != "slsqp":
        raise a.fail("scan", "hands its best points to SLSQP: set polish: slsqp")
    return ScanSettings(points=points, starts=starts)


def _ga_settings(a: KeyReader) -> GASettings:
    """The GA's settings of the section, each checked (defaults: :class:`GASettings`)."""
    d = GASettings()
    for key in ("reproduction_ratio", "mutation_probability"):
        v = a.get(key)
        if isinstance(v, (int, float)) and not isinstance(v, bool) and 1 < v <= 100:
            raise a.fail(key, f"is a fraction in [0, 1]: AMESim's {v:g} % is {v / 100:g}")
    population = a.integer("population", d.population, lo=2)
    return GASettings(
        population=population,
        generations=a.integer("generations", d.generations, lo=0),
        reproduction_ratio=a.number("reproduction_ratio", d.reproduction_ratio, 0.0, 1.0),
        mutation_probability=a.number("mutation_probability", d.mutation_probability, 0.0, 1.0),
        mutation_amplitude=a.number("mutation_amplitude", d.mutation_amplitude, 0.0, open_lo=True),
        seed=a.integer("seed", d.seed, lo=0),
        elite=a.integer("elite", d.elite, lo=0, hi=population - 1),
        # the default tournament (3) shrinks to a smaller population; a given one must fit
        tournament=a.integer("tournament", min(d.tournament, population), lo=1, hi=population),
        crossover_eta=a.number("crossover_eta", d.crossover_eta, 0.0, open_lo=True),
        hall_of_fame=a.integer("hall_of_fame", d.hall_of_fame, lo=1),
        target_fitness=a.number("target_fitness", None, lo=0.0, allow_none=True),
        patience=(None if a.get("patience") is None else a.integer("patience", None, lo=1)),
    )


def _polish(a: KeyReader, kind: str) -> str:
    """The local method run after the GA: none (also written false or left empty) or slsqp."""
    polish = a.get("polish", "none")
    if polish is None or polish is False:
        polish = "none"
    if polish not in POLISH:
        raise a.fail(
            "polish",
            f"{polish!r} is not one of {', '.join(POLISH)}"
            + (suggest(polish, POLISH) if isinstance(polish, str) else ""),
        )
    if kind == "nlpql" and polish != "none":
        raise a.fail("polish", "kind nlpql is already the local method; leave polish out")
    return polish
