"""Train FlexMotion (`biomotion.models.flexmotion`) on the multimodal windows of a dataset cache; write weights and
card.

    biomotion train flexmotion --config configs/flexmotion.yaml --cache ~/.cache/biomotion/dataset \\
        --out checkpoints/flexmotion.safetensors [--data-root ../shared/data] [--seed N]

Data: `biomotion.training.flexmotion_data` (training split only; splits are by subject, so no window of a val or
test subject is read).

Stage 1, the physics-aware autoencoder (FlexMotion Sec. 3.1, Eq. 8): L = ``recon`` x the reconstruction error of
the standardised present features (Huber with ``huber_delta``, `biomotion.models.flexmotion.masked_mse`; the paper
uses the squared error) + ``euler`` x L_euler. L_euler is the Euler-Lagrange residual of the *decoded* modalities,
|M(q) q̈ + C(q, q̇) + g − J_cᵀ λ − τ|₁ in body weights, with q̈ by the central differences of the decoded
coordinates, λ the decoded contact forces applied at the contact points of the decoded pose and τ the decoded
torques, on ``euler_frames`` interior frames per window over the present coordinates; it is computed as the
PhysPT refiner's L_euler is (`biomotion.training.train_refiner.step_losses`): `Refiner.full`, `Refiner.kinematics`,
`finite_rates` and `biomotion.body.dynamics.inverse_dynamics` with `ExternalLoad` per contact point; with
``euler_kinematics_grad`` false the decoded coordinates enter it as constants (only τ and λ are moved; measured
worse, docs/decisions/flexmotion-capacity.md, so the paper's full gradient is the default). L_muscle
(Eq. 7, activations that produce the torques through moment arms) is not trained: activations are reconstructed
only.

Stage 2, latent diffusion (Sec. 3.2): the autoencoder frozen, the latents of all windows (scaled to unit standard
deviation), ε-prediction MSE under `diffusers`' DDPMScheduler (squared-cosine betas) with text and profile each
replaced by the null condition with probability ``cond_dropout`` (classifier-free guidance).

AdamW with cosine decay, gradient clipping, a fixed seed and ``threads`` torch threads, so the card's command
reproduces the weights (same torch and thread count).
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.body.dynamics import ExternalLoad, inverse_dynamics
from biomotion.data.registry import DatasetCache
from biomotion.errors import ConfigError
from biomotion.io.paths import portable
from biomotion.models.flexmotion import FlexMotion, FlexMotionConfig, join, masked_mse, split
from biomotion.models.refiner import GRAVITY, Refiner, RefinerConfig, finite_rates
from biomotion.settings import settings_from_dict
from biomotion.training.cards import environment, write_card
from biomotion.training.flexmotion_data import MultimodalSet, MultimodalSettings, build


@dataclass(frozen=True)
class TrainSettings:
    ae_iterations: int = 1500
    diffusion_iterations: int = 3000
    batch_size: int = 32
    diffusion_batch: int = 64
    lr: float = 1e-3
    diffusion_lr: float = 5e-4
    weight_decay: float = 1e-4
    grad_clip: float = 1.0
    recon: float = 1.0
    huber_delta: float = 1.0
    euler: float = 0.1
    euler_frames: int = 4
    euler_warmup: int = 300
    euler_kinematics_grad: bool = True
    threads: int = 1


def features(data: MultimodalSet, rows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Raw features [B, W, F] of windows ``rows`` and their presence [B, 1, F] (coordinate mask on q, q̇ and τ;
    the force and activation flags on theirs)."""
    x = join(data.q[rows], data.qd[rows], data.torques[rows], data.forces[rows], data.activations[rows])
    mask = data.mask[rows]
    force = data.force_present[rows, None].expand(-1, data.forces.shape[2] * 3)
    act = data.activation_present[rows, None].expand(-1, data.activations.shape[-1])
    return x, torch.cat([mask, mask, mask, force, act], -1)[:, None, :]


