"""Corruptions of clean canonical clips that look like the noise of markerless capture and generated motion.

The refiner (PhysPT, `biomotion.models.refiner`) learns to undo them (Sec. 3.2.1: "we introduce random Gaussian
noise into the input during training while the model is still tasked with reconstructing the clean input"), and
`biomotion eval refine` scores it on held-out clips corrupted the same way. PhysPT adds Gaussian noise only; the
refiner's inputs (video-based kinematics, generated clips) err in more structured ways, each a kind here:

- **jitter**: white noise per coordinate, std up to ``jitter_angle_deg`` (rotations) or ``jitter_translation_m``
  (pelvis translations): frame-to-frame tremor of per-frame pose estimates (CLIFF's outputs on Human3.6M have an
  ACCL of 15 mm/frame², PhysPT Table 1);
- **drift**: slow sinusoids (0.1-1 Hz, two per coordinate) of amplitude up to ``drift_angle_deg``: the slowly varying
  joint-angle bias of markerless kinematics (OpenCap's joint angles differ from marker-based ones by 4.5° on
  average, Uhlrich et al. 2023, PLoS Comput Biol 19:e1011462); the horizontal pelvis path drifts by up to
  ``drift_translation_m`` at 0.2-0.8 Hz (a global trajectory predicted from local pose: PhysPT Supp. E, Table 6,
  G-MPJPE of 336-525 mm over 10 s), which also makes the walking or running speed wander, and the pelvis height by
  a constant offset of up to ``drift_vertical_m`` (floating or sinking feet);
- **foot sliding**: a horizontal pelvis oscillation of amplitude up to ``slide_m`` at 0.7-3 Hz, in a random
  direction, that drags the stance feet over the floor;
- **root bounce**: a vertical pelvis oscillation of up to ``bounce_m`` at 1-5 Hz (depth errors of the root);
- **dropped frames**: runs of 1-4 frames, started at a share of up to ``drop_rate`` of the frames, replaced by the
  last good pose (a tracker that repeats its last detection) or by the straight line between the good poses around
  them (a lab's gap filling), one or the other per clip.

Each kind is applied to a clip with probability ``probability`` and an amplitude drawn uniformly between zero and
its level, so the refiner also sees clean and lightly corrupted inputs. Only the coordinates a clip has (``mask``)
are corrupted, and never the coupled ones (`biomotion.body.canonical.COUPLED_COORDINATES`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from biomotion.body.canonical import CANONICAL_COORDINATES, COUPLED_COORDINATES
from biomotion.settings import settings_from_dict

_TRANSLATIONS = [CANONICAL_COORDINATES.index(n) for n in ("pelvis_tx", "pelvis_ty", "pelvis_tz")]
_TX, _TY, _TZ = _TRANSLATIONS
_COUPLED = [CANONICAL_COORDINATES.index(n) for n in COUPLED_COORDINATES]
KINDS = ("jitter", "drift", "slide", "bounce", "drop")


@dataclass(frozen=True)
class NoiseLevels:
    """Largest amplitude of each kind of corruption (module docstring) and how often each is applied."""

    probability: float = 0.7
    jitter_angle_deg: float = 1.5
    jitter_translation_m: float = 0.008
    drift_angle_deg: float = 4.0
    drift_translation_m: float = 0.10
    drift_vertical_m: float = 0.02
    slide_m: float = 0.03
    bounce_m: float = 0.03
    drop_rate: float = 0.04

    @classmethod
    def from_dict(cls, values: dict) -> NoiseLevels:
        return settings_from_dict(cls, values, "noise")


def _uniform(shape: tuple[int, ...], generator: torch.Generator, low: float = 0.0, high: float = 1.0) -> torch.Tensor:
    return low + (high - low) * torch.rand(shape, generator=generator)


def _sinusoids(
    t: torch.Tensor, count: int, columns: int, band: tuple[float, float], generator: torch.Generator
) -> torch.Tensor:
    """[B, T, columns] sums of ``count`` unit-amplitude sinusoids per column, frequencies uniform in ``band`` (Hz),
    random phases, scaled so the sum's amplitude is at most 1."""
    batch = t.shape[0]
    frequency = _uniform((batch, 1, count, columns), generator, *band)
    phase = _uniform((batch, 1, count, columns), generator, 0.0, 2 * math.pi)
    return torch.sin(2 * math.pi * frequency * t[..., None, None] + phase).sum(2) / count


