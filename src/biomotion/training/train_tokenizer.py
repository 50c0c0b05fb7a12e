"""Train the motion tokenizer (`MotionVQVAE`) on a dataset cache; write safetensors weights and a model card.

    biomotion train tokenizer --config configs/tokenizer.yaml --cache DIR \\
        --out checkpoints/tokenizer.safetensors [--data-root ../shared/data] [--minutes N] [--iterations N] [--seed N]

Optimisation follows PG-BIG Table 4 and the authors' code: AdamW, lr 2e-4 with linear warm-up, step decay
(x gamma every ``lr_step`` iterations), gradient clipping at 1.0. Windows of ``window`` frames are cut from the
training split's clips; validation reports masked reconstruction RMSE on the val split in degrees (rotations)
and centimetres (pelvis translations).

With foot contact (``model.foot_contact``) or a penetration weight, the canonical body model is read from
``--data-root``: contact labels of every window come from its foot points (`FootKinematics.labels`), and the
penetration term of Table 4 is the decoded windows' mean foot depth below the floor in cm, weighted by
``model.w_penetration``; validation then also reports contact accuracy and penetration.
"""

from __future__ import annotations

import hashlib
import math
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from biomotion.data.registry import DatasetCache
from biomotion.errors import BiomotionError, SettingsError
from biomotion.models.foot_contact import FootKinematics
from biomotion.models.vqvae import N_COORDS, TRANSLATIONS, MotionVQVAE, VQVAEConfig
from biomotion.training.cards import environment, write_card


def make_windows(cache: DatasetCache, split: str | None, length: int, stride: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Windows [N, length, 39] (float32, SI) and masks [N, 39] from every clip of ``split`` (None: all) long enough;
    window starts every ``stride`` frames, the last one flush with the clip's end."""
    starts, owners = [], []
    for i in cache.indices(split=split):
        record = cache.records[i]
        n = record["n_frames"]
        if n < length:
            continue
        local = np.unique(np.append(np.arange(0, n - length + 1, stride), n - length))
        starts.append(record["offset"] + local)
        owners.append(np.full(len(local), i))
    if not starts:
        raise BiomotionError(f"no {split} clips of at least {length} frames in {cache.folder}")
    start, owner = np.concatenate(starts), np.concatenate(owners)
    x = cache.values[start[:, None] + np.arange(length)]
    return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)), torch.from_numpy(cache.masks[owner])


