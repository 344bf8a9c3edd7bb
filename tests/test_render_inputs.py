"""No NaN reaches the renderer's force, from any path, and refusals name no server path.

A tester found a NaN in the parameter vector reaching the compiled force as a
ZeroDivisionError or a 200 N command, and a refusal over the control port quoting the
preset's path in the installation. Each path into the force is tried here through the
API: the loop's constructor, ``request_change``, the control port's ``set``, a device
that reads NaN, a device whose mass or damping is not finite, and the kernels alone.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import evo_door
from evo_door.errors import UserError
from evo_door.models.haptic import PARAMS
from evo_door.params.sets import PRESET_DIR, ParamSet
from evo_door.render.control import ControlServer
from evo_door.render.device import SimDevice
from evo_door.render.kernels import compute_command, compute_command_implicit
from evo_door.render.loop import ServoLoop
from evo_door.render.safety import NON_FINITE
from tests.helpers import random_kernel_vectors

LIMIT = 200.0


def _loop(params, device=None, **kw):
    device = device or SimDevice("swing", radius=0.6)
    return ServoLoop(device, params, 2500.0, **kw)


@pytest.mark.parametrize("name", PARAMS.names)
def test_a_set_with_nan_or_out_of_range_is_refused_by_the_loop(name, seed_trial):
    """A ParamSet built by hand skips the loaders' checks: the loop checks it itself.
    Before, a NaN radius or inertia raised ValueError in the simulated device, NaN
    friction_speed_threshold zeroed every cycle as a fault, NaN k_radial was refused
    as "not passive" with K = nan."""
    i = PARAMS.index(name)
    for bad in (math.nan, math.inf, PARAMS[name].upper * 10 + 1, PARAMS[name].lower - 1):
        v = seed_trial.vector.copy()
        v[i] = bad
        with pytest.raises(UserError, match=f"'{name}'"):
            _loop(ParamSet(PARAMS, v))


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e300])
def test_a_change_with_nan_is_refused_and_the_set_in_force_stays(bad, seed_trial):
    loop = _loop(seed_trial)
    with pytest.raises(UserError, match="open_force"):
        loop.request_change({"open_force": bad})
    assert not loop.pending and loop.params["open_force"] == seed_trial["open_force"]
    assert loop.log.events[-1]["kind"] == "refused"


def test_the_control_port_refuses_nan_without_a_server_path(seed_trial):
    """JSON's NaN and 1e999 (inf) parse in Python: the port refuses them, and the reason
    names the change, not the file of the running set (before: the preset's absolute
    path in the installation)."""
    loop = _loop(seed_trial)
    assert seed_trial.source.startswith(str(PRESET_DIR))  # the set came from a preset
    server = ControlServer(loop)
    try:
        for text in ('{"set": {"open_force": NaN}}', '{"set": {"open_force": 1e999}}'):
            answer = server.answer(text.encode())
            # refused as it is read (the message's parser takes finite numbers only)
            assert answer["ok"] is False and (
                "finite" in answer["error"] or "beyond" in answer["error"]
            ), answer
            _no_server_path(answer["error"])
        answer = server.answer(b'{"set": {"open_force": 1e9}}')
        assert answer["ok"] is False and "outside its declared range" in answer["error"]
        _no_server_path(answer["error"])
    finally:
        server.close()
    assert loop.params["open_force"] == seed_trial["open_force"]


def _no_server_path(message: str) -> None:
    for folder in (PRESET_DIR, Path(evo_door.__file__).parent, Path.cwd()):
        assert str(folder) not in message, message
    assert "/" not in message, message


def test_a_bad_value_on_a_preset_names_the_preset_not_its_path(capsys):
    from evo_door.cli import main

    for value in ("1e9", "nan"):
        assert main(["params", "haptic", "--params", "seed_trial", "--set", f"open_force={value}"])
        err = capsys.readouterr().err
        assert "seed_trial: parameter 'open_force'" in err, err
        _no_server_path(err.split("error: ", 1)[1])


class _NaNDevice(SimDevice):
    """Reads NaN (or inf) in one channel every third cycle; records what it is sent."""

    def __init__(self, channel: int, value: float, **kw):
        super().__init__("swing", radius=0.6, **kw)
        self.channel, self.value, self.reads = channel, value, 0
        self.sent: list[np.ndarray] = []

    def read(self):
        self.reads += 1
        out = [np.array(a, dtype=np.float64) for a in super().read()]
        if self.reads % 3 == 0:
            out[self.channel][1] = self.value
        return tuple(out)

    def command(self, force) -> None:
        self.sent.append(np.array(force, dtype=np.float64))
        super().command(force)


@pytest.mark.parametrize("channel", [0, 1, 2], ids=["position", "velocity", "force"])
@pytest.mark.parametrize("value", [math.nan, math.inf])
@pytest.mark.parametrize("friction", ["implicit", "tanh"])
def test_a_device_reading_nan_gets_zero_force_those_cycles(channel, value, friction, seed_trial):
    dev = _NaNDevice(channel, value)
    loop = _loop(seed_trial, dev, friction=friction, clamp=True)  # tanh: seed_trial is stiff
    stats = loop.run(0.4)
    sent = np.array(dev.sent)
    assert len(sent) == 1000 and np.isfinite(sent).all()
    assert (np.linalg.norm(sent, axis=1) <= LIMIT).all()
    # every third cycle read NaN: its force is zero, and counted as a fault
    assert (sent[2::3] == 0.0).all()
    assert stats["faults"] == len(sent[2::3]) and stats["status"] == "done"
    assert np.abs(sent[0::3]).max() > 0.0  # the other cycles rendered


@pytest.mark.parametrize("attribute, unit", [("damping", "N s/m"), ("max_force", "N")])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -1.0])
def test_a_device_with_a_non_finite_damping_or_limit_is_refused(attribute, unit, bad, seed_trial):
    dev = SimDevice("hold", radius=0.6)
    setattr(dev, attribute, bad)
    with pytest.raises(UserError, match=f"device's {attribute} is .* {unit}"):
        _loop(seed_trial, dev)


def test_a_device_whose_mass_is_nan_is_refused_when_it_starts(seed_trial):
    class NoSetMass(SimDevice):
        set_mass = None  # the loop then takes the device's own mass

    dev = NoSetMass("hold", radius=0.6)
    dev.mass = math.nan
    loop = _loop(seed_trial, dev)
    with pytest.raises(UserError, match="device's mass is nan kg"):
        loop.run(0.01)
    assert dev.stopped


def test_the_log_rate_is_at_most_the_loop_rate(seed_trial):
    for bad in (2500.1, 1e8, math.nan, 0.5):
        with pytest.raises(UserError, match="--log-rate"):
            _loop(seed_trial, log_rate=bad)


def test_the_kernels_give_a_finite_force_within_the_limit_for_any_input():
    """Sets drawn within the declaration (extremes included), states from rest to
    absurd, NaN and inf among them, mass, period and damping not finite: never an
    exception, always a finite force within the limit; a non-finite input gives zero
    and the NON_FINITE code."""
    rng = np.random.default_rng(24)
    vectors = random_kernel_vectors(200, rng)
    vectors[:20] = PARAMS.lower
    vectors[20:40] = PARAMS.upper
    specials = [math.nan, math.inf, -math.inf, 1e300, -1e300, 0.0, 1e-300]
    out = np.zeros(3)
    row = np.zeros(15)
    for i, p in enumerate(vectors):
        p_free = p.copy()
        for _ in range(20):
            scale = 10.0 ** rng.uniform(-6, 6)
            state = rng.normal(size=(3, 3)) * scale
            bad = rng.random() < 0.5
            if bad:
                state[rng.integers(3), rng.integers(3)] = specials[rng.integers(len(specials))]
            mass, period, damping = 2.0, 4e-4, 2.0
            odd = rng.integers(4)
            if odd == 1:
                mass = specials[rng.integers(3)]
            elif odd == 2:
                damping = specials[rng.integers(3)]
            elif odd == 3:
                period = specials[rng.integers(3)]
            code = compute_command_implicit(
                state[0], state[1], state[2], p, p_free, mass, period, damping, LIMIT, out, row
            )
            _check(out, code, state, (mass, period, damping))
            code = compute_command(state[0], state[1], state[2], p, LIMIT, out, row)
            _check(out, code, state, ())
        assert i >= 0


def _check(out, code, state, numbers) -> None:
    assert np.isfinite(out).all() and np.linalg.norm(out) <= LIMIT
    if not np.isfinite(state).all() or not all(math.isfinite(x) for x in numbers):
        assert code == NON_FINITE and (out == 0.0).all()
