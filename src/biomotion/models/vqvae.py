"""Motion tokenizer: a temporal-convolution VQ-VAE over canonical coordinates (PG-BIG Sec. 3.1, Table 4).

PG-BIG encodes motion into discrete tokens with a VQ-VAE (van den Oord et al. 2017) in the T2M-GPT layout
(Zhang et al. 2023): Conv1d stem, two stride-2 stages (T/4 tokens) with ResNet1D blocks of dilations 1, 3, 9,
a mirrored decoder with nearest-neighbour upsampling, and an EMA codebook (decay 0.99) whose unused codes are
reset to random encoder outputs. Losses: masked smooth-L1 reconstruction, a masked velocity (first-difference)
term and a 0.02-weighted commitment term (Table 4), plus a masked acceleration (second-difference) term that
is not in the paper: without it the nearest-neighbour upsampling leaves the decoded motion 2.6x as jerky as the
real motion (joint-position jerk of a Fukuchi run, 605 vs 236 m/s^3; 378 with the term). The weights live in
``configs/tokenizer.yaml``.

Foot contact (Sec. 3.1, Table 4), when ``foot_contact`` is set: the decoder has four more output channels, the
logits of heel and forefoot contact of each foot (`biomotion.models.foot_contact`), trained with a binary
cross-entropy against stance labels of the real clip (weight ``w_contact``), and guidance reads them as its contact
mask m_t. They are outputs only: contact is a function of the motion the encoder already sees, and an encoder
input would make every caller compute it. Table 4's penetration term (weight ``w_penetration``: the decoded foot
points' mean depth below the floor, in cm) needs the body model, so the training loop adds it
(`biomotion.training.train_tokenizer`).

Input is the canonical skeleton (`biomotion.body.canonical`, 39 Rajagopal coordinates, SI units) with a
per-coordinate mask [B, 39]. Masked coordinates are zeroed at the input, the mask is given to the encoder as 39
extra channels, and they are excluded from every loss term, so a source lacking a coordinate cannot leak into
the model through its placeholder values.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from biomotion.body.canonical import CANONICAL_COORDINATES, DEFAULT_RATE
from biomotion.errors import ModelError
from biomotion.models.foot_contact import N_CONTACT
from biomotion.settings import settings_from_dict

N_COORDS = len(CANONICAL_COORDINATES)
#: Horizontal pelvis translations, represented as velocities (see `MotionVQVAE.to_features`).
HORIZONTAL = (CANONICAL_COORDINATES.index("pelvis_tx"), CANONICAL_COORDINATES.index("pelvis_tz"))
TRANSLATIONS = tuple(CANONICAL_COORDINATES.index(n) for n in ("pelvis_tx", "pelvis_ty", "pelvis_tz"))
DOWNSAMPLE = 4  # two stride-2 stages


@dataclass(frozen=True)
class VQVAEConfig:
    """Sizes and loss weights. Defaults fit a 2-core CPU; the paper uses width = code_dim = codebook = 512."""

    width: int = 128
    code_dim: int = 128
    codebook_size: int = 256
    depth: int = 3
    dilation_growth: int = 3
    ema_decay: float = 0.99
    dead_threshold: float = 1.0
    rate: float = DEFAULT_RATE
    w_recon: float = 1.0
    w_velocity: float = 0.5
    w_acceleration: float = 0.0
    w_commit: float = 0.02
    foot_contact: bool = False
    w_contact: float = 0.0
    w_penetration: float = 0.0

    @classmethod
    def from_dict(cls, values: dict) -> VQVAEConfig:
        return settings_from_dict(cls, values, "tokenizer model")


class ResBlock1D(nn.Module):
    """Dilated residual block: x + Conv1x1(ReLU(Conv3_dilated(ReLU(x)))) (T2M-GPT ResConv1DBlock)."""

    def __init__(self, width: int, dilation: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv1d(width, width, 3, padding=dilation, dilation=dilation)
        self.conv2 = nn.Conv1d(width, width, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(F.relu(self.conv1(F.relu(x))))


def resnet1d(width: int, depth: int, growth: int) -> nn.Sequential:
    """``depth`` residual blocks with dilations growth**k, largest first (1, 3, 9 reversed, as in T2M-GPT)."""
    return nn.Sequential(*[ResBlock1D(width, growth**k) for k in reversed(range(depth))])


def down_stage(width: int, depth: int, growth: int) -> nn.Sequential:
    """Stride-2 convolution (kernel 4) then a ResNet1D: halves the frame count."""
    return nn.Sequential(nn.Conv1d(width, width, 4, stride=2, padding=1), resnet1d(width, depth, growth))


def up_stage(width: int, depth: int, growth: int) -> nn.Sequential:
    """ResNet1D, nearest-neighbour x2 upsampling, then a smoothing convolution: doubles the frame count."""
    return nn.Sequential(
        resnet1d(width, depth, growth),
        nn.Upsample(scale_factor=2, mode="nearest"),
        nn.Conv1d(width, width, 3, padding=1),
    )


class EMAQuantizer(nn.Module):
    """Nearest-code quantiser with an exponential-moving-average codebook and dead-code reset.

    Codebook update (van den Oord et al. 2017, App. A.1; reset rule of T2M-GPT's QuantizeEMAReset): with one-hot
    assignments, ``count = d*count + (1-d)*n_k`` and ``sum = d*sum + (1-d)*sum_{x->k} x``; codes whose count is
    at least ``dead_threshold`` become ``sum / count``, the others are reset to random encoder outputs of the
    batch. The codebook is initialised from the first training batch.
    """

    def __init__(self, size: int, dim: int, decay: float, dead_threshold: float) -> None:
        super().__init__()
        self.decay, self.dead_threshold = decay, dead_threshold
        self.register_buffer("codebook", torch.zeros(size, dim))
        self.register_buffer("code_sum", torch.zeros(size, dim))
        self.register_buffer("code_count", torch.ones(size))
        self.register_buffer("initialised", torch.tensor(False))

    def nearest(self, z: torch.Tensor) -> torch.Tensor:
        """Index of the nearest code for each row of z [N, D]."""
        distance = z.pow(2).sum(1, keepdim=True) - 2 * z @ self.codebook.T + self.codebook.pow(2).sum(1)
        return distance.argmin(1)

    def _random_rows(self, z: torch.Tensor, n: int) -> torch.Tensor:
        repeats = -(-n // z.shape[0])
        rows = z.repeat(repeats, 1) if repeats > 1 else z
        return rows[torch.randperm(rows.shape[0], device=z.device)[:n]]

    @torch.no_grad()
    def initialise(self, z: torch.Tensor) -> None:
        """Codebook from random rows of z [N, D] (T2M-GPT init_codebook)."""
        self.codebook.copy_(self._random_rows(z, self.codebook.shape[0]))
        self.code_sum.copy_(self.codebook)
        self.code_count.fill_(1.0)
        self.initialised.fill_(True)

    @torch.no_grad()
    def update(self, z: torch.Tensor, indices: torch.Tensor) -> None:
        """One EMA step of the codebook from encoder outputs z [N, D] and their code indices [N]."""
        size = self.codebook.shape[0]
        onehot = F.one_hot(indices, size).to(z.dtype)
        self.code_count.mul_(self.decay).add_(onehot.sum(0), alpha=1 - self.decay)
        self.code_sum.mul_(self.decay).add_(onehot.T @ z, alpha=1 - self.decay)
        alive = (self.code_count >= self.dead_threshold).unsqueeze(1)
        updated = self.code_sum / self.code_count.clamp_min(1e-8).unsqueeze(1)
        self.codebook.copy_(torch.where(alive, updated, self._random_rows(z, size)))

    def forward(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """z [B, D, N] -> (straight-through quantised [B, D, N], indices [B, N], commitment loss, perplexity)."""
        flat = z.permute(0, 2, 1).reshape(-1, z.shape[1])
        if self.training and not bool(self.initialised):
            self.initialise(flat.detach())
        indices = self.nearest(flat.detach())
        quantised = self.codebook[indices]  # a copy: the update below does not change it
        if self.training:
            self.update(flat.detach(), indices)
        commitment = F.mse_loss(flat, quantised)
        usage = torch.bincount(indices, minlength=self.codebook.shape[0]).float() / indices.numel()
        perplexity = torch.exp(-(usage * (usage + 1e-10).log()).sum())
        quantised = flat + (quantised - flat).detach()
        shape = (z.shape[0], z.shape[2], z.shape[1])
        return quantised.view(shape).permute(0, 2, 1), indices.view(z.shape[0], -1), commitment, perplexity


class MotionVQVAE(nn.Module):
    """VQ-VAE tokenizer over [B, T, 39] canonical coordinates (SI units) with masks [B, 39]; T/4 tokens.

    Features: the 39 coordinates, except that pelvis_tx and pelvis_tz are replaced by their velocities (m/s).
    Global horizontal position is not stationary: it grows without bound over a walk or run, so its
    distribution differs between clips and windows and a fixed normalisation cannot cover it, while its
    velocity is stationary and bounded. Pelvis height (pelvis_ty) stays absolute: it is bounded and fixes
    the body against the ground. Features are standardised with per-feature mean/std buffers computed on the
    training split (`set_normalisation`), so a saved model is self-contained.
    """

    def __init__(self, config: VQVAEConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or VQVAEConfig()
        w = config.width
        d, g = config.depth, config.dilation_growth
        # encoder input: standardised features and the mask, 2 x 39 channels
        self.encoder = nn.Sequential(
            nn.Conv1d(2 * N_COORDS, w, 3, padding=1),
            nn.ReLU(),
            down_stage(w, d, g),
            down_stage(w, d, g),
            nn.Conv1d(w, config.code_dim, 3, padding=1),
        )
        self.decoder = nn.Sequential(
            nn.Conv1d(config.code_dim, w, 3, padding=1),
            nn.ReLU(),
            up_stage(w, d, g),
            up_stage(w, d, g),
            nn.Conv1d(w, w, 3, padding=1),
            nn.ReLU(),
            nn.Conv1d(w, N_COORDS + self.contact_channels, 3, padding=1),
        )
        self.quantiser = EMAQuantizer(config.codebook_size, config.code_dim, config.ema_decay, config.dead_threshold)
        self.register_buffer("mean", torch.zeros(N_COORDS))
        self.register_buffer("std", torch.ones(N_COORDS))

    @property
    def contact_channels(self) -> int:
        """Number of decoded foot-contact channels: 4 with ``foot_contact``, else 0."""
        return N_CONTACT if self.config.foot_contact else 0

    # -- features -------------------------------------------------------------------------------------------
    def to_features(self, x: torch.Tensor) -> torch.Tensor:
        """Coordinates [B, T, 39] -> unnormalised features: pelvis_tx/tz as velocities (first frame copies the
        second's, so the map loses only the start position)."""
        h = list(HORIZONTAL)
        velocity = torch.diff(x[..., h], dim=-2) * self.config.rate
        velocity = torch.cat([velocity[..., :1, :], velocity], dim=-2)
        return x.index_copy(-1, torch.tensor(h, device=x.device), velocity)

    def from_features(self, f: torch.Tensor, origin: torch.Tensor | None = None) -> torch.Tensor:
        """Inverse of `to_features`: integrate pelvis_tx/tz velocities from ``origin`` [B, 2] (default 0)."""
        h = list(HORIZONTAL)
        steps = torch.cat([torch.zeros_like(f[..., :1, h]), f[..., 1:, h]], dim=-2) / self.config.rate
        position = steps.cumsum(-2) + (0 if origin is None else origin.unsqueeze(-2))
        return f.index_copy(-1, torch.tensor(h, device=f.device), position)

    def normalise(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Standardised features with masked coordinates set to exactly zero (also when they hold NaN)."""
        m = mask.unsqueeze(-2)
        f = (self.to_features(torch.where(m, x, torch.zeros_like(x))) - self.mean) / self.std
        return torch.where(m, f, torch.zeros_like(f))

    @torch.no_grad()
    def set_normalisation(self, x: torch.Tensor, mask: torch.Tensor) -> None:
        """Per-feature mean/std from training windows x [N, T, 39], mask [N, 39]; features never observed, or
        constant, keep std 1."""
        f = self.to_features(torch.where(mask.unsqueeze(-2), x, torch.zeros_like(x))).double()
        w = mask.unsqueeze(-2).expand_as(f).double()
        count = w.sum((0, 1))
        mean = (f * w).sum((0, 1)) / count.clamp_min(1)
        var = ((f - mean).pow(2) * w).sum((0, 1)) / count.clamp_min(1)
        std = var.sqrt()
        self.mean.copy_(mean.float())
        self.std.copy_(torch.where((count > 1) & (std > 1e-6), std, torch.ones_like(std)).float())

    # -- model ----------------------------------------------------------------------------------------------
    def _check(self, x: torch.Tensor, mask: torch.Tensor) -> None:
        if x.ndim != 3 or x.shape[-1] != N_COORDS or mask.shape != (x.shape[0], N_COORDS):
            raise ModelError(
                f"tokenizer expects x [B, T, {N_COORDS}] and mask [B, {N_COORDS}]; got "
                f"{tuple(x.shape)} and {tuple(mask.shape)}"
            )
        if x.shape[1] % DOWNSAMPLE:
            raise ModelError(f"tokenizer needs T divisible by {DOWNSAMPLE}; got T = {x.shape[1]}")

    def encode_continuous(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Pre-quantisation latents [B, T/4, code_dim]."""
        self._check(x, mask)
        mask = mask.bool()
        f = self.normalise(x, mask)
        channels = torch.cat([f, mask.unsqueeze(1).expand_as(f).to(f.dtype)], dim=-1)
        return self.encoder(channels.transpose(1, 2)).transpose(1, 2)

    def encode(self, x: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(quantised latents [B, T/4, code_dim], token indices [B, T/4])."""
        z = self.encode_continuous(x, mask)
        indices = self.quantiser.nearest(z.reshape(-1, z.shape[-1])).view(z.shape[:2])
        return self.quantiser.codebook[indices], indices

    def decode_with_contact(
        self, z: torch.Tensor, origin: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Latents [B, N, code_dim] -> (coordinates [B, 4N, 39] (SI; pelvis_tx/tz start at ``origin``), contact
        probabilities [B, 4N, 4] of heel and forefoot of each foot, or None without contact channels)."""
        out = self.decoder(z.transpose(1, 2)).transpose(1, 2)
        f, logits = out[..., :N_COORDS], out[..., N_COORDS:]
        q = self.from_features(f * self.std + self.mean, origin)
        return q, (torch.sigmoid(logits) if self.contact_channels else None)

    def decode_latents(self, z: torch.Tensor, origin: torch.Tensor | None = None) -> torch.Tensor:
        """Latents [B, N, code_dim] -> coordinates [B, 4N, 39] (SI); pelvis_tx/tz start at ``origin``."""
        return self.decode_with_contact(z, origin)[0]

    def decode_indices(self, indices: torch.Tensor, origin: torch.Tensor | None = None) -> torch.Tensor:
        """Token indices [B, N] -> coordinates [B, 4N, 39] (SI units, canonical order)."""
        return self.decode_latents(self.quantiser.codebook[indices], origin)

    def forward(
        self, x: torch.Tensor, mask: torch.Tensor, contact: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Reconstruction [B, T, 39] (SI, horizontal pelvis from x's first frame) and the losses:
        ``recon`` (masked smooth-L1 on standardised features), ``velocity`` (masked smooth-L1 on their first
        differences), ``commit`` (encoder-to-code MSE), ``loss`` (weighted sum) and ``perplexity``; with contact
        channels and labels ``contact`` [B, T, 4] (0/1), also ``contact`` (binary cross-entropy) and
        ``contact_accuracy`` (share of channel-frames whose decoded probability falls on the label's side of
        0.5)."""
        mask = mask.bool()
        z = self.encode_continuous(x, mask)
        quantised, _, commit, perplexity = self.quantiser(z.transpose(1, 2))
        out = self.decoder(quantised).transpose(1, 2)
        f_hat, logits = out[..., :N_COORDS], out[..., N_COORDS:]
        target = self.normalise(x, mask)
        m = mask.unsqueeze(1).to(f_hat.dtype)
        recon = (F.smooth_l1_loss(f_hat, target, reduction="none") * m).sum() / (m.sum() * x.shape[1]).clamp_min(1)
        velocity = (
            F.smooth_l1_loss(torch.diff(f_hat, dim=1), torch.diff(target, dim=1), reduction="none") * m
        ).sum() / (m.sum() * (x.shape[1] - 1)).clamp_min(1)
        acceleration = (
            F.smooth_l1_loss(torch.diff(f_hat, 2, dim=1), torch.diff(target, 2, dim=1), reduction="none") * m
        ).sum() / (m.sum() * (x.shape[1] - 2)).clamp_min(1)
        c = self.config
        loss = c.w_recon * recon + c.w_velocity * velocity + c.w_acceleration * acceleration + c.w_commit * commit
        terms = {
            "recon": recon,
            "velocity": velocity,
            "acceleration": acceleration,
            "commit": commit,
            "perplexity": perplexity,
        }
        if self.contact_channels and contact is not None:
            terms["contact"] = F.binary_cross_entropy_with_logits(logits, contact)
            terms["contact_accuracy"] = ((logits > 0) == (contact > 0.5)).float().mean()
            loss = loss + c.w_contact * terms["contact"]
        origin = x[:, 0, list(HORIZONTAL)]
        recon_x = self.from_features(f_hat * self.std + self.mean, torch.where(mask[:, list(HORIZONTAL)], origin, 0))
        return recon_x, {"loss": loss, **terms}

    # -- persistence ----------------------------------------------------------------------------------------
    def save(self, path: str | Path, metadata: dict[str, str] | None = None) -> None:
        """Weights and buffers to ``path`` (safetensors, written atomically) with the config in its metadata."""
        import json

        from safetensors.torch import save

        from biomotion.io.atomic import atomic_write

        state = {k: v.detach().contiguous().cpu() for k, v in self.state_dict().items()}
        state["quantiser.initialised"] = state["quantiser.initialised"].to(torch.uint8)
        blob = save(state, metadata={"config": json.dumps(asdict(self.config)), **(metadata or {})})
        with atomic_write(path, "wb") as handle:
            handle.write(blob)

    @classmethod
    def load(cls, path: str | Path, map_location: str = "cpu") -> MotionVQVAE:
        """A model saved by `save`, in eval mode."""
        import json

        from biomotion.io.tensors import read_metadata, read_tensors

        meta = read_metadata(path, "tokenizer weights")
        if "config" not in meta:
            raise ModelError(f"{path}: no tokenizer config in the safetensors metadata")
        model = cls(VQVAEConfig.from_dict(json.loads(meta["config"])))
        state = read_tensors(path, "tokenizer weights", device=map_location)
        state["quantiser.initialised"] = state["quantiser.initialised"].bool()
        model.load_state_dict(state)
        return model.eval()
