"""Train the PhysPT refiner (`biomotion.models.refiner`) self-supervised on a dataset cache; write weights and card.

    biomotion train refiner --config configs/refiner.yaml --cache DIR --out checkpoints/refiner.safetensors \\
        [--data-root ../shared/data] [--iterations N] [--seed N] [--threads N]

Data. The cache's train split (subject-level, `biomotion.data.registry`), without the sources in
``data.exclude_sources`` (OpenCap: kept for testing); the val split of the same sources tunes what is tuned (the
low-pass baseline's cutoff) and is scored during training. Windows of ``model.window`` frames start every
``data.stride`` frames; clips shorter than a window (down to ``data.min_frames``) are one window, padded.

Targets (PhysPT Sec. 3.2.4, Eq. 5). Per clean training clip, once: velocities and accelerations by central finite
differences at the cache rate, then the contact QP of `biomotion.body.contact.infer_ground_reaction` for the point
forces λ̄ [T, K, 3] and the generalized forces τ̄ [T, 39] (inverse dynamics with those loads). They are cached
under ``~/.cache/biomotion/refiner/`` keyed by the cache's contents.

Self-supervision (Sec. 3.2.1). Each batch of clean windows q̄ is corrupted on the fly (`biomotion.data.noise`:
jitter, drift, foot sliding, root bounce, dropped frames) and the refiner must return q̄. The loss is Eq. 9,
L = L_recon + L_force + L_contact + L_euler, with the weights of ``loss``:

- L_recon (Eq. 3): ``q`` × squared error of the coordinates (standardised, window frame, present coordinates) +
  ``joints`` × squared error of the joint centres relative to the pelvis (m², forward kinematics of the canonical
  body) + ``path`` × squared error of the pelvis position (m²; weighed apart, as the drift of a global path is only
  partly recoverable from the legs); plus, not in the paper, ``acceleration`` × the mean norm of the joint centres'
  acceleration error (m/s², the ACCL the refiner is scored on: PhysPT gets its smoothness from the decoder, a small
  model on little data needs the push);
- L_force (Eq. 6): ``torque`` × |τ − τ̄|₁ + ``force`` × |λ − λ̄|₁, in body weights (N / (m g); N·m / (m g · 1 m)),
  λ the contact head's edge magnitudes through the gate of the refined motion (`FootContact`);
- L_contact (Eq. 7): over the points whose QP force on the clean clip carries more than 20 N (the set C_t),
  ``contact_velocity`` × |v|₁ (m/s) + ``contact_height`` × |h| (m), h the height above the point's resting height
  (the QP's 2nd percentile of the clean clip);
- L_euler (Eq. 8): ``euler`` × |M q̈ + C + g − J_cᵀ λ̄ − τ̄|₁ in body weights: inverse dynamics of the refined
  motion (central differences, as the targets) with the clean clip's contact forces applied at the refined
  contact points, against τ̄; on ``train.euler_frames`` interior frames per window (PhysPT evaluates all; the
  subsample keeps a step affordable on a CPU);
- not in the paper, ``root`` × |root rows of M q̈ + C + g − J_cᵀ λ|₁ with the *predicted* forces λ: the unactuated
  pelvis moved by the contact alone (Eq. 2), on whole-body clips only (trunk measured: the Fukuchi models lump
  trunk and arms into the pelvis, so even their clean clips leave 0.2-0.6 body weights unexplained).

Optimisation (Sec. 4 "Implementation": Adam, weight decay 1e-4): AdamW, linear warm-up, cosine decay to
``lr_final``, gradient clipping; ``train.iterations`` steps with a fixed seed, so the shipped weights are
reproduced by the command on their card (on the same torch and thread count).

After training, on the whole val clips corrupted with every kind of noise at once (``eval_noise``, fixed seed): the
refiner's ACCL, FS and MJE against the clean clips, the noisy input's, and those of a 4th-order zero-lag
Butterworth low-pass whose cutoff is chosen on these clips (lowest ACCL over ``lowpass.cutoffs_hz``): the cutoff
`biomotion eval refine` filters with, recorded in the weights' metadata, so no setting is chosen on test subjects.
"""

