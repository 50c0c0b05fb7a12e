"""Train the profile-action prior (with its subject profiler) on tokenized dataset clips; ship weights + card.

    biomotion train generator --config configs/generator.yaml --cache build/dataset \\
        --tokenizer checkpoints/tokenizer.safetensors --data-root ../shared/data \\
        --out checkpoints/generator.safetensors [--population] [--minutes N] [--seed N]

``dev_fraction`` of the *training* subjects (a stable hash) is set aside to choose the iteration kept (lowest
next-code cross-entropy on them): the prior memorises its few clips, and the val/test subjects stay untouched for
`biomotion eval generation`.

Every clip is tokenized once by the frozen tokenizer (PG-BIG trains the prior on the VQ-VAE's codes, Sec. 3.2).
A training sample is a crop of one train-split clip; its profile comes from up to ``references`` *other* clips of
the same subject (latents, metadata) plus the subject's biodata, so the profile describes the person, not the
target clip. Branches are dropped at random (``drop_references``, ``drop_biodata``) so the model also serves
subjects with no reference clip or no biodata. Loss: next-code cross-entropy plus a triplet term on the profile
token (same subject closer than another subject, margin ``triplet_margin``; the authors' profile-encoder loss,
``pg-big-reference-notes.md``). ``--population`` trains the action-only prior (the T2M-GPT-kind baseline).

The checkpoint also stores what generation needs from the training data: the action vocabulary, the
per-action 5th/95th percentile bounds of coordinate speeds, COM speed and COM acceleration (PG-BIG Table 1) and
the per-action population postures (`biomotion.generation.posture`). ``--statistics-only`` recomputes those
statistics for an already trained ``--out`` from its cache, keeping the weights (the bounds it had must come out
the same, proof that the cache and the clip selection are the training run's).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from biomotion.body.mirror import mirror_coordinates
from biomotion.data.registry import DatasetCache
from biomotion.errors import ConfigError, SettingsError
from biomotion.models.actions import ActionRequest, ActionVocabulary
from biomotion.models.bundle import GeneratorBundle, action_bounds
from biomotion.models.conditioning import (
    Features,
    action_features,
    action_size,
    biodata_features,
    mean_features,
    metadata_features,
)
from biomotion.models.prior import Condition, PriorConfig, ProfileActionPrior
from biomotion.models.vqvae import DOWNSAMPLE, MotionVQVAE
from biomotion.training.cards import environment, write_card


@dataclass
class TokenizedClip:
    """One cache clip after the frozen tokenizer: codes [N], latents [N, D], metadata/biodata/action features."""

    index: int
    subject: str
    split: str
    codes: torch.Tensor
    latents: torch.Tensor
    metadata: Features
    biodata: Features
    action: Features


@torch.no_grad()
def tokenize_cache(
    cache: DatasetCache,
    tokenizer: MotionVQVAE,
    body,
    vocabulary: ActionVocabulary,
    progress: bool = True,
    mirror: bool = False,
) -> list[TokenizedClip]:
    """Tokenize every clip at least one token long (4 frames); COM from ``body`` (the canonical model). With
    ``mirror``, each training-split clip also gives its left-right mirror image (`biomotion.body.mirror`), a clip
    of the same person and action."""
    from biomotion.body.kinematics import center_of_mass

    defaults = body.defaults.to(torch.float32)
    clips = []
    for i in tqdm(range(len(cache)), desc="tokenize", unit="clip", disable=not progress):
        record = cache.records[i]
        n = record["n_frames"] // DOWNSAMPLE * DOWNSAMPLE
        if n < DOWNSAMPLE:
            continue
        q = torch.from_numpy(
            np.ascontiguousarray(cache.values[record["offset"] : record["offset"] + n], dtype=np.float32)
        )
        mask = torch.from_numpy(cache.masks[i]).bool()
        labels = record["labels"]
        request = ActionRequest(labels["action"], labels.get("style"), labels.get("speed"), labels.get("text") or "")
        versions = [(q, mask)]
        if mirror and record["split"] == "train":
            q_m, mask_m = mirror_coordinates(q.numpy(), mask.numpy())
            versions.append((torch.from_numpy(np.ascontiguousarray(q_m)), torch.from_numpy(mask_m.copy())))
        for q_v, mask_v in versions:
            latents = tokenizer.encode_continuous(q_v[None], mask_v[None])[0]
            full = torch.where(mask_v, q_v, defaults)
            com = center_of_mass(body, full.to(body.dtype)).float()
            clips.append(
                TokenizedClip(
                    i,
                    f"{record['source']}/{record['subject']}",
                    record["split"],
                    tokenizer.quantiser.nearest(latents),
                    latents,
                    metadata_features(q_v, mask_v, com, cache.rate),
                    biodata_features(cache.profile(i)),
                    action_features(request, vocabulary),
                )
            )
    return clips


class Batches:
    """Random training batches: target crops and profile inputs built from other clips of the same subject."""

    def __init__(
        self, clips: list[TokenizedClip], crop: int, references: int, max_latents: int, generator: torch.Generator
    ) -> None:
        self.clips, self.crop, self.references, self.max_latents = clips, crop, references, max_latents
        self.generator = generator
        self.by_subject: dict[str, list[int]] = {}
        for k, clip in enumerate(clips):
            self.by_subject.setdefault(clip.subject, []).append(k)

    def _randint(self, high: int) -> int:
        return int(torch.randint(high, (1,), generator=self.generator))

    def reference_set(self, k: int) -> list[TokenizedClip]:
        """Up to ``references`` clips of clip k's subject other than k and its mirror image (k itself when the
        subject has no other clip)."""
        index = self.clips[k].index
        others = [j for j in self.by_subject[self.clips[k].subject] if self.clips[j].index != index] or [k]
        order = torch.randperm(len(others), generator=self.generator)[: self.references]
        return [self.clips[others[int(j)]] for j in order]

    def condition(self, ks: list[int], drop_references: float = 0.0, drop_biodata: float = 0.0) -> Condition:
        return stack_conditions(
            [
                profile_inputs(
                    self.reference_set(k),
                    self.clips[k],
                    self.max_latents,
                    keep_references=float(torch.rand(1, generator=self.generator)) >= drop_references,
                    keep_biodata=float(torch.rand(1, generator=self.generator)) >= drop_biodata,
                )
                for k in ks
            ]
        )

    def targets(self, ks: list[int]) -> torch.Tensor:
        """Crops [B, crop] of the clips' codes; positions past a short clip's end hold -100 (ignored)."""
        out = torch.full((len(ks), self.crop), -100, dtype=torch.long)
        for row, k in enumerate(ks):
            codes = self.clips[k].codes
            start = self._randint(max(len(codes) - self.crop, 0) + 1)
            piece = codes[start : start + self.crop]
            out[row, : len(piece)] = piece
        return out


def dev_subject(subject: str, fraction: float) -> bool:
    """Whether a training subject is set aside to choose the stopping iteration (a stable hash, like the splits)."""
    digest = hashlib.sha256(f"dev/{subject}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2**64 < fraction


def statistics_indices(cache: DatasetCache, dev_fraction: float) -> list[int]:
    """The clips the per-action statistics come from: the training clips the prior learns from (train split, at
    least one token long, subject not set aside by `dev_subject`)."""
    return [
        i
        for i, r in enumerate(cache.records)
        if r["split"] == "train"
        and r["n_frames"] >= DOWNSAMPLE
        and not dev_subject(f"{r['source']}/{r['subject']}", dev_fraction)
    ]


def profile_inputs(
    references: list[TokenizedClip],
    target: TokenizedClip,
    max_latents: int,
    *,
    keep_references: bool = True,
    keep_biodata: bool = True,
) -> Condition:
    """One sample's (unbatched) condition: references' latents + mean metadata, the target's biodata and action."""
    code_dim = target.latents.shape[-1]
    if keep_references and references:
        latents = torch.cat([r.latents for r in references])[:max_latents]
        metadata = mean_features([r.metadata for r in references]).cat()
    else:
        latents = torch.zeros(0, code_dim)
        metadata = torch.zeros_like(target.metadata.cat())
    biodata = target.biodata.cat() if keep_biodata else torch.zeros_like(target.biodata.cat())
    return Condition(latents, torch.ones(len(latents), dtype=torch.bool), biodata, metadata, target.action.cat())


