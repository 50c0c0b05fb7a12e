"""The motion-text evaluator: features, shapes, padding invariance, the contrastive loss, a training step, I/O."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.errors import ModelError
from biomotion.models import motion_text_evaluator as E

TX, TZ, HEADING = (CANONICAL_COORDINATES.index(n) for n in ("pelvis_tx", "pelvis_tz", "pelvis_rotation"))
SMALL = E.EvaluatorConfig(width=16, depth=2, embed_dim=8, text_hidden=16, dropout=0.0)


def _clip(frames: int = 40, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[:, None] / 30.0
    return np.sin(2 * np.pi * (0.5 + rng.random(39)) * t + rng.random(39)) * 0.3 + rng.normal(0, 0.01, (frames, 39))


def test_clip_features_have_the_documented_layout_and_mark_absent_coordinates():
    clip = _clip()
    mask = np.ones(39, bool)
    mask[CANONICAL_COORDINATES.index("knee_angle_r")] = False
    features = E.clip_features(clip, mask, 30.0)
    assert features.shape == (40, E.N_FEATURES) and E.N_FEATURES == 36 + 39
    absent = np.isnan(features).all(0)
    assert absent.sum() == 2  # the knee's value and its velocity
    assert np.all(np.isfinite(features[:, ~absent]))
    with pytest.raises(ModelError):
        E.clip_features(clip[:, :30], None, 30.0)


def test_clip_features_do_not_depend_on_where_the_clip_starts_or_faces():
    """Turning the whole clip about the vertical and moving it leaves the features as they were."""
    clip = _clip(seed=1)
    clip[:, TX] = np.linspace(0, 2, 40)  # walking along x
    clip[:, TZ] = 0.1 * np.sin(np.linspace(0, 6, 40))
    clip[:, HEADING] = 0.2 * np.sin(np.linspace(0, 3, 40))
    turned = clip.copy()
    angle = 1.1
    # R_y(angle) applied to the pelvis path: x' = c x + s z, z' = -s x + c z, heading + angle
    turned[:, TX] = np.cos(angle) * clip[:, TX] + np.sin(angle) * clip[:, TZ] + 3.0
    turned[:, TZ] = -np.sin(angle) * clip[:, TX] + np.cos(angle) * clip[:, TZ] - 1.0
    turned[:, HEADING] = clip[:, HEADING] + angle
    np.testing.assert_allclose(E.clip_features(turned, None, 30.0), E.clip_features(clip, None, 30.0), atol=1e-4)


def test_embeddings_have_unit_length_and_ignore_the_padding():
    model = E.MotionTextEvaluator(SMALL).eval()
    clips = [E.clip_features(_clip(n, seed=n), None, 30.0) for n in (20, 35, 50)]
    x, valid = E.pad_features(clips)
    assert x.shape == (3, 50, E.N_FEATURES) and valid.sum(1).tolist() == [20, 35, 50]
    with torch.no_grad():
        together = model.encode_motion(x, valid)
        alone = model.encode_motion(*E.pad_features(clips[:1]))
    assert together.shape == (3, 8)
    torch.testing.assert_close(together.norm(dim=-1), torch.ones(3))
    torch.testing.assert_close(together[:1], alone, atol=1e-5, rtol=0)
    text = model.encode_text(torch.randn(5, E.TEXT_DIM))
    assert text.shape == (5, 8)
    torch.testing.assert_close(text.norm(dim=-1), torch.ones(5))
    with pytest.raises(ModelError):
        model.encode_motion(x[..., :10], valid)
    with pytest.raises(ModelError):
        model.encode_text(torch.randn(5, 10))


def test_contrastive_loss_counts_equal_texts_as_positives():
    """Motions on their texts, two rows sharing a text: the multi-positive loss is the entropy of splitting the
    target between the two equal texts (log 2 over those rows) and near 0 elsewhere at a low temperature."""
    table = torch.nn.functional.normalize(torch.eye(4)[:3], dim=-1)
    ids = torch.tensor([0, 0, 1, 2])
    embeddings = table[ids]
    loss = E.contrastive_loss(embeddings, embeddings, ids, temperature=0.01)
    assert float(loss) == pytest.approx(0.5 * np.log(2), abs=1e-4)  # rows 0 and 1 of 4: (2 log 2) / 4
    swapped = E.contrastive_loss(embeddings, table[torch.tensor([1, 1, 0, 2])], ids, temperature=0.01)
    assert float(swapped) > 10 * float(loss)


def test_a_few_training_steps_lower_the_loss_on_a_tiny_batch():
    torch.manual_seed(0)
    model = E.MotionTextEvaluator(SMALL)
    clips = [E.clip_features(_clip(30, seed=s), None, 30.0) for s in range(6)]
    model.set_normalisation(clips)
    x, valid = E.pad_features(clips)
    sentences = torch.nn.functional.normalize(torch.randn(3, E.TEXT_DIM), dim=-1)
    ids = torch.tensor([0, 0, 1, 1, 2, 2])
    optimiser = torch.optim.AdamW(model.parameters(), lr=3e-3)
    before = model(x, valid, sentences[ids], ids).item()
    for _ in range(30):
        loss = model(x, valid, sentences[ids], ids)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    assert model(x, valid, sentences[ids], ids).item() < 0.5 * before


def test_set_normalisation_uses_present_frames_only():
    model = E.MotionTextEvaluator(SMALL)
    clips = [E.clip_features(_clip(30, seed=s), None, 30.0) for s in range(2)]
    clips[1][:, 0] = np.nan  # absent in the second clip
    model.set_normalisation(clips)
    assert float(model.mean[0]) == pytest.approx(float(clips[0][:, 0].mean()), abs=1e-6)


def test_save_and_load_give_the_same_embeddings(tmp_path):
    model = E.MotionTextEvaluator(SMALL)
    model.set_normalisation([E.clip_features(_clip(30), None, 30.0)])
    path = tmp_path / "evaluator.safetensors"
    model.save(path)
    loaded = E.MotionTextEvaluator.load(path)
    assert loaded.config == SMALL and not loaded.training
    clips = [_clip(25, seed=3), _clip(60, seed=4)]
    np.testing.assert_allclose(
        E.embed_motions(loaded, clips, rate=30.0), E.embed_motions(model, clips, rate=30.0), atol=1e-6
    )
    from safetensors.torch import save_file

    save_file({"w": torch.zeros(1)}, str(tmp_path / "other.safetensors"))
    with pytest.raises(ModelError, match="not motion-text evaluator weights"):
        E.MotionTextEvaluator.load(tmp_path / "other.safetensors")


def test_clip_text_falls_back_to_action_and_style():
    assert E.clip_text({"action": "walk", "style": "happy", "text": None}) == "walk, happy"
    assert E.clip_text({"action": "run", "style": None, "text": "run at 3 m/s"}) == "run at 3 m/s"


def test_the_shipped_evaluator_loads_with_the_configs_sizes():
    import json
    from pathlib import Path

    import yaml

    root = Path(__file__).resolve().parents[2]
    weights = root / "checkpoints" / "evaluator.safetensors"
    if not weights.exists():
        pytest.skip("no shipped evaluator weights")
    model = E.MotionTextEvaluator.load(weights)
    config = yaml.safe_load((root / "configs" / "evaluator.yaml").read_text())
    assert model.config == E.EvaluatorConfig.from_dict(config["model"])
    card = json.loads(weights.with_suffix(".json").read_text())
    assert card["data"]["trained_on"] == "train split only" and card["data"]["subjects_shared_with_held_out"] == 0
    assert card["command"].startswith("biomotion train evaluator --config configs/evaluator.yaml")
    assert not any(word.startswith("/") for word in card["command"].split())
