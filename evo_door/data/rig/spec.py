"""How a rig specification (an experiment's ``inputs:`` mapping) is checked and run."""

from __future__ import annotations

import copy
import math

from evo_door.data.rig.campaign import Campaign, generate_trials
from evo_door.data.rig.one_trial import KINDS, RigSettings
from evo_door.data.trial import Trial
from evo_door.errors import UserError

#: Keys of a rig specification (an experiment's ``inputs:`` mapping) and their defaults
#: (``kinds: None``: the model's, :func:`default_kinds`).
SPEC_DEFAULTS = {
    "model": "door",
    "params": None,
    "set": {},
    "users": 3,
    "trials": 10,
    "seed": 1,
    "kinds": None,
    "rate": 1024.0,
    "all_sensors": False,
}


class SpecError(UserError):
    """A bad entry of a rig specification: ``key`` names it (None: the whole mapping),
    ``reason`` says what is wrong. An experiment file puts its own file and line in front
    (:mod:`evo_door.experiment.config`); on its own it reads ``rig specification: KEY: ...``.
    """

    def __init__(self, key: str | None, reason: str):
        super().__init__("rig specification: " + (f"{key}: " if key else "") + reason)
        self.key = key
        self.reason = reason


def _shown(value) -> str:
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return repr(value)


def _whole(spec: dict, key: str, lowest: int) -> int:
    """``spec[key]`` as a whole number >= ``lowest`` (3.0 is 3; 2.5, "3" and true are not),
    the same rule as ``rig generate``'s flags."""
    v = spec[key]
    if isinstance(v, float) and v.is_integer():
        v = int(v)
    if isinstance(v, bool) or not isinstance(v, int):
        raise SpecError(key, f"expected a whole number, got {_shown(v)}")
    if v < lowest:
        raise SpecError(key, f"must be at least {lowest}, got {v}")
    return v


def _spec_kinds(model, value) -> list[str] | None:
    """``kinds`` as a list (a comma-separated text is split), each known and supported."""
    from evo_door.params.declaration import suggest

    if value is None:
        return None
    if isinstance(value, str):
        value = value.split(",")
    if not isinstance(value, list) or not all(isinstance(k, str) for k in value):
        raise SpecError(
            "kinds", f"expected a list of trial kinds (e.g. [impulse]), got {_shown(value)}"
        )
    kinds = [k.strip() for k in value if k.strip()]
    if not kinds:
        raise SpecError("kinds", f"no trial kind given; kinds: {', '.join(KINDS)}")
    supported = tuple(getattr(model, "rig_kinds", KINDS))
    for kind in kinds:
        if kind not in KINDS:
            raise SpecError(
                "kinds",
                f"unknown trial kind {kind!r}"
                + suggest(kind, KINDS)
                + f"; kinds: {', '.join(KINDS)}",
            )
        if kind not in supported:
            raise SpecError(
                "kinds",
                f"model {model.name!r} cannot make {kind} trials; it supports {', '.join(supported)}",
            )
    return kinds


def check_spec(spec) -> dict:
    """A rig specification checked entry by entry, completed with :data:`SPEC_DEFAULTS`.

    The rules of ``evo-door rig generate``'s flags: ``users`` and ``trials`` whole numbers
    >= 1, ``seed`` a whole number >= 0, ``rate`` a number > 0 (Hz), ``kinds`` known to the
    rig and made by the model, ``model`` a model, ``params`` a preset, a parameter file or
    a mapping of numbers, ``set`` a mapping of the model's parameters to numbers,
    ``all_sensors`` true or false; an unknown key is refused with a suggestion. The first
    bad entry raises :class:`SpecError` naming its key.

    >>> check_spec({"model": "door", "trials": 2})["users"]
    3
    >>> check_spec({"model": "door", "users": "abc"})
    Traceback (most recent call last):
    ...
    evo_door.data.rig.spec.SpecError: rig specification: users: expected a whole number, got 'abc'
    """
    from evo_door.models import get_model

    _check_keys(spec)
    s = {**SPEC_DEFAULTS, **spec}
    if not isinstance(s["model"], str) or not s["model"].strip():
        raise SpecError("model", f"expected a model's name, got {_shown(s['model'])}")
    try:
        model = get_model(s["model"])
    except UserError as exc:
        raise SpecError("model", str(exc)) from None
    _check_params(model, s)
    rate = s["rate"]
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not math.isfinite(rate):
        raise SpecError("rate", f"expected a number of samples per second (Hz), got {_shown(rate)}")
    if rate <= 0:
        raise SpecError("rate", f"must be positive (Hz), got {rate:g}")
    if not isinstance(s["all_sensors"], bool):
        raise SpecError("all_sensors", f"expected true or false, got {_shown(s['all_sensors'])}")
    s.update(
        users=_whole(s, "users", 1),
        trials=_whole(s, "trials", 1),
        seed=_whole(s, "seed", 0),
        kinds=_spec_kinds(model, s["kinds"]),
        rate=float(rate),
    )
    return s


