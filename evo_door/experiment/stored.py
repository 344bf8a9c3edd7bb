"""What a results file says of its run, checked before anything uses it.

A results file is data (issue 37): its checksums say it is as its sender wrote it, not
that the sender was evo-door. The readers of a run take its root attributes and its
resolved configuration (``experiment/resolved``) from here, and a resumed run the
groups it is rebuilt from (the ``*_from_tree`` functions: its setup and trials, each
job's GA state, its polish): each value in the type the code uses and of the shape the
others say, or one line naming the file, the object and what was expected
(:mod:`evo_door.files.fields`). The layout is :mod:`.store`'s.
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np

from evo_door.channels import RESPONSE_CHANNELS
from evo_door.data.trial import Trial
from evo_door.errors import UserError
from evo_door.experiment.config_algorithm import ALGORITHM_KINDS, POLISH, AlgorithmSpec
from evo_door.experiment.config_target import RATE_BIAS, PreprocessSpec, TargetSpec
from evo_door.files import ATTRS, DamagedFile, Node, fields
from evo_door.optim.ga import LOG_FIELDS
from evo_door.optim.local import LocalResult
from evo_door.optim.problem import COMBINE, OBJECTIVE_KINDS, Objective
from evo_door.sim_settings import METHODS

#: the kinds of target a run is fitted to
TARGET_KINDS = ("data", "model", "curve")


def _whole(lo=None, hi=None):
    return lambda v, where: fields.as_integer(v, where, lo=lo, hi=hi)


def _integers(value, where: str) -> list[int]:
    if not isinstance(value, (list, tuple)):
        raise DamagedFile(f"{where}: expected a list of whole numbers, got {fields.show(value)}")
    return [fields.as_integer(v, f"{where}[{i}]") for i, v in enumerate(value)]


#: a run's root attributes (and a pipeline stage's group's): how each one is read
ROOT_ATTRS = {
    "format": fields.as_text,
    "format_version": _whole(lo=0),
    "name": fields.as_text,
    "model": fields.as_text,
    "status": fields.as_text,
    "created": fields.as_text,
    "updated": fields.as_text,
    "seed": _whole(),
    "algorithm": fields.as_text,
    "polish": fields.as_text,
    "scan": _whole(lo=0),
    "objective": fields.as_mapping,
    "per_trial": fields.as_flag,
    "jobs": _whole(lo=0),
    "jobs_done": _whole(lo=0),
    "generations": _whole(lo=0),
    "generations_done": _integers,
    "evo_door_version": fields.as_text,
    "executor": fields.as_text,
}


#: a pipeline's root attributes
PIPELINE_ATTRS = {
    "format": fields.as_text,
    "format_version": _whole(lo=0),
    "name": fields.as_text,
    "status": fields.as_text,
    "stages": fields.as_texts,
    "stages_done": _whole(lo=0),
    "current": fields.as_text,
    "created": fields.as_text,
    "updated": fields.as_text,
    "total_s": fields.as_number,
    "evo_door_version": fields.as_text,
    "executor": fields.as_text,
}


def checked(node, spec: dict):
    """``node`` with each key of ``spec`` it holds (and not None) read by its function
    ``(value, where) -> value``; a key it lacks is left to the reader that needs it."""
    for key, read in spec.items():
        if key in node and node[key] is not None:
            node[key] = read(node[key], fields.place_of(node, key))
    return node


def root_attrs(node):
    """A run's root attributes, checked (:data:`ROOT_ATTRS`); ``model`` is required."""
    checked(node, ROOT_ATTRS)
    fields.text(node, "model")
    return node


def numbers_of(node) -> dict:
    """Attributes that are all numbers (``timings``): each a number (a count stays a
    whole number), or a list of numbers (``jobs_s``)."""
    out: dict[str, object] = {}
    for k, v in node.items():
        where = fields.place_of(node, k)
        if isinstance(v, list):
            out[k] = fields.as_numbers(v, where)
        else:  # a count stays a whole number
            x = fields.as_number(v, where)
            out[k] = int(v) if isinstance(v, (int, np.integer)) and not isinstance(v, bool) else x
    return out


def config_of(value, where: str) -> dict:
    """``experiment/resolved``: the run's configuration (JSON text), every section the
    commands read checked for its types (``where`` names the dataset)."""
    config = fields.as_json(value, where)
    if not isinstance(config, dict):
        raise DamagedFile(f"{where}: expected a mapping, got {fields.show(config)}")
    return check_config(config, where)


