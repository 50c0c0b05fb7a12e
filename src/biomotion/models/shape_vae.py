"""Shape-conditioned motion c-VAE: move a gait onto another body the way that body would move (HUMOS, ``humos.md``).

HUMOS ("Method Summary", Sec. 3) encodes a motion into an identity-agnostic latent sequence with a Transformer, and
decodes it conditioned on a target identity; without paired data it trains by reconstruction with the person's own
identity, cycle consistency A → B → A, and intuitive-physics terms that rule out the trivial solution of ignoring
the identity. This module is that model for a musculoskeletal gait, sized for a CPU:

- **Motion features** (`FEATURES`): the 13 lower-body rotational coordinates of the canonical skeleton
  (`biomotion.body.canonical`: pelvis tilt, list and heading, hip flexion/adduction/rotation, knee and ankle angles,
  both sides; canonical knee sign), the ones every gait source with a scaled model shares (the Fukuchi ``_simple``
  models have no others below the arms). Pelvis translations, the patella's coupled ``_beta`` and every coordinate
  the model does not read pass through the adapter time-warped, unchanged otherwise.
- **Timing removed from the input**: a clip's stride time T (`stride_time`: the dominant period of the hip flexion
  angles) is measured and the clip resampled to `PHASE_FRAMES` frames per stride (`phase_resample`), so the encoder
  sees the shape of the gait cycle and not its duration. Windows are ``window`` such frames (two strides); the
  heading (``pelvis_rotation``) is taken relative to its window mean.
- **Target identity** (`shape_vector`): log height, log mass, log tibia length and log foot (calcaneus) length of a
  `biomotion.body.shape.Shape`, standardised over the training subjects. Lengths are in metres, so Shapes relative
  to different generic models (Rajagopal, the Fukuchi and Hamner models) are comparable.
- **Encoder** (HUMOS's Transformer encoder to an identity-agnostic latent): a linear embedding, two stride-2
  temporal convolutions (window / 4 tokens), a learned position code, ``layers`` Transformer layers, and a
  Gaussian posterior (μ, log σ²) per token of ``latent`` channels (the c-VAE's KL term).
- **Decoder** conditioned on the Shape: latent tokens plus an embedding of the standardised shape vector, ``layers``
  Transformer layers, two transposed convolutions back to ``window`` frames, a linear head to the 13 standardised
  features; and a **timing head** (the cadence of the target body): from the tokens' mean and the shape embedding to
  the standardised log stride time.

`ShapeAdapter.adapt` applies a trained model to a `Motion`: measure T_A, phase-resample, encode overlapping windows
(posterior means), decode them with the target Shape (overlap-added with triangular weights), and set the stride
time to ``T_B = T_A · exp(Δ)``. With ``timing: head``, Δ = h(z, B) − h(z, A), the timing head's change from the
source's own Shape to the target's (the head's own error on A cancels); with ``timing: ridge``, Δ = w · (s_B − s_A),
a ridge regression of log stride time on the shape vector among people doing the same task
(`biomotion.training.train_shape_vae.timing_ridge`, weights in the buffer ``timing_weights``): a linear time warp
predicted from the shape, which a handful of training people can support where the head's nonlinear response to an
unseen shape cannot. Either way A → A keeps A's timing exactly. Contract: the output has the input's
columns, mask and rate, starts at the input's first time, lasts the same number of strides; bad inputs (too short
for two strides, missing coordinates, a Shape without height, tibia or calcaneus) raise a one-line `ConfigError`.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch
from torch import nn

from biomotion.body.canonical import KNEE_COORDINATES
from biomotion.body.shape import Shape
from biomotion.errors import ConfigError, ModelError
from biomotion.motion import Motion

FEATURES: tuple[str, ...] = (
    "pelvis_tilt",
    "pelvis_list",
    "pelvis_rotation",
    "hip_flexion_r",
    "hip_adduction_r",
    "hip_rotation_r",
    "knee_angle_r",
    "ankle_angle_r",
    "hip_flexion_l",
    "hip_adduction_l",
    "hip_rotation_l",
    "knee_angle_l",
    "ankle_angle_l",
)
N_FEATURES = len(FEATURES)
YAW = FEATURES.index("pelvis_rotation")
#: left/right mirror: column permutation and sign (a gait mirrored in the sagittal plane; augmentation)
MIRROR_ORDER = (0, 1, 2, 8, 9, 10, 11, 12, 3, 4, 5, 6, 7)
MIRROR_SIGN = np.array([1, -1, -1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1], dtype=np.float32)
SHAPE_FEATURES = ("log_height_m", "log_mass_kg", "log_tibia_m", "log_foot_m")
PHASE_FRAMES = 32  # frames per stride after timing is removed
STRIDE_RANGE = (0.45, 1.6)  # s: stride periods searched (running 0.6-0.8 s, walking 1.0-1.2 s)
PEAK_SHARE = 0.8  # of the highest autocorrelation peak: the first peak this strong is the stride
STD_FLOOR = 0.02  # rad: smallest standardisation scale
FORMAT = "biomotion-shape-vae/1"
TIMINGS = ("head", "ridge")


# ---- features --------------------------------------------------------------------------------------------------


def shape_vector(shape: Shape) -> np.ndarray:
    """[4] log height (m), log mass (kg), log mean tibia length (m), log mean calcaneus length (m) of ``shape``
    (`SHAPE_FEATURES`); a one-line `ConfigError` when the Shape lacks one."""
    if shape.height is None:
        raise ConfigError("shape_vector: the Shape has no height (give Shape(height=...))")
    values = [math.log(shape.height), math.log(shape.mass)]
    for body in ("tibia", "calcn"):
        lengths = [shape.lengths[f"{body}_{side}"] for side in ("r", "l") if f"{body}_{side}" in shape.lengths]
        if not lengths:
            raise ConfigError(f"shape_vector: the Shape has no {body}_r/{body}_l length (a model without that body)")
        values.append(math.log(float(np.mean(lengths))))
    return np.asarray(values, dtype=np.float32)


def motion_features(motion: Motion, *, knee_flipped: bool = False) -> np.ndarray:
    """[T, 13] `FEATURES` of ``motion`` (rad, canonical knee sign: ``knee_flipped`` for sources whose knee flexion
    is negative); a one-line `ConfigError` naming absent or unmeasured coordinates."""
    missing = [n for n in FEATURES if n not in motion.names or not motion.mask[motion.index(n)]]
    if missing:
        raise ConfigError(f"the shape adapter needs the coordinates {missing}, absent from the motion")
    values = motion.select(list(FEATURES)).values.astype(np.float64)
    if knee_flipped:
        for name in KNEE_COORDINATES:
            values[:, FEATURES.index(name)] *= -1.0
    return values


def stride_time(values: np.ndarray, rate: float) -> float:
    """Stride time (s) of a gait ``values`` [T, 13] at ``rate`` from the autocorrelation of the
    mean-removed hip flexion angles (both sides): the shortest lag within `STRIDE_RANGE` whose autocorrelation is a
    local maximum within `PEAK_SHARE` of the highest one there (two strides correlate about as well as one), refined
    by a parabola through its neighbours. A one-line `ConfigError` when the clip is shorter than 1.5 of the longest
    period searched or has no periodic hip flexion."""
    values = np.asarray(values, dtype=np.float64)
    low, high = (int(round(s * rate)) for s in STRIDE_RANGE)
    if len(values) < int(1.5 * high) or low < 2:
        raise ConfigError(
            f"stride_time: {len(values)} frames at {rate:g} Hz is too short to find a stride "
            f"(needs {1.5 * STRIDE_RANGE[1]:g} s)"
        )
    hips = values[:, [FEATURES.index("hip_flexion_r"), FEATURES.index("hip_flexion_l")]]
    hips = hips - hips.mean(0)
    n = len(hips)
    lags = np.arange(low - 1, min(high, n - 2) + 2)
    scores = np.array([np.sum(hips[: n - lag] * hips[lag:]) / (n - lag) for lag in lags])
    peaks = [k for k in range(1, len(scores) - 1) if scores[k] >= scores[k - 1] and scores[k] >= scores[k + 1]]
    if not peaks:
        raise ConfigError(f"stride_time: no periodic hip flexion between {STRIDE_RANGE[0]} and {STRIDE_RANGE[1]} s")
    best = max(scores[k] for k in peaks)
    k = next(k for k in peaks if scores[k] >= PEAK_SHARE * best)  # the first strong peak, not a multiple of it
    a, b, c = scores[k - 1], scores[k], scores[k + 1]
    shift = 0.5 * (a - c) / (a - 2 * b + c) if (a - 2 * b + c) < 0 else 0.0
    return float((low - 1 + k + shift) / rate)


def phase_resample(values: np.ndarray, rate: float, stride: float) -> np.ndarray:
    """``values`` [T, F] at ``rate`` resampled to `PHASE_FRAMES` frames per ``stride`` seconds (linear)."""
    times = np.arange(len(values)) / rate
    grid = np.arange(0.0, times[-1] + 1e-9, stride / PHASE_FRAMES)
    return np.stack([np.interp(grid, times, values[:, k]) for k in range(values.shape[1])], -1)


def mirror(features: np.ndarray) -> np.ndarray:
    """``features`` [..., 13] of the left/right mirrored gait."""
    return features[..., list(MIRROR_ORDER)] * MIRROR_SIGN


# ---- the network -----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ShapeVAEConfig:
    """Sizes of `ShapeVAE` (configs/shape_adapter.yaml ``model:``)."""

    window: int = 64
    width: int = 64
    latent: int = 16
    layers: int = 2
    heads: int = 4
    ff: int = 128
    dropout: float = 0.1
    timing: str = "head"  # the adapter's time warp: "head" (the timing head's change) or "ridge" (linear in shape)

    @classmethod
    def from_dict(cls, values: dict) -> ShapeVAEConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ConfigError(f"shape adapter model: unknown settings {unknown}; known: {sorted(known)}")
        config = cls(**values)
        if config.window % 4 or config.window < 8:
            raise ConfigError(f"shape adapter model: window = {config.window} must be a multiple of 4, at least 8")
        if config.timing not in TIMINGS:
            raise ConfigError(f"shape adapter model: timing = {config.timing!r} must be one of {list(TIMINGS)}")
        if config.width % config.heads:
            raise ConfigError(f"shape adapter model: width {config.width} is not a multiple of heads {config.heads}")
        return config


def _transformer(config: ShapeVAEConfig) -> nn.TransformerEncoder:
    layer = nn.TransformerEncoderLayer(
        config.width, config.heads, config.ff, config.dropout, activation="gelu", batch_first=True
    )
    return nn.TransformerEncoder(layer, config.layers, enable_nested_tensor=False)


class ShapeVAE(nn.Module):
    """Encoder to an identity-agnostic latent sequence, decoder and timing head conditioned on a shape vector
    (module docstring). Inputs and outputs are standardised (buffers ``feature_mean/std``, ``shape_mean/std``,
    ``stride_mean/std``, set from training data by `set_normalisation`)."""

    def __init__(self, config: ShapeVAEConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or ShapeVAEConfig()
        w, tokens = config.width, config.window // 4
        self.embed = nn.Linear(N_FEATURES, w)
        self.down = nn.Sequential(
            nn.Conv1d(w, w, 5, stride=2, padding=2), nn.GELU(), nn.Conv1d(w, w, 5, stride=2, padding=2), nn.GELU()
        )
        self.enc_position = nn.Parameter(torch.zeros(tokens, w))
        self.encoder = _transformer(config)
        self.posterior = nn.Linear(w, 2 * config.latent)
        self.from_latent = nn.Linear(config.latent, w)
        self.shape_embed = nn.Sequential(nn.Linear(len(SHAPE_FEATURES), w), nn.GELU(), nn.Linear(w, w))
        self.dec_position = nn.Parameter(torch.zeros(tokens, w))
        self.decoder = _transformer(config)
        self.up = nn.Sequential(
            nn.ConvTranspose1d(w, w, 4, stride=2, padding=1),
            nn.GELU(),
            nn.ConvTranspose1d(w, w, 4, stride=2, padding=1),
            nn.GELU(),
        )
        self.head = nn.Linear(w, N_FEATURES)
        self.timing = nn.Sequential(nn.Linear(2 * w, w), nn.GELU(), nn.Linear(w, 1))
        for name, size in (("feature", N_FEATURES), ("shape", len(SHAPE_FEATURES)), ("stride", 1)):
            self.register_buffer(f"{name}_mean", torch.zeros(size))
            self.register_buffer(f"{name}_std", torch.ones(size))
        self.register_buffer("timing_weights", torch.zeros(len(SHAPE_FEATURES)))

    def set_normalisation(self, features: np.ndarray, shapes: np.ndarray, log_strides: np.ndarray) -> None:
        """Standardisation from training ``features`` [N, 13] (heading window-relative), subject ``shapes`` [S, 4]
        and clip ``log_strides`` [C]."""
        for name, data, floor in (
            ("feature", features, STD_FLOOR),
            ("shape", shapes, 1e-3),
            ("stride", np.reshape(log_strides, (-1, 1)), 1e-3),
        ):
            data = torch.as_tensor(np.asarray(data), dtype=torch.float32)
            getattr(self, f"{name}_mean").copy_(data.mean(0))
            getattr(self, f"{name}_std").copy_(data.std(0).clamp(min=floor) if len(data) > 1 else torch.ones(1))

    def _check(self, x: torch.Tensor) -> None:
        if x.ndim != 3 or x.shape[1] != self.config.window or x.shape[2] != N_FEATURES:
            raise ConfigError(
                f"ShapeVAE input must be [batch, {self.config.window}, {N_FEATURES}], got {list(x.shape)}"
            )

    def encode(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Posterior mean and log-variance [B, window / 4, latent] of standardised windows ``x`` [B, window, 13]."""
        self._check(x)
        h = self.down(self.embed(x).transpose(1, 2)).transpose(1, 2) + self.enc_position
        mu, logvar = self.posterior(self.encoder(h)).chunk(2, -1)
        return mu, logvar.clamp(-10.0, 10.0)

    def decode(self, z: torch.Tensor, shape: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Standardised windows [B, window, 13] and standardised log stride time [B] from latents ``z``
        [B, window / 4, latent] and standardised shape vectors ``shape`` [B, 4]."""
        if shape.ndim != 2 or shape.shape[1] != len(SHAPE_FEATURES) or shape.shape[0] != z.shape[0]:
            raise ConfigError(f"ShapeVAE shape must be [batch, {len(SHAPE_FEATURES)}], got {list(shape.shape)}")
        s = self.shape_embed(shape)
        h = self.decoder(self.from_latent(z) + s[:, None] + self.dec_position)
        x = self.head(self.up(h.transpose(1, 2)).transpose(1, 2))
        log_stride = self.timing(torch.cat([h.mean(1), s], -1))[:, 0]
        return x, log_stride

    def forward(self, x: torch.Tensor, shape: torch.Tensor, sample: bool = True):
        """(decoded windows, log stride, μ, log σ²) of ``x`` decoded with ``shape``; ``sample`` draws z from the
        posterior (training), else takes its mean."""
        mu, logvar = self.encode(x)
        z = mu + torch.randn_like(mu) * torch.exp(0.5 * logvar) if sample else mu
        decoded, log_stride = self.decode(z, shape)
        return decoded, log_stride, mu, logvar

    # ---- standardisation helpers ----
    def standardise_shape(self, vector: np.ndarray) -> torch.Tensor:
        return (torch.as_tensor(vector, dtype=torch.float32) - self.shape_mean) / self.shape_std

    def standardise(self, features: torch.Tensor) -> torch.Tensor:
        return (features - self.feature_mean) / self.feature_std

    def destandardise(self, features: torch.Tensor) -> torch.Tensor:
        return features * self.feature_std + self.feature_mean

    # ---- files ----
    def save(self, path: str | Path, metadata: dict[str, str] | None = None) -> None:
        """Weights and buffers to ``path`` (safetensors, written atomically) with the config in its metadata."""
        from safetensors.torch import save

        from biomotion.io.atomic import atomic_write

        state = {k: v.detach().contiguous() for k, v in self.state_dict().items()}
        meta = {"format": FORMAT, "config": json.dumps(asdict(self.config)), **(metadata or {})}
        with atomic_write(path, "wb") as handle:
            handle.write(save(state, metadata=meta))

    @classmethod
    def load(cls, path: str | Path) -> tuple[ShapeVAE, dict[str, str]]:
        """A model saved by `save` (eval mode, CPU) and its metadata; a file of another kind is a `ModelError`."""
        from biomotion.io.tensors import read_metadata, read_tensors

        meta = read_metadata(path, "shape adapter weights")
        if meta.get("format") != FORMAT:
            raise ModelError(f"{path}: not shape adapter weights (format {meta.get('format')!r}, want {FORMAT})")
        model = cls(ShapeVAEConfig.from_dict(json.loads(meta["config"])))
        model.load_state_dict(read_tensors(path, "shape adapter weights"))
        return model.eval(), meta


def kl_divergence(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """Mean KL(N(μ, σ²) ‖ N(0, 1)) per latent channel (the c-VAE's prior term)."""
    return 0.5 * (mu.square() + logvar.exp() - 1.0 - logvar).mean()


# ---- the adapter -----------------------------------------------------------------------------------------------


def _windows(n: int, window: int) -> list[int]:
    """Starts of windows of ``window`` frames covering ``n`` frames, hop window / 2, the last aligned to the end."""
    starts = list(range(0, n - window + 1, window // 2))
    if starts[-1] != n - window:
        starts.append(n - window)
    return starts


class ShapeAdapter:
    """A trained `ShapeVAE` applied to motions (module docstring, `adapt`)."""

    def __init__(self, model: ShapeVAE, metadata: dict[str, str] | None = None) -> None:
        self.model = model.eval()
        self.metadata = metadata or {}
        self.subjects: tuple[str, ...] = tuple(json.loads(self.metadata.get("subjects", "[]")))

    @classmethod
    def load(cls, path: str | Path) -> ShapeAdapter:
        model, meta = ShapeVAE.load(path)
        return cls(model, meta)

    @torch.no_grad()
    def encode_decode(self, phase: np.ndarray, source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, float]:
        """Phase-normalised features ``phase`` [N, 13] (rad) decoded with the ``target`` shape vector: the decoded
        features [N, 13] and the log stride-time change h(z, target) − h(z, source) (mean over windows)."""
        window = self.model.config.window
        if len(phase) < window:
            raise ConfigError(
                f"the shape adapter needs at least {window // PHASE_FRAMES} strides, the motion has "
                f"{len(phase) / PHASE_FRAMES:.2f}"
            )
        starts = _windows(len(phase), window)
        chunks = np.stack([phase[s : s + window] for s in starts])
        heading = chunks[:, :, YAW].mean(1, keepdims=True)
        chunks[:, :, YAW] -= heading
        x = self.model.standardise(torch.as_tensor(chunks, dtype=torch.float32))
        mu, _ = self.model.encode(x)
        n = len(starts)
        decoded, h_target = self.model.decode(mu, self.model.standardise_shape(target).expand(n, -1))
        _, h_source = self.model.decode(mu, self.model.standardise_shape(source).expand(n, -1))
        out = self.model.destandardise(decoded).double().numpy()
        out[:, :, YAW] += heading
        weight = 1.0 - np.abs(np.linspace(-1.0, 1.0, window + 2)[1:-1])
        total, norm = np.zeros_like(phase), np.zeros(len(phase))
        for k, s in enumerate(starts):
            total[s : s + window] += out[k] * weight[:, None]
            norm[s : s + window] += weight
        if self.model.config.timing == "ridge":
            weights = self.model.timing_weights.double().numpy()
            change = float(weights @ (np.asarray(target, np.float64) - np.asarray(source, np.float64)))
        else:
            change = float(((h_target - h_source) * self.model.stride_std).mean())
        return total / norm[:, None], change

    def adapt(self, motion: Motion, source: Shape, target: Shape, *, knee_flipped: bool = False) -> Motion:
        """``motion`` of the body ``source`` moved onto the body ``target`` (module docstring); ``knee_flipped``
        for motions whose knee flexion is negative (Fukuchi ``_simple``, Hamner models), kept in the output."""
        rate = motion.rate
        values = motion_features(motion, knee_flipped=knee_flipped)
        stride_a = stride_time(values, rate)
        phase = phase_resample(values, rate, stride_a)
        decoded, change = self.encode_decode(phase, shape_vector(source), shape_vector(target))
        stride_b = stride_a * math.exp(change)
        t0 = float(motion.times[0])
        span = (len(phase) - 1) * stride_b / PHASE_FRAMES
        times = t0 + np.arange(0.0, span + 1e-9, 1.0 / rate)
        old_times = t0 + (times - t0) * stride_a / stride_b
        out = np.stack([np.interp(old_times, motion.times, motion.values[:, k]) for k in range(len(motion.names))], -1)
        position = (times - t0) / (stride_b / PHASE_FRAMES)
        grid = np.arange(len(phase))
        for k, name in enumerate(FEATURES):
            column = np.interp(position, grid, decoded[:, k])
            if knee_flipped and name in KNEE_COORDINATES:
                column = -column
            out[:, motion.index(name)] = column
        return Motion(times=times, names=motion.names, values=out, mask=motion.mask.copy())
