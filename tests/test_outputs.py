"""What a command may write over (evo_door.files.claim_outputs), the allowed paths.

The refusals (a trial file without --force, an output that is an input) are in the
every-command table of tests/test_bad_input.py; here: --force replaces a trial file,
--append extends it, a derived output is replaced and the command says so, and
simulate points out a response that leaves the model's range.
"""

import os

import numpy as np
import pytest

from evo_door.data import read_trials, write_trials
from evo_door.errors import UserError
from evo_door.files import DERIVED, TRIALS, Output, claim_outputs, same_file
from tests.test_cli import cli
from tests.test_optim import make_trial


def _replaced_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("evo-door: replaced")]


@pytest.fixture
def trials(tmp_path):
    path = tmp_path / "trials.h5"
    write_trials(path, [make_trial(1, 0.75, tid="t1")])
    return path


def test_force_replaces_a_trial_file_and_says_so(trials, tmp_path, capsys):
    source = tmp_path / "new.h5"
    write_trials(source, [make_trial(2, 0.75, tid="t2")])
    refused = cli(capsys, "data", "import", source, "--out", trials)
    assert refused.returncode == 2 and [t.trial_id for t in read_trials(trials)] == ["t1"]
    forced = cli(capsys, "data", "import", source, "--out", trials, "--force")
    assert forced.returncode == 0, forced.stderr
    assert [t.trial_id for t in read_trials(trials)] == ["t2"]
    assert _replaced_lines(forced.stderr) == [f"evo-door: replaced {trials}"]


def test_append_still_extends_a_trial_file_without_force(trials, tmp_path, capsys):
    source = tmp_path / "new.h5"
    write_trials(source, [make_trial(2, 0.75, tid="t2")])
    res = cli(capsys, "data", "import", source, "--out", trials, "--append")
    assert res.returncode == 0, res.stderr
    assert [t.trial_id for t in read_trials(trials)] == ["t1", "t2"]
    assert res.stderr == ""  # nothing was replaced


def test_rig_generate_replaces_a_trial_file_only_with_force(trials, capsys):
    before = trials.read_bytes()
    args = ["rig", "generate", "--model", "door", "--trials", "1", "--out", trials]
    refused = cli(capsys, *args)
    assert refused.returncode == 2 and "--force" in refused.stderr
    assert trials.read_bytes() == before
    forced = cli(capsys, *args, "--force")
    assert forced.returncode == 0, forced.stderr
    assert trials.read_bytes() != before
    assert _replaced_lines(forced.stderr) == [f"evo-door: replaced {trials}"]


def _force_csv(path, force_n, n=1024, rate=1024.0):
    t = np.arange(n) / rate
    path.write_text("t,force\n" + "".join(f"{a:.8f},{force_n:g}\n" for a in t))
    return path


def test_a_derived_output_is_replaced_with_a_note(tmp_path, capsys):
    inp = _force_csv(tmp_path / "f.csv", 5.0)
    out = tmp_path / "o.csv"
    first = cli(capsys, "simulate", "door", "--input", inp, "--out", out)
    assert first.returncode == 0 and first.stderr == "", first.stderr
    out.write_text("stale\n")
    again = cli(capsys, "simulate", "door", "--input", inp, "--out", out)
    assert again.returncode == 0, again.stderr
    assert again.stderr.splitlines() == [f"evo-door: replaced {out}"]
    assert out.read_text().startswith("t,force,theta")


def test_curve_names_both_files_it_replaced(tmp_path, capsys):
    out, plot = tmp_path / "c.csv", tmp_path / "c.png"
    out.write_text("old\n")
    plot.write_bytes(b"old")
    res = cli(capsys, "curve", "door", "--points", "5", "--out", out, "--plot", plot)
    assert res.returncode == 0, res.stderr
    assert res.stderr.splitlines() == [f"evo-door: replaced {out}, {plot}"]


def test_params_write_replaces_a_parameter_file_with_a_note(tmp_path, capsys):
    out = tmp_path / "p.yaml"
    out.write_text("old\n")
    res = cli(capsys, "params", "door", "--set", "M=1.5", "--write", out)
    assert res.returncode == 0 and res.stderr == f"evo-door: replaced {out}\n", res.stderr
    assert "M:" in out.read_text()


# -- the rule itself -------------------------------------------------------------------
def test_same_file_sees_links_and_other_spellings(tmp_path, monkeypatch):
    a = tmp_path / "a.h5"
    a.write_bytes(b"x")
    os.link(a, tmp_path / "hard.h5")
    (tmp_path / "soft.h5").symlink_to(a)
    monkeypatch.chdir(tmp_path)
    for other in ("hard.h5", "soft.h5", "./a.h5", tmp_path / "." / "a.h5"):
        assert same_file(a, other), other
    assert not same_file(a, tmp_path / "missing.h5")
    with pytest.raises(UserError, match="is also an input"):
        claim_outputs([Output("hard.h5")], [a])


def test_a_trial_output_that_does_not_exist_needs_no_force(tmp_path):
    claim = claim_outputs([Output(tmp_path / "t.h5", kind=TRIALS)], [])
    assert claim.replaced == []
    (tmp_path / "t.h5").write_bytes(b"x")
    with pytest.raises(UserError, match="--force to replace it, or another --out"):
        claim_outputs([Output(tmp_path / "t.h5", kind=TRIALS)], [])
    claim = claim_outputs([Output(tmp_path / "t.h5", kind=DERIVED)], [])
    assert claim.replaced == [tmp_path / "t.h5"]


# -- simulate: a response outside the model's range ----------------------------------
def test_simulate_warns_when_a_force_in_kn_drives_the_door_past_closed(tmp_path, capsys):
    inp = _force_csv(tmp_path / "f.csv", 20.0)  # 20 kN read as kN: 20000 N
    out = tmp_path / "o.csv"
    res = cli(capsys, "simulate", "door", "--input", inp, "--map", "force=force:kN", "--out", out)
    assert res.returncode == 0, res.stderr
    (line,) = res.stderr.splitlines()
    assert line.startswith("evo-door: warning: the response reaches 10")
    assert "deg" in line and "past closed" in line and "range 0..90 deg" in line
    # the same force in N stays in the range: nothing said
    quiet = cli(capsys, "simulate", "door", "--input", inp, "--out", tmp_path / "p.csv")
    assert quiet.returncode == 0 and quiet.stderr == "", quiet.stderr


def test_simulate_warns_past_fully_open_too(tmp_path, capsys):
    inp = _force_csv(tmp_path / "f.csv", -2.0)
    args = ["simulate", "haptic", "--input", inp, "--map", "force=force:kN", "--theta0", "1.2"]
    res = cli(capsys, *args, "--out", tmp_path / "o.csv")
    assert res.returncode == 0 and "past fully open" in res.stderr, res.stderr
    assert "deg at t = " in res.stderr


@pytest.mark.parametrize("name", ["door", "haptic"])
def test_a_hands_push_against_a_stop_stays_within_the_warning_margin(name):
    """RANGE_MARGIN's premise: 200 N held against either end stop for 2 s is not warned."""
    from evo_door.commands.simulate import range_warning
    from evo_door.models import get_model
    from evo_door.sim import simulate

    model = get_model(name)
    params = model.load_params(None)
    for force, theta0 in ((200.0, 1.2), (-200.0, 0.3)):
        response = simulate(model, params, np.full(2048, force), 1 / 1024, theta0=theta0)
        assert range_warning(model, response) is None, (force, response.theta.min())
    kn = simulate(model, params, np.full(2048, 2e4), 1 / 1024, theta0=1.2)
    assert "past closed" in range_warning(model, kn)
