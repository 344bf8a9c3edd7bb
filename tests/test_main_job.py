"""The main job: the bundled experiment, its data, and fits scored against the truth."""

from pathlib import Path

import pytest

from evo_door.cli import main
from evo_door.experiment import Results, load_experiment, run_experiment
from evo_door.models import get_model
from tests.test_experiment import folder  # noqa: F401  (fixture)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "experiments" / "default.yaml"


def test_default_experiment_reads_and_its_data_carry_the_rig_truth(tmp_path):
    exp = load_experiment(
        DEFAULT, ["algorithm.population=8", "algorithm.generations=1", "algorithm.polish=none"]
    )
    res = Results(run_experiment(exp, tmp_path / "quick.h5", progress=False).path)
    door = get_model("door").load_params("default")
    truth = res.truth()
    assert set(truth) == set(res.free) == {"F_load", "M", "F_atD"}
    assert truth == {n: door[n] for n in res.free}
    assert res.summary()["truth"] == truth


def test_show_scores_the_fit_against_the_truth(tmp_path, capsys):
    out = tmp_path / "run.h5"
    assert (
        main(
            [
                "run",
                str(DEFAULT),
                "--out",
                str(out),
                "--quiet",
                "--set",
                "algorithm.population=8",
                "--set",
                "algorithm.generations=1",
                "--set",
                "algorithm.polish=none",
            ]
        )
        == 0
    )
    capsys.readouterr()
    assert main(["show", str(out)]) == 0
    text = capsys.readouterr().out
    best = Results(out).best()
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("M "))
    rel = 100 * (best["M"] - 1.232) / 1.232
    assert "true 1.232" in line and f"({rel:+.2f} %)" in line


def test_no_truth_for_measured_data(folder):  # noqa: F811
    res = Results(
        run_experiment(load_experiment(folder / "exp.yaml"), folder / "a.h5", progress=False).path
    )
    assert res.truth() == {}
    assert res.summary()["truth"] == {}


@pytest.mark.slow
def test_main_job_recovers_the_rig_door_within_3_percent(tmp_path):
    """The accuracy target with rig noise: GA (AMESim's settings) then SLSQP.

    The bundled trials carry load-cell noise, gyroscope noise and a gyroscope bias per
    trial; the experiment removes the bias (target.preprocess) and fits the ISE.
    """
    res = Results(run_experiment(load_experiment(DEFAULT), tmp_path / "full.h5").path)
    assert res.config["target"]["preprocess"] == {
        "rate_bias": "start",
        "lowpass": None,
        "trim": False,
        "windows": None,
    }
    best, truth = res.best(), res.truth()
    for name, value in truth.items():
        assert best[name] == pytest.approx(value, rel=0.03), name
