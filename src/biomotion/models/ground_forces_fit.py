"""Supervised fit of the learned ground reaction (`biomotion.models.ground_forces`) on force-plate trials.

The objective, per frame of random training windows (`FitSettings.window_s`), in body weights:

- vertical: (baseline + Δ_up − plates_up)², the quantity the issue's bars score;
- horizontal: ``horizontal_weight`` · [(baseline + Δ_fwd − plates_fwd)² + (… right)²];
- foot share: ``share_weight`` · binary cross-entropy of the right foot's share of the vertical force where the
  plates carry more than ``min_share_load_bw`` (on the Fukuchi treadmill one foot at a time: running has no
  double support, so the plate's load is assigned to the foot nearest its CoP);
- centre of pressure: ``cop_weight`` · squared error of each loaded foot's CoP (fraction along the heel-to-toe
  axis, sideways offset in leg lengths) where it carries more than ``min_cop_load_bw``;

on the frames the plates can be compared on (`biomotion.analysis.chain.plate_frames`). Mirror augmentation: each
window is also run mirrored (`GroundForceNet.mirror_inputs`) and its outputs taken back (`mirror_outputs`) against
the same targets, so the network learns both feet alike. AdamW with linear warm-up and cosine decay, a fixed number
of iterations and a seed: the same data and settings give the same weights on the same machine.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from biomotion.analysis.ground_features import FEATURE_NAMES, to_heading
from biomotion.data.plate_trials import SPEEDS, TrialSamples
from biomotion.errors import ConfigError
from biomotion.models.ground_forces import (
    ALONG_RANGE,
    GroundForceNet,
    GroundForcesConfig,
    LearnedGroundReaction,
    model_times,
    resample_rows,
)
from biomotion.settings import settings_from_dict


@dataclass(frozen=True)
class FitSettings:
    """Training settings (YAML ``train:``)."""

    iterations: int = 3000
    batch_size: int = 16
    window_s: float = 3.0
    lr: float = 0.002
    weight_decay: float = 0.0001
    warmup: int = 100
    grad_clip: float = 1.0
    mirror: bool = True
    horizontal_weight: float = 0.5
    share_weight: float = 0.05
    cop_weight: float = 0.5
    min_share_load_bw: float = 0.1
    min_cop_load_bw: float = 0.2

    @classmethod
    def from_dict(cls, values: dict) -> FitSettings:
        settings = settings_from_dict(cls, values, "ground-forces training")
        if settings.iterations < 1 or settings.batch_size < 1 or settings.window_s <= 0:
            raise ConfigError("ground-forces training needs iterations, batch_size >= 1 and window_s > 0")
        return settings


SECTIONS = ("model", "train", "data")


def parse_config(config: dict) -> tuple[GroundForcesConfig, FitSettings, tuple[str, ...]]:
    """The model config, training settings and Fukuchi speeds of a YAML config (``model:``, ``train:``,
    ``data: {speeds: [...]}``); unknown sections or keys are a `ConfigError` naming them."""
    unknown = sorted(set(config) - set(SECTIONS))
    if unknown:
        raise ConfigError(f"unknown ground-forces config sections: {unknown}; known: {list(SECTIONS)}")
    data = dict(config.get("data") or {})
    speeds = tuple(data.pop("speeds", SPEEDS))
    if data:
        raise ConfigError(f"unknown ground-forces data settings: {sorted(data)}; known: ['speeds']")
    if not speeds or set(speeds) - set(SPEEDS):
        raise ConfigError(f"ground-forces data.speeds must be some of {list(SPEEDS)}, got {list(speeds)}")
    return (
        GroundForcesConfig.from_dict(config.get("model") or {}),
        FitSettings.from_dict(config.get("train") or {}),
        speeds,
    )


@dataclass(frozen=True)
class FitSequence:
    """One trial on the network's clock: inputs and targets (module docstring), masks say where each applies."""

    x: np.ndarray  # [T, F] features (config order)
    baseline: np.ndarray  # [T, 3] BW (forward, up, right)
    total: np.ndarray  # [T, 3] plates, BW (forward, up, right)
    valid: np.ndarray  # [T] bool
    share: np.ndarray  # [T] right foot's share of the vertical load
    share_mask: np.ndarray  # [T] bool
    cop: np.ndarray  # [T, 2, 2] (along, sideways / L) per foot
    cop_mask: np.ndarray  # [T, 2] bool


