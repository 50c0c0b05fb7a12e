"""Training the motion-text evaluator on a tiny cache: weights and card, the training split only, the CLI, and the
held-out report of `biomotion.evaluation.distribution`."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.errors import SettingsError
from biomotion.models.motion_text_evaluator import TEXT_DIM, MotionTextEvaluator, clip_features

CONFIG = {
    "model": {"width": 16, "depth": 2, "embed_dim": 8, "text_hidden": 16, "rate": 30.0, "max_frames": 60},
    "data": {"crop_min": 10, "crop_max": 30},
    "train": {"batch_size": 6, "iterations": 4, "lr": 1e-3, "weight_decay": 0.0, "warmup": 2, "grad_clip": 1.0},
}
TEXTS = ("walk", "run on a treadmill at 3 m/s", "wave right hand, happy")


def _tiny_cache(folder):
    """Eight training clips of three subjects and four held-out clips whose coordinates are offset by +5, so any
    held-out frame in the normalisation would show."""
    from safetensors.numpy import save_file

    rng = np.random.default_rng(0)
    records, chunks, offset = [], [], 0
    for k in range(12):
        split = "train" if k < 8 else ("val" if k < 10 else "test")
        frames = 20 + 7 * k
        values = rng.normal(0, 0.2, (frames, 39)).astype(np.float32) + (5.0 if split != "train" else 0.0)
        chunks.append(values)
        records.append(
            {
                "clip_id": f"src/s{k % 3 if split == 'train' else 10 + k}/c{k}",
                "source": "src",
                "subject": f"s{k % 3}" if split == "train" else f"h{k}",
                "split": split,
                "labels": {"action": "walk", "style": None, "speed": None, "text": TEXTS[k % 3]},
                "profile": {},
                "offset": offset,
                "n_frames": frames,
                "start_time": 0.0,
                "file": f"c{k}.mot",
            }
        )
        offset += frames
    save_file(
        {"values": np.concatenate(chunks), "masks": np.ones((12, 39), np.uint8)}, str(folder / "clips.safetensors")
    )
    manifest = {
        "format": "biomotion-dataset-cache/1",
        "rate_hz": 30.0,
        "coordinates": list(CANONICAL_COORDINATES),
        "split_rule": "test",
        "counts": {"per_split": {"train": 8, "val": 2, "test": 2}},
        "clips": records,
    }
    (folder / "manifest.json").write_text(json.dumps(manifest))
    return chunks


def _sentences(texts):
    """Deterministic stand-in for MiniLM: one fixed random unit vector per text."""
    rows = [
        np.random.default_rng(int(hashlib.sha256(t.encode()).hexdigest()[:8], 16)).normal(size=TEXT_DIM) for t in texts
    ]
    return torch.nn.functional.normalize(torch.tensor(np.array(rows), dtype=torch.float32), dim=-1)


def test_training_writes_weights_and_a_card_from_the_training_split_only(tmp_path):
    from biomotion.training.train_evaluator import train

    chunks = _tiny_cache(tmp_path)
    out = tmp_path / "evaluator.safetensors"
    torch.set_num_threads(1)
    card = train(CONFIG, tmp_path, out, sentence_embeddings=_sentences, progress=False, command="biomotion train x")
    assert card["sha256"] == hashlib.sha256(out.read_bytes()).hexdigest()
    assert json.loads(out.with_suffix(".json").read_text())["command"] == "biomotion train x"
    assert "training split only" in out.with_suffix(".md").read_text()
    data = card["data"]
    assert (data["train_clips"], data["held_out_clips"], data["train_subjects"], data["held_out_subjects"]) == (
        8,
        4,
        3,
        4,
    )
    assert card["iterations"] == 4 and len(card["history"]) == 4
    assert card["figures_train"]["motions"] == 8 and card["figures_held_out"]["motions"] == 4
    model = MotionTextEvaluator.load(out)
    features = np.concatenate([clip_features(c, None, 30.0) for c in chunks[:8]])
    np.testing.assert_allclose(model.mean.numpy(), features.mean(0), atol=1e-4)  # no held-out (+5) frame in it


def test_a_config_without_a_section_is_a_settings_error(tmp_path):
    from biomotion.training.train_evaluator import train

    with pytest.raises(SettingsError, match="lacks the setting 'data'"):
        train({"model": {}}, tmp_path, tmp_path / "w.safetensors", progress=False)
    with pytest.raises(SettingsError, match="crop_min"):
        train({**CONFIG, "data": {"crop_min": 40, "crop_max": 30}}, tmp_path, tmp_path / "w.safetensors")


def test_score_generated_and_the_real_report(tmp_path, monkeypatch):
    from biomotion.evaluation import distribution as ED
    from biomotion.models import motion_text_evaluator as E
    from biomotion.training.train_evaluator import train

    _tiny_cache(tmp_path)
    out = tmp_path / "evaluator.safetensors"
    train(CONFIG, tmp_path, out, sentence_embeddings=_sentences, progress=False)
    monkeypatch.setattr(E, "embed_sentences", _sentences)
    model = MotionTextEvaluator.load(out)
    from biomotion.data.registry import DatasetCache

    real = ED.held_out_clips(DatasetCache(tmp_path))
    assert [c.text for c in real] == [TEXTS[k % 3] for k in range(8, 12)]
    same = ED.score_generated(model, real, real, repeats=2)
    assert same["fid_generated_to_real"] == pytest.approx(0.0, abs=1e-6)
    assert same["generated"]["r_precision_top1"] == same["real"]["r_precision_top1"]
    shifted = [ED.TextClip(c.values + 1.0, c.text, c.mask, c.rate) for c in real]
    assert ED.score_generated(model, real, shifted, repeats=1)["fid_generated_to_real"] > 0
    ED.main(["--cache", str(tmp_path), "--evaluator", str(out), "--out", str(tmp_path / "report"), "--repeats", "2"])
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["held_out"]["clips"] == 4 and report["evaluator"]["trained_on"] == "train split only"
    assert "FID between two random halves" in (tmp_path / "report.md").read_text()


def test_the_cli_trains_and_records_its_command(tmp_path, monkeypatch, capsys):
    import yaml

    from biomotion.cli import main
    from biomotion.training import train_evaluator

    _tiny_cache(tmp_path)
    monkeypatch.setattr(train_evaluator, "embed_sentences", _sentences)
    config = tmp_path / "evaluator.yaml"
    config.write_text(yaml.safe_dump(CONFIG))
    out = tmp_path / "evaluator.safetensors"
    argv = ["train", "evaluator", "--config", str(config), "--cache", str(tmp_path), "--out", str(out)]
    assert main([*argv, "--iterations", "2", "--quiet"]) == 0
    card = json.loads(out.with_suffix(".json").read_text())
    assert card["iterations"] == 2 and card["command"].startswith("biomotion ")  # the process's own argv
    assert "SHA-256" in capsys.readouterr().out
    config.write_text("model: {}\n")
    assert main(argv) == 2
    assert "evaluator config lacks the setting 'data'" in capsys.readouterr().err