from __future__ import annotations

import hashlib
import math
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.body.contact import ContactSettings, infer_ground_reaction
from biomotion.body.dynamics import ExternalLoad, inverse_dynamics
from biomotion.data.noise import NoiseLevels, corrupt
from biomotion.data.registry import DatasetCache
from biomotion.errors import BiomotionError, ConfigError
from biomotion.io.paths import portable
from biomotion.metrics.contact import FORCE_THRESHOLD
from biomotion.metrics.reconstruction import joint_error
from biomotion.metrics.smoothness import acceleration_error
from biomotion.models.refiner import (
    GRAVITY,
    ROOT,
    Refiner,
    RefinerConfig,
    finite_rates,
    refinement_scores,
    to_local,
    window_frame,
)
from biomotion.motion import lowpass
from biomotion.settings import settings_from_dict
from biomotion.training.cards import environment, write_card

LABELS_FORMAT = "biomotion-refiner-labels/1"
TRUNK = CANONICAL_COORDINATES.index("lumbar_extension")  # a clip with its trunk measured is a whole body


@dataclass(frozen=True)
class LossWeights:
    """Weights of the loss terms (module docstring)."""

    q: float = 1.0
    joints: float = 1000.0
    path: float = 100.0
    acceleration: float = 0.05
    torque: float = 0.1
    force: float = 0.1
    contact_velocity: float = 0.5
    contact_height: float = 5.0
    euler: float = 0.05
    root: float = 0.0


@dataclass(frozen=True)
class TrainSettings:
    batch_size: int = 16
    iterations: int = 12000
    lr: float = 3e-4
    lr_final: float = 1e-5
    weight_decay: float = 1e-4
    warmup: int = 500
    grad_clip: float = 1.0
    eval_every: int = 1000
    euler_frames: int = 8
    threads: int = 2


@dataclass(frozen=True)
class DataSettings:
    stride: int = 8
    min_frames: int = 8
    exclude_sources: tuple[str, ...] = ("opencap",)
    val_clips_max_frames: int = 300
    recipe: str = ""  # how the cache was built, copied to the card (the cache's own manifest does not say)


# ---- data -----------------------------------------------------------------------------------------------------


@dataclass
class ClipData:
    """Clean clips of one split, concatenated: coordinates [N, 39], the QP's point forces [N, K, 3] and generalized
    forces [N, 39], per clip its mask [39], resting heights of its contact points [K], offset and length."""

    q: torch.Tensor
    forces: torch.Tensor
    torques: torch.Tensor
    masks: torch.Tensor
    rest: torch.Tensor
    offsets: np.ndarray
    lengths: np.ndarray
    subjects: list[str]


def cache_folder() -> Path:
    """``~/.cache/biomotion/refiner`` (or under ``$XDG_CACHE_HOME``): the QP targets, computed once per cache."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "biomotion" / "refiner"


def qp_targets(refiner: Refiner, q: torch.Tensor, mask: torch.Tensor, rate: float) -> dict[str, torch.Tensor]:
    """The contact QP (PhysPT Eq. 5, `infer_ground_reaction`) on one clean clip q [T, 39]: point forces [T, K, 3],
    generalized forces [T, 39] and the contact points' resting heights [K], in float64 then float32."""
    body = refiner.body.to(torch.float64)
    full = refiner.full(q.double(), mask).double()
    qd, qdd = finite_rates(full, rate)
    inferred = infer_ground_reaction(body, full, qd, qdd)
    rest = torch.quantile(inferred.point_positions[..., 1], ContactSettings().rest_percentile / 100.0, dim=0)
    return {"forces": inferred.point_forces.float(), "torques": inferred.torques.float(), "rest": rest.float()}