def _on_grid(times: np.ndarray, values: np.ndarray, mask: np.ndarray, grid: np.ndarray):
    """values (NaN-free where ``mask``) and the mask on ``grid``; a grid frame is valid only between valid frames."""
    filled = np.where(mask.reshape(mask.shape + (1,) * (values.ndim - mask.ndim)), values, 0.0)
    on = resample_rows(times, filled, grid)
    valid = resample_rows(times, mask.astype(float), grid) > 0.999
    return on, valid


def fit_sequence(samples: TrialSamples, config: GroundForcesConfig, settings: FitSettings) -> FitSequence:
    """A trial's `TrialSamples` as a `FitSequence` on the network's clock."""
    grid = model_times(samples.times, config.rate_hz)
    columns = [FEATURE_NAMES.index(f) for f in config.features]
    weight = samples.body_weight
    measured = np.nan_to_num(samples.measured)
    total = to_heading(samples.forward, measured.sum(1)) / weight
    valid_frames = samples.keep & np.isfinite(samples.measured).all((1, 2))
    vertical = measured[..., 1]
    load = vertical.sum(1)
    share = np.divide(vertical[:, 0], load, out=np.zeros_like(load), where=load > 0)
    share_mask = valid_frames & (load > settings.min_share_load_bw * weight)
    axis = (samples.toe - samples.heel)[..., [0, 2]]
    offset = (np.nan_to_num(samples.measured_cop) - samples.heel)[..., [0, 2]]
    along = (axis * offset).sum(-1) / np.maximum((axis * axis).sum(-1), 1e-9)
    right = np.stack([-samples.forward[:, 2], samples.forward[:, 0]], axis=-1)
    side = (offset * right[:, None]).sum(-1) / samples.leg_length
    cop_mask = (
        valid_frames[:, None]
        & np.isfinite(samples.measured_cop).all(-1)
        & (vertical > settings.min_cop_load_bw * weight)
    )
    total_g, valid = _on_grid(samples.times, total, valid_frames, grid)
    share_g, share_valid = _on_grid(samples.times, share, share_mask, grid)
    cop_g = np.zeros((len(grid), 2, 2))
    cop_valid = np.zeros((len(grid), 2), dtype=bool)
    for s in range(2):
        cop_g[:, s], cop_valid[:, s] = _on_grid(
            samples.times, np.stack([along[:, s], side[:, s]], -1), cop_mask[:, s], grid
        )
    return FitSequence(
        x=resample_rows(samples.times, samples.features[:, columns].astype(float), grid).astype(np.float32),
        baseline=resample_rows(samples.times, samples.baseline, grid),
        total=total_g,
        valid=valid,
        share=share_g,
        share_mask=share_valid,
        cop=cop_g,
        cop_mask=cop_valid,
    )


def _windows(sequences: Sequence[FitSequence], length: int, count: int, rng: np.random.Generator) -> dict:
    """A batch of ``count`` random windows of ``length`` frames (trials picked in proportion to their valid
    frames; shorter trials padded with their last frame, masked out)."""
    weights = np.array([s.valid.sum() for s in sequences], dtype=float)
    picks = rng.choice(len(sequences), size=count, p=weights / weights.sum())
    batch: dict[str, list] = {
        k: [] for k in ("x", "baseline", "total", "valid", "share", "share_mask", "cop", "cop_mask")
    }
    for i in picks:
        s = sequences[i]
        start = int(rng.integers(0, max(1, len(s.x) - length + 1)))
        for key in batch:
            part = getattr(s, key)[start : start + length]
            if len(part) < length:
                pad = np.repeat(part[-1:], length - len(part), axis=0)
                if key in ("valid", "share_mask", "cop_mask"):
                    pad = np.zeros_like(pad)
                part = np.concatenate([part, pad])
            batch[key].append(part)
    return {k: torch.as_tensor(np.stack(v)) for k, v in batch.items()}


