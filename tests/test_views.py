"""The run-level views: status (interrupted / running), runs, compare, estimates on a
bound, the convergence and fit figures.

Runs are small oscillator fits (tests/test_experiment.py's experiment, well under a
second each), made once per module; commands run in-process (tests.test_cli.cli).
"""

import json
import subprocess
import sys

import h5py
import numpy as np
import pytest
from numba import njit

from evo_door.data.io import write_trials
from evo_door.errors import UserError
from evo_door.experiment import (
    Interrupted,
    Results,
    load_experiment,
    reader,
    run_experiment,
)
from evo_door.models.base import Model
from evo_door.optim.bounds import bound_hits
from evo_door.params import Param, ParamTable
from evo_door.reporting import figures as figure_views
from evo_door.reporting import format_json
from evo_door.reporting.format_text import bound_advice
from tests.conftest import OSCILLATOR_PARAMS, oscillator_accel
from tests.test_cli import cli
from tests.test_experiment import EXPERIMENT
from tests.test_optim import TRUE, make_trial

#: the oscillator's equation under other names for some parameters: a second model
SPRING_MODEL = Model(
    "spring",
    "linear oscillator, other parameter names",
    ParamTable(
        "spring",
        [
            Param("k", "N/rad", 100.0, 0.0, 1e7, "specification", "spring stiffness"),
            Param("damping", "N s/rad", 1.0, 0.0, 1e4, "specification", "viscous damping"),
            Param("inertia", "kg m", 1.0, 1e-3, 100.0, "specification", "inertia"),
            Param("theta_eq", "rad", 0.0, -10.0, 10.0, "geometry", "equilibrium angle"),
        ],
    ),
    njit(oscillator_accel.py_func),
    method="rk4",
    substeps=1,
)


def _interrupt_at(generation):
    def hook(run, job):
        if job.ga is not None and job.ga.generation == generation and not job.done:
            raise Interrupted()

    return hook


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    """Trials that carry their true parameters, and runs of the oscillator experiment.

    a.h5: complete (ise, seed 1); b.h5: max_square, seed 2; bound.h5: k searched in
    [20, 90] (true 100); cut.h5: stopped after generation 3 of 6; results/ holds copies
    for ``runs``.
    """
    w = tmp_path_factory.mktemp("views")
    trials = [make_trial(s, 0.75, tid=f"t{s}") for s in (1, 2, 3)] + [make_trial(4, 0.75, tid="v1")]
    for tr in trials:
        tr.truth = {"model": "oscillator", "params": dict(TRUE, theta_eq=0.0)}
    write_trials(w / "trials.h5", trials)
    (w / "exp.yaml").write_text(EXPERIMENT)
    (w / "results").mkdir()
    out = w / "results"

    def run(name, overrides=(), hook=None):
        exp = load_experiment(w / "exp.yaml", list(overrides))
        if hook is None:
            return run_experiment(exp, out / name)
        with pytest.raises(Interrupted):
            run_experiment(exp, out / name, on_checkpoint=hook)

    run("a.h5")
    run("b.h5", ["objective.kind=max_square", "algorithm.seed=2"])
    run("bound.h5", ["free.k=[20, 90]"])
    run("cut.h5", hook=_interrupt_at(3))
    return w


def _file(ws, name):
    return ws / "results" / name


# -- status: complete, running, interrupted ---------------------------------------------
def test_a_killed_run_shows_interrupted_with_its_generation_in_show_json_and_runs(ws, capsys):
    path = _file(ws, "cut.h5")
    with h5py.File(path) as f:  # the file itself still says running: only the lock tells
        assert f.attrs["status"] == "running"
    shown = cli(capsys, "show", path)
    assert shown.returncode == 0, shown.stderr
    assert "status interrupted (3/6 gen)" in shown.stdout
    assert f"interrupted at generation 3/6; evo-door resume {path} continues it" in shown.stdout
    doc = json.loads(cli(capsys, "show", path, "--json").stdout)
    assert doc["status"] == "interrupted" and doc["pid"] is None
    assert doc["status_text"] == "interrupted at generation 3/6"
    assert doc["resume"] == f"evo-door resume {path}"
    listed = cli(capsys, "runs", ws / "results")
    row = next(line for line in listed.stdout.splitlines() if line.startswith("cut.h5"))
    assert row.split()[3:5] == ["interrupted", "3/6"]
    assert "interrupted: cut.h5; `evo-door resume FILE` continues" in listed.stdout
    rows = {r["file"]: r for r in json.loads(cli(capsys, "runs", ws / "results", "--json").stdout)}
    assert rows["cut.h5"]["status"] == "interrupted" and rows["a.h5"]["status"] == "complete"


