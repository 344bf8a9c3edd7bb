"""The smallest change within the JND: NSGA-II's front, kept specifications, an
unreachable feel, the front in the results file, exact resume and the YAML's checks."""

import json
import random

import numpy as np
import pytest

from evo_door.errors import UserError
from evo_door.experiment import Interrupted, Results, load_experiment, resume_run, run_experiment
from evo_door.experiment.spec import export
from evo_door.optim.ga import GASettings
from evo_door.optim.nsga2 import NSGA2
from evo_door.optim.smallest_change import change_size
from tests.test_cli import cli
from tests.test_experiment import comparable

#: the AS-IS door (preset default) and the two specifications the chosen feel changes
ASIS = {"K": 400.64, "F_load": 101.45, "M": 1.232, "F_atC": 28.92, "F_atD": 18.8, "T_atO": 0.006145}
CHANGED = {"K": 350.0, "F_atD": 12.0}

#: A judge sharper than a hand (1 % of the force, 0.02 N floor): at the default JND
#: (10 %, 0.5 N) the AS-IS door already passes against this feel (its largest
#: difference is 0.72 N on the opening stroke, under a JND of 1.0 N there), and its
#: smallest change would be none at all.
STAGE = """\
name: {name}
model: door
params: default
target: {{curve: {curve}}}
{perception}free:
  K: [200, 800]
  F_load: [40, 160]
  M: [0.3, 3]
  F_atC: [0, 100]
  F_atD: [0, 100]
  T_atO: [0, 0.1]
algorithm: {{kind: nsga2, population: 40, generations: {generations}, seed: 1, polish: slsqp}}
"""
SHARP = "perception: {force: 0.01, force_floor: 0.02}\n"


def assert_same(a: dict, b: dict) -> None:
    """Two results files' datasets and attributes equal bit for bit (a NaN equal to a NaN:
    the feel's identifiability records ``step_agreement`` NaN)."""
    assert a.keys() == b.keys()
    for k in a:
        va, vb = a[k], b[k]
        if isinstance(va, np.ndarray):
            assert va.dtype == vb.dtype and va.tobytes() == vb.tobytes(), k
        elif isinstance(va, float) and np.isnan(va):
            assert np.isnan(vb), k
        else:
            assert va == vb, k


def stage(folder, name, curve, generations=12, perception=SHARP, polish="slsqp", **extra):
    text = STAGE.format(
        name=name, curve=curve, generations=generations, perception=perception
    ).replace("polish: slsqp", f"polish: {polish}") + "".join(
        f"{k}: {v}\n" for k, v in extra.items()
    )
    path = folder / f"{name}.yaml"
    path.write_text(text)
    return load_experiment(path)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """The chosen feel: the AS-IS door with K = 350 N/m and F_atD = 12 N (``evo-door
    curve``), and a feel no door reaches: a closing force of -30 N everywhere."""
    from evo_door.cli import main

    folder = tmp_path_factory.mktemp("smallest")
    argv = ["curve", "door", "--params", "default", "--set", "K=350", "--set", "F_atD=12"]
    assert main([*argv, "--out", str(folder / "feel.csv")]) == 0
    theta = np.linspace(0.0, np.pi / 2, 91)
    rows = [f"{t!r},-30.0,{d},0" for d in ("opening", "closing") for t in map(float, theta)]
    (folder / "pull.csv").write_text("theta,force,direction,speed\n" + "\n".join(rows) + "\n")
    return folder


@pytest.fixture(scope="module")
def reached(folder):
    return run_experiment(stage(folder, "reached", "feel.csv"), folder / "reached.h5")


@pytest.mark.slow
@pytest.mark.numerics
def test_the_smallest_change_passes_changes_the_two_and_keeps_the_others(reached):
    res = Results(reached.path)
    s = res.summary()
    assert s["smallest_change"]["feel_reachable"] is True  # (the yield is another matter)
    check = s["smallest_change"]["check"]
    assert check["passes"] and check["worst_jnd"] <= 1.0
    for d in ("opening", "closing"):
        assert check[d]["verdict"] == "within the JND" and check[d]["worst_jnd"] <= 1.0
        assert check[d]["fraction_beyond_jnd"] == 0.0
    best = s["best"]
    for name, value in CHANGED.items():
        assert best[name] == pytest.approx(value, rel=0.05), name
    kept = set(ASIS) - set(CHANGED)
    assert set(s["kept"]) == kept
    for name in kept:  # set back to the AS-IS value exactly, not near it
        assert best[name] == ASIS[name], name
    assert s["best_meaning"] == "smallest change within the JND"
    # the run's best is the answer (or, where the specification stage centres the nominal
    # for a higher yield, that nominal: the answer stays its alternative), and the
    # change is the answer's
    spec = res.record.tolerance
    job = reached.jobs[0].front
    if spec is not None and spec.design == "centred":
        assert s["fitness"] == pytest.approx(reached.result["best_fitness"])
        x = list(job.x)
    else:
        assert s["fitness"] == pytest.approx(s["smallest_change"]["error"])
        x = [best[n] for n in ASIS]
    lo = [s["free"][n][0] for n in ASIS]
    hi = [s["free"][n][1] for n in ASIS]
    expected = change_size([x], list(ASIS.values()), lo, hi)[0]
    assert s["smallest_change"]["change"] == pytest.approx(expected)