def corrupt(
    q: torch.Tensor,
    mask: torch.Tensor,
    rate: float,
    levels: NoiseLevels = NoiseLevels(),
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Corrupted copies of clips q [B, T, 39] (canonical, SI) with coordinate mask [B, 39] sampled at ``rate`` Hz."""
    generator = generator or torch.Generator().manual_seed(0)
    batch, frames, n = q.shape
    dtype = q.dtype
    on = {kind: (_uniform((batch,), generator) < levels.probability).to(dtype) for kind in KINDS}
    t = (torch.arange(frames, dtype=dtype) / rate)[None].expand(batch, -1)
    translation = torch.zeros(n, dtype=torch.bool)
    translation[_TRANSLATIONS] = True
    noisy = torch.zeros_like(q)

    # jitter: white noise, a std per clip and coordinate
    scale = torch.where(translation, levels.jitter_translation_m, math.radians(levels.jitter_angle_deg)).to(dtype)
    sigma = _uniform((batch, 1, n), generator) * scale * on["jitter"][:, None, None]
    noisy += torch.randn(q.shape, generator=generator, dtype=dtype) * sigma

    # drift: slow joint-angle bias, a wandering horizontal path, a pelvis height offset
    amplitude = _uniform((batch, 1, n), generator) * math.radians(levels.drift_angle_deg) * ~translation
    noisy += _sinusoids(t, 2, n, (0.1, 1.0), generator) * amplitude * on["drift"][:, None, None]
    path = _sinusoids(t, 2, 2, (0.2, 0.8), generator) * _uniform(
        (batch, 1, 2), generator, 0, levels.drift_translation_m
    )
    noisy[..., [_TX, _TZ]] += path * on["drift"][:, None, None]
    noisy[..., _TY] += _uniform((batch, 1), generator, -1, 1) * levels.drift_vertical_m * on["drift"][:, None]

    # foot sliding: a horizontal pelvis oscillation in a random direction
    direction = _uniform((batch, 1), generator, 0.0, 2 * math.pi)
    sway = _sinusoids(t, 1, 1, (0.7, 3.0), generator)[..., 0] * _uniform((batch, 1), generator, 0, levels.slide_m)
    sway = sway * on["slide"][:, None]
    noisy[..., _TX] += sway * torch.cos(direction)
    noisy[..., _TZ] += sway * torch.sin(direction)

    # root bounce: a vertical pelvis oscillation
    bounce = _sinusoids(t, 1, 1, (1.0, 5.0), generator)[..., 0] * _uniform((batch, 1), generator, 0, levels.bounce_m)
    noisy[..., _TY] += bounce * on["bounce"][:, None]

    present = mask.clone()
    present[:, _COUPLED] = False
    out = q + noisy * present[:, None, :].to(dtype)
    return _drop_frames(out, _uniform((batch,), generator, 0, levels.drop_rate) * on["drop"], generator)


def _drop_frames(q: torch.Tensor, rate: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """Runs of 1-4 frames started at a share ``rate`` [B] of the frames, replaced by the pose before them (held) or
    by linear interpolation between the poses around them; the first and last frames are kept."""
    batch, frames, _ = q.shape
    starts = _uniform((batch, frames), generator) < rate[:, None]
    lengths = torch.randint(1, 5, (batch, frames), generator=generator)
    dropped = torch.zeros(batch, frames, dtype=torch.bool)
    for k in range(4):
        dropped[:, k:] |= (starts & (lengths > k))[:, : frames - k]
    dropped[:, 0] = dropped[:, -1] = False
    if not bool(dropped.any()):
        return q
    index = torch.arange(frames).expand(batch, -1)
    before = torch.where(dropped, -1, index).cummax(1).values
    after = torch.where(dropped, frames, index).flip(1).cummin(1).values.flip(1)
    gather = lambda i: q.gather(1, i[..., None].expand_as(q))  # noqa: E731 - one-line row picker
    held = gather(before)
    share = ((index - before) / (after - before).clamp(min=1)).to(q.dtype)[..., None]
    line = held + (gather(after) - held) * share
    interpolate = (_uniform((batch,), generator) < 0.5)[:, None, None]
    return torch.where(dropped[..., None], torch.where(interpolate, line, held), q)