def load_clips(cache: DatasetCache, indices: list[int], refiner: Refiner, progress: bool = True) -> ClipData:
    """The clips ``indices`` of ``cache`` with their QP targets (read from, or computed once into, `cache_folder`)."""
    from safetensors.torch import load_file, save_file

    digest = hashlib.sha256((cache.folder / "clips.safetensors").read_bytes())
    digest.update(repr((LABELS_FORMAT, ContactSettings(), [cache.records[i]["clip_id"] for i in indices])).encode())
    path = cache_folder() / f"labels-{digest.hexdigest()[:20]}.safetensors"
    q = torch.from_numpy(np.concatenate([cache.motion(i).values for i in indices])).float()
    masks = torch.from_numpy(np.stack([cache.masks[i] for i in indices]))
    lengths = np.array([cache.records[i]["n_frames"] for i in indices])
    offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    if path.exists():
        labels = load_file(str(path))
    else:
        parts = []
        for k in tqdm(range(len(indices)), desc="contact QP on clean clips", unit="clip", disable=not progress):
            parts.append(qp_targets(refiner, q[offsets[k] : offsets[k] + lengths[k]], masks[k], cache.rate))
        labels = {key: torch.cat([p[key] for p in parts]) for key in ("forces", "torques")}
        labels["rest"] = torch.stack([p["rest"] for p in parts])
        path.parent.mkdir(parents=True, exist_ok=True)
        save_file(labels, str(path.with_suffix(".tmp")))
        path.with_suffix(".tmp").replace(path)
    subjects = [f"{cache.records[i]['source']}/{cache.records[i]['subject']}" for i in indices]
    return ClipData(q, labels["forces"], labels["torques"], masks, labels["rest"], offsets, lengths, subjects)


def window_starts(data: ClipData, length: int, stride: int) -> np.ndarray:
    """[N, 2] (clip, first frame) of every training window; a clip shorter than ``length`` gives one."""
    rows = []
    for clip, n in enumerate(data.lengths):
        local = np.unique(np.append(np.arange(0, max(n - length, 0) + 1, stride), max(n - length, 0)))
        rows.append(np.stack([np.full(len(local), clip), local], 1))
    return np.concatenate(rows)


@dataclass
class Batch:
    """Clean windows q [B, W, 39] (padded by repeating the last frame), mask [B, 39], valid [B, W], targets
    forces [B, W, K, 3] and torques [B, W, 39], resting heights [B, K]."""

    q: torch.Tensor
    mask: torch.Tensor
    valid: torch.Tensor
    forces: torch.Tensor
    torques: torch.Tensor
    rest: torch.Tensor


def make_batch(data: ClipData, rows: np.ndarray, length: int) -> Batch:
    clips, starts = rows[:, 0], rows[:, 1]
    last = data.offsets[clips] + data.lengths[clips] - 1
    frames = np.minimum(data.offsets[clips, None] + starts[:, None] + np.arange(length), last[:, None])
    valid = torch.from_numpy(starts[:, None] + np.arange(length) < data.lengths[clips, None])
    index = torch.from_numpy(frames)
    clip_index = torch.from_numpy(clips)
    return Batch(
        data.q[index], data.masks[clip_index], valid, data.forces[index], data.torques[index], data.rest[clip_index]
    )


# ---- losses ---------------------------------------------------------------------------------------------------


def _masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    mask = mask.to(x.dtype)
    return (x * mask).sum() / mask.sum().clamp(min=1.0)


