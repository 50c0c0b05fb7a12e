"""Time-warped training copies (`biomotion data augment`): on a cache of the Hamner runs (all training subjects)."""

import json

import numpy as np
import pytest

from biomotion.cli import main
from biomotion.data.augment import augmented_cache
from biomotion.data.registry import DatasetCache, build_cache
from biomotion.errors import ConfigError


@pytest.fixture(scope="module")
def hamner(tmp_path_factory, data_root):
    out = tmp_path_factory.mktemp("hamner")
    build_cache(data_root, out, sources=["hamner"], progress=False)
    return DatasetCache(out)


def test_copies_replay_each_training_clip_faster_and_slower(tmp_path, hamner):
    out = tmp_path / "warped"
    assert (
        main(
            [
                "data",
                "augment",
                "--cache",
                str(hamner.folder),
                "--out",
                str(out),
                "--time-warp",
                "0.8",
                "1.25",
                "--quiet",
            ]
        )
        == 0
    )
    warped = DatasetCache(out)
    train = hamner.indices(split="train")
    assert len(train) == len(hamner) == 6  # Hamner's three subjects all hash to train
    assert len(warped) == len(hamner) + 2 * len(train)
    assert warped.manifest["augmentation"] == {
        "time_warp": [0.8, 1.25],
        "posture_copies": 0,
        "seed": 0,
        "split": "train",
        "sources": "all",
        "from": str(hamner.folder),
        "copies": 12,
    }
    for i in range(len(hamner)):  # the originals unchanged, first
        assert warped.records[i] == hamner.records[i]
        np.testing.assert_array_equal(warped.motion(i).values, hamner.motion(i).values)
    original = hamner.motion(0)
    for factor, copy_index in ((0.8, len(hamner)), (1.25, len(hamner) + 1)):
        record, copy = warped.records[copy_index], warped.motion(copy_index)
        assert record["clip_id"] == f"{hamner.records[0]['clip_id']}@x{factor:g}"
        assert record["split"] == "train" and record["subject"] == hamner.records[0]["subject"]
        assert record["labels"]["speed"] == pytest.approx(hamner.records[0]["labels"]["speed"] * factor)
        assert copy.duration == pytest.approx(original.duration / factor, abs=1.0 / hamner.rate)
        # a pose the original passes at time t, the copy passes at t / factor (cubic resampling of smooth data)
        probe = original.times[::7][1:-1]
        expected = original.values[::7][1:-1]
        got = np.stack(
            [
                np.interp(original.times[0] + (probe - original.times[0]) / factor, copy.times, copy.values[:, k])
                for k in range(copy.values.shape[1])
            ],
            1,
        )
        rotations = [k for k, name in enumerate(copy.names) if not name.startswith("pelvis_t")]
        assert np.abs(got - expected)[:, rotations][:, copy.mask[rotations]].max() < np.radians(3.0)
        forward = np.diff(copy.values[[0, -1], 3])[0] / copy.duration
        assert forward == pytest.approx(np.diff(original.values[[0, -1], 3])[0] / original.duration * factor, rel=0.03)
    counts = json.loads((out / "manifest.json").read_text())["counts"]
    assert counts["clips"] == len(warped) and counts["per_split"] == {"train": 18}


def test_copies_of_named_sources_only(tmp_path, hamner):
    manifest = augmented_cache(hamner.folder, tmp_path / "named", [1.1], sources=["hamner"], progress=False)
    assert manifest["augmentation"]["sources"] == ["hamner"] and manifest["augmentation"]["copies"] == 6
    with pytest.raises(ConfigError, match="no clips of source.s. fukuchi"):
        augmented_cache(hamner.folder, tmp_path / "none", [1.1], sources=["hamner", "fukuchi"], progress=False)
    assert not (tmp_path / "none").exists()


def test_bad_factors_and_same_folder_are_refused(tmp_path, hamner):
    with pytest.raises(ConfigError, match="positive and not 1"):
        augmented_cache(hamner.folder, tmp_path / "x", [1.0])
    with pytest.raises(ConfigError, match="positive and not 1"):
        augmented_cache(hamner.folder, tmp_path / "x", [-0.5])
    with pytest.raises(ConfigError, match="must differ"):
        augmented_cache(hamner.folder, hamner.folder, [1.1])
    with pytest.raises(ConfigError, match="no 'val' clips"):
        augmented_cache(hamner.folder, tmp_path / "x", [1.1], split="val")


def test_posture_copies_through_the_command(tmp_path, hamner, data_root):
    out = tmp_path / "posture"
    assert (
        main(
            [
                "data",
                "augment",
                "--cache",
                str(hamner.folder),
                "--out",
                str(out),
                "--time-warp",
                "--posture-copies",
                "1",
                "--seed",
                "3",
                "--data-root",
                str(data_root),
                "--quiet",
            ]
        )
        == 0
    )
    posed = DatasetCache(out)
    assert len(posed) == 2 * len(hamner)
    tilt = hamner.coordinates.index("pelvis_tilt")
    for i in range(len(hamner)):
        record, original = posed.records[len(hamner) + i], hamner.motion(i)
        assert record["clip_id"] == f"{hamner.records[i]['clip_id']}@posture1"
        offsets = record["augmentation"]["posture_deg"]
        assert set(offsets) >= {"pelvis_tilt", "hip_rotation_r"} and all(abs(v) <= 8.0 for v in offsets.values())
        copy = posed.motion(len(hamner) + i)
        turned = copy.values[:, tilt] - original.values[:, tilt]  # offsets kept to 1e-3 deg, values in float32
        np.testing.assert_allclose(turned, np.radians(offsets["pelvis_tilt"]), atol=2e-5)
        np.testing.assert_array_equal(copy.mask, original.mask)
    with pytest.raises(ConfigError, match="nothing to add"):
        augmented_cache(hamner.folder, tmp_path / "y", [])