def _check_keys(spec) -> None:
    """A mapping whose every key is one of :data:`SPEC_DEFAULTS`."""
    from evo_door.params.declaration import suggest

    if not isinstance(spec, dict):
        raise SpecError(
            None, f"expected a mapping of keys ({', '.join(SPEC_DEFAULTS)}), got {_shown(spec)}"
        )
    for key in spec:
        if key not in SPEC_DEFAULTS:
            raise SpecError(
                str(key),
                "unknown key"
                + suggest(str(key), SPEC_DEFAULTS)
                + f"; keys: {', '.join(SPEC_DEFAULTS)}",
            )


def _check_params(model, s: dict) -> None:
    """``params`` and ``set`` of the specification ``s``: a set the model loads, each
    ``set`` entry one of its parameters with a number it accepts (``set`` None becomes
    an empty mapping in ``s``)."""
    from evo_door.params.declaration import suggest

    params = s["params"]
    if isinstance(params, dict) and "from" in params:
        raise SpecError(
            "params", "{from: STAGE} is for params and target.params, not the rig's inputs"
        )
    if params is not None and not isinstance(params, (str, dict)):
        raise SpecError(
            "params", f"expected a preset name, a parameter file or a mapping, got {_shown(params)}"
        )
    if s["set"] is None:
        s["set"] = {}
    if not isinstance(s["set"], dict):
        raise SpecError(
            "set", f"expected a mapping of parameter names to numbers, got {_shown(s['set'])}"
        )
    try:
        base = model.load_params(params)
    except UserError as exc:
        raise SpecError("params", str(exc)) from None
    for name, value in s["set"].items():
        if name not in model.params:
            raise SpecError(
                "set",
                f"model {model.name!r} has no parameter {name!r}"
                + suggest(str(name), model.params.names),
            )
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SpecError(f"set.{name}", f"expected a number, got {_shown(value)}")
    try:
        base.replace({str(k): float(v) for k, v in s["set"].items()})
    except UserError as exc:
        raise SpecError("set", str(exc)) from None


def trials_from_spec(spec: dict) -> list[Trial]:
    """Rig trials from a mapping, e.g. an experiment's ``inputs:``::

        inputs: {model: door, params: default, users: 3, trials: 10, seed: 1}

    Keys and defaults: :data:`SPEC_DEFAULTS` (``set`` overrides parameters by name;
    ``kinds`` a list or a comma-separated string), checked by :func:`check_spec`.
    """
    from evo_door.models import get_model

    s = check_spec(spec)
    model = get_model(s["model"])
    params = model.load_params(s["params"], {str(k): float(v) for k, v in s["set"].items()})
    campaign = Campaign(users=s["users"], trials=s["trials"], seed=s["seed"], kinds=s["kinds"])
    rig = RigSettings(rate=s["rate"], all_sensors=s["all_sensors"])
    # the same campaign on the same door gives the same trials, value for value: made
    # once a process (the case study's stages share their users' inputs), a copy each time
    key = (id(model), params.vector.tobytes(), repr(campaign), repr(rig))
    made = _MADE.get(key)
    if made is None or made[0] is not model:
        made = (model, generate_trials(model, params, campaign, rig))
        if len(_MADE) >= _MADE_MAX:
            _MADE.pop(next(iter(_MADE)))  # the oldest
        _MADE[key] = made
    return copy.deepcopy(made[1])


#: trials_from_spec's last campaigns: key -> (model, trials)
_MADE: dict[tuple, tuple] = {}
_MADE_MAX = 8