def step_losses(
    refiner: Refiner,
    batch: Batch,
    noisy: torch.Tensor,
    weights: LossWeights,
    euler_frames: int,
    generator: torch.Generator,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Eq. 9 on one batch: the refiner's output for ``noisy`` against the clean ``batch`` (module docstring)."""
    net, rate = refiner.net, refiner.config.rate
    weight = float(refiner.body.total_mass) * GRAVITY
    estimate = net(noisy, batch.mask, batch.valid)
    valid, present = batch.valid, batch.mask[:, None, :].expand_as(batch.q)
    terms: dict[str, torch.Tensor] = {}

    # L_recon (Eq. 3) and the acceleration term
    frame = window_frame(noisy, valid)
    error = (to_local(estimate.q, frame) - to_local(batch.q, frame)) / net.std
    terms["q"] = _masked_mean(error.square(), present & valid[..., None])
    full, clean_full = refiner.full(estimate.q, batch.mask), refiner.full(batch.q, batch.mask)
    joints, feet = refiner.kinematics(full)
    with torch.no_grad():
        clean_joints, _ = refiner.kinematics(clean_full)
    relative, clean_relative = joints - joints[..., :1, :], clean_joints - clean_joints[..., :1, :]
    terms["joints"] = _masked_mean((relative - clean_relative).square().sum(-1).mean(-1), valid)
    terms["path"] = _masked_mean((joints[..., 0, :] - clean_joints[..., 0, :]).square().sum(-1), valid)
    accel = torch.diff(joints - clean_joints, 2, dim=1).norm(dim=-1).mean(-1) * rate**2
    terms["acceleration"] = _masked_mean(accel, valid[:, 2:] & valid[:, :-2])

    # L_force (Eq. 6): torques, and contact forces through the gate of the refined motion (Eq. 4)
    terms["torque"] = _masked_mean((estimate.torques - batch.torques).abs().sum(-1), valid) / weight
    height = feet[..., 1] - batch.rest[:, None, :]
    vertical = torch.gradient(feet[..., 1], spacing=1.0 / rate, dim=1)[0]
    forces = refiner.contact.forces(estimate.edges, refiner.contact.gate(height, vertical))
    terms["force"] = _masked_mean((forces - batch.forces).abs().sum((-1, -2)), valid) / weight

    # L_contact (Eq. 7): points the clean clip loads must stay still and on the floor
    loaded = (batch.forces[..., 1] > FORCE_THRESHOLD) & valid[..., None]
    velocity = torch.gradient(feet, spacing=1.0 / rate, dim=1)[0]
    terms["contact_velocity"] = _masked_mean(velocity.abs().sum(-1), loaded)
    terms["contact_height"] = _masked_mean(height.abs(), loaded)

    # L_euler (Eq. 8) on a few interior frames per window
    qd, qdd = finite_rates(full, rate)
    lengths = valid.sum(1)
    picks = 1 + (torch.rand(len(lengths), euler_frames, generator=generator) * (lengths[:, None] - 2).clamp(min=1))
    picks = picks.long().clamp(max=(lengths - 2).clamp(min=1)[:, None])
    rows = torch.arange(len(lengths))[:, None].expand_as(picks)
    loads = [
        ExternalLoad(
            refiner.body.body_names[int(refiner.feet.bodies[k])], batch.forces[rows, picks, k], feet[rows, picks, k]
        )
        for k in range(len(refiner.feet.names))
    ]
    at = (full[rows, picks], qd[rows, picks], qdd[rows, picks])
    generalized = inverse_dynamics(refiner.body, *at, loads)
    terms["euler"] = (generalized - batch.torques[rows, picks]).abs().sum(-1).mean() / weight

    # not in the paper: the unactuated root moved by the predicted contact forces alone (whole-body clips only)
    if weights.root > 0:
        predicted = [replace(load, force=forces[rows, picks, k]) for k, load in enumerate(loads)]
        root = inverse_dynamics(refiner.body, *at, predicted)[..., list(ROOT)].abs().sum(-1).mean(-1)
        whole = batch.mask[:, TRUNK].to(root.dtype)
        terms["root"] = (root * whole).sum() / whole.sum().clamp(min=1.0) / weight

    loss = sum(getattr(weights, name) * value for name, value in terms.items())
    return loss, terms


# ---- validation -----------------------------------------------------------------------------------------------


def val_report(
    refiner: Refiner, data: ClipData, levels: NoiseLevels, cutoffs: list[float], seed: int, max_frames: int
) -> dict:
    """Whole val clips corrupted by every kind of noise (``levels``, seed ``seed``): mean ACCL/FS/MJE of the noisy
    input, the refiner and the low-pass at each cutoff, and the cutoff with the lowest ACCL."""
    generator = torch.Generator().manual_seed(seed)
    rate = refiner.config.rate
    rows: dict[str, list[dict[str, float]]] = {"noisy": [], "refined": []}
    rows.update({f"lowpass_{c:g}": [] for c in cutoffs})
    for k in range(len(data.lengths)):
        n = min(int(data.lengths[k]), max_frames)
        clean = data.q[data.offsets[k] : data.offsets[k] + n]
        mask = data.masks[k]
        noisy = corrupt(clean[None], mask[None], rate, levels, generator)[0]
        rows["noisy"].append(refinement_scores(refiner, clean, noisy, mask))
        rows["refined"].append(refinement_scores(refiner, clean, refiner.refine(noisy, mask).q, mask))
        for c in cutoffs:
            filtered = (
                torch.from_numpy(np.ascontiguousarray(lowpass(noisy.double().numpy(), rate, c, order=4))).float()
                if n > 15
                else noisy
            )
            rows[f"lowpass_{c:g}"].append(refinement_scores(refiner, clean, torch.where(mask, filtered, noisy), mask))
    means = {name: {m: float(np.nanmean([r[m] for r in v])) for m in ("accl", "fs", "mje")} for name, v in rows.items()}
    best = min(cutoffs, key=lambda c: means[f"lowpass_{c:g}"]["accl"])
    return {"clips": len(data.lengths), "means": means, "lowpass_cutoff_hz": best}


# ---- training -------------------------------------------------------------------------------------------------


def learning_rate(step: int, settings: TrainSettings) -> float:
    """Linear warm-up to ``lr``, then cosine decay to ``lr_final`` at the last step."""
    if step < settings.warmup:
        return settings.lr * (step + 1) / settings.warmup
    progress = (step - settings.warmup) / max(settings.iterations - settings.warmup, 1)
    return settings.lr_final + 0.5 * (settings.lr - settings.lr_final) * (1 + math.cos(math.pi * min(progress, 1.0)))


def _split(cache: DatasetCache, split: str, exclude: tuple[str, ...], min_frames: int) -> list[int]:
    return [
        i
        for i in cache.indices(split=split)
        if cache.records[i]["source"] not in exclude and cache.records[i]["n_frames"] >= min_frames
    ]


def train(
    config: dict,
    cache_dir: str | Path,
    out: str | Path,
    *,
    data_root: str | Path = "../shared/data",
    iterations: int | None = None,
    seed: int = 0,
    threads: int | None = None,
    progress: bool = True,
    command: str = "",
) -> dict:
    """Train from ``config`` (the YAML's dict: model, data, noise, eval_noise, loss, train, lowpass) on the cache;
    save weights + card beside ``out``; return the card."""
    from biomotion.body.kinematics import torch_threads
    from biomotion.data.clips import body_model

    try:
        model_cfg = RefinerConfig.from_dict(config.get("model", {}))
        data_cfg = settings_from_dict(DataSettings, config.get("data", {}), "refiner data")
        data_cfg = DataSettings(**{**asdict(data_cfg), "exclude_sources": tuple(data_cfg.exclude_sources)})
        noise = NoiseLevels.from_dict(config.get("noise", {}))
        eval_noise = NoiseLevels.from_dict(config.get("eval_noise", {"probability": 1.0}))
        weights = settings_from_dict(LossWeights, config.get("loss", {}), "refiner loss")
        settings = settings_from_dict(TrainSettings, config.get("train", {}), "refiner train")
        cutoffs = [float(c) for c in config.get("lowpass", {}).get("cutoffs_hz", [2, 3, 4, 5, 6, 8, 10, 12])]
    except TypeError as error:
        raise ConfigError(f"refiner config: {error}") from None
    if iterations is not None:
        settings = TrainSettings(**{**asdict(settings), "iterations": int(iterations)})
    torch.manual_seed(seed)
    np.random.seed(seed)
    cache = DatasetCache(cache_dir)
    if abs(cache.rate - model_cfg.rate) > 1e-6:
        raise ConfigError(f"cache at {cache.rate:g} Hz, the refiner config at {model_cfg.rate:g} Hz")
    refiner = Refiner.new(model_cfg, body_model(data_root))
    train_ids = _split(cache, "train", data_cfg.exclude_sources, data_cfg.min_frames)
    val_ids = _split(cache, "val", data_cfg.exclude_sources, data_cfg.min_frames)
    if not train_ids or not val_ids:
        raise BiomotionError(f"{cache_dir}: needs train and val clips outside {data_cfg.exclude_sources}")
    with torch_threads(threads or settings.threads):
        train_data = load_clips(cache, train_ids, refiner, progress)
        val_data = load_clips(cache, val_ids, refiner, progress)
        windows = window_starts(train_data, model_cfg.window, data_cfg.stride)
        _set_normalisation(refiner, train_data, windows, model_cfg.window)
        net = refiner.net
        optimiser = torch.optim.AdamW(net.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
        generator = torch.Generator().manual_seed(seed)
        val_rows = window_starts(val_data, model_cfg.window, model_cfg.window)
        val_batch = make_batch(val_data, val_rows, model_cfg.window)
        val_noisy = corrupt(val_batch.q, val_batch.mask, cache.rate, eval_noise, torch.Generator().manual_seed(seed))
        history = [{"step": 0, **_val_terms(refiner, val_batch, val_noisy, weights, settings)}]
        started = time.monotonic()
        bar = tqdm(range(settings.iterations), desc="refiner", unit="it", disable=not progress)
        for step in bar:
            for group in optimiser.param_groups:
                group["lr"] = learning_rate(step, settings)
            rows = windows[torch.randint(len(windows), (settings.batch_size,), generator=generator).numpy()]
            batch = make_batch(train_data, rows, model_cfg.window)
            noisy = corrupt(batch.q, batch.mask, cache.rate, noise, generator)
            net.train()
            loss, terms = step_losses(refiner, batch, noisy, weights, settings.euler_frames, generator)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), settings.grad_clip)
            optimiser.step()
            if step % 20 == 0:
                bar.set_postfix(loss=f"{loss.item():.4f}", q=f"{terms['q'].item():.4f}")
            if (step + 1) % settings.eval_every == 0 or step + 1 == settings.iterations:
                history.append({"step": step + 1, **_val_terms(refiner, val_batch, val_noisy, weights, settings)})
                if progress:
                    tqdm.write(str({k: round(v, 5) for k, v in history[-1].items()}))
        train_seconds = time.monotonic() - started
        net.eval()
        report = val_report(refiner, val_data, eval_noise, cutoffs, seed, data_cfg.val_clips_max_frames)
    refiner.metadata = {
        "train_subjects": sorted(set(train_data.subjects)),
        "val_subjects": sorted(set(val_data.subjects)),
        "excluded_sources": list(data_cfg.exclude_sources),
        "lowpass_cutoff_hz": report["lowpass_cutoff_hz"],
        "eval_noise": asdict(eval_noise),
        "command": command,
    }
    out = Path(out)
    refiner.save(out)
    card = _card(out, config, cache, seed, settings, train_data, val_data, windows, history, report, train_seconds)
    card["command"] = command or "biomotion.training.train_refiner.train (Python API)"
    card["threads"] = threads or settings.threads
    write_card(out, card, _markdown(card))
    return card