def euler_loss(
    refiner: Refiner,
    decoded: dict[str, torch.Tensor],
    mask: torch.Tensor,
    frames: int,
    generator: torch.Generator,
    kinematics_grad: bool = True,
) -> torch.Tensor:
    """L_euler (module docstring) of decoded modalities (`split` of raw features, [B, W, ·]) in body weights; with
    ``kinematics_grad`` False the decoded coordinates enter as constants, so the term moves only the decoded
    torques and contact forces towards what the decoded motion needs."""
    full = refiner.full(decoded["q"] if kinematics_grad else decoded["q"].detach(), mask)
    qd, qdd = finite_rates(full, refiner.config.rate)
    _, feet = refiner.kinematics(full)
    b, w = full.shape[:2]
    picks = torch.randint(1, w - 1, (b, frames), generator=generator)
    rows = torch.arange(b)[:, None].expand_as(picks)
    weight = float(refiner.body.total_mass) * GRAVITY
    loads = [
        ExternalLoad(
            refiner.body.body_names[int(refiner.feet.bodies[k])],
            decoded["forces"][rows, picks, k] * weight,
            feet[rows, picks, k],
        )
        for k in range(len(refiner.feet.names))
    ]
    generalized = inverse_dynamics(refiner.body, full[rows, picks], qd[rows, picks], qdd[rows, picks], loads)
    residual = (generalized / weight - decoded["torques"][rows, picks]) * mask[:, None, :]
    return residual.abs().sum(-1).mean()


def cosine_lr(step: int, total: int, lr: float) -> float:
    """The learning rate at ``step`` of ``total`` on a cosine decay from ``lr`` to 0."""
    return lr * 0.5 * (1 + math.cos(math.pi * step / max(total, 1)))


def set_normalisation(model: FlexMotion, data: MultimodalSet) -> None:
    """Per-feature mean and std over the present entries of the training windows."""
    x, present = features(data, torch.arange(len(data)))
    keep = present.expand_as(x).double()
    count = keep.sum((0, 1)).clamp(min=1)
    mean = (x.double() * keep).sum((0, 1)) / count
    std = (((x.double() - mean) ** 2 * keep).sum((0, 1)) / count).sqrt()
    model.autoencoder.mean.copy_(mean.float())
    model.autoencoder.std.copy_(torch.where(std > 1e-4, std, torch.ones_like(std)).float())


