"""Speed of the evaluation harness: 1000 clips of 3 s scored against 1000 reference clips; writes
docs/results/eval_benchmark.md.

    python benchmarks/eval.py [--data-root ../shared/data] [--clips 1000] [--seconds 3] [--out
    docs/results/eval_benchmark.md]

Clips are 3 s windows (90 frames at 30 Hz) cut with a stride of 1/6 s, round-robin over every clip of the dataset
cache (built from the data root in a temporary folder), so they are real motion; the reference of window i is
window i + 1 (another clip, or the same clip 1/6 s later). Timed stages (wall clock, one process, `torch_threads(1)`
inside the harness): loading the clips through the body model (one forward-kinematics call for all frames), the per-set
metrics of both sets (contact family, jerk, COM energy, joint ranges, entropy, diversity), the paired metrics (MJE,
P-MJE, ACCL, VEL, DTW fidelity, W2 fidelity) and writing JSON + Markdown. The optional full-body energy and ZMP
(``physics=True``) are timed on ``--physics-clips`` clips.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import torch

from biomotion.data.clips import (
    CoordinateClip,
    body_model,
    build_temporary_cache,
    coordinate_set,
)
from biomotion.evaluation.harness import evaluate, evaluation_markdown, write_json, write_text
from biomotion.io.atomic import atomic_write
from biomotion.metrics.registry import score_set


def windows(cache, count: int, frames: int) -> list[CoordinateClip]:
    """``count`` windows of ``frames`` frames, cut round-robin over the cache's clips with a stride of 1/6 s."""
    per_clip = []
    for i, record in enumerate(cache.records):
        starts = list(range(0, record["n_frames"] - frames + 1, max(1, round(cache.rate / 6))))
        per_clip.append((i, starts))
    out: list[CoordinateClip] = []
    motions = {}
    while len(out) < count:
        added = False
        for i, starts in per_clip:
            if starts and len(out) < count:
                start = starts.pop(0)
                motion = motions.setdefault(i, cache.motion(i))
                group = f"{cache.records[i]['source']}/{cache.records[i]['labels']['action']}"
                out.append(CoordinateClip(f"w{len(out):04d}", group, motion.frames(slice(start, start + frames))))
                added = True
        if not added:
            raise SystemExit(f"the cache holds fewer than {count} windows of {frames} frames")
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-root", default="../shared/data")
    parser.add_argument("--clips", type=int, default=1000)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--physics-clips", type=int, default=100)
    parser.add_argument("--out", default="docs/results/eval_benchmark.md")
    args = parser.parse_args(argv)

    handle, cache = build_temporary_cache(args.data_root)
    model = body_model(args.data_root)
    frames = round(args.seconds * cache.rate)
    with handle:
        cut = windows(cache, args.clips + 1, frames)
        pred_clips = cut[:-1]
        ref_clips = [CoordinateClip(p.name, c.group, c.motion) for p, c in zip(pred_clips, cut[1:])]
        physics_clips = pred_clips[: args.physics_clips]

    timings = {}
    started = time.perf_counter()
    pred = coordinate_set(pred_clips, model, cache.rate)
    ref = coordinate_set(ref_clips, model, cache.rate)
    timings["load both sets (FK of all frames)"] = time.perf_counter() - started
    t0 = time.perf_counter()
    result = evaluate(pred, ref, model)
    timings["all metrics: both sets + paired"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        write_json(Path(folder) / "eval.json", result)
        write_text(Path(folder) / "eval.md", evaluation_markdown(result))
    timings["write JSON + Markdown"] = time.perf_counter() - t0
    total = time.perf_counter() - started

    t0 = time.perf_counter()
    small = coordinate_set(physics_clips, model, cache.rate, derivatives=True)
    score_set(small, model, physics=True)
    physics = time.perf_counter() - t0

    lines = [
        "# Evaluation harness speed",
        "",
        (
            f"Written by `python benchmarks/eval.py` ({args.clips} clips of {args.seconds:g} s = {frames} frames at "
            f"{cache.rate:g} Hz, real windows of the dataset cache, each scored against the next window as its "
            "reference)."
        ),
        "",
        (
            f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, Python "
            f"{sys.version.split()[0]}, torch {torch.__version__} (CPU), one process."
        ),
        "",
        "| stage | seconds |",
        "|---|---:|",
        *[f"| {name} | {seconds:.2f} |" for name, seconds in timings.items()],
        f"| **total, {args.clips} predicted + {args.clips} reference clips** | **{total:.2f}** |",
        "",
        f"Target: under 60 s for 1000 clips of 3 s: {'met' if total < 60 else 'NOT met'}.",
        "",
        (
            f"Optional physics (`physics=True`: full-body energy with segment rotation and ZMP inside the support, "
            "spline derivatives, body velocities and accelerations by forward-mode derivatives of the kinematics): "
            f"{physics:.1f} s for {len(physics_clips)} clips "
            f"(including loading), about {physics / len(physics_clips) * args.clips:.0f} s per {args.clips}; off by "
            "default for that reason."
        ),
        "",
    ]
    with atomic_write(Path(args.out)) as out:
        out.write("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