def stack_conditions(items: list[Condition]) -> Condition:
    """Batch unbatched conditions, padding reference latents (at least one padded slot, all invalid if none)."""
    longest = max(1, max(len(c.latents) for c in items))
    dim = items[0].latents.shape[-1]
    latents = torch.zeros(len(items), longest, dim)
    valid = torch.zeros(len(items), longest, dtype=torch.bool)
    for row, c in enumerate(items):
        latents[row, : len(c.latents)] = c.latents
        valid[row, : len(c.latents)] = c.latent_valid
    return Condition(
        latents,
        valid,
        torch.stack([c.biodata for c in items]),
        torch.stack([c.metadata for c in items]),
        torch.stack([c.action for c in items]),
    )


def cross_entropy(prior: ProfileActionPrior, codes: torch.Tensor, cond: Condition) -> torch.Tensor:
    """Teacher-forced next-code cross-entropy with -100 targets ignored."""
    logits = prior(codes, cond)
    return F.cross_entropy(logits.reshape(-1, logits.shape[-1]), codes.reshape(-1), ignore_index=-100)


def triplet(prior: ProfileActionPrior, batches: Batches, ks: list[int], margin: float) -> torch.Tensor:
    """Profile tokens of two reference draws of the same subject closer than of two different subjects."""
    if prior.profiler is None:
        return torch.zeros(())

    def tokens(indices: list[int]) -> torch.Tensor:
        c = batches.condition(indices)
        return F.normalize(prior.profiler(c.latents, c.latent_valid, c.biodata, c.metadata), dim=-1)

    anchor, positive = tokens(ks), tokens(ks)
    subjects = [batches.clips[k].subject for k in ks]
    shift = [(i + 1) % len(ks) for i in range(len(ks))]
    different = torch.tensor([subjects[i] != subjects[j] for i, j in enumerate(shift)])
    if not different.any():
        return torch.zeros(())
    negative = anchor[shift]
    loss = F.relu((anchor - positive).pow(2).sum(-1) - (anchor - negative).pow(2).sum(-1) + margin)
    return loss[different].mean()