def test_a_run_whose_lock_another_process_holds_shows_running(ws, capsys):
    path = _file(ws, "cut.h5")
    code = (
        "import time; from evo_door.files import FileLock; "
        f"lock = FileLock({str(path)!r}).acquire(); print('held', flush=True); time.sleep(30)"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        shown = cli(capsys, "show", path)
        assert f"status running (3/6 gen, process {holder.pid})" in shown.stdout
        assert "interrupted" not in shown.stdout
        doc = json.loads(cli(capsys, "show", path, "--json").stdout)
        assert doc["status"] == "running" and doc["pid"] == holder.pid and doc["resume"] == ""
        rows = {r["file"]: r for r in format_json.list_runs(ws / "results")}
        assert rows["cut.h5"]["status"] == "running"
    finally:
        holder.kill()
        holder.wait()
    # the holder died without letting go: the system dropped its lock
    assert Results(path).status().state == "interrupted"


@pytest.mark.parametrize(
    "per_trial, generation, text",
    [
        (False, "last", "interrupted after the last fit, before the results were written"),
        (True, 1, "interrupted in fit 2/3 (1/3 fits done), at generation 1/3"),
    ],
)
def test_interrupted_says_where_the_run_stopped(ws, tmp_path, per_trial, generation, text):
    exp = load_experiment(
        ws / "exp.yaml",
        [f"per_trial={str(per_trial).lower()}", "algorithm.generations=3", "algorithm.polish=none"],
    )

    def hook(run, job):
        if generation == "last" and job.done:
            raise Interrupted()
        if generation != "last" and job.name == "t2" and job.ga.generation == generation:
            raise Interrupted()

    with pytest.raises(Interrupted):
        run_experiment(exp, tmp_path / "r.h5", on_checkpoint=hook)
    assert Results(tmp_path / "r.h5").status().text == text


def test_show_and_runs_agree_on_the_fits_of_a_killed_and_resumed_per_trial_run(
    ws, tmp_path, capsys
):
    """A per_trial run (three fits and the pooled one) killed in its second fit, then
    resumed: show and runs say the same (status, fits done, answer) at every step, and
    the resumed run ends as the uninterrupted one."""
    from evo_door.experiment import resume_run

    exp = load_experiment(
        ws / "exp.yaml", ["per_trial=true", "pooled=true", "algorithm.generations=3"]
    )
    whole = run_experiment(exp, tmp_path / "whole.h5")

    def kill(run, job):
        if job.name == "t2" and job.ga is not None and job.ga.generation == 1:
            raise Interrupted()

    with pytest.raises(Interrupted):
        run_experiment(exp, tmp_path / "cut.h5", on_checkpoint=kill)

    def both():
        shown = json.loads(cli(capsys, "show", tmp_path / "cut.h5", "--json").stdout)
        rows = json.loads(cli(capsys, "runs", tmp_path, "--json").stdout)
        row = next(r for r in rows if r["file"] == "cut.h5")
        for key in ("status", "status_text", "progress", "fitness"):
            assert shown[key] == row[key], key
        assert shown["best"] == row["values"]
        return shown

    cut = both()
    # one count of fits in both places: those done (the fit in progress is named apart)
    assert cut["progress"] == "1/4 fits done x 3 gen"
    assert cut["status_text"] == "interrupted in fit 2/4 (1/4 fits done), at generation 1/3"
    resume_run(tmp_path / "cut.h5")
    done = both()
    assert done["progress"] == "4/4 fits done x 3 gen" and len(done["per_trial_fits"]) == 3
    assert done["best"] == Results(whole.path).best()


# -- runs: parameters, objective, status, cheaply ---------------------------------------
def test_runs_shows_parameters_with_units_objective_and_status_without_reading_arrays(
    ws, capsys, monkeypatch
):
    def no_arrays(group):
        raise AssertionError(f"runs read the whole of {group.name}")

    monkeypatch.setattr(reader, "read_group", no_arrays)
    listed = cli(capsys, "runs", ws / "results")
    assert listed.returncode == 0, listed.stderr
    header, _, *lines = listed.stdout.split("\n\n")[0].splitlines()
    assert header.split()[:7] == [
        "file",
        "name",
        "model",
        "status",
        "progress",
        "objective",
        "best",
    ]
    rows = {line.split()[0]: line for line in lines}
    assert set(rows) == {"a.h5", "b.h5", "bound.h5", "cut.h5"}
    assert "complete" in rows["a.h5"] and "ise on dtheta" in rows["a.h5"]
    assert "max_square on dtheta" in rows["b.h5"] and "(rad/s)^2 s" not in rows["b.h5"]
    assert "k=100 N/rad, c=2 N s/rad, inertia=1.5 kg m" in rows["a.h5"]
    assert "k=90 N/rad (upper bound)" in rows["bound.h5"]
    # a run without an answer yet shows the best of its hall of fame so far
    monkeypatch.undo()
    so_far = Results(_file(ws, "cut.h5")).best()
    assert f"k={so_far['k']:.4g} N/rad" in rows["cut.h5"]
    doc = {r["file"]: r for r in json.loads(cli(capsys, "runs", ws / "results", "--json").stdout)}
    assert doc["cut.h5"]["values"] == so_far
    assert doc["a.h5"]["units"]["k"] == "N/rad" and doc["a.h5"]["fitness_unit"] == "(rad/s)^2 s"
    assert doc["bound.h5"]["at_bound"] == {"k": "upper"}


# -- estimates on a bound ------------------------------------------------------------------
def test_bound_hits_within_a_hundredth_of_the_range():
    lo, hi = [10.0, 10.0, 10.0, 10.0, 10.0], [20.0] * 5
    x = [10.09, 10.11, 19.91, 19.89, float("nan")]
    assert bound_hits("abcde", x, lo, hi) == {"a": "lower", "c": "upper"}
    assert bound_hits(["k"], [10.0], [10.0], [20.0]) == {"k": "lower"}


def test_bound_advice_widens_inside_the_declaration_or_names_its_limit():
    k, c = OSCILLATOR_PARAMS["k"], OSCILLATOR_PARAMS["c"]
    assert bound_advice("k", "upper", 20, 9e6, k).endswith("(e.g. k: [20, 1e+07])")
    assert bound_advice("k", "lower", 50, 90, k).endswith("(e.g. k: [10, 90])")
    at_limit = bound_advice("c", "lower", 0, 10, c)
    assert at_limit.startswith("c is on the lower bound of its search range, 0 N s/rad, the ")
    assert "model's declared limit" in at_limit and "widen" not in at_limit


def test_an_estimate_on_a_bound_is_flagged_in_show_json_and_the_file(ws, capsys):
    path = _file(ws, "bound.h5")
    with h5py.File(path) as f:
        assert f["best"].attrs["at_bound"] == 'json:{"k":"upper"}'
    shown = cli(capsys, "show", path).stdout
    k_line = next(line for line in shown.splitlines() if line.lstrip().startswith("k "))
    assert k_line.split()[1] == "90" and k_line.endswith("<- upper bound")
    assert (
        "! k is on the upper bound of its search range, 90 N/rad: the bound, not the data, "
        "decided it; widen the range in free: (e.g. k: [20, 160])"
    ) in shown
    assert not any(
        line.lstrip().startswith("c ") and "bound" in line for line in shown.splitlines()
    )
    doc = json.loads(cli(capsys, "show", path, "--json").stdout)
    assert doc["at_bound"] == {"k": "upper"}
    assert json.loads(cli(capsys, "show", _file(ws, "a.h5"), "--json").stdout)["at_bound"] == {}


def test_per_trial_fits_on_a_bound_are_named(ws, tmp_path, capsys):
    exp = load_experiment(
        ws / "exp.yaml",
        ["per_trial=true", "free.k=[20, 90]", "algorithm.generations=2"],
    )
    run_experiment(exp, tmp_path / "p.h5")
    doc = json.loads(cli(capsys, "show", tmp_path / "p.h5", "--json").stdout)
    assert doc["per_trial_at_bound"] == {t: {"k": "upper"} for t in ("t1", "t2", "t3")}
    shown = cli(capsys, "show", tmp_path / "p.h5").stdout
    row = next(line for line in shown.splitlines() if line.startswith("  k "))
    assert row.endswith("on a bound: t1 upper, t2 upper, t3 upper")


# -- compare ---------------------------------------------------------------------------------
def table(text: str) -> dict[str, list[str]]:
    """``compare``'s table as label -> cells, cut at the columns of its dashed line.

    The rows ``true`` and ``error`` under a parameter are keyed ``NAME true``, ``NAME error``.
    """
    lines = text.split("\n\n")[0].splitlines()
    spans, at = [], 0
    for dashes in lines[1].split("  "):
        spans.append((at, at + len(dashes)))
        at += len(dashes) + 2
    rows, param = {}, ""
    for line in [lines[0], *lines[2:]]:
        cells = [line[a:b].strip() for a, b in spans]
        if cells[0] in ("true", "error"):
            cells[0] = f"{param} {cells[0]}"
        elif line.startswith("  ") and not line.startswith("    "):
            param = cells[0].split()[0]
        rows[cells[0]] = cells[1:]
    return rows


def test_compare_puts_runs_side_by_side_with_the_settings_that_differ(ws, capsys):
    a, b, cut = _file(ws, "a.h5"), _file(ws, "b.h5"), _file(ws, "cut.h5")
    res = cli(capsys, "compare", a, b, cut)
    assert res.returncode == 0, res.stderr
    rows = table(res.stdout)
    assert rows[""] == ["a.h5", "b.h5", "cut.h5"]
    assert rows["status"] == ["complete (6/6 gen)", "complete (6/6 gen)", "interrupted (3/6 gen)"]
    assert rows["objective"] == ["ise on dtheta, sum", "max_square on dtheta, sum"] + [
        "ise on dtheta, sum"
    ]
    # the settings that differ, and only those
    assert rows["objective.kind"] == ["ise", "max_square", "ise"]
    assert rows["algorithm.seed"] == ["1", "2", "1"]
    assert "algorithm.population" not in rows and "free.k" not in rows
    # values with units, the truth and the error; the fitness unit of each objective
    best = [Results(p).best() for p in (a, b, cut)]
    assert rows["k [N/rad]"] == [f"{x['k']:.8g}" for x in best]
    assert rows["k true"] == ["100", "100", "100"] and rows["c true"] == ["2", "2", "2"]
    assert rows["k error"][0] == f"{100 * (best[0]['k'] - 100) / 100:+.3f} %"
    assert rows["fitness"][1].endswith(" (rad/s)^2") and rows["fitness"][0].endswith(" (rad/s)^2 s")
    assert rows["unit"] == ["(rad/s)^2 s", "(rad/s)^2", "(rad/s)^2 s"]
    assert "the objectives differ: fitness and errors are not on one scale" in res.stdout
    errors = Results(a).summary()["fit_errors"]
    assert rows["t1"] == [f"{errors['t1']:.4g}", rows["t1"][1], "-"]  # none yet when cut
    assert rows["evaluations"][0] == str(Results(a).tree["timings"]["@attrs"]["evaluations"])
    assert "wall time [s]" in rows and "GA evaluations/s" in rows
    assert f"cut.h5: interrupted at generation 3/6; evo-door resume {cut} continues it" in (
        res.stdout.splitlines()
    )
    doc = json.loads(cli(capsys, "compare", a, b, "--json").stdout)
    assert doc["differences"] == {
        "objective.kind": ["ise", "max_square"],
        "algorithm.seed": [1, 2],
    }
    assert not doc["models_differ"] and doc["params"] == ["k", "c", "inertia"]
    ka = doc["runs"][0]["params"]["k"]
    assert ka["value"] == best[0]["k"] and ka["unit"] == "N/rad" and ka["true"] == 100.0
    assert ka["error_percent"] == pytest.approx(best[0]["k"] - 100)
    assert doc["runs"][1]["fitness_unit"] == "(rad/s)^2"
    assert doc["runs"][0]["fit_errors"] == errors
    assert doc["runs"][0]["timings"]["evaluations"] > 0


def test_compare_runs_of_different_models_on_what_they_share(ws, tmp_path, capsys):
    text = (
        EXPERIMENT.replace(
            "model: tests.conftest:OSCILLATOR_MODEL", "model: tests.test_views:SPRING_MODEL"
        )
        .replace("  c: [0, 10]", "  damping: [0, 10]")
        .replace("generations: 6", "generations: 2")
    )
    (ws / "spring.yaml").write_text(text)
    run_experiment(load_experiment(ws / "spring.yaml"), tmp_path / "s.h5")
    doc = json.loads(cli(capsys, "compare", _file(ws, "a.h5"), tmp_path / "s.h5", "--json").stdout)
    assert doc["models_differ"] and doc["params"] == ["k", "inertia"]
    assert doc["not_shared"] == ["c", "damping"]
    assert doc["differences"]["model"] == [
        "tests.conftest:OSCILLATOR_MODEL",
        "tests.test_views:SPRING_MODEL",
    ]
    shown = cli(capsys, "compare", _file(ws, "a.h5"), tmp_path / "s.h5").stdout
    assert (
        "runs of different models (tests.conftest:OSCILLATOR_MODEL, "
        "tests.test_views:SPRING_MODEL): compared on what they share; parameters declared by "
        "every model: k, inertia; not shared: c, damping"
    ) in shown
    assert not any(line.startswith("  c ") for line in shown.splitlines())


def test_compare_shows_fixed_values_beside_free_ones(ws, tmp_path, capsys):
    exp = load_experiment(
        ws / "exp.yaml", ["free={k: [20, 500], inertia: [0.2, 8]}", "fixed={c: 2.5}"]
    )
    run_experiment(exp, tmp_path / "f.h5")
    doc = json.loads(cli(capsys, "compare", _file(ws, "a.h5"), tmp_path / "f.h5", "--json").stdout)
    c = doc["runs"][1]["params"]["c"]
    assert c["role"] == "fixed" and c["value"] == 2.5 and c["error_percent"] is None
    assert doc["differences"]["fixed.c"] == [None, 2.5]
    rows = table(cli(capsys, "compare", _file(ws, "a.h5"), tmp_path / "f.h5").stdout)
    assert rows["c [N s/rad]"] == [f"{Results(_file(ws, 'a.h5')).best()['c']:.8g}", "fixed 2.5"]


@pytest.mark.parametrize(
    "args, message",
    [
        (["{a}"], "compare needs two results files or more, got only"),
        (["{a}", "{w}/missing.h5"], "missing.h5: results file not found"),
        (["{a}", "{w}/trials.h5"], "trials.h5: not an evo-door results file"),
        (["{a}", "{w}/exp.yaml"], "exp.yaml: not a readable HDF5 file"),
    ],
)
def test_compare_refuses_bad_input_in_one_line(ws, capsys, args, message):
    a = _file(ws, "a.h5")
    res = cli(capsys, "compare", *(x.format(a=a, w=ws) for x in args))
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.count("\n") == 1 and message in res.stderr, res.stderr
    with pytest.raises(UserError, match="compare needs two results files or more: only"):
        format_json.compare([Results(a)])


# -- figures ---------------------------------------------------------------------------------
@pytest.fixture()
def figures(monkeypatch):
    """The figures the views would write, kept instead (name -> Figure)."""
    kept = {}
    monkeypatch.setattr(
        figure_views, "save_figure", lambda fig, path, dpi=110: kept.update({path: fig})
    )
    return kept


def test_convergence_plot_is_best_and_mean_per_generation_on_a_log_scale(ws, tmp_path, figures):
    res = Results(_file(ws, "a.h5"))
    figure_views.plot_convergence(res, "conv.png")
    ax = figures["conv.png"].axes[0]
    log = res.jobs()[0]["ga"]["logbook"]
    lines = {line.get_label(): line for line in ax.get_lines()}
    np.testing.assert_array_equal(lines["best"].get_xdata(), log["gen"])
    np.testing.assert_array_equal(lines["best"].get_ydata(), log["min"])
    np.testing.assert_array_equal(lines["mean"].get_ydata(), log["mean"])
    assert lines["mean"].get_linestyle() == "--"
    assert ax.get_yscale() == "log" and ax.get_ylabel() == "fitness [(rad/s)^2 s]"
    assert ax.get_xlabel() == "generation"
    assert "stopped: 6 generations done" in figures["conv.png"].get_suptitle()
    # the SLSQP polish: a star at its final fitness
    stars = [line for line in ax.get_lines() if line.get_marker() == "*"]
    assert stars[0].get_ydata()[0] == pytest.approx(res.jobs()[0]["local"]["@attrs"]["fitness"])
    assert "after the SLSQP polish" in [t.get_text() for t in ax.get_legend().get_texts()]


def test_convergence_of_an_interrupted_run_and_of_per_trial_fits(ws, tmp_path, figures):
    figure_views.plot_convergence(Results(_file(ws, "cut.h5")), "cut.png")
    fig = figures["cut.png"]
    assert "interrupted at generation 3/6" in fig.get_suptitle()
    best = next(line for line in fig.axes[0].get_lines() if line.get_label() == "best")
    assert list(best.get_xdata()) == [0, 1, 2, 3]
    exp = load_experiment(
        ws / "exp.yaml", ["per_trial=true", "algorithm.generations=2", "algorithm.polish=none"]
    )
    run_experiment(exp, tmp_path / "p.h5")
    figure_views.plot_convergence(Results(tmp_path / "p.h5"), "p.png")
    labels = [line.get_label() for line in figures["p.png"].axes[0].get_lines()]
    assert labels == ["t1: best", "t1: mean", "t2: best", "t2: mean", "t3: best", "t3: mean"]


def test_convergence_command_writes_a_png_and_refuses_a_run_without_ga(ws, tmp_path, capsys):
    out = tmp_path / "conv.png"
    res = cli(capsys, "show", _file(ws, "cut.h5"), "--convergence", out)
    assert res.returncode == 0, res.stderr and f"wrote {out}" in res.stdout
    assert out.read_bytes()[:4] == b"\x89PNG" and out.stat().st_size > 10000
    exp = load_experiment(
        ws / "exp.yaml",
        [
            "algorithm.kind=nlpql",
            "algorithm.polish=none",
            "algorithm.start={k: 120, c: 1, inertia: 1.8}",
        ],
    )
    run_experiment(exp, tmp_path / "n.h5")
    res = cli(capsys, "show", tmp_path / "n.h5", "--convergence", tmp_path / "n.png")
    assert res.returncode == 2
    assert "no convergence to plot: it has no genetic algorithm (algorithm nlpql)" in res.stderr
    assert not (tmp_path / "n.png").exists()


def test_fit_plot_shows_target_under_a_dashed_model_errors_with_units_and_the_force(ws, figures):
    figure_views.plot_fit(Results(_file(ws, "a.h5")), "fit.png")
    fig = figures["fit.png"]
    host = fig.axes[0]
    twin = next(ax for ax in fig.axes if ax is not host and ax.bbox.bounds == host.bbox.bounds)
    target = next(line for line in host.get_lines() if line.get_label() == "target")
    model = next(line for line in host.get_lines() if line.get_label() == "model (best)")
    # the target wide and light under the model, the model dashed: both visible
    assert target.get_linewidth() > 2 * model.get_linewidth()
    assert model.get_linestyle() == "--"
    assert host.get_lines().index(target) < host.get_lines().index(model)
    # the responses' axes drawn over the force's twin axes, not under it
    assert host.get_zorder() > twin.get_zorder() and not host.patch.get_visible()
    assert host.get_title().startswith("t1 (fitted), error ")
    assert host.get_title().endswith(" (rad/s)^2 s")
    legend = [t.get_text() for t in host.get_legend().get_texts()]
    assert legend == ["target", "model (best)", "force"]


# -- errors a person reads ---------------------------------------------------------------
def test_each_trials_error_is_given_in_the_channels_unit_consistent_with_the_ise(ws, capsys):
    res = Results(_file(ws, "a.h5"))  # ise on dtheta
    errors = res.channel_errors()
    assert set(errors) == {"t1", "t2", "t3", "v1"} and errors["v1"]["role"] == "validate"
    fit = res.summary()["fit_errors"]
    for r in res.responses():
        e = errors[r.trial_id]
        diff = r.model - r.target
        assert e["unit"] == "rad/s" and e["max"] == pytest.approx(np.max(np.abs(diff)))
        assert e["max_deg"] == pytest.approx(np.degrees(e["max"]))
        if r.role == "fit":
            # the ISE (trapezoid rule) is the mean square times the duration, near enough
            duration = r.t[-1] - r.t[0]
            assert fit[r.trial_id] == pytest.approx(e["rms"] ** 2 * duration, rel=0.05)
    shown = cli(capsys, "show", _file(ws, "a.h5")).stdout
    t1 = errors["t1"]
    assert f"t1       {t1['rms']:.3g} / {t1['max']:.3g} rad/s ({t1['rms_deg']:.3g} /" in shown