def check_config(config: dict, where: str) -> dict:
    """A resolved configuration (a JSON mapping) read from ``where``, its sections
    checked and their values made the types the commands use."""
    node = Node(config, place=f"{where}:", style="key")
    out = dict(config)
    out["name"] = fields.text(node, "name")
    out["description"] = fields.text(node, "description", "")
    out["model"] = fields.text(node, "model", "")
    out["objective"] = _objective(fields.group(node, "objective"), f"{where}: objective")
    out["algorithm"] = _algorithm(fields.group(node, "algorithm"), f"{where}: algorithm")
    out["per_trial"] = fields.flag(node, "per_trial", False)
    out["pooled"] = fields.flag(node, "pooled", False)
    out["free"] = {
        name: _range(bounds, f"{where}: free.{name}")
        for name, bounds in fields.mapping(node, "free", {}).items()
    }
    out["fixed"] = fields.mapping(node, "fixed", {}, fields.as_number)
    out["target"] = _target(fields.group(node, "target"), f"{where}: target")
    if "perception" in config:
        out["perception"] = fields.mapping(node, "perception", {}, fields.as_number)
    if "perception_sources" in config:
        out["perception_sources"] = fields.mapping(node, "perception_sources", {}, fields.as_text)
    if "simulation" in config:
        out["simulation"] = _simulation(
            fields.group(node, "simulation", {}), f"{where}: simulation"
        )
    if config.get("process") is not None:
        fields.group(node, "process")
    return out


def _sub(mapping: dict, where: str) -> Node:
    return Node(mapping, place=where, style="key")


def _objective(obj: dict, where: str) -> dict:
    node = _sub(obj, where)
    return {
        **obj,
        "kind": fields.text(node, "kind", choices=OBJECTIVE_KINDS),
        "derivative": fields.integer(node, "derivative", lo=0, hi=2),
        "combine": fields.text(node, "combine", "sum", choices=COMBINE),
    }


def _algorithm(alg: dict, where: str) -> dict:
    """The algorithm section: its kind, and every setting as the run reads it back
    (:meth:`AlgorithmSpec.from_resolved`, which checks each one)."""
    node = _sub(alg, where)
    fields.text(node, "kind", choices=ALGORITHM_KINDS)
    fields.text(node, "polish", choices=POLISH)
    spec = algorithm_of(alg, where)
    return {**alg, **spec.resolved()}


def algorithm_of(alg: dict, where: str) -> AlgorithmSpec:
    """:meth:`AlgorithmSpec.from_resolved` of a stored section, or one line naming it."""
    node = _sub(alg, where)
    try:
        return AlgorithmSpec.from_resolved(node)
    except DamagedFile:
        raise
    except (TypeError, ValueError) as exc:  # a setting out of its range (__post_init__)
        raise DamagedFile(f"{where}: {exc}") from None


def _range(bounds, where: str) -> list[float]:
    values = fields.as_numbers(bounds, where)
    if len(values) != 2:
        raise DamagedFile(f"{where}: expected [lower, upper], got {fields.show(bounds)}")
    return values


def _target(target: dict, where: str) -> dict:
    node = _sub(target, where)
    fields.text(node, "kind", choices=TARGET_KINDS)
    preprocess = fields.group(node, "preprocess", {})
    pre = fields.stored(PreprocessSpec, _sub(preprocess, f"{where}.preprocess"))
    fields.text(_sub(asdict(pre), f"{where}.preprocess"), "rate_bias", choices=RATE_BIAS)
    spec = fields.stored(TargetSpec, node, preprocess=pre)
    for key in ("trials", "validate"):
        value = getattr(spec, key)
        if not (value == "all" or isinstance(value, list)):
            raise DamagedFile(f"{where}.{key}: expected all or a list, got {fields.show(value)}")
    if spec.params is not None and not isinstance(spec.params, (str, dict)):
        raise DamagedFile(
            f"{where}.params: expected a name or a mapping, got {fields.show(spec.params)}"
        )
    fields.mapping(node, "set", {}, fields.as_number)
    return {**target, **{k: v for k, v in asdict(spec).items() if k != "locs"}}


def _simulation(sim: dict, where: str) -> dict:
    node = _sub(sim, where)
    return {
        **sim,
        "method": fields.text(node, "method", ""),
        "substeps": fields.integer(node, "substeps", 1, lo=1),
        "tolerance": fields.number(node, "tolerance", None),
    }