@torch.no_grad()
def evaluate(
    prior: ProfileActionPrior, clips: list[TokenizedClip], crop: int, references: int, max_latents: int, seed: int = 1
) -> dict[str, float]:
    """Mean next-code cross-entropy and top-1 accuracy over every clip (first ``crop`` codes), fixed references."""
    was = prior.training
    prior.eval()
    batches = Batches(clips, crop, references, max_latents, torch.Generator().manual_seed(seed))
    ks = list(range(len(clips)))
    codes = torch.full((len(ks), crop), -100, dtype=torch.long)
    for row, k in enumerate(ks):
        piece = clips[k].codes[:crop]
        codes[row, : len(piece)] = piece
    logits = prior(codes, batches.condition(ks))
    keep = codes >= 0
    ce = F.cross_entropy(logits[keep], codes[keep])
    accuracy = (logits.argmax(-1)[keep] == codes[keep]).float().mean()
    prior.train(was)
    return {"cross_entropy": float(ce), "accuracy": float(accuracy), "clips": len(clips)}


def train(
    config: dict,
    cache_dir: str | Path,
    tokenizer_path: str | Path,
    data_root: str | Path,
    out: str | Path,
    *,
    population: bool = False,
    minutes: float | None = None,
    iterations: int | None = None,
    seed: int = 0,
    progress: bool = True,
    command: str = "",
    stop_at: int | None = None,
) -> dict:
    """Train the prior from ``config`` (YAML dict); save `GeneratorBundle` weights + card next to ``out``.
    ``stop_at`` ends training after that many iterations with the learning-rate schedule still spanning
    ``iterations`` (the config's by default): the same run as the full one, cut short (the cross-validated
    evaluation trains its fold models so, `biomotion.training.folds`)."""
    from biomotion.data.clips import body_model

    try:
        model_cfg, train_cfg = dict(config.get("model", {})), config["train"]
        crop, refs, max_latents = int(train_cfg["crop"]), int(train_cfg["references"]), int(train_cfg["max_latents"])
    except KeyError as missing:
        raise SettingsError(f"generator config lacks the setting {missing}") from None
    except (AttributeError, TypeError, ValueError) as error:  # a section that is no mapping, a word for a number
        raise SettingsError(f"generator config: a setting of the wrong type ({error})") from None
    torch.manual_seed(seed)
    cache = DatasetCache(cache_dir)
    tokenizer = MotionVQVAE.load(tokenizer_path)
    body = body_model(data_root)
    vocabulary = ActionVocabulary.from_labels([r["labels"] for r in cache.records])
    clips = tokenize_cache(cache, tokenizer, body, vocabulary, progress, mirror=bool(train_cfg.get("mirror", False)))
    val_clips = [c for c in clips if c.split != "train"]
    dev_fraction = float(train_cfg.get("dev_fraction", 0.0))
    dev_clips = [c for c in clips if c.split == "train" and dev_subject(c.subject, dev_fraction)]
    train_clips = [c for c in clips if c.split == "train" and not dev_subject(c.subject, dev_fraction)]
    config_obj = PriorConfig.from_dict(
        {
            **model_cfg,
            "codebook_size": tokenizer.config.codebook_size,
            "code_dim": tokenizer.config.code_dim,
            "action_size": action_size(vocabulary),
            "use_profile": not population,
        }
    )
    prior = ProfileActionPrior(config_obj)
    optimiser = torch.optim.AdamW(prior.parameters(), lr=train_cfg["lr"], weight_decay=train_cfg["weight_decay"])
    generator = torch.Generator().manual_seed(seed)
    batches = Batches(train_clips, crop, refs, max_latents, generator)
    total = int(iterations or train_cfg["iterations"])
    deadline = time.monotonic() + 60 * minutes if minutes else math.inf
    before = evaluate(prior, val_clips, crop, refs, max_latents)
    started = time.monotonic()
    history = []
    best = (math.inf, 0, None)  # dev cross-entropy, step, weights
    step = 0
    bar = tqdm(range(total), desc="population prior" if population else "generator", unit="it", disable=not progress)
    for step in bar:
        if time.monotonic() > deadline or (stop_at is not None and step >= stop_at):
            break
        lr = train_cfg["lr"] * min(1.0, (step + 1) / train_cfg["warmup"])
        lr *= 0.5 * (1 + math.cos(math.pi * step / total))
        for group in optimiser.param_groups:
            group["lr"] = lr
        ks = torch.randint(len(train_clips), (train_cfg["batch_size"],), generator=generator).tolist()
        cond = batches.condition(ks, train_cfg["drop_references"], train_cfg["drop_biodata"])
        ce = cross_entropy(prior, batches.targets(ks), cond)
        tri = triplet(prior, batches, ks, train_cfg["triplet_margin"])
        loss = ce + train_cfg["w_triplet"] * tri
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(prior.parameters(), train_cfg["grad_clip"])
        optimiser.step()
        if step % 20 == 0:
            bar.set_postfix(ce=f"{ce.item():.3f}", triplet=f"{tri.item():.3f}")
        if (step + 1) % train_cfg["eval_every"] == 0:
            history.append(
                {
                    "step": step + 1,
                    "train_ce": ce.item(),
                    **{f"val_{k}": v for k, v in evaluate(prior, val_clips, crop, refs, max_latents).items()},
                }
            )
            if dev_clips:
                dev = evaluate(prior, dev_clips, crop, refs, max_latents)["cross_entropy"]
                history[-1]["dev_cross_entropy"] = dev
                if dev < best[0]:
                    best = (dev, step + 1, copy.deepcopy(prior.state_dict()))
    else:
        step = total
    if best[2] is not None:  # early stopping on the training subjects set aside, never on held-out ones
        prior.load_state_dict(best[2])
    prior.eval()
    after_val = evaluate(prior, val_clips, crop, refs, max_latents)
    after_train = evaluate(prior, train_clips, crop, refs, max_latents)
    bounds = action_bounds(cache, body, statistics_indices(cache, dev_fraction))
    seen = tuple(sorted({c.subject for c in train_clips + dev_clips}))
    bundle = GeneratorBundle(
        prior,
        vocabulary,
        bounds,
        tokenizer_sha256=hashlib.sha256(Path(tokenizer_path).read_bytes()).hexdigest(),
        train_subjects=seen,
    )
    out = Path(out)
    bundle.save(out)
    card = {
        "model": (
            "biomotion population prior (action only, T2M-GPT-kind baseline)"
            if population
            else "biomotion profile-action prior + subject profiler (PG-BIG Sec. 3.2, A.6)"
        ),
        "weights": out.name,
        "sha256": hashlib.sha256(out.read_bytes()).hexdigest(),
        "tokenizer": Path(tokenizer_path).name,
        "tokenizer_sha256": bundle.tokenizer_sha256,
        "command": command or "biomotion.training.train_generator.train (Python API)",
        "config": config,
        "seed": seed,
        "iterations": step,
        "kept_iteration": best[1] if best[2] is not None else step,
        "dev_clips": len(dev_clips),
        "dev_cross_entropy": None if best[2] is None else best[0],
        "train_seconds": round(time.monotonic() - started, 1),
        "data": {
            "train_clips": len(train_clips),
            "held_out_clips": len(val_clips),
            "mirrored": bool(train_cfg.get("mirror", False)),
            "subjects_train": len({c.subject for c in train_clips}),
            "actions": list(vocabulary.actions),
            "styles": list(vocabulary.styles),
        },
        "metrics_held_out_before": before,
        "metrics_held_out": after_val,
        "metrics_train": after_train,
        "history": history,
        "environment": environment(),
    }
    write_card(out, card, _markdown(card))
    return card


