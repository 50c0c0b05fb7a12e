"""Train FlexMotion's control module (`biomotion.models.control_net`, FlexMotion Sec. 3.3) over the shipped, frozen
FlexMotion; write weights and card.

    biomotion train control-net --config configs/control_net.yaml --cache ~/.cache/biomotion/dataset \\
        --out checkpoints/control_net.safetensors [--data-root ../shared/data] [--seed N]

Data: the very windows FlexMotion trained on (`biomotion.training.flexmotion_data`, the ``train`` split only:
splits are by subject, so no window of a val or test subject is read), their latents through the frozen encoder
(scaled as FlexMotion scales them), and per window the origins of the canonical bodies (forward kinematics of the
window's coordinates in its own frame) and the total vertical ground reaction (sum of the foot points' vertical
forces of the contact solve).

Targets (Sec. 3.3: the control signal is drawn from the real clip's own modalities): per training window, with
probability ``p_none`` nothing, otherwise 1 to ``max_targets`` targets, each a quantity of that very window drawn
at random (`QUANTITY_SHARES`): the origin of a body whose joint chain the clip measures (x, y, z), the vertical
ground reaction, one joint's generalized force (a knee with probability ``p_knee``), one muscle's activation, or
one coordinate; over a time pattern drawn at random: a dense span of 8 frames up to the whole window, 1-8 sparse
frames, or every third frame over a span (the path targets of `biomotion eval control`).

Loss: FlexMotion's ε-prediction MSE (Sec. 3.2) with the control residuals added to the frozen denoiser, with text
and profile dropped as in FlexMotion's training (so classifier-free guidance samples with the module too), each
sample weighted min(SNR, γ) / SNR (``snr_gamma``; min-SNR weighting, Hang et al. 2023: the nearly clean steps,
whose ε the control says little about, otherwise dominate the gradient), plus ``consistency`` x the standardised
squared error between the constrained entries and the same quantities of the decoded clean-latent estimate
(x̂₀ from ε̂, through the frozen decoder, forward kinematics for body origins), weighted by ᾱ_t. The second term is
not in the paper; it is the direct signal ControlNet++ (Li et al. 2024) adds as a cycle-consistency loss. With
ε-MSE alone (and with min-SNR weighting alone) 800-step pilots left the control signal unused: the sampled clips
came out the same with and without it.

AdamW with cosine decay, gradient clipping, a fixed seed and ``threads`` torch threads, so the card's command
reproduces the weights (same torch and thread count).
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.body.canonical import COUPLED_COORDINATES
from biomotion.data.registry import DatasetCache
from biomotion.errors import ConfigError
from biomotion.io.paths import portable
from biomotion.models.control_net import (
    CONTROL_BODIES,
    CONTROL_DIM,
    CONTROL_SLICES,
    ControlNet,
    ControlNetConfig,
    position_channels,
)
from biomotion.models.flexmotion import FlexMotion
from biomotion.settings import settings_from_dict
from biomotion.training.cards import environment, write_card
from biomotion.training.flexmotion_data import MultimodalSet, MultimodalSettings, build
from biomotion.training.train_flexmotion import cosine_lr, encode_all, noised

#: shares of the quantities a random target constrains
QUANTITY_SHARES = {"position": 0.45, "grf": 0.15, "torque": 0.15, "activation": 0.1, "angle": 0.15}
KNEES = ("knee_angle_r", "knee_angle_l")


@dataclass(frozen=True)
class TrainSettings:
    iterations: int = 3000
    batch_size: int = 64
    lr: float = 3e-4
    weight_decay: float = 1e-4
    grad_clip: float = 1.0
    p_none: float = 0.1
    max_targets: int = 3
    p_knee: float = 0.3
    snr_gamma: float = 0.0
    consistency: float = 0.0
    threads: int = 1


@dataclass
class ControlData:
    """What target sampling reads per window: the set, its body origins [N, W, bodies, 3] (m, window frame),
    vertical force [N, W] (body weights), the bodies each window measures [N, bodies], its actuated present
    coordinates [N, 39] and the indices of `KNEES`."""

    data: MultimodalSet
    positions: torch.Tensor
    grf: torch.Tensor
    bodies: torch.Tensor
    actuated: torch.Tensor
    knees: list[int]


def body_chains(body) -> torch.Tensor:
    """[bodies, 39] bool: the coordinates of the joints between each control body and the ground (coupled ones
    excluded: they follow their knee)."""
    chains = torch.zeros(len(CONTROL_BODIES), len(body.coordinate_names), dtype=torch.bool)
    joint_of_child = {joint.child: joint for joint in body.joints}
    for k, name in enumerate(CONTROL_BODIES):
        b = body.body_index(name)
        while b >= 0 and b in joint_of_child:
            joint = joint_of_child[b]
            chains[k, list(joint.coordinates)] = True
            b = joint.parent
    coupled = [body.coordinate_names.index(c) for c in COUPLED_COORDINATES]
    chains[:, coupled] = False
    return chains


def control_data(data: MultimodalSet, refiner) -> ControlData:
    """Body origins, vertical force and per-window eligibility of ``data`` (module docstring)."""
    from biomotion.guidance.control import body_origins

    positions = []
    with torch.no_grad():
        for start in range(0, len(data), 128):
            rows = slice(start, min(start + 128, len(data)))
            full = refiner.full(data.q[rows], data.mask[rows])
            origins = body_origins(refiner.body, full)
            positions.append(origins[:, :, [refiner.body.body_index(b) for b in CONTROL_BODIES]])
    chains = body_chains(refiner.body)
    mask = data.mask.bool()
    bodies = (chains[None] <= mask[:, None]).all(-1)  # a body whose whole chain is measured
    names = refiner.body.coordinate_names
    actuated = mask.clone()
    actuated[:, [k for k, n in enumerate(names) if n.startswith("pelvis_") or n in COUPLED_COORDINATES]] = False
    knees = [names.index(k) for k in KNEES]
    return ControlData(data, torch.cat(positions), data.forces[..., 1].sum(-1), bodies, actuated, knees)


def _frames(window: int, generator: torch.Generator) -> torch.Tensor:
    """A random time pattern (module docstring): [window] bool."""
    frames = torch.zeros(window, dtype=torch.bool)
    kind = float(torch.rand((), generator=generator))
    if kind < 0.4:
        length = int(torch.randint(8, window + 1, (), generator=generator))
        start = int(torch.randint(0, window - length + 1, (), generator=generator))
        frames[start : start + length] = True
    elif kind < 0.75:
        count = int(torch.randint(1, 9, (), generator=generator))
        frames[torch.randperm(window, generator=generator)[:count]] = True
    else:
        length = int(torch.randint(15, window + 1, (), generator=generator))
        start = int(torch.randint(0, window - length + 1, (), generator=generator))
        frames[start : start + length : 3] = True
    return frames


def _pick(candidates: torch.Tensor, generator: torch.Generator) -> int | None:
    index = candidates.nonzero().flatten()
    if len(index) == 0:
        return None
    return int(index[torch.randint(len(index), (), generator=generator)])


def random_control(
    source: ControlData, rows: torch.Tensor, settings: TrainSettings, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """Raw control values and mask [B, W, CONTROL_DIM] drawn from the windows ``rows``' own modalities (module
    docstring)."""
    data = source.data
    b, w = len(rows), data.q.shape[1]
    values = torch.zeros(b, w, CONTROL_DIM)
    mask = torch.zeros(b, w, CONTROL_DIM, dtype=torch.bool)
    names, shares = list(QUANTITY_SHARES), torch.tensor(list(QUANTITY_SHARES.values()))
    for i, row in enumerate(rows.tolist()):
        if float(torch.rand((), generator=generator)) < settings.p_none:
            continue
        count = int(torch.randint(1, settings.max_targets + 1, (), generator=generator))
        for _ in range(count):
            quantity = names[int(torch.multinomial(shares, 1, generator=generator))]
            frames = _frames(w, generator)
            if quantity == "position":
                k = _pick(source.bodies[row], generator)
                if k is None:
                    continue
                channels = position_channels(CONTROL_BODIES[k])
                values[i, :, channels] = source.positions[row, :, k]
            elif quantity == "grf":
                channels = CONTROL_SLICES["grf"]
                values[i, :, channels] = source.grf[row, :, None]
            elif quantity == "activation":
                m = int(torch.randint(data.activations.shape[-1], (), generator=generator))
                channels = slice(CONTROL_SLICES["activations"].start + m, CONTROL_SLICES["activations"].start + m + 1)
                values[i, :, channels] = data.activations[row, :, m, None]
            else:
                present = source.actuated[row] if quantity == "torque" else data.mask[row].bool()
                k = _pick(present, generator)
                if k is None:
                    continue
                if quantity == "torque" and float(torch.rand((), generator=generator)) < settings.p_knee:
                    k = source.knees[int(torch.randint(2, (), generator=generator))]
                block, series = ("torques", data.torques) if quantity == "torque" else ("q", data.q)
                start = CONTROL_SLICES[block].start + k
                channels = slice(start, start + 1)
                values[i, :, channels] = series[row, :, k, None]
            mask[i, frames, channels] = True
    return values, mask


def decoded_control(model, refiner, z: torch.Tensor) -> torch.Tensor:
    """Raw control-layout values [B, W, CONTROL_DIM] of scaled latents z [B, d]: the frozen decoder's modalities,
    the body origins by forward kinematics of its coordinates and the vertical force summed over the foot points."""
    from biomotion.guidance.control import body_origins

    decoded = model.decode_latent(z)
    every = torch.ones(decoded["q"].shape[-1], dtype=torch.bool)
    origins = body_origins(refiner.body, refiner.full(decoded["q"], every))
    positions = origins[:, :, [refiner.body.body_index(b) for b in CONTROL_BODIES]].flatten(2)
    grf = decoded["forces"][..., 1].sum(-1, keepdim=True)
    return torch.cat([positions, decoded["q"], decoded["torques"], grf, decoded["activations"]], -1)


def control_loss(
    model, net, scheduler, z0, text, profile, values, mask, generator, settings=None, refiner=None
) -> tuple[torch.Tensor, dict[str, float]]:
    """ε-prediction MSE of the frozen denoiser with the control residuals (module docstring), per sample weighted
    min(SNR, γ) / SNR with ``snr_gamma`` γ > 0, plus ``consistency`` x the standardised squared error of the
    constrained entries of the decoded clean-latent estimate, weighted by ᾱ_t; returns (loss, terms)."""
    settings = settings or TrainSettings()
    noise, t, noisy, drop_text, drop_profile = noised(model, scheduler, z0, generator)
    x, m = net.standardise(values, mask)
    residuals = net.residuals(noisy, t, text, profile, x, m, drop_text, drop_profile)
    eps = model.denoiser(noisy, t, text, profile, drop_text, drop_profile, residuals)
    alpha = scheduler.alphas_cumprod[t].to(z0.dtype)
    per_sample = (eps - noise).square().mean(-1)
    if settings.snr_gamma > 0:
        snr = alpha / (1 - alpha)
        per_sample = per_sample * snr.clamp(max=settings.snr_gamma) / snr
    terms = {"eps": float(per_sample.mean().detach())}
    loss = per_sample.mean()
    if settings.consistency > 0 and refiner is not None:
        estimate = (noisy - (1 - alpha)[:, None].sqrt() * eps) / alpha[:, None].sqrt().clamp(min=0.05)
        got = (decoded_control(model, refiner, estimate) - net.mean) / net.std
        want = (values - net.mean) / net.std
        error = ((got - want).clamp(-10, 10).square() * m).sum((1, 2)) / m.sum((1, 2)).clamp(min=1)
        consistency = (alpha * error).mean()
        terms["consistency"] = float(consistency.detach())
        loss = loss + settings.consistency * consistency
    return loss, terms


def train(
    config: dict,
    cache_dir: str | Path,
    out: str | Path,
    *,
    data_root: str | Path = "../shared/data",
    seed: int = 0,
    sentence_embeddings=None,
    progress: bool = True,
    command: str = "",
) -> dict:
    """Train from ``config`` (``flexmotion``, ``surrogate``, ``model``, ``data``, ``train``) and save weights +
    card at ``out``; return the card."""
    from diffusers import DDPMScheduler

    from biomotion.body.kinematics import torch_threads
    from biomotion.data.clips import body_model
    from biomotion.models.motion_text_evaluator import embed_sentences
    from biomotion.models.refiner import Refiner, RefinerConfig

    try:
        net_cfg = ControlNetConfig.from_dict(config.get("model", {}))
        data_cfg = settings_from_dict(MultimodalSettings, config.get("data", {}), "control net data")
        settings = settings_from_dict(TrainSettings, config.get("train", {}), "control net train")
    except TypeError as error:
        raise ConfigError(f"control net config: {error}") from None
    flex_path = Path(config.get("flexmotion", "checkpoints/flexmotion.safetensors"))
    surrogate = Path(config.get("surrogate", "checkpoints/surrogate.safetensors"))
    for path, what in ((flex_path, "flexmotion"), (surrogate, "surrogate")):
        if not path.is_file():
            raise ConfigError(f"control net config: {what} {path} is not a file")
    model = FlexMotion.load(flex_path)
    model.requires_grad_(False)
    if data_cfg.window != model.config.window:
        raise ConfigError(f"control net config: data.window {data_cfg.window} != FlexMotion's {model.config.window}")
    cache = DatasetCache(cache_dir)
    if abs(cache.rate - model.config.rate) > 1e-6:
        raise ConfigError(f"cache at {cache.rate:g} Hz, FlexMotion at {model.config.rate:g} Hz")
    torch.manual_seed(seed)
    body = body_model(data_root)
    started = time.monotonic()
    with torch_threads(settings.threads):
        data = build(cache, body, surrogate, data_cfg, progress=progress)
        refiner = Refiner.new(RefinerConfig(rate=cache.rate), body)
        source = control_data(data, refiner)
        latents = encode_all(model, data) / model.latent_scale
        table = (sentence_embeddings or embed_sentences)(data.texts)
        net = ControlNet.from_flexmotion(model, net_cfg)
        net.set_statistics(source.positions.flatten(2).flatten(0, 1), source.grf.flatten())
        build_seconds = time.monotonic() - started
        scheduler = DDPMScheduler(num_train_timesteps=model.config.train_timesteps, beta_schedule="squaredcos_cap_v2")
        trainable = [p for p in net.parameters() if p.requires_grad]
        optimiser = torch.optim.AdamW(trainable, lr=settings.lr, weight_decay=settings.weight_decay)
        generator = torch.Generator().manual_seed(seed)
        history, running = [], []
        t0 = time.monotonic()
        for step in range(settings.iterations):
            for group in optimiser.param_groups:
                group["lr"] = cosine_lr(step, settings.iterations, settings.lr)
            rows = torch.randint(len(data), (settings.batch_size,), generator=generator)
            values, mask = random_control(source, rows, settings, generator)
            loss, terms = control_loss(model, net, scheduler, latents[rows], table[data.text_ids[rows]],
                                       data.profiles[rows], values, mask, generator, settings, refiner)  # fmt: skip
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(trainable, settings.grad_clip)
            optimiser.step()
            running.append({"loss": float(loss.detach()), **terms})
            if (step + 1) % max(settings.iterations // 15, 1) == 0 or step + 1 == settings.iterations:
                means = {k: round(float(np.mean([r[k] for r in running])), 5) for k in running[0]}
                history.append({"step": step + 1, **means})
                running = []
                if progress:
                    print(f"control net {history[-1]} ({time.monotonic() - t0:.0f} s)", flush=True)
        train_seconds = time.monotonic() - t0
    net.eval()
    train_subjects = sorted(set(data.subjects))
    held = sorted({f"{r['source']}/{r['subject']}" for r in cache.records if r["split"] != "train"})
    flex_sha = hashlib.sha256(flex_path.read_bytes()).hexdigest()
    net.metadata = {"train_subjects": train_subjects, "flexmotion_sha256": flex_sha, "command": command}
    out = Path(out)
    net.save(out)
    card = {
        "model": "biomotion FlexMotion control module (ControlNet over the frozen latent denoiser; FlexMotion "
        "Sec. 3.3)",
        "weights": out.name,
        "sha256": hashlib.sha256(out.read_bytes()).hexdigest(),
        "command": command or "biomotion.training.train_control_net.train (Python API)",
        "config": config,
        "seed": seed,
        "threads": settings.threads,
        "flexmotion": {"weights": portable(flex_path), "sha256": flex_sha},
        "data": {
            "cache": portable(cache.folder),
            "cache_format": cache.manifest.get("format"),
            "split_rule": cache.manifest.get("split_rule"),
            "split": data_cfg.split,
            "clips": data.clips,
            "windows": len(data),
            "window_frames": model.config.window,
            "rate_hz": cache.rate,
            "train_subjects": len(train_subjects),
            "held_out_subjects_shared": len(set(train_subjects) & set(held)),
            "targets": "drawn per window from its own modalities: body origins, vertical GRF, a joint's "
            "generalized force, a muscle's activation, a coordinate; dense spans, sparse frames, every third frame",
        },
        "trainable_parameters": sum(p.numel() for p in trainable),
        "seconds": {"data_and_latents": round(build_seconds, 1), "training": round(train_seconds, 1)},
        "history": history,
        "environment": environment(torch_threads=settings.threads),
    }
    write_card(out, card, markdown(card))
    return card


def markdown(card: dict) -> str:
    d, s = card["data"], card["seconds"]
    return (
        f"# FlexMotion control module: {card['weights']}\n\n{card['model']}.\n\n"
        f"- SHA-256: `{card['sha256']}`\n- command: `{card['command']}`\n"
        f"- over FlexMotion `{card['flexmotion']['weights']}` (SHA-256 `{card['flexmotion']['sha256']}`), frozen\n"
        f"- seed {card['seed']}, {card['threads']} torch thread(s); data and latents {s['data_and_latents']} s, "
        f"training {s['training']} s (torch {card['environment']['torch']}); "
        f"{card['trainable_parameters']} trainable parameters\n"
        f"- data: {d['windows']} windows of {d['window_frames']} frames at {d['rate_hz']:g} Hz from {d['clips']} "
        f"clips of the `{d['split']}` split ({d['train_subjects']} subjects, none held out); split rule: "
        f"{d['split_rule']}\n"
        f"- targets: {d['targets']}\n"
        f"- final terms (loss = min-SNR-weighted ε-MSE + consistency x decoded-target error): {card['history'][-1]}\n"
    )