def step_losses(
    model: MotionVQVAE, x: torch.Tensor, mask: torch.Tensor, contact: torch.Tensor | None, feet: FootKinematics | None
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The model's reconstruction and losses on a batch, plus Table 4's penetration term when ``feet`` is given
    (added to ``loss`` with weight ``w_penetration``)."""
    recon, losses = model(x, mask, contact)
    if feet is not None:
        losses["penetration_cm"] = feet.penetration_cm(recon, mask.bool())
        losses["loss"] = losses["loss"] + model.config.w_penetration * losses["penetration_cm"]
    return recon, losses


@torch.no_grad()
def evaluate(
    model: MotionVQVAE,
    x: torch.Tensor,
    mask: torch.Tensor,
    contact: torch.Tensor | None = None,
    feet: FootKinematics | None = None,
    batch: int = 256,
) -> dict[str, float]:
    """Masked reconstruction RMSE over windows: rotations in degrees, pelvis translations in cm (the horizontal
    ones integrated from the window's first frame), plus the mean loss terms (contact accuracy and penetration
    among them when trained for) and codebook usage."""
    was_training = model.training
    model.eval()
    sq = torch.zeros(N_COORDS, dtype=torch.float64)
    count = torch.zeros(N_COORDS, dtype=torch.float64)
    terms: dict[str, float] = {}
    used = torch.zeros(model.config.codebook_size, dtype=torch.bool)
    for i in range(0, len(x), batch):
        xb, mb = x[i : i + batch], mask[i : i + batch]
        recon, losses = step_losses(model, xb, mb, None if contact is None else contact[i : i + batch], feet)
        w = mb.unsqueeze(1).expand_as(xb).double()
        sq += ((recon.double() - xb.double()).pow(2) * w).sum((0, 1))
        count += w.sum((0, 1))
        for k, v in losses.items():
            terms[k] = terms.get(k, 0.0) + float(v) * len(xb) / len(x)
        used[model.encode(xb, mb)[1].unique()] = True
    model.train(was_training)
    translation = torch.zeros(N_COORDS, dtype=torch.bool)
    translation[list(TRANSLATIONS)] = True
    rot = ~translation
    rmse_deg = math.degrees(math.sqrt(float(sq[rot].sum() / count[rot].sum().clamp_min(1))))
    rmse_cm = 100 * math.sqrt(float(sq[translation].sum() / count[translation].sum().clamp_min(1)))
    return {
        "rmse_rotations_deg": rmse_deg,
        "rmse_translations_cm": rmse_cm,
        "codes_used": int(used.sum()),
        **{f"loss_{k}": v for k, v in terms.items()},
    }


def learning_rate(step: int, lr: float, warmup: int, lr_step: int, gamma: float) -> float:
    """Linear warm-up to ``lr`` over ``warmup`` steps, then x ``gamma`` every ``lr_step`` steps."""
    return lr * min(1.0, (step + 1) / max(warmup, 1)) * gamma ** (step // lr_step)


def train(
    config: dict,
    cache_dir: str | Path,
    out: str | Path,
    *,
    data_root: str | Path = "../shared/data",
    minutes: float | None = None,
    iterations: int | None = None,
    seed: int = 0,
    progress: bool = True,
    command: str = "",
) -> dict:
    """Train from ``config`` (the YAML's dict) on the cache; save weights + card next to ``out``; return card.
    ``data_root`` holds the canonical body model (read only for foot contact or penetration); ``command`` is
    recorded in the card (the CLI passes its command line)."""
    try:
        model_cfg = VQVAEConfig.from_dict(config.get("model", {}))
        data_cfg, train_cfg = config["data"], config["train"]
        window, stride = int(data_cfg["window"]), int(data_cfg["stride"])
    except KeyError as missing:
        raise SettingsError(f"tokenizer config lacks the setting {missing}") from None
    except (AttributeError, TypeError, ValueError) as error:  # a section that is no mapping, a word for a number
        raise SettingsError(f"tokenizer config: a setting of the wrong type ({error})") from None
    torch.manual_seed(seed)
    np.random.seed(seed)
    cache = DatasetCache(cache_dir)
    x_train, m_train = make_windows(cache, "train", window, stride)
    x_val, m_val = make_windows(cache, "val", window, window)
    model = MotionVQVAE(model_cfg)
    model.set_normalisation(x_train, m_train)
    body_feet = c_train = c_val = None
    if model_cfg.foot_contact or model_cfg.w_penetration > 0:
        from biomotion.data.clips import body_model

        body_feet = FootKinematics(body_model(data_root))
    if model_cfg.foot_contact:
        c_train = body_feet.labels(x_train, m_train.bool(), cache.rate)
        c_val = body_feet.labels(x_val, m_val.bool(), cache.rate)
    feet = body_feet if model_cfg.w_penetration > 0 else None  # the penetration term's foot points
    optimiser = torch.optim.AdamW(model.parameters(), lr=train_cfg["lr"], weight_decay=train_cfg["weight_decay"])
    total = int(iterations or train_cfg["iterations"])
    deadline = time.monotonic() + 60 * minutes if minutes else math.inf
    generator = torch.Generator().manual_seed(seed)
    before = evaluate(model, x_val, m_val, c_val, feet)
    history = []
    started = time.monotonic()
    bar = tqdm(range(total), desc="tokenizer", unit="it", disable=not progress)
    step = 0
    for step in bar:
        if time.monotonic() > deadline:
            break
        for group in optimiser.param_groups:
            group["lr"] = learning_rate(
                step, train_cfg["lr"], train_cfg["warmup"], train_cfg["lr_step"], train_cfg["lr_gamma"]
            )
        pick = torch.randint(len(x_train), (train_cfg["batch_size"],), generator=generator)
        _, losses = step_losses(model, x_train[pick], m_train[pick], None if c_train is None else c_train[pick], feet)
        optimiser.zero_grad(set_to_none=True)
        losses["loss"].backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), train_cfg["grad_clip"])
        optimiser.step()
        if step % 20 == 0:
            bar.set_postfix(loss=f"{losses['loss'].item():.4f}", ppl=f"{losses['perplexity'].item():.0f}")
        if (step + 1) % train_cfg["eval_every"] == 0:
            history.append(
                {"step": step + 1, "train_loss": losses["loss"].item(), **evaluate(model, x_val, m_val, c_val, feet)}
            )
    else:
        step = total
    after = evaluate(model, x_val, m_val, c_val, feet)
    out = Path(out)
    model.save(out, metadata={"format": "biomotion-tokenizer/1"})
    card = {
        "model": "biomotion MotionVQVAE (PG-BIG Sec. 3.1 tokenizer)",
        "weights": out.name,
        "sha256": hashlib.sha256(out.read_bytes()).hexdigest(),
        "command": command or "biomotion.training.train_tokenizer.train (Python API)",
        "config": config,
        "seed": seed,
        "iterations": step,
        "train_seconds": round(time.monotonic() - started, 1),
        "data": {
            "cache_format": cache.manifest.get("format"),
            "rate_hz": cache.rate,
            "train_windows": len(x_train),
            "val_windows": len(x_val),
            "contact_share_train": None if c_train is None else round(float(c_train.mean()), 4),
            "clips_per_split": cache.manifest["counts"]["per_split"],
            "clips_per_source": cache.manifest["counts"]["per_source"],
        },
        "metrics_val_before": before,
        "metrics_val": after,
        "history": history,
        "environment": environment(),
    }
    write_card(out, card, _markdown(card))
    return card


def _markdown(card: dict) -> str:
    m = card["metrics_val"]
    return (
        f"# Motion tokenizer: {card['weights']}\n\n{card['model']}.\n\n"
        f"- SHA-256: `{card['sha256']}`\n- command: `{card['command']}`\n- seed {card['seed']}, "
        f"{card['iterations']} iterations, {card['train_seconds']} s\n"
        f"- data: {card['data']['train_windows']} train / {card['data']['val_windows']} val windows, "
        f"clips per split {card['data']['clips_per_split']}\n\n"
        "| val metric | before training | after |\n|---|---|---|\n"
        + "".join(f"| {k} | {card['metrics_val_before'][k]:.4g} | {v:.4g} |\n" for k, v in m.items())
    )