def train_autoencoder(model, refiner, data, settings, generator, progress=True) -> list[dict]:
    """Stage 1 (module docstring); returns the loss history."""
    ae = model.autoencoder
    optimiser = torch.optim.AdamW(ae.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
    history = []
    for step in range(settings.ae_iterations):
        for group in optimiser.param_groups:
            group["lr"] = cosine_lr(step, settings.ae_iterations, settings.lr)
        rows = torch.randint(len(data), (settings.batch_size,), generator=generator)
        loss, terms = autoencoder_loss(model, refiner, data, rows, settings, generator, step)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(ae.parameters(), settings.grad_clip)
        optimiser.step()
        if (step + 1) % max(settings.ae_iterations // 15, 1) == 0 or step + 1 == settings.ae_iterations:
            history.append(
                {
                    "step": step + 1,
                    **{k: round(float(v.detach() if torch.is_tensor(v) else v), 5) for k, v in terms.items()},
                }
            )
            if progress:
                print(f"flexmotion autoencoder {history[-1]}", flush=True)
    return history


def autoencoder_loss(model, refiner, data, rows, settings, generator, step: int = 10**9):
    """Eq. 8 on the windows ``rows``: (loss, terms)."""
    x, present = features(data, rows)
    target = model.normalise(x)
    latent = model.autoencoder.encode(target, present)
    out = model.autoencoder.decode(latent)
    terms = {"recon": masked_mse(out, target, present, settings.huber_delta)}
    euler_weight = settings.euler * min(1.0, step / max(settings.euler_warmup, 1))
    if settings.euler > 0:
        terms["euler"] = euler_loss(refiner, split(model.denormalise(out)), data.mask[rows], settings.euler_frames,
                                    generator, settings.euler_kinematics_grad)  # fmt: skip
    loss = settings.recon * terms["recon"] + euler_weight * terms.get("euler", 0.0)
    return loss, {"loss": loss, **terms}


@torch.no_grad()
def encode_all(model: FlexMotion, data: MultimodalSet) -> torch.Tensor:
    """Unscaled flat latents [N, d] of every window."""
    out = []
    for start in range(0, len(data), 256):
        rows = torch.arange(start, min(start + 256, len(data)))
        x, present = features(data, rows)
        out.append(model.autoencoder.encode(model.normalise(x), present).flatten(1))
    return torch.cat(out)


def train_diffusion(model, latents, text_table, data, settings, generator, progress=True) -> list[dict]:
    """Stage 2 (module docstring) on scaled latents [N, d]; returns the loss history."""
    from diffusers import DDPMScheduler

    c = model.config
    scheduler = DDPMScheduler(num_train_timesteps=c.train_timesteps, beta_schedule="squaredcos_cap_v2")
    net = model.denoiser
    optimiser = torch.optim.AdamW(net.parameters(), lr=settings.diffusion_lr, weight_decay=settings.weight_decay)
    history, running = [], []
    for step in range(settings.diffusion_iterations):
        for group in optimiser.param_groups:
            group["lr"] = cosine_lr(step, settings.diffusion_iterations, settings.diffusion_lr)
        rows = torch.randint(len(latents), (settings.diffusion_batch,), generator=generator)
        loss = diffusion_loss(model, scheduler, latents[rows], text_table[data.text_ids[rows]], data.profiles[rows],
                              generator)  # fmt: skip
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), settings.grad_clip)
        optimiser.step()
        running.append(float(loss.detach()))
        if (step + 1) % max(settings.diffusion_iterations // 15, 1) == 0 or step + 1 == settings.diffusion_iterations:
            history.append({"step": step + 1, "loss": round(float(np.mean(running)), 5)})
            running = []
            if progress:
                print(f"flexmotion diffusion {history[-1]}", flush=True)
    return history


def noised(model, scheduler, z0: torch.Tensor, generator: torch.Generator) -> tuple[torch.Tensor, ...]:
    """A training draw for latents z0 [B, d]: (noise, timesteps, noisy latents, text dropped, profile dropped),
    the timesteps uniform over the schedule and each condition dropped with ``cond_dropout`` (DDPM training with
    classifier-free guidance). The draws come in a fixed order from ``generator``, so seeded runs repeat."""
    b, p = len(z0), model.config.cond_dropout
    noise = torch.randn(z0.shape, generator=generator)
    t = torch.randint(0, model.config.train_timesteps, (b,), generator=generator)
    noisy = scheduler.add_noise(z0, noise, t)
    drop_text = torch.rand(b, generator=generator) < p
    drop_profile = torch.rand(b, generator=generator) < p
    return noise, t, noisy, drop_text, drop_profile


def diffusion_loss(model, scheduler, z0, text, profile, generator) -> torch.Tensor:
    """ε-prediction MSE at random timesteps with condition dropout (module docstring)."""
    noise, t, noisy, drop_text, drop_profile = noised(model, scheduler, z0, generator)
    return (model.denoiser(noisy, t, text, profile, drop_text, drop_profile) - noise).square().mean()


def train(
    config: dict,
    cache_dir: str | Path,
    out: str | Path,
    *,
    data_root: str | Path = "../shared/data",
    surrogate: str | Path = "checkpoints/surrogate.safetensors",
    seed: int = 0,
    sentence_embeddings=None,
    progress: bool = True,
    command: str = "",
) -> dict:
    """Train from ``config`` (``model``, ``data``, ``train``) and save weights + card at ``out``; return the card."""
    from biomotion.body.kinematics import torch_threads
    from biomotion.data.clips import body_model
    from biomotion.models.motion_text_evaluator import embed_sentences

    try:
        model_cfg = FlexMotionConfig.from_dict(config.get("model", {}))
        data_cfg = settings_from_dict(MultimodalSettings, config.get("data", {}), "flexmotion data")
        settings = settings_from_dict(TrainSettings, config.get("train", {}), "flexmotion train")
    except TypeError as error:
        raise ConfigError(f"flexmotion config: {error}") from None
    if data_cfg.window != model_cfg.window:
        raise ConfigError(f"flexmotion config: data.window {data_cfg.window} != model.window {model_cfg.window}")
    cache = DatasetCache(cache_dir)
    if abs(cache.rate - model_cfg.rate) > 1e-6:
        raise ConfigError(f"cache at {cache.rate:g} Hz, the flexmotion config at {model_cfg.rate:g} Hz")
    torch.manual_seed(seed)
    body = body_model(data_root)
    started = time.monotonic()
    with torch_threads(settings.threads):
        data = build(cache, body, surrogate, data_cfg, progress=progress)
        build_seconds = time.monotonic() - started
        refiner = Refiner.new(RefinerConfig(rate=cache.rate), body)
        table = (sentence_embeddings or embed_sentences)(data.texts)
        model = FlexMotion(model_cfg)
        set_normalisation(model, data)
        generator = torch.Generator().manual_seed(seed)
        t0 = time.monotonic()
        ae_history = train_autoencoder(model, refiner, data, settings, generator, progress)
        ae_seconds = time.monotonic() - t0
        model.autoencoder.requires_grad_(False)
        latents = encode_all(model, data)
        model.latent_scale.fill_(float(latents.std()))
        t0 = time.monotonic()
        diffusion_history = train_diffusion(model, latents / model.latent_scale, table, data, settings, generator,
                                            progress)  # fmt: skip
        diffusion_seconds = time.monotonic() - t0
    model.eval()
    train_subjects = sorted(set(data.subjects))
    held = sorted({f"{r['source']}/{r['subject']}" for r in cache.records if r["split"] != "train"})
    model.metadata = {"train_subjects": train_subjects, "texts": data.texts, "command": command}
    out = Path(out)
    model.save(out)
    card = {
        "model": "biomotion FlexMotion (physics-aware multimodal autoencoder + latent diffusion; FlexMotion Sec. 3)",
        "weights": out.name,
        "sha256": hashlib.sha256(out.read_bytes()).hexdigest(),
        "command": command or "biomotion.training.train_flexmotion.train (Python API)",
        "config": config,
        "seed": seed,
        "threads": settings.threads,
        "data": {
            "cache": portable(cache.folder),
            "cache_format": cache.manifest.get("format"),
            "split_rule": cache.manifest.get("split_rule"),
            "split": data_cfg.split,
            "clips": data.clips,
            "clips_limited_to": data_cfg.max_clips or "all of the split with at least one window",
            "windows": len(data),
            "window_frames": model_cfg.window,
            "rate_hz": cache.rate,
            "train_subjects": len(train_subjects),
            "held_out_subjects_shared": len(set(train_subjects) & set(held)),
            "texts": len(data.texts),
            "ground_reaction": "contact solve (infer_ground_reaction) on every window: no plate data in the cache",
            "activations": "shipped muscle surrogate (checkpoints/surrogate.safetensors)",
        },
        "latent_dim": model_cfg.latent_dim,
        "input_dim": model_cfg.window * model.autoencoder.mean.numel(),
        "seconds": {
            "data_build_or_load": round(build_seconds, 1),
            "autoencoder": round(ae_seconds, 1),
            "diffusion": round(diffusion_seconds, 1),
        },
        "history_autoencoder": ae_history,
        "history_diffusion": diffusion_history,
        "not_trained": "L_muscle (Eq. 7): activations are reconstructed, not tied to the torques",
        "environment": environment(torch_threads=settings.threads),
    }
    write_card(out, card, markdown(card))
    return card


def markdown(card: dict) -> str:
    d, s = card["data"], card["seconds"]
    last_ae, last_df = card["history_autoencoder"][-1], card["history_diffusion"][-1]
    return (
        f"# FlexMotion: {card['weights']}\n\n{card['model']}.\n\n"
        f"- SHA-256: `{card['sha256']}`\n- command: `{card['command']}`\n"
        f"- seed {card['seed']}, {card['threads']} torch thread(s); data {s['data_build_or_load']} s, autoencoder "
        f"{s['autoencoder']} s, diffusion {s['diffusion']} s (torch {card['environment']['torch']})\n"
        f"- data: {d['windows']} windows of {d['window_frames']} frames at {d['rate_hz']:g} Hz from {d['clips']} "
        f"clips of the `{d['split']}` split ({d['train_subjects']} subjects, none held out; clips: "
        f"{d['clips_limited_to']}), {d['texts']} distinct texts; split rule: {d['split_rule']}\n"
        f"- ground reaction: {d['ground_reaction']}; activations: {d['activations']}\n"
        f"- latent d = {card['latent_dim']} for an input of D = {card['input_dim']}\n"
        f"- final autoencoder terms: {last_ae}; final diffusion loss {last_df['loss']}\n"
        f"- not trained: {card['not_trained']}\n"
    )
