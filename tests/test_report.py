"""The HTML report: self-contained, every section, and the perceptual check's numbers."""

import base64
import re

import numpy as np
import pytest

from evo_door.errors import UserError
from evo_door.experiment.pipeline import PipelineRun, load_pipeline
from evo_door.perception import JND, perceptual_check
from evo_door.reporting.report import JNDChanges, write_report
from tests.test_cli import cli
from tests.test_pipeline import PIPELINE, folder  # noqa: F401  (the fixture)


@pytest.fixture()
def pipeline_file(folder):  # noqa: F811
    pipe = load_pipeline(folder / "pipe.yaml")
    return PipelineRun.create(pipe, folder / "p.h5").run().path


@pytest.mark.slow
def test_the_page_needs_nothing_but_itself(pipeline_file, tmp_path, capsys):
    res = cli(capsys, "report", pipeline_file, "--out", tmp_path / "rep")
    assert res.returncode == 0, res.stderr
    page = (tmp_path / "rep" / "report.html").read_text()
    # no network, no file beside it: every image is inline, no external reference
    assert not re.search(r"""(src|href)=["'](https?:|//|[^"'#d])""", page)
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    pngs = sorted((tmp_path / "rep").glob("*.png"))
    assert len(images) == len(pngs) >= 6
    for data in images:
        assert base64.b64decode(data)[:8] == b"\x89PNG\r\n\x1a\n"
    for stage in ("first", "second"):
        assert f'id="stage-{stage}"' in page
        assert f"{stage}-convergence.png" in {p.name for p in pngs}
    assert "identifiability at the estimate" in page and "correlation" in page
    assert "seed table 5.4" in page


def test_the_perceptual_check_finds_the_angles_beyond_the_jnd():
    theta = np.linspace(0.0, 1.5, 301)
    chosen = {"theta": theta, "opening": -5.0 + 0 * theta, "closing": 5.0 + 0 * theta}
    # the mechanism is 20 % stronger between 0.5 and 0.8 rad, 5 % elsewhere
    scale = np.where((theta >= 0.5) & (theta <= 0.8), 1.2, 1.05)
    mech = {
        "theta": theta[::2],
        "opening": (chosen["opening"] * scale)[::2],
        "closing": (chosen["closing"] * scale)[::2],
    }
    check = perceptual_check(mech, chosen, JND(force=0.10))
    for d in ("opening", "closing"):
        c = check[d]
        assert len(c["bands"]) == 1
        lo, hi = c["bands"][0]
        assert lo == pytest.approx(0.5, abs=0.011) and hi == pytest.approx(0.8, abs=0.011)
        assert c["fraction"] == pytest.approx(0.3 / 1.5, abs=0.02)
        assert abs(c["worst"][1]) == pytest.approx(1.0)  # 20 % of 5 N
    # a looser JND passes everywhere; below the floor the JND is the floor, an absolute
    # 0.5 N (not 10 % of it): 0.45 N off a 0.1 N force passes, 0.55 N does not
    assert not perceptual_check(mech, chosen, JND(force=0.25))["opening"]["fails"].any()
    small = {"theta": theta, "opening": 0 * theta - 0.1, "closing": 0 * theta + 0.1}
    near = {"theta": theta, "opening": 0 * theta - 0.55, "closing": 0 * theta + 0.55}
    far = {"theta": theta, "opening": 0 * theta - 0.65, "closing": 0 * theta + 0.65}
    assert not perceptual_check(near, small, JND())["closing"]["fails"].any()
    far_check = perceptual_check(far, small, JND())["closing"]
    # every point of the stroke fails; the latch zone (the last 3 deg) is judged by its
    # peak and its angle instead, never point by point
    assert np.array_equal(far_check["fails"], far_check["stroke"])
    assert far_check["stroke"].any() and not far_check["stroke"].all()


def test_bad_settings_and_unfinished_runs_are_refused(pipeline_file, tmp_path):
    with pytest.raises(UserError, match="--jnd 1.5"):
        write_report(pipeline_file, tmp_path / "a", JNDChanges(jnd=1.5))
    with pytest.raises(UserError, match="--force-floor 0"):
        write_report(pipeline_file, tmp_path / "a", JNDChanges(force_floor=0.0))
    (tmp_path / "afile").write_text("x")
    with pytest.raises(UserError, match="not a folder"):
        write_report(pipeline_file, tmp_path / "afile")


def test_the_pipeline_file_sets_the_jnd_and_the_command_line_wins(folder, tmp_path):  # noqa: F811
    from evo_door.experiment.pipeline_status import pipeline_summary
    from evo_door.reporting.report import pipeline_settings

    (folder / "pipe.yaml").write_text(
        PIPELINE.replace("name: two\n", "name: two\nreport: {jnd: 0.2}\n")
    )
    path = PipelineRun.create(load_pipeline(folder / "pipe.yaml"), folder / "j.h5").run().path
    summary = pipeline_summary(path)
    assert pipeline_settings(path, summary).jnd == 0.2
    assert pipeline_settings(path, summary, jnd=0.05).jnd == 0.05
    # no report: key and no flag: each run's own perception settings are kept
    assert pipeline_settings(path, None) == JNDChanges()
    # the pipeline's report.jnd replaces the force fraction of the stages' own JND,
    # the floor stays theirs
    from evo_door.perception import JND

    changes = pipeline_settings(path, summary, force_floor=2.0)
    assert changes.apply(JND()) == JND(force=0.2, force_floor=2.0)


@pytest.mark.slow
def test_a_stage_without_a_genetic_algorithm_is_reported_without_its_convergence(
    folder,  # noqa: F811
    tmp_path,
):
    """SLSQP alone (``kind: nlpql``, the case study's redesign) has no generations to
    draw: the report says so and draws the rest."""
    text = (folder / "pipe.yaml").read_text()
    (folder / "pipe.yaml").write_text(
        text.replace("seed: 2, polish: slsqp}", "seed: 2, kind: nlpql}")
    )
    pipe = load_pipeline(folder / "pipe.yaml")
    path = PipelineRun.create(pipe, folder / "nlpql.h5").run().path
    page = write_report(path, tmp_path / "rep").read_text()
    assert "second: nlpql (SLSQP) without a genetic algorithm" in page
    names = {p.name for p in (tmp_path / "rep").glob("*.png")}
    assert "first-convergence.png" in names and "second-convergence.png" not in names