def _same_bounds(old, new) -> bool:
    fields = ("speed_high", "jerk_high", "com_speed", "com_acceleration", "frames")
    return all(
        np.allclose(
            np.asarray(getattr(old, f), float), np.asarray(getattr(new, f), float), rtol=1e-9, atol=0.0, equal_nan=True
        )
        for f in fields
    )


def refresh_statistics(
    config: dict, cache_dir: str | Path, data_root: str | Path, out: str | Path, *, command: str = ""
) -> dict:
    """Recompute the per-action statistics of the trained bundle ``out`` (bounds, population postures and
    amplitudes, COM energy) from the `statistics_indices` clips of ``cache_dir``, as `train` does, keep its
    weights, and update its card.
    Raises `ConfigError`, writing nothing, when the bounds the bundle had do not come out the same."""
    from biomotion.data.clips import body_model

    out = Path(out)
    bundle = GeneratorBundle.load(out)
    cache = DatasetCache(cache_dir)
    dev_fraction = float(config.get("train", {}).get("dev_fraction", 0.0))
    bounds = action_bounds(cache, body_model(data_root), statistics_indices(cache, dev_fraction))
    changed = sorted(
        k
        for k in set(bounds) | set(bundle.bounds)
        if k not in bounds or k not in bundle.bounds or not _same_bounds(bundle.bounds[k], bounds[k])
    )
    if changed:
        raise ConfigError(
            f"{cache_dir} does not give the bounds stored in {out} (actions {changed}): not the cache "
            "or the settings this bundle was trained with; nothing written"
        )
    GeneratorBundle(bundle.prior, bundle.vocabulary, bounds, bundle.tokenizer_sha256, bundle.train_subjects).save(out)
    card_file = out.with_suffix(".json")
    card = json.loads(card_file.read_text()) if card_file.exists() else {"weights": out.name}
    card.update(
        {
            "sha256": hashlib.sha256(out.read_bytes()).hexdigest(),
            "statistics_command": command or "biomotion.training.train_generator.refresh_statistics (Python API)",
        }
    )
    if {"metrics_held_out", "metrics_train", "metrics_held_out_before", "data"} <= set(card):
        write_card(out, card, _markdown(card))
    else:
        write_card(out, card, f"# {out.name}\n\n- SHA-256: `{card['sha256']}`\n")
    return card