@pytest.mark.slow
def test_kept_specifications_in_show_and_every_spec_format(reached, capsys):
    shown = cli(capsys, "show", str(reached.path))
    assert shown.returncode == 0, shown.stderr
    for name in ("F_load", "M", "F_atC", "T_atO"):
        assert any(name in line and "kept (AS-IS)" in line for line in shown.stdout.splitlines())
    assert any("K" in line and "changed" in line for line in shown.stdout.splitlines())
    doc = json.loads(cli(capsys, "show", str(reached.path), "--json").stdout)
    assert doc["smallest_change"]["feel_reachable"] is True and "F_load" in doc["kept"]
    res = Results(reached.path)
    lines = export(res, "csv").splitlines()
    status = lines[0].split(",").index("status")
    rows = {line.split(",")[0]: line.split(",") for line in lines}
    assert rows["F_load"][status] == "kept" and rows["K"][status] == "estimated"
    assert rows["I_z"][status] == "given"
    for fmt in ("md", "tex", "html"):
        text = export(res, fmt)
        assert "kept" in text and "smallest change within the JND" in text, fmt
    yaml_text = export(res, "yaml")
    assert "kept at AS-IS: F_load, M, F_atC, T_atO" in yaml_text


@pytest.mark.slow
def test_the_front_is_stored_and_read_back(reached):
    job = reached.jobs[0]
    stored = Results(reached.path).smallest_change()
    np.testing.assert_array_equal(stored.front_x, job.front.front_x)
    np.testing.assert_array_equal(stored.front_f, job.front.front_f)
    assert stored.chosen == job.front.chosen and stored.kept == job.front.kept
    F = stored.front_f
    assert F.shape == (len(stored.front_x), 2) and len(F) >= 5
    # a front: the error rises where the change falls, and no point dominates another
    assert np.all(np.diff(F[:, 0]) >= 0) and np.all(np.diff(F[:, 1]) <= 0)
    assert 0.0 in F[:, 1]  # the AS-IS door, seeded in generation 0, is on it
    x = job.front.front_x
    expected = change_size(x, stored.asis, [200, 40, 0.3, 0, 0, 0], [800, 160, 3, 100, 100, 0.1])
    np.testing.assert_allclose(F[:, 1], expected, rtol=1e-12)
    doc = Results(reached.path).summary()["smallest_change"]
    assert len(doc["front"]) == len(F) and set(doc["front"][0]["values"]) == set(ASIS)


@pytest.mark.slow
@pytest.mark.numerics
def test_an_unreachable_feel_names_the_closest_door_and_where_it_misses(folder, capsys):
    run = run_experiment(
        stage(folder, "pull", "pull.csv", generations=6, perception=""), folder / "pull.h5"
    )
    s = Results(run.path).summary()
    assert s["reachable"] is False
    c = s["smallest_change"]
    assert c["closest_door"] == s["best"] and set(c["closest_door"]) == set(ASIS)
    assert c["error"] <= float(run.jobs[0].front.front_f[:, 0].min())  # polished, not worse
    for d in ("opening", "closing"):
        miss = c["miss"][d]
        assert miss["verdict"] == "noticeable" and miss["fraction_beyond_jnd"] > 0.05
        assert abs(miss["worst"]["difference_N"]) > miss["worst"]["jnd_N"]
        assert miss["bands_deg"] and 0.0 <= miss["bands_deg"][0][0] < 90.0
    assert "unreachable" in s["best_meaning"]
    text = cli(capsys, "show", str(run.path)).stdout
    assert "unreachable" in text and "where it misses" in text and "worst" in text
    assert "UNREACHABLE" in export(Results(run.path), "md")


@pytest.mark.slow
def test_resume_of_an_interrupted_nsga2_run_gives_the_same_front(folder):
    """Without the polish (what resume restores is the GA's state; the polish after it
    is the same code on the same front, tested above)."""
    whole = run_experiment(
        stage(folder, "whole", "feel.csv", generations=5, polish="none"), folder / "w.h5"
    )

    def kill_after_two(run, job):
        if job.ga is not None and job.ga.generation == 2:
            raise Interrupted()

    exp = stage(folder, "whole", "feel.csv", generations=5, polish="none")
    with pytest.raises(Interrupted):
        run_experiment(exp, folder / "cut.h5", on_checkpoint=kill_after_two)
    assert Results(folder / "cut.h5").attrs["generations_done"] == [2]
    resumed = resume_run(folder / "cut.h5")
    assert resumed.status == "complete"
    a, b = whole.jobs[0].front, resumed.jobs[0].front
    np.testing.assert_array_equal(a.front_x, b.front_x)
    np.testing.assert_array_equal(a.front_f, b.front_f)
    assert_same(comparable(whole.path), comparable(folder / "cut.h5"))


