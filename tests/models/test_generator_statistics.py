"""Per-action statistics of a generator bundle (`action_bounds`, `train_generator.refresh_statistics`) on a cache
of the Hamner runs: six training clips at 2, 3, 4 and 5 m/s."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.data.clips import body_model
from biomotion.data.registry import DatasetCache, build_cache
from biomotion.errors import ConfigError
from biomotion.models.actions import ActionVocabulary
from biomotion.models.bundle import GeneratorBundle, action_bounds
from biomotion.models.conditioning import action_size
from biomotion.models.prior import PriorConfig, ProfileActionPrior
from biomotion.training.train_generator import refresh_statistics

KNEE = CANONICAL_COORDINATES.index("knee_angle_r")


@pytest.fixture(scope="module")
def hamner(tmp_path_factory, data_root):
    out = tmp_path_factory.mktemp("hamner")
    build_cache(data_root, out, sources=["hamner"], progress=False)
    return DatasetCache(out)


@pytest.fixture(scope="module")
def bounds(hamner, data_root):
    return action_bounds(hamner, body_model(data_root), list(range(len(hamner))))


def test_the_population_posture_is_the_line_through_the_clip_means_in_speed(hamner, bounds):
    speeds = np.array([r["labels"]["speed"] for r in hamner.records])
    knees = np.array([hamner.motion(i).values[:, KNEE].mean() for i in range(len(hamner))])
    slope, at_mean = np.polyfit(speeds - speeds.mean(), knees, 1)
    run = bounds["run"]
    assert run.posture_speed == pytest.approx(speeds.mean())
    assert run.posture[KNEE] == pytest.approx(at_mean, abs=1e-9)
    assert run.posture_slope[KNEE] == pytest.approx(slope, abs=1e-9)
    assert slope > 0  # the Hamner runners bend the knee more the faster they run
    assert not any(bounds["*"].posture_slope)  # speeds of different actions are not one line


def _bundle(hamner, bounds) -> GeneratorBundle:
    vocabulary = ActionVocabulary.from_labels([r["labels"] for r in hamner.records])
    prior = ProfileActionPrior(
        PriorConfig(
            codebook_size=16, code_dim=8, action_size=action_size(vocabulary), width=16, layers=1, heads=2, max_tokens=8
        )
    ).eval()
    return GeneratorBundle(prior, vocabulary, bounds, "tokenizer-sha", ("hamner/subject01",))


def test_statistics_are_added_to_a_trained_bundle_only_from_the_cache_it_was_trained_on(
    tmp_path, hamner, bounds, data_root
):
    without_postures = {
        k: replace(b, posture=(), posture_slope=(), posture_speed=float("nan")) for k, b in bounds.items()
    }
    path = tmp_path / "generator.safetensors"
    _bundle(hamner, without_postures).save(path)
    assert GeneratorBundle.load(path).posture("run") is None
    card = refresh_statistics({"train": {"dev_fraction": 0.0}}, hamner.folder, data_root, path, command="refresh")
    refreshed = GeneratorBundle.load(path)
    assert refreshed.posture("run", 5.0)[KNEE] == pytest.approx(
        bounds["run"].posture[KNEE] + bounds["run"].posture_slope[KNEE] * (5.0 - bounds["run"].posture_speed)
    )
    assert refreshed.train_subjects == ("hamner/subject01",) and refreshed.tokenizer_sha256 == "tokenizer-sha"
    assert card["statistics_command"] == "refresh"

    other = {k: replace(b, speed_high=tuple(2 * v for v in b.speed_high)) for k, b in bounds.items()}
    _bundle(hamner, other).save(path)
    before = path.read_bytes()
    with pytest.raises(ConfigError, match="does not give the bounds stored"):
        refresh_statistics({"train": {"dev_fraction": 0.0}}, hamner.folder, data_root, path)
    assert path.read_bytes() == before  # nothing written