def _set_normalisation(refiner: Refiner, data: ClipData, windows: np.ndarray, length: int) -> None:
    """Window-frame coordinate statistics over (a subsample of) the training windows, the torque scale per
    coordinate and the body weight."""
    rows = windows[:: max(1, len(windows) // 2000)]
    batch = make_batch(data, rows, length)
    local = to_local(batch.q, window_frame(batch.q, batch.valid))
    keep = (batch.valid[..., None] & batch.mask[:, None, :]).float()
    count = keep.sum((0, 1)).clamp(min=1)
    mean = (local * keep).sum((0, 1)) / count
    std = (((local - mean) ** 2 * keep).sum((0, 1)) / count).sqrt()
    refiner.net.set_normalisation(
        mean,
        torch.where(count > 1, std, torch.ones_like(std)),
        data.torques.std(0),
        float(refiner.body.total_mass) * GRAVITY,
    )


@torch.no_grad()
def _val_terms(refiner: Refiner, batch: Batch, noisy: torch.Tensor, weights: LossWeights, settings) -> dict:
    """Loss terms and the joint-centre ACCL / MJE (refined and noisy) on the fixed val windows."""
    refiner.net.eval()
    generator = torch.Generator().manual_seed(0)
    terms: dict[str, float] = {}
    sums = {"accl": 0.0, "accl_noisy": 0.0, "mje": 0.0, "mje_noisy": 0.0}
    chunk = 64
    for i in range(0, len(batch.q), chunk):
        part = Batch(*(getattr(batch, f)[i : i + chunk] for f in ("q", "mask", "valid", "forces", "torques", "rest")))
        loss, parts = step_losses(refiner, part, noisy[i : i + chunk], weights, settings.euler_frames, generator)
        share = len(part.q) / len(batch.q)
        for name, value in {"loss": loss, **parts}.items():
            terms[name] = terms.get(name, 0.0) + float(value) * share
        refined = refiner.net(noisy[i : i + chunk], part.mask, part.valid).q
        clean, _ = refiner.kinematics(refiner.full(part.q, part.mask))
        for name, pred in (("", refined), ("_noisy", noisy[i : i + chunk])):
            joints, _ = refiner.kinematics(refiner.full(pred, part.mask))
            sums["accl" + name] += float(acceleration_error(joints, clean, refiner.config.rate, part.valid).sum())
            sums["mje" + name] += float(joint_error(joints, clean, part.valid, root=0).sum())
    return {**terms, **{k: v / len(batch.q) for k, v in sums.items()}}


def _card(out, config, cache, seed, settings, train_data, val_data, windows, history, report, seconds) -> dict:
    return {
        "model": "biomotion PhysPT refiner (Zhang et al. 2024, Sec. 3.2)",
        "weights": out.name,
        "sha256": hashlib.sha256(out.read_bytes()).hexdigest(),
        "config": config,
        "seed": seed,
        "iterations": settings.iterations,
        "train_seconds": round(seconds, 1),
        "data": {
            "cache_format": cache.manifest.get("format"),
            "rate_hz": cache.rate,
            "split_rule": cache.manifest.get("split_rule"),
            "cache": portable(cache.folder),
            "recipe": config.get("data", {}).get("recipe", ""),
            "train_clips": len(train_data.lengths),
            "train_frames": int(train_data.lengths.sum()),
            "train_windows": len(windows),
            "train_subjects": len(set(train_data.subjects)),
            "val_clips": len(val_data.lengths),
            "val_subjects": len(set(val_data.subjects)),
            "train_clips_per_source": _per_source(train_data.subjects),
            "val_clips_per_source": _per_source(val_data.subjects),
        },
        "val": report,
        "history": history,
        "environment": environment(),
    }


def _per_source(subjects: list[str]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for s in subjects:
        counts[s.split("/")[0]] = counts.get(s.split("/")[0], 0) + 1
    return counts


def _markdown(card: dict) -> str:
    means = card["val"]["means"]
    best = f"lowpass_{card['val']['lowpass_cutoff_hz']:g}"
    rows = [("noisy input", means["noisy"]), ("refined", means["refined"]), (f"low-pass {best[8:]} Hz", means[best])]
    return (
        f"# PhysPT refiner: {card['weights']}\n\n{card['model']}.\n\n"
        f"- SHA-256: `{card['sha256']}`\n- command: `{card['command']}`\n- seed {card['seed']}, "
        f"{card['iterations']} iterations, {card['train_seconds']} s on {card['threads']} CPU threads "
        f"(torch {card['environment']['torch']})\n"
        f"- data: {card['data']['train_clips']} train clips ({card['data']['train_subjects']} subjects, "
        f"{card['data']['train_clips_per_source']}), {card['data']['val_clips']} val clips "
        f"({card['data']['val_subjects']} subjects); split {card['data']['split_rule']}\n\n"
        f"Val clips corrupted by every kind of noise (`biomotion.data.noise`), whole clips:\n\n"
        "| | ACCL (m/s²) | FS (mm/frame) | MJE (mm) |\n|---|---|---|---|\n"
        + "".join(f"| {name} | {m['accl']:.3f} | {1000 * m['fs']:.2f} | {1000 * m['mje']:.1f} |\n" for name, m in rows)
    )
