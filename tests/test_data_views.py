"""What people see of trials: import reports, the trial figure, the curve figure, the
bundled data set and how it is reproduced."""

import os
from pathlib import Path

import h5py
import numpy as np

from evo_door.data import Trial, read_trials, write_trials
from evo_door.data.show import STYLE_KEY, trial_colors, trials_figure
from tests.test_cli import cli

RATE = 1024.0
ROOT = Path(__file__).resolve().parents[1]


def small_trial(tid, user="U1", kind="impulse", n=400, **kw):
    t = np.arange(n) / RATE
    return Trial(t, np.sin(7 * t), trial_id=tid, user_id=user, kind=kind, **kw)


# -- data import --append -------------------------------------------------------------
def test_append_reports_what_it_added_and_what_the_file_holds(tmp_path, capsys):
    out = tmp_path / "all.h5"
    write_trials(tmp_path / "first.h5", [small_trial("A"), small_trial("B")])
    write_trials(tmp_path / "more.h5", [small_trial("C"), small_trial("D")])
    res = cli(capsys, "data", "import", tmp_path / "first.h5", "--out", out)
    assert res.returncode == 0 and res.stdout == f"wrote {out}: 2 trial(s): A, B\n"
    res = cli(capsys, "data", "import", tmp_path / "more.h5", "--out", out, "--append")
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == [
        f"added to {out}: 2 trial(s): C, D",
        f"{out} now holds 4 trial(s): A, B, C, D",
    ]
    assert [t.trial_id for t in read_trials(out)] == ["A", "B", "C", "D"]
    # appending to a file that is not there yet: it holds what was added
    res = cli(
        capsys, "data", "import", tmp_path / "more.h5", "--out", tmp_path / "new.h5", "--append"
    )
    assert res.stdout.splitlines()[-1] == f"{tmp_path / 'new.h5'} now holds 2 trial(s): C, D"


def test_append_refuses_an_id_the_file_holds_and_leaves_it(tmp_path, capsys):
    out = tmp_path / "all.h5"
    write_trials(out, [small_trial("A"), small_trial("B")])
    write_trials(tmp_path / "again.h5", [small_trial("B")])
    before = out.read_bytes()
    res = cli(capsys, "data", "import", tmp_path / "again.h5", "--out", out, "--append")
    assert res.returncode == 2 and res.stderr.count("\n") == 1
    assert f"{out} already holds trial(s) B" in res.stderr and "--id" in res.stderr
    assert out.read_bytes() == before
    res = cli(
        capsys, "data", "import", tmp_path / "again.h5", "--out", out, "--append", "--id", "B2"
    )
    assert res.returncode == 0 and "now holds 3 trial(s): A, B, B2" in res.stdout


# -- data show --plot -----------------------------------------------------------------
def _force_lines(ax):
    return [line for line in ax.get_lines() if line.get_label().startswith("T")]


def test_every_trial_has_its_own_colour_and_the_legend_names_its_user():
    trials = [
        small_trial("T01", "U1"),
        small_trial("T02", "U1"),  # the same user: the old figure drew both alike
        small_trial("T03", "U2"),
        small_trial("T04", "U1", kind="unlock", theta=np.full(400, 1.5)),
    ]
    fig = trials_figure(trials)
    impulse = fig.axes[1]  # force row, second column (unlock first)
    lines = _force_lines(impulse)
    assert [line.get_label() for line in lines] == ["T01 (U1)", "T02 (U1)", "T03 (U2)"]
    colours = {line.get_label(): line.get_color() for line in lines}
    colours.update({line.get_label(): line.get_color() for line in _force_lines(fig.axes[0])})
    assert len(set(colours.values())) == 4
    # many trials: still distinct within each column
    many = [small_trial(f"T{i:02d}", f"U{i % 3}") for i in range(14)]
    assert len(set(trial_colors(many, ["impulse"]).values())) == 14


