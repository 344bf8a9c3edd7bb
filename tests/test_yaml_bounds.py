"""YAML within bounds: a file cannot make evo-door build billions of values, recurse or
nest without end (part of issue 37). Each is one line naming the file and its line;
before, an alias bomb took 5.4 GB and deep nesting printed some 3000 traceback lines."""

from __future__ import annotations

import time

import pytest

from evo_door.errors import UserError
from evo_door.experiment import load_experiment
from evo_door.params import load_params
from evo_door.yaml_numbers import MAX_ALIASES, MAX_DEPTH

BOMB = "a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{c}: &{c} [{', '.join([f'*{p}'] * 10)}]\n" for p, c in zip("abcdefgh", "bcdefghi")
)


@pytest.mark.parametrize(
    "text, words",
    [
        (BOMB + "model: door\n", "expands to more than"),
        ("a: &a [1, *a]\n", "recursive alias"),
        ("x: " + "[" * (MAX_DEPTH + 10) + "1" + "]" * (MAX_DEPTH + 10) + "\n", "nested more than"),
        ("x: " + "[" * 20000 + "]" * 20000 + "\n", "nested more than"),
        ("a: &a 1\nb: [" + ", ".join(["*a"] * (MAX_ALIASES + 1)) + "]\n", "aliases"),
    ],
)
def test_an_experiment_beyond_the_bounds_is_one_line_quickly(tmp_path, text, words):
    path = tmp_path / "exp.yaml"
    path.write_text(text)
    t0 = time.perf_counter()
    with pytest.raises(UserError) as got:
        load_experiment(path)
    assert time.perf_counter() - t0 < 5.0
    message = str(got.value)
    assert "\n" not in message and "exp.yaml" in message and words in message, message


def test_a_parameter_file_with_a_recursive_alias_is_one_line(tmp_path):
    from evo_door.models import get_model

    path = tmp_path / "p.yaml"
    path.write_text("values: &v {K: 400.0, more: *v}\n")
    with pytest.raises(UserError) as got:
        load_params(get_model("door").params, str(path))
    assert "\n" not in str(got.value) and "recursive alias" in str(got.value)


def test_the_case_studys_anchor_and_alias_still_read():
    from evo_door.experiment.pipeline import load_pipeline

    pipe = load_pipeline("experiments/case_study.yaml")  # target: &chosen ... *chosen
    assert pipe.stage("redesign").experiment.target.model == "haptic"
