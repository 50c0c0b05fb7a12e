"""Tempo: reach a requested locomotion speed by playing a sampled clip faster or slower, not by sliding its feet.

The prior's samples often move at another speed than the one asked for (on the generator's dev subjects the
unguided samples missed it by 0.6 m/s on average). Guidance's speed term (`biomotion.guidance.losses.
locomotion_speed`) can only close that gap through the decoder, and the cheapest way there is to move the pelvis
faster than the stance foot pushes it: the feet slide. Played ``f`` times faster, a clip covers the same strides in
1/f of the time: its speed is multiplied by f, its stance feet stay as still as they were, and its cadence rises
by f. People change speed by stride length and cadence together (Cavanagh & Kram 1989, Med. Sci. Sports Exerc.
21(4):467, "Stride length in distance running"), so within a bounded ``f`` (default 0.8-1.25, the range the
surrogate's time-warped training copies use, `biomotion.data.augment`) the result is still a person's gait, and
guidance's bounds on joint speeds, COM accelerations and muscle activations judge the faster clip as it is.

`warp_factor` picks f from the unguided sample's speed; `warp` resamples a clip at those times by linear
interpolation, differentiably, so guidance optimises the latents through it.
"""

from __future__ import annotations

import torch

from biomotion.models.foot_contact import mean_horizontal_speed

#: Range of playback-speed factors (slower, faster).
WARP_RANGE = (0.8, 1.25)


def warp_factor(
    q: torch.Tensor, rate: float, target: torch.Tensor, bounds: tuple[float, float] = WARP_RANGE
) -> torch.Tensor:
    """[B] playback factors that bring clips q [B, T, 39] from their mean horizontal speed to ``target`` [B] (m/s),
    clamped to ``bounds``; 1 for a clip that barely moves (below 0.05 m/s: no locomotion to scale)."""
    speed = mean_horizontal_speed(q, rate)
    factor = (target / speed.clamp_min(1e-6)).clamp(*bounds)
    return torch.where(speed > 0.05, factor, torch.ones_like(factor))


def warp(x: torch.Tensor, factor: torch.Tensor, frames: int) -> torch.Tensor:
    """``frames`` frames of clips x [B, T, C] played ``factor`` [B] times faster: frame t is x at time t * factor
    (in frames), linearly interpolated, held at the last frame beyond the clip's end."""
    t = x.shape[1]
    if t == 1:
        return x.expand(-1, frames, -1)
    position = (torch.arange(frames, dtype=x.dtype)[None] * factor.to(x.dtype)[:, None]).clamp(max=t - 1)
    lower = position.floor().long().clamp(max=t - 2)
    share = (position - lower.to(x.dtype))[..., None]
    return _frames_at(x, lower) * (1 - share) + _frames_at(x, lower + 1) * share


def _frames_at(x: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """x [B, T, C] at frame indices [B, F] -> [B, F, C]."""
    return torch.gather(x, 1, index[..., None].expand(-1, -1, x.shape[-1]))
