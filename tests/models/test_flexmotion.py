"""FlexMotion (`biomotion.models.flexmotion`, its training losses and its generation): shapes, masks, one step of
each loss lowers it on a tiny batch, seeded sampling is deterministic, bad prompts and profiles are one-line
errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from biomotion.errors import BiomotionError, ModelError
from biomotion.models.flexmotion import (
    FEATURES,
    N_COORDS,
    N_MUSCLES,
    N_POINTS,
    PROFILE_DIM,
    TEXT_DIM,
    FlexMotion,
    FlexMotionConfig,
    join,
    masked_mse,
    profile_vector,
    split,
)

TINY = FlexMotionConfig(window=8, width=16, latent_channels=2, denoiser_width=32, denoiser_blocks=1, sample_steps=4)


def _features(batch: int = 3, window: int = 8, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(batch, window, FEATURES, generator=g)


def test_shapes_and_latent_is_much_smaller():
    torch.manual_seed(0)
    model = FlexMotion(TINY)
    x = _features()
    z = model.encode_latent(x, torch.ones(1, 1, FEATURES))
    assert z.shape == (3, TINY.latent_dim) and TINY.latent_dim == 2 * 2
    out = model.decode_latent(z)
    assert out["q"].shape == (3, 8, N_COORDS) and out["torques"].shape == (3, 8, N_COORDS)
    assert out["forces"].shape == (3, 8, N_POINTS, 3) and out["activations"].shape == (3, 8, N_MUSCLES)
    assert torch.equal(join(**split(x)), x)
    shipped = FlexMotionConfig()
    assert shipped.latent_dim * 50 < shipped.window * FEATURES


def test_masked_entries_do_not_reach_the_latent_or_the_loss():
    torch.manual_seed(0)
    model = FlexMotion(TINY)
    x = _features(1)
    present = torch.ones(1, 1, FEATURES, dtype=torch.bool)
    present[..., :5] = False
    changed = x.clone()
    changed[..., :5] += 100.0
    assert torch.allclose(model.encode_latent(x, present), model.encode_latent(changed, present))
    assert float(masked_mse(changed, x, present)) == 0.0
    assert float(masked_mse(changed, x, torch.ones_like(present))) > 0.0
    small, large = x + 0.1, x + 10.0
    assert float(masked_mse(small, x, present, delta=1.0)) == pytest.approx(float(masked_mse(small, x, present)))
    assert float(masked_mse(large, x, present, delta=1.0)) < 0.25 * float(masked_mse(large, x, present))


def test_profile_vector_and_bad_profiles():
    v = profile_vector({"height": 1.8, "mass": 75.0, "age": None, "sex": "F"})
    assert v.shape == (PROFILE_DIM,) and list(v[4:]) == [1, 1, 0, 1] and v[2] == 0 and v[3] == -1
    assert not profile_vector(None).any()
    for bad in ({"height": -1.7}, {"mass": "heavy"}, {"age": float("nan")}):
        with pytest.raises(ModelError):
            profile_vector(bad)


def test_one_autoencoder_step_lowers_the_reconstruction_loss():
    torch.manual_seed(0)
    model = FlexMotion(TINY)
    x, present = _features(4), torch.ones(1, 1, FEATURES, dtype=torch.bool)
    ae = model.autoencoder
    optimiser = torch.optim.Adam(ae.parameters(), lr=1e-3)

    def loss():
        return masked_mse(ae.decode(ae.encode(x, present)), x, present)

    before = loss()
    optimiser.zero_grad()
    before.backward()
    optimiser.step()
    assert float(loss().detach()) < float(before.detach())


def test_one_denoising_step_lowers_the_diffusion_loss():
    from diffusers import DDPMScheduler

    from biomotion.training.train_flexmotion import diffusion_loss

    torch.manual_seed(0)
    model = FlexMotion(TINY)
    scheduler = DDPMScheduler(num_train_timesteps=TINY.train_timesteps, beta_schedule="squaredcos_cap_v2")
    z0 = torch.randn(8, TINY.latent_dim)
    text, profile = torch.randn(8, TEXT_DIM), torch.zeros(8, PROFILE_DIM)
    optimiser = torch.optim.Adam(model.denoiser.parameters(), lr=1e-3)

    def loss():
        return diffusion_loss(model, scheduler, z0, text, profile, torch.Generator().manual_seed(1))

    before = loss()
    optimiser.zero_grad()
    before.backward()
    optimiser.step()
    assert float(loss().detach()) < float(before.detach())


def test_seeded_sampling_is_deterministic_and_save_load_round_trips(tmp_path):
    torch.manual_seed(0)
    model = FlexMotion(TINY).eval()
    for p in model.denoiser.out.parameters():
        torch.nn.init.normal_(p, std=0.1)
    text, profile = torch.randn(2, TEXT_DIM), torch.zeros(2, PROFILE_DIM)
    a, b = model.sample(text, profile, seed=3), model.sample(text, profile, seed=3)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not torch.equal(a["q"], model.sample(text, profile, seed=4)["q"])
    model.save(tmp_path / "f.safetensors")
    again = FlexMotion.load(tmp_path / "f.safetensors")
    assert torch.equal(again.sample(text, profile, seed=3)["q"], a["q"])
    with pytest.raises(ModelError):
        model.sample(torch.randn(2, 10), profile)
    (tmp_path / "bad.safetensors").write_bytes(b"not weights")
    with pytest.raises(BiomotionError):
        FlexMotion.load(tmp_path / "bad.safetensors")


def test_sampling_does_not_clip_the_unit_scale_latent(monkeypatch):
    """The latents are scaled to unit standard deviation, so DDIM must not clip its clean-latent prediction to
    [-1, 1] (diffusers' default): with an untrained (zero) ε-predictor the sample keeps the noise's scale."""
    torch.manual_seed(0)
    model = FlexMotion(TINY).eval()
    monkeypatch.setattr(model, "decode_latent", lambda z: {"z": z})
    z = model.sample(torch.randn(64, TEXT_DIM), torch.zeros(64, PROFILE_DIM), seed=0)["z"]
    assert float(z.abs().max()) > 1.5


def test_generator_rejects_bad_prompts_and_profiles():
    from biomotion.errors import ConfigError
    from biomotion.generation.flexmotion import FlexMotionGenerator

    generator = FlexMotionGenerator(FlexMotion(TINY).eval(), None, None)
    sentences = torch.zeros(1, TEXT_DIM)
    for texts, profiles in (([""], [None]), (["   "], [None]), (["walk"], [{"height": 0}]), (["walk"], [])):
        with pytest.raises(ConfigError) as info:
            generator.sample(texts, profiles, sentences=sentences)
        assert "\n" not in str(info.value)
    out = generator.sample(["walk"], [{"height": 1.7, "mass": 70}], sentences=sentences)
    assert out["q"].shape == (1, 8, N_COORDS)


def test_euler_term_is_zero_for_consistent_modalities(data_root):
    """Modalities whose torques are inverse dynamics of their coordinates and forces give L_euler ~ 0; other
    torques do not."""
    from biomotion.body.dynamics import ExternalLoad, inverse_dynamics
    from biomotion.data.clips import body_model
    from biomotion.models.refiner import GRAVITY, Refiner, RefinerConfig, finite_rates
    from biomotion.training.train_flexmotion import euler_loss

    refiner = Refiner.new(RefinerConfig(), body_model(data_root))
    t = torch.linspace(0, 1, 12)[:, None]
    q = refiner.defaults[None].repeat(12, 1) + 0.2 * torch.sin(6 * t) * (torch.arange(N_COORDS) % 3 == 0)
    mask = torch.ones(N_COORDS, dtype=torch.bool)
    full = refiner.full(q, mask)
    qd, qdd = finite_rates(full, 30.0)
    _, feet = refiner.kinematics(full)
    weight = float(refiner.body.total_mass) * GRAVITY
    forces = torch.zeros(12, N_POINTS, 3)
    forces[..., 1] = 0.1
    loads = [
        ExternalLoad(refiner.body.body_names[int(refiner.feet.bodies[k])], forces[:, k] * weight, feet[:, k])
        for k in range(N_POINTS)
    ]
    torques = inverse_dynamics(refiner.body, full, qd, qdd, loads) / weight
    decoded = {"q": q[None], "torques": torques[None], "forces": forces[None]}
    g = torch.Generator().manual_seed(0)
    assert float(euler_loss(refiner, decoded, mask[None], 4, g)) < 1e-4
    decoded["torques"] = torques[None] + 0.1
    assert float(euler_loss(refiner, decoded, mask[None], 4, g)) > 1.0
    assert np.isfinite(float(euler_loss(refiner, decoded, mask[None], 4, g)))
