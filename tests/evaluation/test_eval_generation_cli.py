"""`biomotion eval generation` on a data root that holds only other people: every subject there is unseen."""

from __future__ import annotations

import json
import os

import pytest

from biomotion.cli import main
from biomotion.evaluation.generation import VARIANTS
from biomotion.generation.pipeline import CHECKPOINTS, GENERATOR_FILE, POPULATION_FILE, SURROGATE_FILE, TOKENIZER_FILE
from tests.conftest import DATA_ROOT, data_path

RUNNERS = ("RBDS012", "RBDS017")  # held-out (val) runners: the shipped generator never trained on them


def test_eval_generation_on_a_root_of_new_people(tmp_path, capsys):
    missing = [
        f for f in (TOKENIZER_FILE, GENERATOR_FILE, POPULATION_FILE, SURROGATE_FILE) if not (CHECKPOINTS / f).exists()
    ]
    if missing:
        pytest.skip(f"shipped weights absent: {missing}")
    data_path("fukuchi-running/participantInfo.csv")
    root = tmp_path / "root"
    (root / "fukuchi-running").mkdir(parents=True)
    os.symlink(data_path("opensim-models"), root / "opensim-models")
    os.symlink(DATA_ROOT / "fukuchi-running/participantInfo.csv", root / "fukuchi-running/participantInfo.csv")
    for speed in ("T25", "T35", "T45"):
        (root / f"fukuchi-running/ik/{speed}").mkdir(parents=True)
        for runner in RUNNERS:
            name = f"{runner}_{speed}_ik_simple.mot"
            os.symlink(data_path(f"fukuchi-running/ik/{speed}/{name}"), root / f"fukuchi-running/ik/{speed}/{name}")
    out = tmp_path / "eval.json"
    code = main(
        [
            "eval",
            "generation",
            "--data-root",
            str(root),
            "--json",
            str(out),
            "--md",
            str(tmp_path / "e.md"),
            "--max-seconds",
            "2",
            "--manipulation-samples",
            "0",
            "--repeats",
            "2",
        ]
    )
    assert code == 0, capsys.readouterr().err
    report = json.loads(out.read_text())
    assert report["targets"] == 6 and report["subjects"] == 2  # 2 runners x 3 speeds, each the others' reference
    assert set(report["table"]) == set(VARIANTS)
    assert report["table"]["reference"]["speed_error"]["mean"] < 0.05  # the real clips run at their label speed
    assert report["identity"]["subjects"] == 2 and 0.0 <= report["identity"]["full"] <= 1.0
    assert "unseen subjects" in capsys.readouterr().out
    assert report["repeats"] == 2 and report["repeat_seeds"] == [0, 6]
    full = report["table"]["full"]["jerk"]
    assert len(full["repeat_means"]) == 2 and full["count"] == 12  # 6 targets x 2 repeats pooled
    assert abs(full["mean"] - sum(full["repeat_means"]) / 2) < 1e-9 * full["mean"]
    assert report["table"]["reference"]["jerk"]["ci95"] == 0.0  # the real clips are the same in every repeat
    assert len(report["identity"]["per_repeat"]["full"]) == 2
    assert "## Spread over repeats" in (tmp_path / "e.md").read_text()
