"""Motion tokenizer (PG-BIG Sec. 3.1): shapes, masking, EMA codebook, learning on real clips, save/load."""

from __future__ import annotations

import pytest
import torch

from biomotion.errors import ModelError
from biomotion.models.vqvae import HORIZONTAL, N_COORDS, EMAQuantizer, MotionVQVAE, VQVAEConfig

SMALL = VQVAEConfig(width=32, code_dim=16, codebook_size=32)


def _random_batch(b: int = 3, t: int = 32, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(b, t, N_COORDS, generator=g).cumsum(1) * 0.05
    mask = torch.ones(b, N_COORDS, dtype=torch.bool)
    mask[:, 30:] = False
    return x, mask


def test_shapes_and_token_count():
    torch.manual_seed(0)
    model = MotionVQVAE(SMALL)
    x, mask = _random_batch(t=48)
    recon, losses = model(x, mask)
    assert recon.shape == x.shape
    assert set(losses) == {"loss", "recon", "velocity", "acceleration", "commit", "perplexity"}
    latents, indices = model.encode(x, mask)
    assert indices.shape == (3, 12) and latents.shape == (3, 12, SMALL.code_dim)
    assert indices.dtype == torch.int64 and int(indices.max()) < SMALL.codebook_size
    assert model.decode_indices(indices).shape == x.shape
    with pytest.raises(ModelError, match="divisible by 4"):
        model.encode(x[:, :46], mask)


def test_features_round_trip_and_velocity_units():
    model = MotionVQVAE(SMALL)
    x, _ = _random_batch()
    f = model.to_features(x)
    h = list(HORIZONTAL)
    # pelvis_tx/tz become m/s at the config rate; everything else is untouched
    assert torch.allclose(f[:, 5, h], (x[:, 5, h] - x[:, 4, h]) * SMALL.rate, atol=1e-5)
    other = [i for i in range(N_COORDS) if i not in h]
    assert torch.equal(f[..., other], x[..., other])
    assert torch.allclose(model.from_features(f, x[:, 0, h]), x, atol=1e-5)


def test_masked_coordinates_do_not_change_the_loss():
    torch.manual_seed(0)
    model = MotionVQVAE(SMALL).eval()
    x, mask = _random_batch()
    model.quantiser.initialise(model.encode_continuous(x, mask).reshape(-1, SMALL.code_dim))
    _, base = model(x, mask)
    changed = x.clone()
    changed[..., 30:] = torch.randn_like(changed[..., 30:]) * 100
    changed[0, :, 35] = float("nan")
    recon, other = model(changed, mask)
    for key in ("loss", "recon", "velocity", "commit"):
        assert torch.equal(base[key], other[key]), key
    assert torch.isfinite(recon).all()
    # and an observed column does change it (the test can fail)
    changed[..., 0] += 0.5
    assert not torch.equal(model(changed, mask)[1]["loss"], base["loss"])


def test_ema_update_and_dead_code_reset():
    torch.manual_seed(0)
    q = EMAQuantizer(size=2, dim=2, decay=0.9, dead_threshold=1.0)
    q.codebook.copy_(torch.tensor([[0.0, 0.0], [10.0, 10.0]]))
    q.code_sum.copy_(q.codebook)
    q.code_count.fill_(1.0)
    q.initialised.fill_(True)
    z = torch.tensor([[1.0, 0.0], [1.0, 2.0], [1.0, 1.0]])  # all nearest to code 0
    indices = q.nearest(z)
    assert indices.tolist() == [0, 0, 0]
    q.update(z, indices)
    # code 0: count = 0.9*1 + 0.1*3 = 1.2, sum = 0.9*(0,0) + 0.1*(3,3) -> centre (0.25, 0.25)
    assert q.code_count[0].item() == pytest.approx(1.2)
    assert torch.allclose(q.codebook[0], torch.tensor([0.25, 0.25]))
    # code 1 got nothing: count 0.9 < threshold 1.0, so it is reset onto one of the encoder outputs
    assert q.code_count[1].item() == pytest.approx(0.9)
    assert any(torch.equal(q.codebook[1], row) for row in z)


def test_training_steps_reduce_loss_on_real_clips(tmp_path, data_root):
    from biomotion.data.registry import DatasetCache, build_cache
    from biomotion.training.train_tokenizer import make_windows

    build_cache(data_root, tmp_path, sources=["hamner"], progress=False)
    x, mask = make_windows(DatasetCache(tmp_path), split=None, length=32, stride=16)
    torch.manual_seed(0)
    model = MotionVQVAE(SMALL)
    model.set_normalisation(x, mask)
    batch = torch.arange(min(32, len(x)))
    optimiser = torch.optim.AdamW(model.parameters(), lr=2e-3)
    first = None
    for _ in range(40):
        _, losses = model(x[batch], mask[batch])
        optimiser.zero_grad()
        losses["loss"].backward()
        optimiser.step()
        first = first if first is not None else losses["recon"].item()
    model.eval()
    last = model(x[batch], mask[batch])[1]["recon"].item()
    assert last < 0.7 * first, (first, last)


def test_save_load_round_trip(tmp_path):
    torch.manual_seed(0)
    model = MotionVQVAE(SMALL)
    x, mask = _random_batch()
    model.set_normalisation(x, mask)
    model.train()
    model(x, mask)  # initialises and updates the codebook
    model.eval()
    path = tmp_path / "tok.safetensors"
    model.save(path)
    loaded = MotionVQVAE.load(path)
    assert loaded.config == model.config
    recon_a, losses_a = model(x, mask)
    recon_b, losses_b = loaded(x, mask)
    assert torch.equal(recon_a, recon_b) and torch.equal(losses_a["loss"], losses_b["loss"])
    assert torch.equal(model.encode(x, mask)[1], loaded.encode(x, mask)[1])
