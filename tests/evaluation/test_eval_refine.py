"""`biomotion eval refine`: held-out subjects are whoever the weights do not name, on any data root of the shared
layout; scores of corrupted, refined and low-passed clips; the bars and the report."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from biomotion.evaluation.refine import bars, corrupted_real, held_out_clips, markdown, root_residual
from biomotion.models.refiner import Refiner, RefinerConfig

TINY = RefinerConfig(d_model=16, heads=2, encoder_layers=1, decoder_layers=1, feedforward=32, window=16)


@pytest.fixture(scope="module")
def refiner(data_root):
    from biomotion.data.clips import body_model

    model = Refiner.new(TINY, body_model(data_root))
    model.metadata = {"train_subjects": ["schreiber/2014001"], "val_subjects": ["schreiber/2014004"]}
    return model


@pytest.fixture(scope="module")
def small_root(tmp_path_factory, data_root):
    """A data root of the shared layout holding five Schreiber-Moissenet walkers (two of them the refiner's) and
    the models."""
    from tests.conftest import data_path

    root = tmp_path_factory.mktemp("root")
    (root / "opensim-models").symlink_to(data_path("opensim-models"))
    walkers = root / "SchreiberMoissenet2019"
    walkers.mkdir()
    source = data_path("SchreiberMoissenet2019")
    for entry in source.iterdir():
        if entry.is_file() or entry.name in ("2014001", "2014004", "2014007", "2014014", "2014015"):
            (walkers / entry.name).symlink_to(entry)
    return root


@pytest.fixture(scope="module")
def clips(refiner, small_root):
    return held_out_clips(small_root, refiner, max_seconds=10.0, per_subject=1, progress=False)


def test_held_out_clips_are_the_subjects_the_weights_do_not_name(clips):
    subjects = {c.subject for c in clips}
    assert subjects == {"schreiber/2014007", "schreiber/2014014", "schreiber/2014015"} and len(clips) == 3
    for clip in clips:
        assert clip.q.shape[1] == 39 and clip.q.shape[0] >= 8 and bool(clip.mask[3])
        # placed like the training clips: started at the origin
        assert abs(float(clip.q[0, 3])) < 1e-6 and abs(float(clip.q[0, 5])) < 1e-6


def test_scores_of_noisy_refined_and_lowpassed_clips(refiner, clips):
    result = corrupted_real(refiner, clips[:3], seed=0, progress=False)
    means = result["means"]
    assert result["clips"] == 3 and set(means) == {"noisy", "refined", "lowpass"}
    # an untrained refiner returns its input: the refined clip scores as the noisy one
    assert means["refined"]["accl"] == pytest.approx(means["noisy"]["accl"], rel=1e-4)
    assert means["noisy"]["accl"] > 0 and means["noisy"]["mje"] > 0
    assert means["lowpass"]["accl"] < means["noisy"]["accl"]  # jitter is what a low-pass removes
    again = corrupted_real(refiner, clips[:3], seed=0, progress=False)
    assert again["means"] == means  # seeded


def test_root_residual_is_in_body_weights(refiner, clips):
    from biomotion.body.canonical import CANONICAL_COORDINATES
    from biomotion.motion import Motion

    clip = clips[0]
    motion = Motion(
        times=np.arange(len(clip.q)) / 30.0, names=CANONICAL_COORDINATES, values=clip.q.double().numpy(),
        mask=clip.mask.numpy(),
    )  # fmt: skip
    force, moment, both = root_residual(refiner.body.to(torch.float64), motion)
    assert 0 <= force < 2 and 0 <= moment < 2 and max(force, moment) <= both <= force + moment + 1e-9


def test_bars_and_report():
    means = {
        "noisy": {"accl": 30.0, "fs": 0.02, "mje": 0.02, "mje_global": 0.05},
        "refined": {"accl": 6.0, "fs": 0.008, "mje": 0.019, "mje_global": 0.04},
        "lowpass": {"accl": 10.0, "fs": 0.012, "mje": 0.02, "mje_global": 0.05},
    }
    generated = {"means": {}}
    for name, residual, zmp, energy in (("real", 0.1, 0.14, 50.0), ("generated", 0.2, 0.03, 170.0)):
        generated["means"][name] = {"residual_bw": residual, "zmp_in_support": zmp, "energy_body": energy}
    generated["means"]["refined"] = {"residual_bw": 0.09, "zmp_in_support": 0.05, "energy_body": 70.0}
    result = bars({"means": means}, generated, {"median_seconds": 0.2})
    assert result["refine_accl_reduction"]["value"] == pytest.approx(0.8) and result["refine_accl_reduction"]["met"]
    assert result["refine_fs_reduction"]["value"] == pytest.approx(0.6)
    assert result["refine_mje_ratio"]["value"] == pytest.approx(0.95)
    assert result["refine_accl_ratio_to_lowpass"]["value"] == pytest.approx(0.6)
    assert result["refine_generated_residual_ratio"]["value"] == pytest.approx(0.45)
    assert result["refine_generated_zmp_gap_points"]["value"] == pytest.approx(9.0)
    assert result["refine_generated_energy_ratio_to_real"]["value"] == pytest.approx(1.4)
    assert all(row["met"] for row in result.values())
    skipped = bars({"means": means}, {"skipped": "no generator"}, {"median_seconds": 0.9})
    assert skipped["refine_generated_residual_ratio"]["met"] is None
    assert skipped["refine_seconds_per_10s_trial"]["met"] is False
    report = {
        "command": "biomotion eval refine",
        "corrupted_real": {"clips": 2, "subjects": ["a/1"], "seed": 0, "lowpass_cutoff_hz": 5.0, "means": means},
        "generated": {"skipped": "no generator"},
        "speed": {"trial": "x", "threads": 2, "runs": [0.2], "median_seconds": 0.2},
        "bars": skipped,
    }
    text = markdown(report)
    assert "| refined (PhysPT) | 6.000 |" in text and "refine_accl_reduction" in text and not math.isnan(len(text))
