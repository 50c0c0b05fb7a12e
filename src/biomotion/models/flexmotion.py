"""FlexMotion (Tashakori et al., "FlexMotion", `papers/flexmotion.md`): a physics-aware multimodal autoencoder
(Sec. 3.1) and a latent diffusion denoiser (Sec. 3.2) conditioned on text and on the subject profile, sized for a
2-core CPU.

Modalities (Sec. 3.1), per frame of a fixed window of ``window`` frames at ``rate`` Hz, concatenated into the
D = window x `FEATURES` input:

- canonical coordinates q (39, in the window's frame: `biomotion.models.refiner.to_local`, so where a window
  starts and faces is not modelled) and their velocities q̇ (39);
- generalized forces τ (39, in body weights: N·m / (m g · 1 m)), inverse dynamics with the ground reaction applied;
- the contact forces at the `biomotion.body.contact.foot_points` (K x 3, body weights), whose sums per foot are
  the ground reaction the outputs report;
- muscle activations (`N_MUSCLES`, 0-1).

Each feature is standardised with statistics of the training windows; a missing modality or coordinate (its mask)
is zero on input (the training mean) and left out of the reconstruction loss (`masked_mse`).

Autoencoder. A 1-D convolutional encoder-decoder (the paper uses a Transformer; convolutions are several times
cheaper on a CPU at this size): two stride-2 convolutions reduce the window 4-fold in time to ``latent_channels``
channels, a latent of d = latent_channels x window / 4 numbers (128 for 64 frames, against D = 64 x 227). Its loss
(Eq. 8) is the reconstruction term here plus the Euler-Lagrange term between the decoded kinematics, torques and
contact forces, computed through `biomotion.body` in `biomotion.training.train_flexmotion`.

Diffusion (Sec. 3.2). A residual MLP ε-predictor over the flattened, scaled latent, given the diffusion timestep
(sinusoidal embedding), the MiniLM embedding of the text (384) and a profile vector (`profile_vector`: height,
mass, age and sex with their presence flags). A learnt null condition replaces text or profile when dropped in
training (classifier-free guidance, Ho & Salimans 2022), and sampling mixes the two predictions with ``guidance``.
Schedules are `diffusers`' DDPM (training) and DDIM (sampling).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from biomotion.body.canonical import CANONICAL_COORDINATES, DEFAULT_RATE
from biomotion.errors import ModelError
from biomotion.settings import settings_from_dict

FORMAT = "biomotion-flexmotion/1"
N_COORDS = len(CANONICAL_COORDINATES)
N_POINTS = 10
"""Contact points of the canonical feet (`biomotion.body.contact.foot_points`: five per foot, right first)."""
N_MUSCLES = 80
"""Activations of the shipped muscle surrogate."""
TEXT_DIM = 384
PROFILE_FIELDS = ("height", "mass", "age", "sex")
PROFILE_DIM = 2 * len(PROFILE_FIELDS)
_PROFILE_CENTRE = np.array([1.72, 70.0, 35.0, 0.0])
_PROFILE_SCALE = np.array([0.10, 15.0, 15.0, 1.0])

#: feature slices of one frame, in input order
SLICES = {
    "q": slice(0, N_COORDS),
    "qd": slice(N_COORDS, 2 * N_COORDS),
    "torques": slice(2 * N_COORDS, 3 * N_COORDS),
    "forces": slice(3 * N_COORDS, 3 * N_COORDS + 3 * N_POINTS),
    "activations": slice(3 * N_COORDS + 3 * N_POINTS, 3 * N_COORDS + 3 * N_POINTS + N_MUSCLES),
}
FEATURES = SLICES["activations"].stop
INPUT_CLIP = 6.0


@dataclass(frozen=True)
class FlexMotionConfig:
    """Sizes of the autoencoder and the denoiser, the window, and the diffusion settings."""

    window: int = 64
    rate: float = DEFAULT_RATE
    width: int = 128
    latent_channels: int = 8
    denoiser_width: int = 512
    denoiser_blocks: int = 4
    train_timesteps: int = 1000
    sample_steps: int = 25
    guidance: float = 2.5
    cond_dropout: float = 0.1

    @classmethod
    def from_dict(cls, values: dict) -> FlexMotionConfig:
        return settings_from_dict(cls, values, "flexmotion model")

    @property
    def latent_frames(self) -> int:
        return self.window // 4

    @property
    def latent_dim(self) -> int:
        return self.latent_channels * self.latent_frames


def profile_vector(profile) -> np.ndarray:
    """[PROFILE_DIM] float32: height (m), mass (kg), age (y) and sex (M +1, F -1) of a `Profile` (or a dict of
    those fields), centred and scaled, zero where unknown, followed by their presence flags. None: all unknown."""
    values, present = np.zeros(len(PROFILE_FIELDS)), np.zeros(len(PROFILE_FIELDS))
    get = (lambda k: profile.get(k)) if isinstance(profile, dict) else (lambda k: getattr(profile, k, None))
    for k, name in enumerate(PROFILE_FIELDS if profile is not None else ()):
        value = get(name)
        if name == "sex":
            value = {"M": 1.0, "F": -1.0}.get(str(value).upper()[:1]) if value is not None else None
        if value is None:
            continue
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise ModelError(f"profile {name} {value!r} is not a number") from None
        if not math.isfinite(value) or (name in ("height", "mass") and value <= 0) or (name == "age" and value < 0):
            raise ModelError(f"profile {name} {value!r} must be a finite number, positive for height and mass")
        values[k], present[k] = (value - _PROFILE_CENTRE[k]) / _PROFILE_SCALE[k], 1.0
    return np.concatenate([values * present, present]).astype(np.float32)


def masked_mse(x: torch.Tensor, target: torch.Tensor, present: torch.Tensor, delta: float = 0.0) -> torch.Tensor:
    """Mean squared error over the ``present`` entries (broadcast to x's shape); with ``delta`` > 0 the Huber loss
    (quadratic within ``delta``, linear beyond, times 2 so that it equals the squared error near zero): the
    standardised modalities are heavy-tailed (0.1-0.8 % of entries beyond 5 standard deviations hold 8-55 % of
    each modality's squared deviation), and squared errors let those few windows steer training."""
    present = present.expand_as(x).to(x.dtype)
    error = x - target
    if delta > 0:
        loss = 2 * F.huber_loss(x, target, reduction="none", delta=delta)
    else:
        loss = error.square()
    return (loss * present).sum() / present.sum().clamp(min=1.0)


class _Res(nn.Module):
    def __init__(self, width: int) -> None:
        super().__init__()
        self.a, self.b = nn.Conv1d(width, width, 3, padding=1), nn.Conv1d(width, width, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.b(F.gelu(self.a(F.gelu(x))))


class MultimodalAutoencoder(nn.Module):
    """Standardised features [B, W, FEATURES] to a latent [B, C, W/4] and back (module docstring)."""

    def __init__(self, config: FlexMotionConfig) -> None:
        super().__init__()
        w, c = config.width, config.latent_channels
        self.register_buffer("mean", torch.zeros(FEATURES))
        self.register_buffer("std", torch.ones(FEATURES))
        self.encoder = nn.Sequential(
            nn.Conv1d(FEATURES, w, 3, padding=1), _Res(w), nn.GELU(),
            nn.Conv1d(w, w, 4, stride=2, padding=1), _Res(w), nn.GELU(),
            nn.Conv1d(w, w, 4, stride=2, padding=1), _Res(w), nn.GELU(),
            nn.Conv1d(w, c, 1),
        )  # fmt: skip
        self.decoder = nn.Sequential(
            nn.Conv1d(c, w, 3, padding=1), _Res(w), nn.GELU(),
            nn.ConvTranspose1d(w, w, 4, stride=2, padding=1), _Res(w), nn.GELU(),
            nn.ConvTranspose1d(w, w, 4, stride=2, padding=1), _Res(w), nn.GELU(),
            nn.Conv1d(w, FEATURES, 3, padding=1),
        )  # fmt: skip

    def encode(self, x: torch.Tensor, present: torch.Tensor) -> torch.Tensor:
        """Latent [B, C, W/4] of standardised features x [B, W, F] (entries not ``present`` [B, 1|W, F] zeroed,
        the rest clipped to ``INPUT_CLIP`` standard deviations: the heavy tails, `masked_mse`)."""
        return self.encoder((x.clamp(-INPUT_CLIP, INPUT_CLIP) * present.to(x.dtype)).transpose(1, 2))

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Standardised features [B, W, F] of latents [B, C, W/4]."""
        return self.decoder(z).transpose(1, 2)


def timestep_embedding(t: torch.Tensor, width: int) -> torch.Tensor:
    """Sinusoidal embedding [B, width] of integer timesteps [B]."""
    half = width // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32) / half)
    angles = t.float()[:, None] * freqs[None]
    return torch.cat([angles.sin(), angles.cos()], -1)


class _Block(nn.Module):
    def __init__(self, width: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(width)
        self.film = nn.Linear(width, 2 * width)
        self.mlp = nn.Sequential(nn.Linear(width, 2 * width), nn.GELU(), nn.Linear(2 * width, width))

    def forward(self, h: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        scale, shift = self.film(cond).chunk(2, -1)
        return h + self.mlp(self.norm(h) * (1 + scale) + shift)


class LatentDenoiser(nn.Module):
    """ε-prediction for flattened latents [B, d] given timesteps [B], text embeddings [B, 384] and profile vectors
    [B, PROFILE_DIM]; ``drop_text`` / ``drop_profile`` [B] bool swap in the learnt null conditions."""

    def __init__(self, config: FlexMotionConfig) -> None:
        super().__init__()
        w, d = config.denoiser_width, config.latent_dim
        self.width = w
        self.inp = nn.Linear(d, w)
        self.time = nn.Sequential(nn.Linear(w, w), nn.GELU(), nn.Linear(w, w))
        self.text = nn.Linear(TEXT_DIM, w)
        self.profile = nn.Linear(PROFILE_DIM, w)
        self.null_text = nn.Parameter(torch.zeros(w))
        self.null_profile = nn.Parameter(torch.zeros(w))
        self.blocks = nn.ModuleList(_Block(w) for _ in range(config.denoiser_blocks))
        self.out = nn.Sequential(nn.LayerNorm(w), nn.Linear(w, d))
        nn.init.zeros_(self.out[1].weight)
        nn.init.zeros_(self.out[1].bias)

    def condition(
        self,
        t: torch.Tensor,
        text: torch.Tensor,
        profile: torch.Tensor,
        drop_text: torch.Tensor | None = None,
        drop_profile: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """The blocks' condition [B, width]: timestep, text and profile embeddings, the dropped ones (``drop_*``
        [B] bool) replaced by their learned null embeddings (classifier-free guidance)."""
        text_c, profile_c = self.text(text), self.profile(profile)
        if drop_text is not None:
            text_c = torch.where(drop_text[:, None], self.null_text, text_c)
        if drop_profile is not None:
            profile_c = torch.where(drop_profile[:, None], self.null_profile, profile_c)
        return F.gelu(self.time(timestep_embedding(t, self.width)) + text_c + profile_c)

    def forward(
        self,
        z: torch.Tensor,
        t: torch.Tensor,
        text: torch.Tensor,
        profile: torch.Tensor,
        drop_text: torch.Tensor | None = None,
        drop_profile: torch.Tensor | None = None,
        residuals: list[torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """ε [B, d]; ``residuals`` (one [B, width] per block, the control module's,
        `biomotion.models.control_net`) are added to the blocks' outputs (FlexMotion Sec. 3.3)."""
        cond = self.condition(t, text, profile, drop_text, drop_profile)
        h = self.inp(z)
        for k, block in enumerate(self.blocks):
            h = block(h, cond)
            if residuals is not None:
                h = h + residuals[k]
        return self.out(h)


class FlexMotion(nn.Module):
    """The autoencoder, the denoiser and the latent scale, with save/load and sampling (module docstring)."""

    def __init__(self, config: FlexMotionConfig | None = None, metadata: dict | None = None) -> None:
        super().__init__()
        self.config = config = config or FlexMotionConfig()
        if config.window % 4:
            raise ModelError(f"flexmotion window must be a multiple of 4 frames, got {config.window}")
        self.autoencoder = MultimodalAutoencoder(config)
        self.denoiser = LatentDenoiser(config)
        self.register_buffer("latent_scale", torch.ones(()))
        self.metadata = dict(metadata or {})

    # -- features ----------------------------------------------------------------------------------------------
    def normalise(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.autoencoder.mean) / self.autoencoder.std

    def denormalise(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.autoencoder.std + self.autoencoder.mean

    def encode_latent(self, features: torch.Tensor, present: torch.Tensor) -> torch.Tensor:
        """Scaled flat latents [B, d] of raw features [B, W, F] (`SLICES`) with presence [B, 1|W, F]."""
        z = self.autoencoder.encode(self.normalise(features), present)
        return z.flatten(1) / self.latent_scale

    def decode_latent(self, z: torch.Tensor) -> dict[str, torch.Tensor]:
        """Raw modalities (`split`) of scaled flat latents [B, d]."""
        c = self.config
        latent = (z * self.latent_scale).view(len(z), c.latent_channels, c.latent_frames)
        return split(self.denormalise(self.autoencoder.decode(latent)))

    # -- sampling ----------------------------------------------------------------------------------------------
    @torch.no_grad()
    def sample(
        self,
        text: torch.Tensor,
        profile: torch.Tensor,
        *,
        seed: int = 0,
        steps: int | None = None,
        guidance: float | None = None,
        control=None,
    ) -> dict[str, torch.Tensor]:
        """Decoded modalities of one sample per row of ``text`` [B, 384] and ``profile`` [B, PROFILE_DIM]: DDIM
        (``steps``, default the config's) from seeded noise with classifier-free ``guidance``.

        ``control``: None, or a callable (z, t, text, profile, drop_text, drop_profile) -> per-block residuals,
        the control module bound to its control signal (`biomotion.models.control_net.ControlNet.bind`, Sec. 3.3);
        it acts on the conditional and the unconditional prediction alike, and the same seed starts from the same
        noise with and without it.

        The predicted clean latent is not clipped (``clip_sample=False``; `diffusers`' default clips it to [-1, 1],
        a range meant for images in [-1, 1]): the latents are scaled to unit standard deviation, so about a third
        of their entries lie beyond ±1, and clipping them at every step shrank the sampled latents to a standard
        deviation near 0.5 and the decoded motion with them."""
        from diffusers import DDIMScheduler

        c = self.config
        if text.ndim != 2 or text.shape[1] != TEXT_DIM or profile.shape != (len(text), PROFILE_DIM):
            raise ModelError(f"flexmotion samples from text [B, {TEXT_DIM}] and profile [B, {PROFILE_DIM}]")
        steps = int(steps or c.sample_steps)
        guidance = c.guidance if guidance is None else float(guidance)
        scheduler = DDIMScheduler(
            num_train_timesteps=c.train_timesteps, beta_schedule="squaredcos_cap_v2", clip_sample=False
        )
        scheduler.set_timesteps(steps)
        generator = torch.Generator().manual_seed(int(seed))
        z = torch.randn(len(text), c.latent_dim, generator=generator)
        n = len(text)
        none, every = torch.zeros(n, dtype=torch.bool), torch.ones(n, dtype=torch.bool)
        both_text, both_profile = torch.cat([text, text]), torch.cat([profile, profile])
        drops = torch.cat([none, every])
        for t in scheduler.timesteps:
            ts = torch.full((2 * n,), int(t), dtype=torch.long)
            both_z = torch.cat([z, z])
            residuals = None if control is None else control(both_z, ts, both_text, both_profile, drops, drops)
            eps = self.denoiser(both_z, ts, both_text, both_profile, drops, drops, residuals)
            cond, uncond = eps[:n], eps[n:]
            z = scheduler.step(uncond + guidance * (cond - uncond), t, z).prev_sample
        return self.decode_latent(z)

    # -- persistence -------------------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        from safetensors.torch import save

        from biomotion.io.atomic import atomic_write

        state = {k: v.detach().contiguous().cpu() for k, v in self.state_dict().items()}
        meta = {"format": FORMAT, "config": json.dumps(asdict(self.config)), "metadata": json.dumps(self.metadata)}
        with atomic_write(path, "wb") as handle:
            handle.write(save(state, metadata=meta))

    @classmethod
    def load(cls, path: str | Path) -> FlexMotion:
        """Weights saved by `save`, in eval mode; another file is a `ModelError`."""
        from biomotion.io.tensors import read_metadata, read_tensors

        meta = read_metadata(path, "flexmotion weights")
        if meta.get("format") != FORMAT or "config" not in meta:
            raise ModelError(f"{path}: not flexmotion weights (format {meta.get('format')!r})")
        model = cls(FlexMotionConfig.from_dict(json.loads(meta["config"])), json.loads(meta.get("metadata", "{}")))
        model.load_state_dict(read_tensors(path, "flexmotion weights"))
        return model.eval()


def split(features: torch.Tensor) -> dict[str, torch.Tensor]:
    """Raw features [..., W, F] as modalities: q and qd [..., W, 39], torques [..., W, 39] (body weights), forces
    [..., W, K, 3] (body weights), activations [..., W, M]."""
    out = {name: features[..., s] for name, s in SLICES.items()}
    out["forces"] = out["forces"].unflatten(-1, (N_POINTS, 3))
    return out


def join(q, qd, torques, forces, activations) -> torch.Tensor:
    """The inverse of `split`: raw features [..., W, F]."""
    return torch.cat([q, qd, torques, forces.flatten(-2), activations], -1)
