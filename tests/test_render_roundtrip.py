"""A render log is the "TO BE" behaviour an experiment fits: the round trip.

The seed_trial set is rendered to a virtual user who swings the door three times
(``--user swing``), on the simulated device and, over real TCP, on the emulated
HapticMaster (``evo-door emulate`` in its own process). An experiment then fits the
haptic model's heaviness and frictions to the log and must find the set that was
rendered, plus what the device itself adds, which is known: its viscous damping b
(N s/m) acts on the handle as ``viscous_damping`` b R (N s/rad), and the simulated
device's own dry friction (0.3 N) adds to both friction levels.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from evo_door.cli import main
from evo_door.experiment.results import Results
from evo_door.models import get_model
from tests.helpers import LOADED_MACHINE_LIMITS

pytestmark = pytest.mark.slow

SWING = 9.5  # s: the swing script's three swings
FREE = {
    "inertia": (0.5, 3.0),
    "friction_closing": (0.0, 6.0),
    "friction_opening": (0.0, 6.0),
    "viscous_damping": (0.0, 3.0),
}


def _fit(folder, log):
    exp = folder / "fit.yaml"
    free = "".join(f"  {k}: [{lo}, {hi}]\n" for k, (lo, hi) in FREE.items())
    exp.write_text(
        f"name: render_fit\nmodel: haptic\nparams: seed_trial\ntarget:\n  data: {log.name}\n"
        f"free:\n{free}objective: {{kind: ise, derivative: 1, combine: sum}}\n"
        "algorithm: {kind: ga, population: 40, generations: 15, seed: 1, polish: slsqp}\n"
    )
    out = folder / "fit.h5"
    assert main(["run", str(exp), "--out", str(out), "--quiet"]) == 0
    return Results(out).best()


def _check(best, device_damping, device_friction):
    rendered = get_model("haptic").load_params("seed_trial")
    assert best["inertia"] == pytest.approx(rendered["inertia"], rel=0.02)
    for name in ("friction_closing", "friction_opening"):
        assert best[name] == pytest.approx(rendered[name] + device_friction, abs=0.1)
    felt = rendered["viscous_damping"] + device_damping * rendered["radius"]
    assert best["viscous_damping"] == pytest.approx(felt, abs=0.05)


def test_a_log_of_the_simulated_device_fits_back_to_the_rendered_set(tmp_path):
    log = tmp_path / "sim.h5"
    args = ["render", "--params", "seed_trial", "--device", "sim", "--user", "swing"]
    assert main([*args, "--duration", str(SWING), "--log", str(log)]) == 0
    assert main(["data", "show", str(log), "--plot", str(tmp_path / "sim.png")]) == 0
    _check(_fit(tmp_path, log), device_damping=2.0, device_friction=0.3)


def test_a_log_over_the_emulated_hapticmaster_fits_back_to_the_rendered_set(tmp_path):
    emulator = subprocess.Popen(
        [sys.executable, "-m", "evo_door", "emulate", "hapticmaster", "--port", "0"]
        + ["--user", "swing", "--damping", "2", "--noise", "0.05", "--seconds", "60"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        line = emulator.stdout.readline()
        port = int(line.split("127.0.0.1:")[1].split()[0])
        log = tmp_path / "emu.h5"
        device = ["--device", f"hapticmaster://127.0.0.1:{port}", "--device-damping", "2"]
        args = ["render", "--params", "seed_trial", *device, "--rate", "1000"]
        args += LOADED_MACHINE_LIMITS
        assert main([*args, "--duration", str(SWING), "--log", str(log)]) == 0
    finally:
        emulator.terminate()
        emulator.wait(10)
    assert main(["data", "show", str(log)]) == 0
    _check(_fit(tmp_path, log), device_damping=2.0, device_friction=0.0)