def _masked_mean(value: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    mask = mask.to(value.dtype)
    return (value * mask).sum() / mask.sum().clamp(min=1.0)


def objective(outputs: torch.Tensor, batch: dict, settings: FitSettings) -> tuple[torch.Tensor, dict[str, float]]:
    """The loss of raw outputs [B, T, 8] on a batch (module docstring), and its parts."""
    baseline, total = batch["baseline"].float(), batch["total"].float()
    valid = batch["valid"]
    predicted = baseline + outputs[..., :3]
    error = (predicted - total) ** 2
    vertical = _masked_mean(error[..., 1], valid)
    horizontal = _masked_mean(error[..., 0] + error[..., 2], valid)
    share = _masked_mean(
        F.binary_cross_entropy_with_logits(outputs[..., 3], batch["share"].float(), reduction="none"),
        batch["share_mask"],
    )
    low, high = ALONG_RANGE
    along = low + (high - low) * torch.sigmoid(outputs[..., [4, 6]])
    side = outputs[..., [5, 7]]
    cop_error = (along - batch["cop"][..., 0].float()) ** 2 + (side - batch["cop"][..., 1].float()) ** 2
    cop = _masked_mean(cop_error, batch["cop_mask"])
    loss = (
        vertical + settings.horizontal_weight * horizontal + settings.share_weight * share + settings.cop_weight * cop
    )
    parts = {
        name: float(value.detach())
        for name, value in (("vertical_mse", vertical), ("horizontal_mse", horizontal), ("share_bce", share))
    }
    parts["cop_mse"] = float(cop.detach())
    return loss, parts


def standardise(net: GroundForceNet, sequences: Sequence[FitSequence]) -> None:
    """Set the network's input mean and scale from the training frames."""
    x = np.concatenate([s.x for s in sequences]).astype(float)
    net.mean.copy_(torch.as_tensor(x.mean(0), dtype=torch.float32))
    net.scale.copy_(torch.as_tensor(np.maximum(x.std(0), 1e-6), dtype=torch.float32))


def vertical_rmse(model: LearnedGroundReaction, sequences: Sequence[FitSequence]) -> float:
    """Pooled vertical RMSE (BW) of ``model`` over the valid frames of ``sequences`` (on the network's clock)."""
    errors = []
    with torch.no_grad():
        for s in sequences:
            y = model.net.symmetric(torch.as_tensor(s.x)[None])[0].numpy()
            predicted = np.maximum(s.baseline[:, 1] + y[:, 1], 0.0)
            errors.append((predicted - s.total[:, 1])[s.valid])
    joined = np.concatenate(errors)
    return float(np.sqrt(np.mean(joined**2))) if joined.size else float("nan")


def fit(
    train: Sequence[TrialSamples],
    config: GroundForcesConfig,
    settings: FitSettings,
    *,
    seed: int = 0,
    validation: Sequence[TrialSamples] = (),
    eval_every: int = 500,
    log: Callable[[str], None] | None = None,
) -> tuple[LearnedGroundReaction, dict]:
    """Train a `LearnedGroundReaction` on ``train`` (module docstring); returns it and a record (iterations,
    seconds, loss history, and the vertical RMSE on ``validation`` every ``eval_every`` iterations when given).
    Runs in the calling thread count (the commands set one thread)."""
    if not train:
        raise ConfigError("no training trials with force plates")
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    sequences = [fit_sequence(s, config, settings) for s in train]
    held = [fit_sequence(s, config, settings) for s in validation]
    net = GroundForceNet(config)
    standardise(net, sequences)
    model = LearnedGroundReaction(net)
    optimiser = torch.optim.AdamW(net.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
    length = max(8, int(round(settings.window_s * config.rate_hz)))
    history: list[dict] = []
    started = time.perf_counter()
    running: dict[str, float] = {}
    for step in range(1, settings.iterations + 1):
        net.train()
        batch = _windows(sequences, length, settings.batch_size, rng)
        x = batch["x"].float()
        outputs = net(x)
        loss, parts = objective(outputs, batch, settings)
        if settings.mirror:
            mirrored, mirrored_parts = objective(net.mirror_outputs(net(net.mirror_inputs(x))), batch, settings)
            loss = 0.5 * (loss + mirrored)
            parts = {k: 0.5 * (v + mirrored_parts[k]) for k, v in parts.items()}
        progress = step / settings.iterations
        scale = min(1.0, step / max(1, settings.warmup)) * 0.5 * (1.0 + math.cos(math.pi * progress))
        for group in optimiser.param_groups:
            group["lr"] = settings.lr * scale
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        if settings.grad_clip:
            torch.nn.utils.clip_grad_norm_(net.parameters(), settings.grad_clip)
        optimiser.step()
        for k, v in parts.items():
            running[k] = running.get(k, 0.0) + v
        if step % eval_every == 0 or step == settings.iterations:
            count = eval_every if step % eval_every == 0 else step % eval_every
            entry = {"iteration": step, **{k: v / count for k, v in running.items()}}
            running = {}
            if held:
                net.eval()
                entry["validation_vertical_rmse_bw"] = vertical_rmse(model, held)
            entry["seconds"] = round(time.perf_counter() - started, 1)
            history.append(entry)
            if log is not None:
                log(" ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in entry.items()))
    net.eval()
    record = {
        "iterations": settings.iterations,
        "seconds": round(time.perf_counter() - started, 1),
        "history": history,
        "train_frames": int(sum(s.valid.sum() for s in sequences)),
        "parameters": sum(p.numel() for p in net.parameters()),
    }
    return model, record