def test_nsga2_snapshot_and_restore_continue_exactly():
    class Two:
        lower, upper, start = np.zeros(3), np.ones(3), np.full(3, 0.2)

        def evaluate(self, X):
            F = np.c_[((X - 0.7) ** 2).sum(axis=1), np.abs(X - 0.2).mean(axis=1)]
            return F, np.zeros(len(X), dtype=bool)

    settings = GASettings(population=12, generations=6, seed=4)
    whole = NSGA2(settings).run(Two())
    part = NSGA2(GASettings(population=12, generations=3, seed=4)).run(Two())
    random.seed(99)  # the global generator has no part in it
    snap = NSGA2.snapshot(part)
    resumed = NSGA2(settings).run(Two(), NSGA2(settings).restore(snap))
    np.testing.assert_array_equal(whole.front_f, resumed.front_f)
    np.testing.assert_array_equal(whole.history_x[-1], resumed.history_x[-1])
    assert whole.crowding == resumed.crowding
    # the AS-IS point (change 0) is in generation 0 and stays on the front
    assert whole.front_f[-1, 1] == 0.0


@pytest.mark.parametrize(
    "line, message",
    [
        (
            "kind: nsga2, change: normalized",
            "algorithm.change: 'normalized' is not one of normalised",
        ),
        ("kind: ga, change: normalised", "algorithm.change: belongs to kind nsga2"),
        ("kind: ga, margin: 0.5", "algorithm.margin: belongs to kind nsga2"),
        ("kind: nsga2, margin: 1.5", "algorithm.margin"),
        ("kind: nsga3", "algorithm.kind: 'nsga3' is not one of ga, nlpql, nsga2"),
    ],
)
def test_bad_algorithm_values_are_one_line(folder, line, message):
    text = STAGE.format(name="bad", curve="feel.csv", generations=2, perception="")
    text = text.replace("kind: nsga2,", line + ",")
    (folder / "bad.yaml").write_text(text)
    with pytest.raises(UserError) as err:
        load_experiment(folder / "bad.yaml")
    assert message in str(err.value) and "\n" not in str(err.value)
    assert "bad.yaml:12:" in str(err.value)


def test_nsga2_needs_a_chosen_feel_and_one_front(folder):
    (folder / "push.csv").write_text("t,force\n0,0\n0.01,1\n0.02,1\n")
    text = STAGE.format(name="bad", curve="feel.csv", generations=2, perception="").replace(
        "target: {curve: feel.csv}",
        "target: {model: door, params: default, inputs: push.csv}\nobjective: {kind: ise}",
    )
    (folder / "bad.yaml").write_text(text)
    with pytest.raises(UserError, match=r"algorithm.kind nsga2: trades the perceptual error"):
        load_experiment(folder / "bad.yaml")
    stage_text = STAGE.format(name="bad", curve="feel.csv", generations=2, perception="")
    (folder / "bad.yaml").write_text(stage_text + "per_trial: true\n")
    with pytest.raises(UserError, match=r"bad.yaml:\d+: per_trial: .*nsga2 makes one front"):
        load_experiment(folder / "bad.yaml")


@pytest.mark.slow
def test_the_report_draws_the_front_with_the_answer(reached, tmp_path):
    from evo_door.reporting.report import write_report

    page = write_report(reached.path, tmp_path / "rep").read_text()
    assert "smallest change within the JND" in page and "kept at their AS-IS values" in page
    (png,) = (tmp_path / "rep").rglob("*-front.png")
    assert png.stat().st_size > 1000


@pytest.mark.slow
def test_a_margin_chooses_within_that_share_of_the_jnd_or_says_it_could_not(reached):
    from evo_door.optim.smallest_change import _Judge, choose_smallest_change

    problem = reached.setup.problem()
    front = Results(reached.path).smallest_change()
    half = choose_smallest_change(problem, front.front_x, front.front_f, None, True, margin=0.5)
    assert half.margin == 0.5 and half.reachable
    assert _Judge(problem, 0.5).passes(half.x)
    # no door is within a millionth of the JND: the whole JND is taken, and said
    tiny = choose_smallest_change(problem, front.front_x, front.front_f, None, True, margin=1e-6)
    assert tiny.reachable and "the whole JND taken" in tiny.steps[0]
