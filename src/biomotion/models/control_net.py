"""FlexMotion's spatial control module (Tashakori et al., "FlexMotion", `papers/flexmotion.md` Sec. 3.3): a
ControlNet (Zhang et al. 2023) over the frozen latent denoiser of `biomotion.models.flexmotion`.

Architecture. A trainable copy of the `LatentDenoiser` (input projection, timestep, text and profile embeddings,
null conditions and every residual block; initialised from the frozen weights) reads the noisy latent plus the
control features, and after each of its blocks a zero-initialised linear layer adds its hidden state to the
output of the frozen denoiser's block of the same depth (`LatentDenoiser.forward`'s ``residuals``). The control
features enter the copy's input through a linear layer (``hint``; zero-initialised too with ``zero_hint``, as in
ControlNet, but then no gradient reaches the control encoder until the output layers have moved, which a CPU
training of a few thousand steps cannot wait for). With the output layers at zero the module adds exactly nothing,
so at initialisation the controlled ε equals the frozen model's (the ControlNet property the tests check); training
moves only the copy, the control encoder and the linear layers.

The control signal. Per frame of the model's window, the target values of a few quantities and a mask of which
entries and frames are constrained (`CONTROL_SLICES`): the origins of the canonical bodies (m, in the window's
frame: `biomotion.models.refiner.to_local`), the 39 coordinates q, the 39 generalized forces τ (body weights, as
FlexMotion's features), the total vertical ground reaction (body weights; the sum of the foot points' vertical
forces) and the 80 muscle activations. q, τ and the activations are standardised with FlexMotion's own feature
statistics (`MultimodalAutoencoder.mean`/``std``, "normalised as FlexMotion normalises"); body positions and the
vertical force with statistics of the training windows stored here. Values are clipped to ``INPUT_CLIP`` standard
deviations, zero where not constrained, and the mask rides along as channels.

Why a small learned encoder and not the frozen autoencoder's encoder (the paper passes control signals through
the frozen encoder). The code decides it: `MultimodalAutoencoder.encode` (a) zeroes the absent entries, so an
unconstrained entry and a target at the training mean (standardised zero) are the same input and the mask is lost;
(b) was trained on whole windows with every modality present for every frame (only coordinates of a source can be
absent, for the whole window), so a window with a handful of constrained entries in a few frames lies far outside
what it has seen; and (c) has no input for body positions, which are not a FlexMotion feature but are the
commonest control (joint paths). The control encoder here has the autoencoder's shape (a 1-D convolution and two
stride-2 convolutions, the window reduced 4-fold as the latent is) over values and mask, followed by a linear map
to the denoiser's width and a layer norm (a few constrained entries among 225 channels otherwise give features too
small to steer the copy).

What it can steer is what the frozen latent holds: the shipped FlexMotion autoencoder reconstructs joint angles
(about 0.08 rad mean error on the training windows) but not the forward travel of the window (``pelvis_tx``:
0.61 m mean error against a 1.04 m spread), so body-origin targets along the direction of travel are beyond any
latent control and are met by the coordinate stage after sampling (`biomotion.generation.flexmotion_control`).

Sizes (defaults): the copy is the denoiser's size (512 wide, 4 blocks), the encoder 64 channels; about 8.7 M
trainable parameters, trained on a 2-core CPU in minutes (`biomotion.training.train_control_net`).
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from biomotion.body.canonical import CANONICAL_BODIES
from biomotion.errors import ModelError
from biomotion.models.flexmotion import (
    INPUT_CLIP,
    N_COORDS,
    N_MUSCLES,
    SLICES,
    FlexMotion,
    FlexMotionConfig,
    LatentDenoiser,
)
from biomotion.settings import settings_from_dict

FORMAT = "biomotion-flexmotion-control/1"
CONTROL_BODIES: tuple[str, ...] = CANONICAL_BODIES
"""Bodies whose origins the signal can constrain (`biomotion.body.canonical.CANONICAL_BODIES`, in order)."""
_NB = 3 * len(CONTROL_BODIES)
#: channel slices of one frame of the control signal (values; the mask has the same layout)
CONTROL_SLICES = {
    "positions": slice(0, _NB),
    "q": slice(_NB, _NB + N_COORDS),
    "torques": slice(_NB + N_COORDS, _NB + 2 * N_COORDS),
    "grf": slice(_NB + 2 * N_COORDS, _NB + 2 * N_COORDS + 1),
    "activations": slice(_NB + 2 * N_COORDS + 1, _NB + 2 * N_COORDS + 1 + N_MUSCLES),
}
CONTROL_DIM = CONTROL_SLICES["activations"].stop


def position_channels(body: str) -> slice:
    """The three channels (x, y, z) of a body's origin in the control signal."""
    if body not in CONTROL_BODIES:
        raise ModelError(f"no control channels for body {body!r}; the control bodies are {', '.join(CONTROL_BODIES)}")
    k = CONTROL_BODIES.index(body)
    return slice(3 * k, 3 * k + 3)


