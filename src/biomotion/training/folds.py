"""Train the learned parts of PG-BIG that see subjects for one cross-validation fold (`biomotion eval generation
--folds K`, `biomotion.evaluation.generation_cv`).

What a fold trains, on the clips of its training subjects only (the fold cache marks every held-out subject's clips
``val``, which training reads for its held-out report and never learns from):

- the tokenizer (PG-BIG Sec. 3.1): the reference-clip encoder of the subject profiler (A.6), the codes the prior
  learns, and the embedding the identity probe reads;
- the profile-action prior with its subject profiler (Sec. 3.2, A.6), early-stopped on the training subjects set
  aside by `biomotion.training.train_generator.dev_subject`, with the per-action guidance bounds and population
  postures of Table 1 and `biomotion.generation.posture` measured on the training clips;
- the action-only population prior (the T2M-GPT-kind baseline of Table 2), when asked for.

Each with the configuration recorded on the bundle's own model cards (``checkpoints/*.json``) and the shipped
seed, for fewer iterations than the shipped runs so that five folds fit a 2-core CPU
(`biomotion.evaluation.generation_cv.FoldTraining`). The muscle surrogate is not retrained: it maps coordinates
to activations with no notion of who moves (A.8), and is the shipped one in every fold.

This is the training half of the cross-validation; the evaluation layer cannot import training
(DESIGN.md, "Layers"), so the CLI hands `train_fold` to `biomotion.evaluation.generation_cv.eval_generation_cv`.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import torch

from biomotion.data.registry import DatasetCache
from biomotion.training import train_generator, train_tokenizer


def train_fold(
    cache_dir: Path,
    out: Path,
    *,
    data_root: Path,
    tokenizer_config: dict,
    generator_config: dict,
    tokenizer_iterations: int,
    generator_iterations: int,
    population: bool,
    seed: int = 0,
    progress: bool = False,
) -> dict:
    """Train one fold's tokenizer, generator (and population prior) on the ``train`` clips of the fold cache
    ``cache_dir``; write ``tokenizer.safetensors``, ``generator.safetensors`` (``population.safetensors``) with
    their cards into ``out``. Returns what the evaluation needs to know: the dev subjects the generator's early
    stopping set aside (never generated for in the fold's held-out figures; the fold's tuning subjects) and the
    training seconds of each model.

    A model whose weights and card are already in ``out`` from a run with the same config, iterations and seed is
    kept (an interrupted fold resumes where it stopped; ``out`` is the fold's own folder, keyed by its data).

    Contract: single-threaded torch for the duration (restored after), deterministic for a given cache, settings
    and seed."""
    out.mkdir(parents=True, exist_ok=True)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        tokenizer_card = _finished(out / "tokenizer.safetensors", tokenizer_config, tokenizer_iterations, seed)
        tokenizer_card = tokenizer_card or train_tokenizer.train(
            copy.deepcopy(tokenizer_config),
            cache_dir,
            out / "tokenizer.safetensors",
            data_root=data_root,
            iterations=tokenizer_iterations,
            seed=seed,
            progress=progress,
            command="biomotion.training.folds.train_fold",
        )
        total = int(generator_config["train"]["iterations"])
        cards = {}
        for name, is_population in (("generator", False), ("population", True)):
            if is_population and not population:
                continue
            stop = min(generator_iterations, total)
            cards[name] = _finished(out / f"{name}.safetensors", generator_config, stop, seed) or train_generator.train(
                copy.deepcopy(generator_config),
                cache_dir,
                out / "tokenizer.safetensors",
                data_root,
                out / f"{name}.safetensors",
                population=is_population,
                iterations=total,
                stop_at=stop,
                seed=seed,
                progress=progress,
                command="biomotion.training.folds.train_fold",
            )
    finally:
        torch.set_num_threads(threads)
    fraction = float(generator_config["train"].get("dev_fraction", 0.0))
    cache = DatasetCache(cache_dir)
    trained = sorted({f"{r['source']}/{r['subject']}" for r in cache.records if r["split"] == "train"})
    return {
        "dev_subjects": [s for s in trained if train_generator.dev_subject(s, fraction)],
        "train_seconds": {
            "tokenizer": tokenizer_card["train_seconds"],
            **{name: card["train_seconds"] for name, card in cards.items()},
        },
        "tokenizer_val_rmse_rotations_deg": tokenizer_card["metrics_val"]["rmse_rotations_deg"],
        "generator_kept_iteration": cards["generator"]["kept_iteration"],
        "generator_dev_cross_entropy": cards["generator"]["dev_cross_entropy"],
    }


def _finished(weights: Path, config: dict, iterations: int, seed: int) -> dict | None:
    """The card of ``weights`` when both exist and the card records ``config``, ``iterations`` and ``seed``."""
    card = weights.with_suffix(".json")
    if not weights.exists() or not card.exists():
        return None
    recorded = json.loads(card.read_text())
    same = (
        recorded.get("config") == config and recorded.get("iterations") == iterations and recorded.get("seed") == seed
    )
    return recorded if same else None
