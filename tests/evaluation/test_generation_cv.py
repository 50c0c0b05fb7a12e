"""`biomotion eval generation --folds K`: subject-level folds (no subject on both sides) and a quick run end to end."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from biomotion.errors import ConfigError
from biomotion.evaluation.generation_cv import (
    BARS,
    cv_keys,
    feature_errors,
    fold_cache,
    person_features,
    subject_folds,
)
from biomotion.motion import Motion
from tests.conftest import DATA_ROOT, data_path

SUBJECTS = [f"fukuchi/RBDS{k:03d}" for k in range(23)] + [f"schreiber/s{k}" for k in range(18)] + ["opencap/Subject4"]


def test_folds_cover_every_subject_once_and_balance_sources():
    folds = subject_folds(SUBJECTS, 5)
    flat = [s for f in folds for s in f]
    assert sorted(flat) == sorted(SUBJECTS)  # every subject held out exactly once
    assert len(flat) == len(set(flat))
    for fold in folds:
        training = set(SUBJECTS) - set(fold)
        assert not training & set(fold)  # never on both sides
        assert len(fold) in (8, 9)
        assert sum(s.startswith("fukuchi/") for s in fold) in (4, 5)
    assert subject_folds(list(reversed(SUBJECTS)), 5) == folds  # the order of the input does not matter
    assert subject_folds(SUBJECTS, 5, seed=1) != folds
    with pytest.raises(ConfigError):
        subject_folds(SUBJECTS[:3], 5)


class _Cache:
    """The parts of a `DatasetCache` that `fold_cache` reads."""

    def __init__(self, folder, records):
        self.folder, self.records = folder, records
        self.values = np.zeros((10 * len(records), 39), np.float32)
        self.masks = np.ones((len(records), 39), bool)
        self.manifest = {"clips": records, "counts": {}, "rate_hz": 30.0, "coordinates": []}


def test_fold_cache_marks_held_out_subjects_val_and_nobody_else(tmp_path):
    from biomotion.data.registry import DatasetCache

    records = [
        {
            "clip_id": f"{s}_{k}",
            "source": s.split("/")[0],
            "subject": s.split("/")[1],
            "split": "train",
            "offset": 10 * i,
        }
        for i, (s, k) in enumerate((s, k) for s in SUBJECTS[:6] for k in range(1))
    ]
    for r in records:
        r.update(labels={"action": "run"}, profile={}, n_frames=10, start_time=0.0, file="x")
    held_out = SUBJECTS[:2]
    cache = DatasetCache(fold_cache(_Cache(tmp_path, records), held_out, tmp_path / "fold"))
    sides = {f"{r['source']}/{r['subject']}": r["split"] for r in cache.records}
    assert {s for s, split in sides.items() if split == "val"} == set(held_out)
    assert {s for s, split in sides.items() if split == "train"} == set(SUBJECTS[2:6])
    assert cache.manifest["counts"]["per_split"] == {"val": 2, "train": 4}


def test_person_features_and_errors():
    rate, t = 30.0, np.arange(180) / 30.0
    from biomotion.body.canonical import CANONICAL_COORDINATES as names

    def clip(amplitude: float, frequency: float, speed: float = 3.0) -> Motion:
        q = np.zeros((len(t), 39))
        for side, phase in (("r", 0.0), ("l", np.pi)):
            q[:, names.index(f"knee_angle_{side}")] = 0.6 + amplitude * np.sin(2 * np.pi * frequency * t + phase)
            q[:, names.index(f"hip_flexion_{side}")] = 0.3 * np.sin(2 * np.pi * frequency * t + phase)
        q[:, names.index("pelvis_tx")] = speed * t
        return Motion(times=t, values=q, names=names)

    f = person_features(clip(0.5, 0.9), rate)
    assert f["cadence"] == pytest.approx(0.9, rel=0.05)
    assert f["stride_length"] == pytest.approx(3.0 / 0.9, rel=0.05)
    assert f["range_knee_angle"] == pytest.approx(np.degrees(1.0), rel=0.02)
    assert abs(f["asymmetry_knee_angle"]) < 0.5
    real = [clip(0.5, 1.4), clip(0.7, 1.3), clip(0.3, 1.5)]
    errors = feature_errors({"reference": real, "same": real, "other": [clip(0.9, 1.6)] * 3}, ["run"] * 3, rate)
    assert errors["same"]["mean"] == 0.0
    assert errors["other"]["range_knee_angle"] > 1.0


def test_cv_keys_take_the_worst_fold():
    def fold(real, full, unguided, energy_full):
        return {
            "identity": {"reference": real, "full": full, "no_guidance": unguided},
            "identity_gap_points": 100 * (real - full),
            "identity_full_minus_unguided": full - unguided,
            "energy_ratio_to_real": energy_full / 50.0,
            "energy": {"reference": 50.0, "full": energy_full},
            "zmp_in_support": {"reference": 10.0, "full": 5.0},
            "contacts": {
                k: {"reference": 1.0, "full": 1.0, "no_guidance": 2.0}
                for k in ("foot_contact_velocity", "skate_ratio", "floating", "penetration")
            },
            "diversity": {"reference": 30.0, "full": 35.0},
        }

    keys = cv_keys([fold(0.8, 0.75, 0.7, 60.0), fold(0.9, 0.7, 0.72, 90.0)])
    assert keys["identity_cv_gap_points"] == pytest.approx(20.0)
    assert keys["identity_cv_full_minus_unguided_min"] == pytest.approx(-0.02)
    assert keys["energy_cv_ratio_to_real"] == pytest.approx(1.8)
    assert keys["bars"] == {k: False for k in BARS}


RUNNERS = ("RBDS001", "RBDS002", "RBDS012", "RBDS017")


def test_quick_cross_validation_produces_every_key(tmp_path, capsys):
    from biomotion.cli import main
    from biomotion.generation.pipeline import CHECKPOINTS, GENERATOR_FILE, SURROGATE_FILE

    if not all(
        (CHECKPOINTS / f).exists() for f in (GENERATOR_FILE, SURROGATE_FILE, "tokenizer.json", "generator.json")
    ):
        pytest.skip("shipped generator, surrogate or model cards absent")
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
    out = tmp_path / "cv.json"
    args = [
        "eval",
        "generation",
        "--quick",
        "--data-root",
        str(root),
        "--json",
        str(out),
        "--md",
        str(tmp_path / "cv.md"),
    ]
    assert main([*args, "--cache-dir", str(tmp_path / "cache")]) == 0, capsys.readouterr().err
    report = json.loads(out.read_text())
    assert len(report["folds"]) == 2 and report["subjects"] == 4
    held_out = [set(f) for f in report["folds"]]
    assert not held_out[0] & held_out[1] and held_out[0] | held_out[1] == {f"fukuchi/{r}" for r in RUNNERS}
    for key in BARS:
        assert len(report["per_fold"][key]) == 2 and key in report and key in report["bars"]
    for fold, subjects in zip(report["fold_results"], held_out):
        assert set(fold["subjects"]) == subjects  # targets are the fold's held-out subjects only
        assert {"reference", "full", "no_guidance", "no_personalization"} <= set(fold["identity"])
        assert set(fold["zmp_in_support"]) >= {"reference", "full"}
        assert fold["contacts"]["foot_contact_velocity"]["full"] is not None
        assert fold["diversity"]["full"] is not None and fold["feature_errors"]["full"]["mean"] is not None
    assert "Bars (worst fold)" in (tmp_path / "cv.md").read_text()
    # the fold models are kept where a second run finds them
    assert all((tmp_path / "cache" / "generation_cv").glob(f"*/fold_{f}/fold.json") for f in (0, 1))
