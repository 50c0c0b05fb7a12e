"""FlexMotion against PG-BIG on held-out subjects (issue bars of FlexMotion's first build; FlexMotion Sec. 4,
Tables 1-3): physical consistency of what FlexMotion generates, the distribution metrics of both generators by the
same motion-text evaluator on the same prompts, and FlexMotion's sampling time.

    python -m biomotion.evaluation.flexmotion --cache ~/.cache/biomotion/dataset \\
        --evaluator checkpoints/evaluator.safetensors --data-root ../shared/data \\
        --out docs/results/eval_flexmotion [--samples 2]

Prompts. The targets of `biomotion.evaluation.distribution.pgbig_report`: every clip (cut to 6 s) of the subjects
that neither PG-BIG nor the evaluator was trained on, of the sources PG-BIG learnt, kept only where the subject is
outside the cache's train split (FlexMotion's training data). Each target gives its label text and its subject's
profile; each generator makes ``samples`` clips per target (FlexMotion: seed ``seed + r``, all targets in one
batch; PG-BIG as `pgbig_report`). Both generated sets are scored against the same real clips with
`score_generated`, each generated clip read through its target's coordinate mask. PG-BIG's clips are as long as
their targets (up to 6 s); FlexMotion's are one window (2.13 s): the evaluator pools over time, but the lengths
differ.

Figures. ``flexmotion_torque_consistency_rel_rmse`` and ``flexmotion_grf_consistency_bw``: means over the
generated clips of `biomotion.generation.flexmotion.consistency`. ``flexmotion_fid_ratio_to_pgbig``: FID(FlexMotion)
/ FID(PG-BIG) against the real targets; ``flexmotion_rprecision_ratio_to_pgbig``: the ratio of the R-precision
top-1 means (top-2 and top-3 are given beside: with 24 targets and few distinct texts, top-2 and top-3 are 1.0 for
the real clips and for PG-BIG, a ceiling that hides differences). ``knee_range_ratio``: the median over generated
clips of the range of the right knee angle over the range in the target's first 64 frames, a check that the motion
moves (a still body is trivially consistent); PG-BIG's beside it is over the whole target (its clips are as long).
``flexmotion_seconds_2048_clips``: wall time to sample and decode 2048 clips (DDIM steps as shipped, batches of
256, text embedding included) on ONE torch thread of this CPU (the bar is stated for 2 cores; one thread is the
slower case).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.errors import BiomotionError
from biomotion.evaluation.distribution import TextClip, pgbig_report, score_generated, text_clip
from biomotion.generation.flexmotion import FlexMotionGenerator, consistency
from biomotion.models.motion_text_evaluator import MotionTextEvaluator, clip_text, embed_sentences

BARS = {
    "flexmotion_torque_consistency_rel_rmse": ("<=", 0.10),
    "flexmotion_grf_consistency_bw": ("<=", 0.15),
    "flexmotion_fid_ratio_to_pgbig": ("<=", 1.1),
    "flexmotion_rprecision_ratio_to_pgbig": (">=", 0.9),
    "flexmotion_seconds_2048_clips": ("<=", 300.0),
}


def flexmotion_targets(cache, data_root, checkpoints="checkpoints"):
    """The held-out targets (module docstring) as (cache index, real `TextClip`) pairs."""
    from biomotion.evaluation.generation import unseen_targets
    from biomotion.generation.pipeline import Generator

    generator = Generator.load(data_root, checkpoints, surrogate=False)
    sources = sorted({key.split("/", 1)[0] for key in generator.bundle.train_subjects})
    out = []
    for t in unseen_targets(cache, generator.bundle.train_subjects, 6.0, per_subject=10**6):
        record = cache.records[t.index]
        if record["source"] in sources and record["split"] != "train":
            out.append((t.index, text_clip(t.motion, clip_text(record["labels"]), name=record["clip_id"])))
    if len(out) < 4:
        raise BiomotionError(f"{len(out)} held-out targets: too few to score")
    return out


def seconds_2048(generator: FlexMotionGenerator, texts: list[str], profiles: list, batch: int = 256) -> float:
    """Wall seconds to sample and decode 2048 clips of the given prompts (cycled), in batches of ``batch``."""
    started = time.perf_counter()
    sentences = embed_sentences(sorted(set(texts)))
    lookup = {t: k for k, t in enumerate(sorted(set(texts)))}
    for start in range(0, 2048, batch):
        rows = [(start + k) % len(texts) for k in range(batch)]
        generator.sample(
            [texts[r] for r in rows],
            [profiles[r] for r in rows],
            seed=start,
            sentences=sentences[[lookup[texts[r]] for r in rows]],
        )
    return time.perf_counter() - started


def report(
    cache_dir,
    evaluator_path: str | Path,
    data_root: str | Path,
    *,
    checkpoints: str | Path = "checkpoints",
    samples: int = 2,
    seed: int = 0,
    repeats: int = 10,
    command: str = "",
) -> dict:
    """Every figure of the module docstring, the PG-BIG figures beside FlexMotion's, and the bars; ``cache_dir`` is
    a dataset cache folder or an open `DatasetCache`."""
    from biomotion.data.registry import DatasetCache

    cache = cache_dir if isinstance(cache_dir, DatasetCache) else DatasetCache(cache_dir)
    evaluator = MotionTextEvaluator.load(evaluator_path)
    targets = flexmotion_targets(cache, data_root, checkpoints)
    real = [clip for _, clip in targets]
    flex = FlexMotionGenerator.load(data_root, checkpoints)
    texts = [clip.text for clip in real]
    profiles = [cache.records[i].get("profile") for i, _ in targets]
    generated, figures = [], {"torque_rel_rmse": [], "grf_bw": []}
    knee, ranges = CANONICAL_COORDINATES.index("knee_angle_r"), []
    sentences = embed_sentences(texts)
    for r in range(samples):
        decoded = flex.sample(texts, profiles, seed=seed + r, sentences=sentences)
        for key, values in consistency(flex.refiner, decoded).items():
            figures[key].extend(values.tolist())
        for k, clip in enumerate(real):
            values = decoded["q"][k].double().numpy()
            generated.append(TextClip(values, clip.text, clip.mask, flex.model.config.rate, clip.name))
            real_range = np.ptp(clip.values[: len(values), knee])
            ranges.append(float(np.ptp(values[:, knee]) / max(real_range, 1e-3)))
    flex_scores = score_generated(evaluator, real, generated, repeats=repeats)
    pgbig = pgbig_report(evaluator, cache, data_root, checkpoints=checkpoints, samples=samples, seed=seed,
                         repeats=repeats, progress=False)  # fmt: skip
    if pgbig["targets"] != len(real):  # the same target selection, so the same prompts
        raise BiomotionError(f"PG-BIG scored {pgbig['targets']} targets, FlexMotion {len(real)}: not the same set")
    with torch.no_grad():
        timing = seconds_2048(flex, texts, profiles)
    r_flex = {k: flex_scores["generated"][f"r_precision_top{k}"]["mean"] for k in (1, 2, 3)}
    r_pg = {k: pgbig["generated"][f"r_precision_top{k}"]["mean"] for k in (1, 2, 3)}
    figures_out = {
        "flexmotion_torque_consistency_rel_rmse": float(np.mean(figures["torque_rel_rmse"])),
        "flexmotion_grf_consistency_bw": float(np.mean(figures["grf_bw"])),
        "flexmotion_fid_ratio_to_pgbig": flex_scores["fid_generated_to_real"] / pgbig["fid_generated_to_real"],
        "flexmotion_rprecision_ratio_to_pgbig": r_flex[1] / max(r_pg[1], 1e-9),
        "flexmotion_seconds_2048_clips": timing,
    }
    bars = {
        name: {"value": figures_out[name], "bar": f"{op} {limit:g}",
               "met": bool(figures_out[name] <= limit if op == "<=" else figures_out[name] >= limit)}
        for name, (op, limit) in BARS.items()
    }  # fmt: skip
    return {
        "command": command,
        "targets": len(real),
        "subjects": len({cache.records[i]["subject"] for i, _ in targets}),
        "samples_per_target": samples,
        "seed": seed,
        "figures": figures_out,
        "bars": bars,
        "knee_range_ratio": {"flexmotion": float(np.median(ranges)), "pgbig": pgbig.get("knee_range_ratio_median")},
        "rprecision_ratio_top1_top2_top3": {k: r_flex[k] / max(r_pg[k], 1e-9) for k in (1, 2, 3)},
        "consistency_per_clip": {k: [round(v, 5) for v in vals] for k, vals in figures.items()},
        "timing": {
            "threads": torch.get_num_threads(),
            "ddim_steps": flex.model.config.sample_steps,
            "batch": 256,
            "includes": "text embedding, DDIM sampling with guidance, decoding",
        },  # fmt: skip
        "flexmotion": flex_scores,
        "pgbig": pgbig,
        "flexmotion_clip_seconds": flex.model.config.window / flex.model.config.rate,
        "flexmotion_clip_frames": flex.model.config.window,
        "weights_card": "checkpoints/flexmotion.md",
    }


def markdown(rep: dict) -> str:
    f, pg = rep["flexmotion"], rep["pgbig"]
    rows = [
        "| bar | value | target | met |",
        "|---|---|---|---|",
        *(f"| {k} | {v['value']:.4g} | {v['bar']} | {'yes' if v['met'] else 'no'} |" for k, v in rep["bars"].items()),
    ]
    knee = rep["knee_range_ratio"].get("pgbig")
    pgbig_knee = "not computed" if knee is None else f"{knee:.3g}"
    side = ["| figure | FlexMotion | PG-BIG | real |", "|---|---|---|---|"]
    side.append(f"| FID to real | {f['fid_generated_to_real']:.4g} | {pg['fid_generated_to_real']:.4g} | "
                f"{f['fid_real_halves']['mean']:.4g} (halves) |")  # fmt: skip
    for key in ("r_precision_top1", "r_precision_top2", "r_precision_top3", "matching_score", "diversity_evaluator"):
        side.append(
            f"| {key} | {f['generated'][key]['mean']:.4g} | {pg['generated'][key]['mean']:.4g} | "
            f"{f['real'][key]['mean']:.4g} |"
        )
    return (
        "# FlexMotion against PG-BIG on held-out subjects\n\n"
        f"Command: `{rep['command']}`\n\n{rep['targets']} targets of {rep['subjects']} held-out subjects, "
        f"{rep['samples_per_target']} samples each; FlexMotion clips are {rep['flexmotion_clip_seconds']:.2f} s "
        "(one window), PG-BIG's as long as their targets (up to 6 s). Definitions: "
        "`python -m biomotion.evaluation.flexmotion --help`.\n\n"
        + "\n".join(rows)
        + f"\n\nKnee range, generated over real (median): FlexMotion {rep['knee_range_ratio']['flexmotion']:.3g} "
        f"(its window over the target's first {rep['flexmotion_clip_frames']} frames), PG-BIG {pgbig_knee} (over "
        "the whole target). R-precision ratio is of top-1; top-1/2/3 ratios: "
        + ", ".join(f"{v:.3g}" for v in rep["rprecision_ratio_top1_top2_top3"].values())
        + f". Sampling time on {rep['timing']['threads']} torch thread(s) of this CPU (bar: 2 cores), "
        f"{rep['timing']['ddim_steps']} DDIM steps, batches of {rep['timing']['batch']}.\n\n" + "\n".join(side) + "\n"
    )


def eval_flexmotion(
    data_root: str | Path,
    json_path: str | Path,
    md_path: str | Path | None = None,
    *,
    cache_dir: str | Path | None = None,
    evaluator: str | Path | None = None,
    checkpoints: str | Path = "checkpoints",
    samples: int = 2,
    seed: int = 0,
    repeats: int = 10,
    command: str = "",
) -> dict:
    """`report` written as JSON (and Markdown at ``md_path``). Without ``cache_dir`` the clips come from a temporary
    cache of ``data_root`` (`biomotion.data.clips.build_temporary_cache`: the sources PG-BIG learnt, without its
    training subjects), so any folder laid out like ../shared/data can be scored; ``evaluator`` defaults to the
    ``evaluator.safetensors`` of ``checkpoints``."""
    from biomotion.data.clips import build_temporary_cache
    from biomotion.generation.pipeline import Generator
    from biomotion.io.atomic import atomic_write

    checkpoints = Path(checkpoints)
    evaluator = Path(evaluator).expanduser() if evaluator is not None else checkpoints / "evaluator.safetensors"
    if not evaluator.is_file():
        raise BiomotionError(f"{evaluator}: no motion-text evaluator weights (`biomotion train evaluator`)")
    handle = None
    if cache_dir is None:
        seen = Generator.load(data_root, checkpoints, surrogate=False).bundle.train_subjects
        sources = sorted({key.split("/", 1)[0] for key in seen})
        try:
            handle, cache_dir = build_temporary_cache(data_root, sources=sources, exclude_subjects=seen)
        except BiomotionError as error:
            raise BiomotionError(f"no held-out subject under {data_root}: {error}") from error
    try:
        rep = report(Path(cache_dir).expanduser() if isinstance(cache_dir, (str, Path)) else cache_dir, evaluator,
                     data_root, checkpoints=checkpoints, samples=samples, seed=seed, repeats=repeats,
                     command=command)  # fmt: skip
    finally:
        if handle is not None:
            handle.cleanup()
    with atomic_write(Path(json_path)) as out:
        json.dump(rep, out, indent=1)
        out.write("\n")
    if md_path is not None:
        with atomic_write(Path(md_path)) as out:
            out.write(markdown(rep))
    return rep


def main(argv: Sequence[str] | None = None) -> int:
    from biomotion.io.paths import portable

    parser = argparse.ArgumentParser(prog="python -m biomotion.evaluation.flexmotion", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--cache", type=Path, help="dataset cache folder (`biomotion data build`; default: a "
                        "temporary one of --data-root)")  # fmt: skip
    parser.add_argument("--evaluator", type=Path, help="motion-text evaluator weights (default: in --checkpoints)")
    parser.add_argument("--data-root", type=Path, default=Path("../shared/data"), help="folder with opensim-models/")
    parser.add_argument("--checkpoints", type=Path, default=Path("checkpoints"), help="shipped weights folder")
    parser.add_argument("--out", type=Path, required=True, help="report path without suffix (.json and .md)")
    parser.add_argument("--samples", type=int, default=2, help="clips per target and generator (default: 2)")
    parser.add_argument("--repeats", type=int, default=10, help="seeds of the random draws (default: 10)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    words = ["python", "-m", "biomotion.evaluation.flexmotion", *(sys.argv[1:] if argv is None else argv)]
    command = " ".join(shlex.quote(portable(word)) for word in words)
    out = Path(args.out)
    rep = eval_flexmotion(args.data_root, out.with_suffix(".json"), out.with_suffix(".md"), cache_dir=args.cache,
                          evaluator=args.evaluator, checkpoints=args.checkpoints, samples=args.samples,
                          repeats=args.repeats, command=command)  # fmt: skip
    print(markdown(rep))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
