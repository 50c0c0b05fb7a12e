"""FlexMotion's control module (FlexMotion Sec. 3.3, `biomotion.models.control_net`): the zero-initialised module
leaves the frozen denoiser's output exactly as it was, a trained-looking one does not, and its weights round-trip."""

from __future__ import annotations

import pytest
import torch

from biomotion.errors import ModelError
from biomotion.models.control_net import CONTROL_DIM, ControlNet, position_channels
from biomotion.models.flexmotion import PROFILE_DIM, TEXT_DIM, FlexMotion, FlexMotionConfig

CONFIG = FlexMotionConfig(window=16, width=16, latent_channels=2, denoiser_width=32, denoiser_blocks=2, sample_steps=3)


def _model() -> FlexMotion:
    torch.manual_seed(0)
    model = FlexMotion(CONFIG)
    for p in model.denoiser.parameters():  # a denoiser whose output is not zero (its out layer starts at zero)
        torch.nn.init.normal_(p, std=0.1)
    return model.eval()


def _inputs(batch: int = 3):
    g = torch.Generator().manual_seed(1)
    z = torch.randn(batch, CONFIG.latent_dim, generator=g)
    t = torch.randint(0, CONFIG.train_timesteps, (batch,), generator=g)
    text, profile = torch.randn(batch, TEXT_DIM, generator=g), torch.randn(batch, PROFILE_DIM, generator=g)
    values = torch.randn(batch, CONFIG.window, CONTROL_DIM, generator=g)
    mask = torch.rand(batch, CONFIG.window, CONTROL_DIM, generator=g) < 0.2
    return z, t, text, profile, values, mask


def test_zero_initialised_module_reproduces_the_frozen_denoiser_exactly():
    model = _model()
    net = ControlNet.from_flexmotion(model)
    z, t, text, profile, values, mask = _inputs()
    x, m = net.standardise(values, mask)
    drop = torch.tensor([False, True, False])
    with torch.no_grad():
        frozen = model.denoiser(z, t, text, profile, drop, ~drop)
        residuals = net.residuals(z, t, text, profile, x, m, drop, ~drop)
        controlled = model.denoiser(z, t, text, profile, drop, ~drop, residuals)
    assert frozen.abs().max() > 0
    assert torch.equal(controlled, frozen)
    # the copy starts as the frozen denoiser: same blocks, same weights
    assert torch.equal(net.copy.blocks[0].mlp[0].weight, model.denoiser.blocks[0].mlp[0].weight)
    # and whole DDIM samples are identical with and without the zero module
    text1, profile1 = text[:1], profile[:1]
    plain = model.sample(text1, profile1, seed=3)
    bound = model.sample(text1, profile1, seed=3, control=net.bind(values[:1], mask[:1]))
    assert all(torch.equal(plain[k], bound[k]) for k in plain)


def test_a_non_zero_module_changes_the_output_and_depends_on_the_signal():
    model = _model()
    net = ControlNet.from_flexmotion(model)
    torch.manual_seed(2)
    for layer in (net.hint, *net.zero):
        torch.nn.init.normal_(layer.weight, std=0.05)
    z, t, text, profile, values, mask = _inputs()
    with torch.no_grad():
        frozen = model.denoiser(z, t, text, profile)
        a = model.denoiser(
            z, t, text, profile, residuals=net.residuals(z, t, text, profile, *net.standardise(values, mask))
        )
        nothing = torch.zeros_like(mask)
        b = model.denoiser(
            z, t, text, profile, residuals=net.residuals(z, t, text, profile, *net.standardise(values, nothing))
        )
    assert not torch.allclose(a, frozen) and not torch.allclose(a, b)


def test_weights_round_trip_and_refuse_another_flexmotion(tmp_path):
    model = _model()
    net = ControlNet.from_flexmotion(model)
    net.set_statistics(torch.randn(100, 3 * 22), torch.rand(100) + 0.5)
    net.save(tmp_path / "c.safetensors")
    loaded = ControlNet.load(tmp_path / "c.safetensors", CONFIG)
    assert all(torch.equal(a, b) for a, b in zip(net.state_dict().values(), loaded.state_dict().values()))
    with pytest.raises(ModelError, match="another FlexMotion configuration"):
        ControlNet.load(tmp_path / "c.safetensors", FlexMotionConfig())
    model.save(tmp_path / "f.safetensors")
    with pytest.raises(ModelError, match="not flexmotion control weights"):
        ControlNet.load(tmp_path / "f.safetensors")
    with pytest.raises(ModelError, match="hand_R"):
        position_channels("hand_R")
