"""Stride of each walking style, real against generated; writes docs/results/walking_styles.md.

    python benchmarks/walking_styles.py [--cache build/dataset_bn] [--checkpoints checkpoints/full-body]

Real: every clip of the cache labelled "walk" with a style (the Bandai-Namco walks; cache built by the command in
`checkpoints/full-body/README.md`). Generated: `--samples` clips of 4 s per style from the full-body bundle, no
profile, at the style's median training speed as `biomotion generate` asks (`ActionVocabulary.resolve`), guided
with the defaults, with the foot and ground terms' contact mask by height alone (the rule before
`biomotion.models.foot_contact.stance_mask`) and without the foot-skim term (`biomotion.guidance.losses.foot_skim`),
whose pull on feet near the floor could shorten slow walks' strides. Stride length and frequency
as the manipulation study of `biomotion eval generation` measures them
(`biomotion.evaluation.generation.kinematic_measures`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from biomotion.body.kinematics import torch_threads
from biomotion.data.registry import DatasetCache
from biomotion.evaluation.generation import kinematic_measures
from biomotion.generation.pipeline import CHECKPOINTS, Generator
from biomotion.generation.routing import FULL_BODY
from biomotion.guidance.refine import GuidanceConfig
from biomotion.io.atomic import atomic_write

MEASURES = ("stride_length", "stride_frequency")


def real_measures(cache: DatasetCache) -> dict[str, list[dict[str, float]]]:
    """Per walking style, the measures of each real clip."""
    out: dict[str, list[dict[str, float]]] = {}
    for record in cache.records:
        labels = record["labels"]
        if labels.get("action") == "walk" and labels.get("style") and record["source"] == "bandai-namco":
            q = np.asarray(cache.values[record["offset"] : record["offset"] + record["n_frames"]], dtype=np.float64)
            out.setdefault(labels["style"], []).append(kinematic_measures(q, cache.rate))
    return out


def generated_measures(
    generator: Generator, style: str, samples: int, config: GuidanceConfig
) -> list[dict[str, float]]:
    request = generator.bundle.vocabulary.resolve(f"walk, {style}")
    out = generator.generate(request, seconds=4.0, samples=samples, seed=0, personalised=False, guidance_config=config)
    return [kinematic_measures(q, generator.rate) for q in out.q.detach().double().numpy()]


def summary(rows: list[dict[str, float]], key: str) -> str:
    values = np.array([r[key] for r in rows])
    return f"{values.mean():.2f} ({values.min():.2f}-{values.max():.2f})"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cache", default="build/dataset_bn")
    parser.add_argument("--checkpoints", default=str(CHECKPOINTS / FULL_BODY))
    parser.add_argument("--data-root", default="../shared/data")
    parser.add_argument("--samples", type=int, default=8)
    parser.add_argument("--out", default="docs/results/walking_styles.md")
    args = parser.parse_args(argv)
    real = real_measures(DatasetCache(args.cache))
    generator = Generator.load(args.data_root, args.checkpoints)
    known = {
        style for style in generator.bundle.vocabulary.styles if f"walk, {style}" in generator.bundle.vocabulary.texts
    }
    lines = [
        "# Walking styles: stride, real against generated",
        "",
        f"Command: `python {' '.join(sys.argv)}`; real: the Bandai-Namco walks of `{args.cache}`; generated: "
        f"{args.samples} clips of 4 s per style, full-body bundle, no profile, seed 0, at the style's median "
        "training speed. Mean (range) over clips.",
        "",
        "| style | real clips | real stride (m) | generated stride (m) | generated, contact by height alone | "
        "generated, no foot-skim term | real stride frequency (Hz) | generated stride frequency (Hz) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    with torch_threads(1):
        for style in sorted(set(real) & known):
            guided = generated_measures(generator, style, args.samples, GuidanceConfig())
            by_height = generated_measures(generator, style, args.samples, GuidanceConfig(stance_speed_ratio=None))
            no_skim = generated_measures(generator, style, args.samples, GuidanceConfig(w_foot_skim=0.0))
            lines.append(
                f"| {style} | {len(real[style])} | {summary(real[style], 'stride_length')} | "
                f"{summary(guided, 'stride_length')} | {summary(by_height, 'stride_length')} | "
                f"{summary(no_skim, 'stride_length')} | "
                f"{summary(real[style], 'stride_frequency')} | {summary(guided, 'stride_frequency')} |"
            )
            print(lines[-1], flush=True)
    with atomic_write(Path(args.out)) as handle:
        handle.write("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