def _markdown(card: dict) -> str:
    rows = "".join(
        f"| {k} | {card['metrics_held_out_before'][k]:.4g} | {v:.4g} | {card['metrics_train'][k]:.4g} |\n"
        for k, v in card["metrics_held_out"].items()
        if k != "clips"
    )
    return (
        f"# {card['weights']}\n\n{card['model']}.\n\n- SHA-256: `{card['sha256']}`\n"
        f"- tokenizer: `{card['tokenizer']}` (SHA-256 `{card['tokenizer_sha256']}`)\n"
        f"- command: `{card['command']}`\n"
        + (
            f"- per-action statistics (bounds, population postures and amplitudes, COM energy) recomputed: "
            f"`{card['statistics_command']}`\n"
            if card.get("statistics_command")
            else ""
        )
        + f"- seed {card['seed']}, {card['iterations']} iterations, "
        f"{card['train_seconds']} s, weights of iteration {card['kept_iteration']} kept (early stopping on "
        f"{card['dev_clips']} clips of training subjects set aside)\n- data: {card['data']['train_clips']} train clips "
        f"({card['data']['subjects_train']} subjects), {card['data']['held_out_clips']} held-out clips "
        "(val + test splits, unseen subjects)\n\n"
        "| metric (first crop of every clip) | held-out, before | held-out, after | train, after |\n"
        "|---|---|---|---|\n" + rows
    )