def job_keys(jobs) -> list[str]:
    """The numbered members of ``jobs`` (``jobs/``, ``response/``) in order; a member not
    named by a number is one line naming it."""
    keys = [k for k in jobs if k != ATTRS]
    for k in keys:
        if not (isinstance(k, str) and k.isdigit() and len(k) < 10):
            raise DamagedFile(f"{fields.place_of(jobs, k)}: expected a group named by a number")
    return sorted(keys, key=int)


# -- what a resumed run rebuilds -------------------------------------------------------
def feel_from_tree(node: dict):
    from evo_door.perception import JND, FeelCurve, FeelTarget

    a = node[ATTRS]
    theta = fields.array(node, "theta", shape=(None,))
    where = fields.node_place(node)
    curve = FeelCurve(
        theta,
        fields.array(node, "opening", shape=theta.shape),
        fields.array(node, "closing", shape=theta.shape),
        source=where,
        origin=fields.as_mapping(fields.json_value(a, "origin"), fields.place_of(a, "origin")),
    )
    curve.source = fields.text(a, "source")
    dynamics = fields.json_value(a, "dynamics")
    if dynamics is not None:
        dynamics = fields.as_numbers(dynamics, fields.place_of(a, "dynamics"))
        if len(dynamics) != 2:
            raise DamagedFile(f"{fields.place_of(a, 'dynamics')}: expected [inertia, damping]")
    return FeelTarget(
        curve,
        JND.from_mapping(fields.json_value(a, "jnd"), fields.place_of(a, "jnd")),
        dynamics=tuple(dynamics) if dynamics is not None else None,
        closed=fields.number(a, "closed", finite=True),
        latch_zone=fields.number(a, "latch_zone", finite=True),
        peak_weight=fields.number(a, "peak_weight", finite=True),
        # (a file written before the excess and angle terms: none, so that it resumes
        # as it ran)
        excess_weight=fields.number(a, "excess_weight", 0.0, finite=True),
        angle_weight=fields.number(a, "angle_weight", 0.0, finite=True),
    )


def trial_from_tree(node: dict) -> Trial:
    a = node[ATTRS]
    t = fields.array(node, "t", shape=(None,))
    kwargs: dict = {
        "trial_id": fields.text(a, "trial_id"),
        "user_id": fields.text(a, "user_id", ""),
        "kind": fields.text(a, "kind", ""),
        "theta0": fields.number(a, "theta0", None),
        "dtheta0": fields.number(a, "dtheta0", None),
        "source": fields.text(a, "source", ""),
        "sensors": fields.mapping(a, "sensors", {}),
        "truth": fields.mapping(a, "truth", None),
        "meta": fields.mapping(a, "meta", {}),
    }
    kwargs = {k: v for k, v in kwargs.items() if k in a}
    for ch in RESPONSE_CHANNELS:
        if ch in node:
            kwargs[ch] = fields.array(node, ch, shape=t.shape)
    where = fields.node_place(node)
    try:
        tr = Trial(t, fields.array(node, "force", shape=t.shape), **kwargs)
    except UserError as exc:  # named by its source: say where it is stored too
        raise DamagedFile(f"{where}: {exc}") from None
    stored = fields.text(a, "data_digest", None)
    if stored is not None and tr.digest() != stored:
        raise UserError(f"{where}: damaged: its signals do not match their checksum")
    return tr


def _stored_base(attrs: dict, base: np.ndarray) -> np.ndarray:
    """A run's base vector in its model's declaration order of today.

    A run written before a parameter was added to its model stored fewer values: they
    are matched by name, and each parameter added since takes its declared default.
    """
    names = attrs.get("param_names")
    if names is None:
        return base
    from evo_door.models import get_model

    try:
        params = get_model(attrs["model"]).params
    except UserError:
        return base  # the model cannot be loaded here: the run says so when it starts
    if list(names) == list(params.names):
        return base
    out = np.array(params.defaults, dtype=np.float64)
    for name, value in zip(names, base):
        if name in params.names:
            out[params.index(name)] = value
    return out


