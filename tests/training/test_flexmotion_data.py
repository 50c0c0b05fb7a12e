"""The FlexMotion multimodal windows (`biomotion.training.flexmotion_data`) on a few clips of the built dataset
cache: shapes, masks, physical sense of the solved forces, and the on-disk cache."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from biomotion.generation.pipeline import CHECKPOINTS, SURROGATE_FILE
from biomotion.models.flexmotion import N_COORDS, N_MUSCLES, N_POINTS, PROFILE_DIM
from tests.conftest import data_path

CACHE = Path.home() / ".cache" / "biomotion" / "dataset"


def test_windows_have_every_modality_and_mask(tmp_path, monkeypatch):
    if not (CACHE / "manifest.json").exists() or not (CACHE / "clips.safetensors").exists():
        pytest.skip("no built dataset cache (biomotion data build)")
    if not (CHECKPOINTS / SURROGATE_FILE).exists():
        pytest.skip("shipped surrogate absent")
    from biomotion.data.clips import body_model
    from biomotion.data.registry import DatasetCache
    from biomotion.training.flexmotion_data import MultimodalSettings, build, cache_folder

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    body = body_model(data_path("."))
    settings = MultimodalSettings(window=32, stride=32, max_clips=3, split="val")
    data = build(DatasetCache(CACHE), body, CHECKPOINTS / SURROGATE_FILE, settings, progress=False)
    n = len(data)
    assert n >= 3 and data.clips == 3
    assert data.q.shape == (n, 32, N_COORDS) and data.torques.shape == (n, 32, N_COORDS)
    assert data.forces.shape == (n, 32, N_POINTS, 3) and data.activations.shape == (n, 32, N_MUSCLES)
    assert data.mask.shape == (n, N_COORDS) and data.profiles.shape == (n, PROFILE_DIM)
    assert data.force_present.all() and data.activation_present.all()
    assert (data.qd[~data.mask[:, None, :].expand_as(data.qd)] == 0).all()  # absent coordinates carry nothing
    vertical = data.forces[..., 1].sum(-1).mean()  # over a window the ground carries about one body weight
    assert 0.6 < float(vertical) < 1.5
    assert cache_folder().is_relative_to(tmp_path) and any(cache_folder().iterdir())
    again = build(DatasetCache(CACHE), body, CHECKPOINTS / SURROGATE_FILE, settings, progress=False)
    assert torch.equal(again.torques, data.torques) and again.texts == data.texts
