"""Tempo: a clip played faster moves faster with the same strides (`biomotion.guidance.tempo`)."""

from __future__ import annotations

import math

import torch

from biomotion.guidance.tempo import WARP_RANGE, warp, warp_factor

RATE = 30.0


def _walk(speed: float, frames: int = 60) -> torch.Tensor:
    """[1, T, 39] pelvis moving forward at ``speed`` (m/s) while the hip swings at 1 Hz."""
    q = torch.zeros(1, frames, 39, dtype=torch.float64)
    t = torch.arange(frames, dtype=torch.float64) / RATE
    q[0, :, 3] = speed * t
    q[0, :, 6] = 0.5 * torch.sin(2 * math.pi * t)
    return q


def test_warp_samples_the_clip_at_scaled_times_and_holds_the_end():
    x = torch.arange(10.0)[None, :, None].repeat(2, 1, 1)
    out = warp(x, torch.tensor([1.25, 0.8]), 6)[..., 0]
    assert torch.allclose(out, torch.tensor([[0.0, 1.25, 2.5, 3.75, 5.0, 6.25], [0.0, 0.8, 1.6, 2.4, 3.2, 4.0]]))
    assert torch.allclose(warp(x, torch.tensor([3.0, 3.0]), 6)[0, -2:, 0], torch.tensor([9.0, 9.0]))  # past the end


def test_played_faster_the_clip_reaches_the_target_speed_with_a_faster_cadence():
    q = _walk(3.0)
    factor = warp_factor(q, RATE, torch.tensor([3.6]))
    assert torch.allclose(factor, torch.tensor([1.2], dtype=torch.float64))
    played = warp(q, factor, 40)
    speed = (played[0, -1, 3] - played[0, 0, 3]) * RATE / 39
    assert abs(float(speed) - 3.6) < 1e-6
    # the same hip angles, 1.2 times as often: the swing at played frame t is the original's at 1.2 t
    assert torch.allclose(played[0, 10, 6], 0.5 * torch.sin(torch.tensor(2 * math.pi * 12 / RATE, dtype=torch.float64)))


def test_factor_is_bounded_and_neutral_without_locomotion():
    fast, still = _walk(2.0), _walk(0.0)
    assert float(warp_factor(fast, RATE, torch.tensor([4.0]))) == WARP_RANGE[1]
    assert float(warp_factor(fast, RATE, torch.tensor([1.0]))) == WARP_RANGE[0]
    assert float(warp_factor(still, RATE, torch.tensor([3.0]))) == 1.0


def test_warp_passes_gradients_to_the_clip():
    x = torch.randn(1, 12, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: warp(v, torch.tensor([1.1]), 8), (x,))