def _check_declared(attrs, free: list[str], lower, upper, base, where: str) -> None:
    """Each free parameter is its model's, searched within its declared range, and each
    value of the base within its declared range, as an experiment file must say (a file
    could ask for a search no simulation ends); a model that cannot be loaded here is
    left to the run, which says so."""
    from evo_door.models import get_model

    try:
        params = get_model(fields.text(attrs, "model")).params
    except UserError:
        return
    if len(base) == len(params.names):
        for p, value in zip(params, base):
            try:
                p.check(float(value))
            except UserError as exc:
                raise DamagedFile(f"{where}/base: {exc}") from None
    for name, lo, hi in zip(free, lower, upper):
        if name not in params.names:
            raise DamagedFile(f"{where}: free parameter {name!r} is not one of its model's")
        p = params[name]
        if lo < p.lower or hi > p.upper:
            raise DamagedFile(
                f"{where}: {name} searched in [{lo:g}, {hi:g}] {p.unit}, beyond its declared "
                f"range [{p.lower:g}, {p.upper:g}] {p.unit}"
            )


def setup_from_tree(tree: dict):
    from evo_door.experiment.setup import Setup

    s = fields.group(tree, "setup")
    a = s[ATTRS]
    stored = fields.group(tree, "trials")
    trials: dict[str, list[Trial]] = {"fit": [], "validate": []}
    for role in trials:
        keys = sorted(
            (k for k in stored if k.startswith(role + "_")),
            key=lambda k: _trial_number(stored, k),
        )
        trials[role] = [trial_from_tree(fields.group(stored, k)) for k in keys]
    free = fields.texts(a, "free")
    names = fields.texts(a, "param_names", None)
    base = fields.array(s, "base", shape=(len(names) if names is not None else None,))
    try:
        objective = Objective(**fields.mapping(a, "objective"))
    except (TypeError, ValueError) as exc:
        raise DamagedFile(f"{fields.place_of(a, 'objective')}: {exc}") from None
    lower = fields.array(s, "lower", shape=(len(free),))
    upper = fields.array(s, "upper", shape=(len(free),))
    if not (np.all(np.isfinite(base)) and np.all(np.isfinite(lower) & np.isfinite(upper))):
        raise DamagedFile(f"{fields.node_place(s)}: a base value or a bound is not finite")
    if not np.all(lower <= upper):
        raise DamagedFile(f"{fields.node_place(s)}: a lower bound above its upper bound")
    base = _stored_base(a, base)
    _check_declared(a, free, lower, upper, base, fields.node_place(s))
    return Setup(
        model_name=fields.text(a, "model"),
        base=base,
        free=free,
        lower=lower,
        upper=upper,
        fit=trials["fit"],
        validation=trials["validate"],
        objective=objective,
        method=fields.text(a, "method", choices=tuple(METHODS)),
        substeps=fields.integer(a, "substeps", lo=1, hi=1000),
        start=fields.mapping(a, "start", {}, fields.as_number),
        # None: written before it was kept (the model's)
        tolerance=fields.number(a, "tolerance", None, lo=1e-13, hi=1.0),
        feel=feel_from_tree(fields.group(s, "feel")) if "feel" in s else None,
    )


def _trial_number(trials, key: str) -> int:
    """The number of a stored trial's group (``fit_3``: 3), or one line naming it."""
    number = key.rsplit("_", 1)[1]
    if not (number.isdigit() and len(number) < 10):
        raise DamagedFile(f"{fields.place_of(trials, key)}: expected fit_<k> or validate_<k>")
    return int(number)


def identifiability_from_tree(node: dict):
    from evo_door.optim.identifiability import Identifiability

    return Identifiability.from_tree(node)


#: the words of a stored generator state (:func:`evo_door.optim.operators.rng_state`)
RNG_WORDS = 628