@dataclass(frozen=True)
class ControlNetConfig:
    """Sizes of the control encoder (the copy takes the frozen denoiser's)."""

    encoder_width: int = 64
    encoder_channels: int = 16
    zero_hint: bool = False

    @classmethod
    def from_dict(cls, values: dict) -> ControlNetConfig:
        return settings_from_dict(cls, values, "control net model")


class ControlEncoder(nn.Module):
    """Control values and mask [B, W, CONTROL_DIM] each to features [B, width] (module docstring)."""

    def __init__(self, config: ControlNetConfig, flex: FlexMotionConfig) -> None:
        super().__init__()
        w, c = config.encoder_width, config.encoder_channels
        self.net = nn.Sequential(
            nn.Conv1d(2 * CONTROL_DIM, w, 3, padding=1), nn.GELU(),
            nn.Conv1d(w, w, 4, stride=2, padding=1), nn.GELU(),
            nn.Conv1d(w, w, 4, stride=2, padding=1), nn.GELU(),
            nn.Conv1d(w, c, 1),
        )  # fmt: skip
        self.proj = nn.Linear(c * flex.latent_frames, flex.denoiser_width)
        self.norm = nn.LayerNorm(flex.denoiser_width)

    def forward(self, values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        x = torch.cat([values * mask, mask], -1).transpose(1, 2)
        return self.norm(self.proj(F.gelu(self.net(x).flatten(1))))


def _zero_linear(width: int) -> nn.Linear:
    layer = nn.Linear(width, width)
    nn.init.zeros_(layer.weight)
    nn.init.zeros_(layer.bias)
    return layer


class ControlNet(nn.Module):
    """The control module (module docstring): ``copy`` (trainable copy of the denoiser), ``encoder``, ``hint`` and
    ``zero`` (zero-initialised linears), and the control signal's standardisation (``mean``, ``std``
    [CONTROL_DIM])."""

    def __init__(
        self, flex: FlexMotionConfig, config: ControlNetConfig | None = None, metadata: dict | None = None
    ) -> None:
        super().__init__()
        self.flex_config = flex
        self.config = config = config or ControlNetConfig()
        self.copy = LatentDenoiser(flex)
        del self.copy.out  # the copy's output is its hidden states, not an ε
        self.encoder = ControlEncoder(config, flex)
        self.hint = _zero_linear(flex.denoiser_width) if config.zero_hint else nn.Linear(w := flex.denoiser_width, w)
        self.zero = nn.ModuleList(_zero_linear(flex.denoiser_width) for _ in range(flex.denoiser_blocks))
        self.register_buffer("mean", torch.zeros(CONTROL_DIM))
        self.register_buffer("std", torch.ones(CONTROL_DIM))
        self.metadata = dict(metadata or {})

    @classmethod
    def from_flexmotion(cls, model: FlexMotion, config: ControlNetConfig | None = None) -> ControlNet:
        """A fresh module for ``model``: the copy holds the frozen denoiser's weights, q, τ and activations are
        standardised with its feature statistics, body positions and the vertical force with mean 0 and std 1
        until `set_statistics`."""
        net = cls(model.config, config)
        state = {k: v for k, v in copy.deepcopy(model.denoiser.state_dict()).items() if not k.startswith("out.")}
        net.copy.load_state_dict(state)
        mean, std = model.autoencoder.mean, model.autoencoder.std
        for name in ("q", "torques", "activations"):
            net.mean[CONTROL_SLICES[name]] = mean[SLICES[name]]
            net.std[CONTROL_SLICES[name]] = std[SLICES[name]]
        return net

    def set_statistics(self, positions: torch.Tensor, grf: torch.Tensor) -> None:
        """Standardisation of body positions [N, 3 x bodies] and vertical force [N] from training frames."""
        s = CONTROL_SLICES
        self.mean[s["positions"]] = positions.mean(0)
        self.std[s["positions"]] = positions.std(0).clamp(min=1e-3)
        self.mean[s["grf"]] = grf.mean()
        self.std[s["grf"]] = grf.std().clamp(min=1e-3)

    def standardise(self, values: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Raw control values [B, W, CONTROL_DIM] (SI / body weights) and mask (bool) to the encoder's input."""
        mask = mask.to(values.dtype)
        x = ((values - self.mean) / self.std).clamp(-INPUT_CLIP, INPUT_CLIP)
        return torch.where(mask > 0, x, torch.zeros_like(x)), mask

    def residuals(
        self,
        z: torch.Tensor,
        t: torch.Tensor,
        text: torch.Tensor,
        profile: torch.Tensor,
        values: torch.Tensor,
        mask: torch.Tensor,
        drop_text: torch.Tensor | None = None,
        drop_profile: torch.Tensor | None = None,
    ) -> list[torch.Tensor]:
        """Per block of the frozen denoiser, [B, width] to add to its output, for scaled latents z [B, d],
        timesteps [B], text [B, 384], profile [B, PROFILE_DIM] and standardised control ``values``/``mask``
        [B, W, CONTROL_DIM] (`standardise`)."""
        c = self.copy
        cond = c.condition(t, text, profile, drop_text, drop_profile)
        h = c.inp(z) + self.hint(self.encoder(values, mask))
        out = []
        for block, zero in zip(c.blocks, self.zero):
            h = block(h, cond)
            out.append(zero(h))
        return out

    def bind(self, values: torch.Tensor, mask: torch.Tensor) -> Callable[..., list[torch.Tensor]]:
        """The module bound to raw control ``values``/``mask`` [B, W, CONTROL_DIM] for `FlexMotion.sample`
        (which doubles the batch for classifier-free guidance: the signal is repeated to match)."""
        x, m = self.standardise(values, mask)

        def control(z, t, text, profile, drop_text=None, drop_profile=None):
            reps = len(z) // len(x)
            return self.residuals(z, t, text, profile, x.repeat(reps, 1, 1), m.repeat(reps, 1, 1), drop_text,
                                  drop_profile)  # fmt: skip

        return control

    # -- persistence -------------------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        from safetensors.torch import save

        from biomotion.io.atomic import atomic_write

        state = {k: v.detach().contiguous().cpu() for k, v in self.state_dict().items()}
        meta = {
            "format": FORMAT,
            "flexmotion_config": json.dumps(asdict(self.flex_config)),
            "config": json.dumps(asdict(self.config)),
            "metadata": json.dumps(self.metadata),
        }
        with atomic_write(path, "wb") as handle:
            handle.write(save(state, metadata=meta))

    @classmethod
    def load(cls, path: str | Path, flex: FlexMotionConfig | None = None) -> ControlNet:
        """Weights saved by `save`, in eval mode; another file, or one made for a FlexMotion of another
        configuration than ``flex``, is a `ModelError`."""
        from biomotion.io.tensors import read_metadata, read_tensors

        meta = read_metadata(path, "flexmotion control weights")
        if meta.get("format") != FORMAT or "flexmotion_config" not in meta:
            raise ModelError(f"{path}: not flexmotion control weights (format {meta.get('format')!r})")
        made_for = FlexMotionConfig.from_dict(json.loads(meta["flexmotion_config"]))
        if flex is not None and made_for != flex:
            raise ModelError(f"{path}: control weights made for another FlexMotion configuration ({made_for})")
        net = cls(made_for, ControlNetConfig.from_dict(json.loads(meta["config"])), json.loads(meta["metadata"]))
        net.load_state_dict(read_tensors(path, "flexmotion control weights"))
        return net.eval()