def test_the_figure_explains_its_line_styles():
    """Solid measured, dashed derived, dotted range limit, triangles force peaks."""
    trials = read_trials(ROOT / "experiments" / "data" / "default.h5", ["T01", "T02", "T04"])
    fig = trials_figure(trials)
    (key,) = fig.legends
    texts = [t.get_text() for t in key.get_texts()]
    assert texts == [STYLE_KEY[k] for k in ("measured", "derived", "limit", "peak")]
    assert texts[0].startswith("solid: measured") and texts[2].startswith("dotted: sensor range")
    assert "gyroscope" in texts[1] and "inclinometer" in texts[1]
    styles = [h.get_linestyle() for h in key.legend_handles]
    assert styles[:3] == ["-", "--", ":"] and key.legend_handles[3].get_marker() == "^"
    # only what the figure shows is explained: impulse trials alone have no peaks
    (key,) = trials_figure(trials[:1]).legends
    assert not any(t.get_text().startswith("triangle") for t in key.get_texts())


def test_data_show_writes_the_figure(tmp_path, capsys):
    write_trials(tmp_path / "t.h5", [small_trial("T01"), small_trial("T02")])
    res = cli(capsys, "data", "show", tmp_path / "t.h5", "--plot", tmp_path / "t.png")
    assert res.returncode == 0 and (tmp_path / "t.png").stat().st_size > 10_000


# -- curve --plot ---------------------------------------------------------------------
def test_curve_zoom_panel_has_a_force_label():
    from evo_door.commands.curve import curve_figure

    theta = np.linspace(0, np.pi / 2, 11)
    curve = {"theta": theta, "opening": -theta, "closing": theta}
    fig = curve_figure(curve, zoom=curve)
    main, zoom = fig.axes
    assert zoom.get_ylabel() == "user force at the handle [N]"
    assert main.get_ylabel().startswith("user force at the handle [N]")


def test_curve_command_draws_the_zoom_for_the_door(tmp_path, capsys):
    res = cli(
        capsys,
        "curve",
        "door",
        "--points",
        "50",
        "--out",
        tmp_path / "c.csv",
        "--plot",
        tmp_path / "c.png",
    )
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "c.png").stat().st_size > 10_000


# -- the bundled data set ---------------------------------------------------------------
def test_rig_records_a_preset_by_name():
    from evo_door.data.rig import params_source
    from evo_door.models import get_model

    door = get_model("door")
    assert params_source(door, door.load_params("default")) == "default"
    changed = door.load_params("default", {"M": 1.5})
    assert params_source(door, changed) == "default, changed: M=1.5"
    assert params_source(door, door.load_params(None)) == "defaults"
    # --set on the declared defaults says what was set (it said "defaults")
    both = door.load_params(None, {"M": 1.2, "K": 450.0})
    assert params_source(door, both) == "defaults, changed: K=450, M=1.2"


def test_rig_records_a_users_file_by_its_path(tmp_path):
    from evo_door.data.rig import params_source
    from evo_door.models import get_model

    door = get_model("door")
    mine = tmp_path / "default.yaml"  # a preset's name, but the user's own file
    mine.write_text(door.load_params("default").to_yaml())
    assert params_source(door, door.load_params(str(mine))) == str(mine)
    assert params_source(door, door.load_params(str(mine), {"M": 2.0})) == f"{mine}, changed: M=2"


def test_bundled_data_names_its_preset():
    with h5py.File(ROOT / "experiments" / "data" / "default.h5") as f:
        assert "/" not in f.attrs["description"]
        assert {g["truth"].attrs["params_source"] for g in f["trials"].values()} == {"default"}


def test_rig_file_is_the_same_bytes_from_any_folder(tmp_path, capsys):
    """What experiments/data/README.md promises, on a one-trial campaign."""
    outs = []
    cwd = os.getcwd()
    try:
        for name in ("a", "b"):
            folder = tmp_path / name
            folder.mkdir()
            os.chdir(folder)
            args = ["rig", "generate", "--model", "door", "--params", "default"]
            res = cli(capsys, *args, "--users", "1", "--trials", "1", "--out", "t.h5")
            assert res.returncode == 0, res.stderr
            outs.append((folder / "t.h5").read_bytes())
    finally:
        os.chdir(cwd)
    assert outs[0] == outs[1]