def snapshot_from_tree(
    node: dict, population: int | None = None, n_free: int | None = None, objectives: int = 1
) -> dict:
    """The :meth:`GeneticAlgorithm.snapshot` stored in a job's ``ga`` group, every array
    of the shape the others say: ``g`` generations kept of ``population`` individuals of
    ``n_free`` parameters, ``objectives`` values each (NSGA-II: 2)."""
    from evo_door.optim.operators import rng_from_state

    a = node[ATTRS]
    pop = fields.array(node, "population", shape=(None, population, n_free))
    g, p, n = pop.shape
    fit_shape = (g, p) if objectives == 1 else (g, p, objectives)
    hof_x = fields.array(node, "hof_x", shape=(None, n))
    h = hof_x.shape[0]
    snap = {k: v for k, v in node.items() if k not in (ATTRS, "logbook")}
    snap.update(
        population=pop,
        fitness=fields.array(node, "fitness", shape=fit_shape),
        rng_states=fields.array(node, "rng_states", shape=(g, RNG_WORDS), kind="i"),
        rng_state=fields.array(node, "rng_state", shape=(RNG_WORDS,), kind="i"),
        hof_x=hof_x,
        hof_fitness=fields.array(
            node, "hof_fitness", shape=(h,) if objectives == 1 else (h, objectives)
        ),
        times=fields.array(node, "times", shape=(g,)),
        eval_times=fields.array(node, "eval_times", shape=(g,)),
    )
    if "crowding" in node:
        snap["crowding"] = fields.array(node, "crowding", shape=(p,))
    for i, state in enumerate([snap["rng_state"], *snap["rng_states"]]):
        try:
            rng_from_state(state)
        except (ValueError, TypeError, OverflowError, struct_error()):
            key = "rng_state" if i == 0 else f"rng_states[{i - 1}]"
            raise DamagedFile(f"{fields.place_of(node, key)}: not a generator state") from None
    log = fields.group(node, "logbook")
    logbook = {k: fields.array(log, k, shape=(None,), kind="n") for k in LOG_FIELDS}
    if len({v.size for v in logbook.values()}) > 1:
        raise DamagedFile(f"{fields.node_place(log)}: columns of different lengths")
    snap.update(
        generation=fields.integer(a, "generation", lo=0, hi=g - 1),
        evaluations=fields.integer(a, "evaluations", lo=0),
        blowups=fields.integer(a, "blowups", lo=0),
        logbook=logbook,
    )
    if g == 0:
        raise DamagedFile(f"{fields.place_of(node, 'population')}: no generation kept")
    return snap


def struct_error():
    import struct

    return struct.error


def local_from_tree(node: dict) -> LocalResult:
    a = node[ATTRS]
    x = fields.array(node, "x", shape=(None,))
    return LocalResult(
        x0=fields.array(node, "x0", shape=x.shape),
        x=x,
        fitness0=fields.number(a, "fitness0"),
        fitness=fields.number(a, "fitness"),
        iterations=fields.integer(a, "iterations", lo=0),
        evaluations=fields.integer(a, "evaluations", lo=0),
        blowups=fields.integer(a, "blowups", lo=0),
        success=fields.flag(a, "success"),
        message=fields.text(a, "message"),
        seconds=fields.number(a, "seconds"),
    )


def restore_jobs(jobs: list, stored, algorithm, setup, path) -> None:
    """Each of ``jobs`` (a resumed run's, in order) as its group of ``stored``
    (``jobs/``) left it: its GA's state (of ``algorithm``'s population of ``setup``'s
    free parameters), and, once done, its answer, polish, identifiability and front."""
    from evo_door.optim.smallest_change import SmallestChange

    ga = algorithm.search()
    n_free = len(setup.free)
    objectives = 2 if algorithm.kind == "nsga2" else 1
    for job, key in zip(jobs, job_keys(stored)):
        node = fields.group(stored, key)
        a = node[ATTRS]
        name = fields.text(a, "name")
        if name != job.name:
            raise UserError(f"{path}: job {key} is {name!r}, expected {job.name!r}")
        job.seconds = fields.number(a, "seconds", 0.0)
        if "ga" in node:
            snap = snapshot_from_tree(
                fields.group(node, "ga"), algorithm.ga.population, n_free, objectives
            )
            for key in ("population", "hof_x"):  # genes stay within their bounds
                genes = snap[key].reshape(-1, n_free)
                if not np.all((genes >= setup.lower) & (genes <= setup.upper)):
                    where = fields.place_of(fields.group(node, "ga"), key)
                    raise DamagedFile(f"{where}: a gene outside its search range")
            job.ga = ga.restore(snap)
            job.ga_stop = fields.text(a, "ga_stop", "")
        if not fields.flag(a, "done", False):
            continue
        job.done = True
        job.best_x = fields.array(node, "best_x", shape=(n_free,))
        job.best_fitness = fields.number(a, "best_fitness")
        job.fit_errors = fields.array(node, "fit_errors", shape=(None,))
        job.validation_errors = fields.array(
            node, "validation_errors", shape=(len(setup.validation),)
        )
        if "local" in node:
            job.local = local_from_tree(fields.group(node, "local"))
        if "identifiability" in node:
            job.identifiability = identifiability_from_tree(fields.group(node, "identifiability"))
        if "front" in node:
            job.front = SmallestChange.from_tree(fields.group(node, "front"))
