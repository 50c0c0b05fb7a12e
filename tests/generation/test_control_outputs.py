"""`biomotion generate --control` writes control.json and control.png/.svg: the reach example, a short real run
with the shipped weights, its hand path measured from the written motion.mot."""

from __future__ import annotations

import json

import pytest

from biomotion.cli import main
from biomotion.generation.pipeline import CHECKPOINTS, GENERATOR_FILE, SURROGATE_FILE, TOKENIZER_FILE
from tests.conftest import REPO, data_path

REACH = REPO / "examples/control/reach_hand_path.yaml"


@pytest.fixture(scope="module")
def shipped():
    missing = [f for f in (TOKENIZER_FILE, GENERATOR_FILE, SURROGATE_FILE) if not (CHECKPOINTS / f).exists()]
    if missing:
        pytest.skip(f"shipped weights absent: {missing} not in {CHECKPOINTS}")
    return data_path(".")


def test_a_controlled_generation_writes_its_targets_against_what_it_achieved(shipped, tmp_path, capsys):
    from biomotion.generation.outputs import write_control
    from biomotion.guidance.control import Control

    out = tmp_path / "reach"
    args = ["generate", "--action", "static", "--seconds", "2", "--seed", "0", "--threads", "1"]
    assert main([*args, "--data-root", str(shipped), "--control", str(REACH), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "control_json" in printed and "plot_control" in printed
    for name in ("control.json", "control.png", "control.svg"):
        assert (out / name).is_file(), name
    record = json.loads((out / "control.json").read_text())
    assert record["spec"] == str(REACH) and record["targets"] == 1
    (target,) = record["per_target"]
    assert (target["quantity"], target["kind"], target["body"]) == ("joint_position", "path", "hand_r")
    assert len(target["achieved"]) == len(target["target"]) == 5
    assert target["met"] is True and record["all_met"] is True
    assert target["largest_distance_m"] < 0.02  # docs/control.md: 0.001 m with seed 0
    # the same targets on a clip generated without control (its start: the standing clip, hand at the side)
    free = tmp_path / "free"
    assert main([*args, "--no-figures", "--data-root", str(shipped), "--out", str(free)]) == 0
    assert not (free / "control.json").exists()
    files = write_control(free, Control.load(REACH), figures=False)
    assert list(files) == ["control_json"]
    uncontrolled = json.loads((free / "control.json").read_text())["per_target"][0]
    assert uncontrolled["met"] is False and uncontrolled["largest_distance_m"] > 0.1
