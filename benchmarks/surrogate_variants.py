"""Short training runs of muscle-surrogate variants side by side: the figures that choose its settings.

    python benchmarks/surrogate_variants.py --variant base: --variant d4lr2:model.depth=4,train.lr=0.002
        [--config configs/surrogate.yaml] [--cache build/dataset_lab_post] [--iterations 8000] [--threads 2]
        [--data-root ../shared/data] [--work build/surrogate_variants] [--out docs/results/surrogate_variants.md]

Each variant is the config with the listed ``SECTION.KEY=VALUE`` settings changed (values parsed as YAML; ``NAME:``
alone is the config itself), trained with `biomotion.training.train_surrogate.train` for ``--iterations`` (the
cosine schedule completed at that count, so a short run ranks settings, it does not reach the shipped figures),
then scored twice, both mirror-averaged (`MuscleSurrogate.predict_symmetric`): on the cache's val split (the
clips `train_surrogate` monitors; choose settings by this column) and as `biomotion validate muscles` scores it
(`surrogate_figures`: fresh labels of every clip of a subject the surrogate was not trained on, val and test).
Timing: the best of 30 mirror-averaged calls on a 3 s (90-frame) slice of the first val clip, one thread, with the
contact features' forward kinematics inside the call. One seed per variant: differences below about 0.005 in mean
R² are within what a change of seed moves.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch
import yaml

from biomotion.data.clips import body_model
from biomotion.data.registry import DatasetCache
from biomotion.muscles.surrogate import MuscleSurrogate
from biomotion.muscles.surrogate_scores import evaluate
from biomotion.training.train_surrogate import clip_arrays, labels_for_cache, train
from biomotion.validation.muscles import surrogate_figures

CLIP_FRAMES = 90


def parse_variant(text: str) -> tuple[str, dict[str, object]]:
    """``NAME:SECTION.KEY=VALUE,...`` -> (NAME, {"SECTION.KEY": value})."""
    name, _, settings = text.partition(":")
    changes = {}
    for item in filter(None, settings.split(",")):
        key, equals, value = item.partition("=")
        if not equals or "." not in key:
            raise SystemExit(f"variant {text!r}: each setting is SECTION.KEY=VALUE, got {item!r}")
        changes[key] = yaml.safe_load(value)
    if not name:
        raise SystemExit(f"variant {text!r} has no name")
    return name, changes


def configured(base: dict, changes: dict[str, object]) -> dict:
    """A copy of ``base`` with the ``SECTION.KEY`` settings changed; unknown sections or keys are errors."""
    config = yaml.safe_load(yaml.safe_dump(base))
    for dotted, value in changes.items():
        section, key = dotted.split(".", 1)
        if key not in config.get(section, {}):
            raise SystemExit(f"{dotted}: the config has no such setting")
        config[section][key] = value
    return config


def clip_ms(model: MuscleSurrogate, clip: tuple) -> float:
    """Best wall time (ms) of 30 mirror-averaged calls on the first ``CLIP_FRAMES`` frames of ``clip``, one thread."""
    q, mask = clip[0][:, :CLIP_FRAMES], clip[1]
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with torch.no_grad():
            model.predict_symmetric(q, mask)
            best = float("inf")
            for _ in range(30):
                tic = time.perf_counter()
                model.predict_symmetric(q, mask)
                best = min(best, time.perf_counter() - tic)
    finally:
        torch.set_num_threads(threads)
    return 1e3 * best


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", action="append", required=True, help="NAME:SECTION.KEY=VALUE,...")
    parser.add_argument("--config", type=Path, default=Path("configs/surrogate.yaml"))
    parser.add_argument("--cache", type=Path, default=Path("build/dataset_lab_post"))
    parser.add_argument("--data-root", type=Path, default=Path("../shared/data"))
    parser.add_argument("--iterations", type=int, default=8000)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--work", type=Path, default=Path("build/surrogate_variants"))
    parser.add_argument("--out", type=Path, default=Path("docs/results/surrogate_variants.md"))
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    base = yaml.safe_load(args.config.read_text())
    variants = [parse_variant(text) for text in args.variant]
    cache = DatasetCache(args.cache)
    val_clips = clip_arrays(cache, labels_for_cache(cache, args.data_root, None, progress=False), "val")
    long_clip = next(c for c in val_clips if c[0].shape[1] >= CLIP_FRAMES)
    body = body_model(args.data_root)
    args.work.mkdir(parents=True, exist_ok=True)
    rows = []
    for name, changes in variants:
        weights = args.work / f"{name}.safetensors"
        card = train(
            configured(base, changes),
            args.cache,
            weights,
            data_root=args.data_root,
            iterations=args.iterations,
            progress=True,
        )
        model = MuscleSurrogate.load(weights, body=body).eval()
        val = evaluate(model, val_clips, symmetric=True)
        skipped: list[str] = []
        held_out = surrogate_figures(args.data_root, weights, skipped)
        rows.append(
            (
                name,
                changes,
                card["iterations"],
                card["train_seconds"],
                val["r2_mean_per_muscle"],
                held_out["surrogate_r2"],
                held_out["surrogate_r2_pooled"],
                held_out["surrogate_rmse"],
                held_out["surrogate_held_out_clips"],
                clip_ms(model, long_clip),
            )
        )
        print(f"{name}: val {val['r2_mean_per_muscle']:.4f}, held out {held_out['surrogate_r2']}", skipped, flush=True)
    given = argv if argv is not None else sys.argv[1:]
    lines = [
        "# Muscle-surrogate variants",
        "",
        f"Command: `python benchmarks/surrogate_variants.py {' '.join(given)}`",
        "",
        f"Config `{args.config}`, cache `{args.cache}`, {args.iterations} iterations each, seed 0, "
        f"{args.threads} threads; mean R² over muscles, mirror-averaged.",
        "",
        "| variant | changes | iterations | train (s) | val mean R² | held-out mean R² | held-out pooled R² "
        "| held-out RMSE | held-out clips | ms per 3 s clip (1 thread) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, changes, its, seconds, val_r2, r2, pooled, rmse, clips, ms in rows:
        shown = ", ".join(f"{k}={v}" for k, v in changes.items()) or "(config)"
        lines.append(
            f"| {name} | {shown} | {its} | {seconds:.0f} | {val_r2:.4f} | {r2:.4f} | {pooled:.4f} "
            f"| {rmse:.4f} | {clips} | {ms:.2f} |"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
