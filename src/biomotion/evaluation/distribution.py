"""Distribution metrics of generated motion against real motion, through the shipped motion-text evaluator: FID,
R-precision top-1/2/3, matching score, diversity and multimodality (T2M, Guo et al. 2022, Sec. 5; FlexMotion
Tables 1-3), with the real-vs-real reference figures they are read against.

`score_generated` takes clips already generated (canonical coordinates with their prompt text) and the real clips
of the held-out subjects, and gives the figures of both sets, the FID of the generated set against the real one,
and the FID between two random halves of the real set: a finite real set has a positive FID against itself, so
a generator's FID means something only beside that floor (and FID grows as the sets shrink: compare figures of
equal set sizes). Any generator's output can be scored this way (FlexMotion, PG-BIG).

`pgbig_report` generates PG-BIG clips for the held-out clips of the sources the shipped lab generator learnt and
scores them with `score_generated` (``--pgbig-data-root`` below adds it to the report).

`real_report` gives the evaluator's sanity figures on the real clips of the held-out (val + test) subjects of a
dataset cache, subjects the evaluator was never trained on (`biomotion.training.train_evaluator`):

    python -m biomotion.evaluation.distribution --cache ~/.cache/biomotion/dataset \\
        --evaluator checkpoints/evaluator.safetensors --out docs/results/eval_distribution \\
        [--pgbig-data-root ../shared/data]

R-precision draws the distractor texts, diversity its pairs and the half split its halves at random: each figure is
given as the mean and standard deviation over ``repeats`` seeds (T2M repeats its evaluation 20 times).
"""

from __future__ import annotations

import argparse
import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from biomotion.body.canonical import CANONICAL_COORDINATES, DEFAULT_RATE
from biomotion.errors import BiomotionError
from biomotion.metrics.distribution import fid, half_split_fid, set_figures
from biomotion.models.motion_text_evaluator import MotionTextEvaluator, clip_text, embed_motions, embed_texts
from biomotion.motion import Motion

HELD_OUT = ("val", "test")
REPEATS = 10


@dataclass(frozen=True)
class TextClip:
    """A clip to score: canonical coordinates ``values`` [T, 39] (SI) at ``rate`` Hz, the text it shows (real
    clips) or was generated from, and the coordinate ``mask`` [39] (None: all present). Scoring generated clips
    against real ones that lack coordinates (the Fukuchi runners have no arms), pass the real target's mask so
    both are read through the same coordinates."""

    values: np.ndarray
    text: str
    mask: np.ndarray | None = None
    rate: float = DEFAULT_RATE
    name: str = ""


def text_clip(motion: Motion, text: str, *, mask: np.ndarray | None = None, name: str = "") -> TextClip:
    """A `TextClip` of a `Motion` holding the canonical coordinates (any column order); ``mask`` overrides the
    motion's own (combined with it by AND)."""
    missing = [n for n in CANONICAL_COORDINATES if n not in motion.names]
    if missing:
        raise BiomotionError(f"{name or 'a clip'} lacks canonical coordinates {missing[:4]}")
    order = [motion.names.index(n) for n in CANONICAL_COORDINATES]
    own = motion.mask[order]
    return TextClip(
        motion.values[:, order], text, own if mask is None else own & np.asarray(mask, bool), motion.rate, name
    )


def embed(evaluator: MotionTextEvaluator, clips: Sequence[TextClip]) -> tuple[np.ndarray, np.ndarray]:
    """Motion embeddings [N, D] and text embeddings [N, D] of ``clips`` (each distinct text embedded once)."""
    if not clips:
        raise BiomotionError("no clips to score")
    rates = {round(c.rate, 6) for c in clips}
    if len(rates) != 1:
        raise BiomotionError(f"clips at several rates {sorted(rates)}: resample them to one")
    motions = embed_motions(evaluator, [c.values for c in clips], [c.mask for c in clips], clips[0].rate)
    unique = sorted({c.text for c in clips})
    table = dict(zip(unique, embed_texts(evaluator, unique)))
    return motions, np.stack([table[c.text] for c in clips])


def _repeated(function, repeats: int) -> dict:
    """Mean and std over seeds 0 .. repeats - 1 of the figures ``function(seed)`` returns (dict or float)."""
    runs = [function(seed) for seed in range(repeats)]
    if not isinstance(runs[0], dict):
        values = np.asarray(runs, dtype=np.float64)
        return {"mean": float(values.mean()), "std": float(values.std())}
    out = {}
    for key, first in runs[0].items():
        if isinstance(first, float):
            values = np.asarray([run[key] for run in runs], dtype=np.float64)
            out[key] = {"mean": float(values.mean()), "std": float(values.std())}
        else:
            out[key] = first
    return out


def score_generated(
    evaluator: MotionTextEvaluator,
    real: Sequence[TextClip],
    generated: Sequence[TextClip],
    *,
    repeats: int = REPEATS,
) -> dict:
    """Figures of the ``real`` and ``generated`` sets (`set_figures`: R-precision, matching score, diversity,
    multimodality over prompts), ``fid_generated_to_real`` and the reference ``fid_real_halves``; random figures as
    mean and std over ``repeats`` seeds."""
    real_m, real_t = embed(evaluator, real)
    gen_m, gen_t = embed(evaluator, generated)
    real_texts, gen_texts = [c.text for c in real], [c.text for c in generated]
    return {
        "real": _repeated(lambda s: set_figures(real_m, real_t, real_texts, seed=s), repeats),
        "generated": _repeated(lambda s: set_figures(gen_m, gen_t, gen_texts, seed=s), repeats),
        "fid_generated_to_real": fid(gen_m, real_m),
        "fid_real_halves": _repeated(lambda s: half_split_fid(real_m, s), repeats),
    }


def held_out_clips(cache, splits: Sequence[str] = HELD_OUT) -> list[TextClip]:
    """The real clips of the cache's ``splits`` (default: the held-out subjects) as `TextClip` with their label
    texts."""
    return [
        TextClip(
            cache.motion(i).values,
            clip_text(cache.records[i]["labels"]),
            cache.masks[i],
            cache.rate,
            cache.records[i]["clip_id"],
        )
        for split in splits
        for i in cache.indices(split=split)
    ]


def real_report(
    evaluator_path: str | Path,
    cache_dir: str | Path,
    *,
    repeats: int = REPEATS,
    command: str = "",
    pgbig_data_root: str | Path | None = None,
) -> dict:
    """The evaluator's figures on the held-out real clips of the cache: `set_figures` of all of them, the FID
    between two random halves (the floor of a generator's FID against them), per split figures too."""
    from biomotion.data.registry import DatasetCache

    evaluator_path = Path(evaluator_path)
    evaluator = MotionTextEvaluator.load(evaluator_path)
    cache = DatasetCache(cache_dir)
    clips = held_out_clips(cache)
    motions, texts = embed(evaluator, clips)
    names = [c.text for c in clips]
    card_path = evaluator_path.with_suffix(".json")
    card = json.loads(card_path.read_text()) if card_path.exists() else {}
    sources: dict[str, int] = {}
    for i in (i for split in HELD_OUT for i in cache.indices(split=split)):
        sources[cache.records[i]["source"]] = sources.get(cache.records[i]["source"], 0) + 1
    subjects = {
        f"{cache.records[i]['source']}/{cache.records[i]['subject']}" for s in HELD_OUT for i in cache.indices(split=s)
    }
    return {
        "command": command,
        "evaluator": {
            "weights": evaluator_path.name,
            "sha256": hashlib.sha256(evaluator_path.read_bytes()).hexdigest(),
            "trained_on": card.get("data", {}).get("trained_on"),
            "train_clips": card.get("data", {}).get("train_clips"),
        },
        "held_out": {
            "splits": list(HELD_OUT),
            "clips": len(clips),
            "subjects": len(subjects),
            "clips_per_source": sources,
            "distinct_texts": len(set(names)),
        },
        "repeats": repeats,
        "real_held_out": _repeated(lambda s: set_figures(motions, texts, names, seed=s), repeats),
        "fid_real_halves": _repeated(lambda s: half_split_fid(motions, s), repeats),
        "pgbig": None if pgbig_data_root is None else pgbig_report(evaluator, cache, pgbig_data_root, repeats=repeats),
    }


def pgbig_report(
    evaluator: MotionTextEvaluator,
    cache,
    data_root: str | Path,
    *,
    checkpoints: str | Path | None = None,
    max_seconds: float = 6.0,
    samples: int = 4,
    seed: int = 0,
    repeats: int = REPEATS,
    progress: bool = True,
) -> dict:
    """PG-BIG scored by the evaluator on the cache's subjects that neither the generator nor the evaluator was
    trained on, of the sources the generator learnt (its actions): every clip of those subjects is a target
    (`biomotion.evaluation.generation.unseen_targets`, cut to ``max_seconds``) and gets ``samples`` personalised,
    guided generations of its action as long as itself (profile and the subject's other clips as references; sample
    r of target k has seed ``seed + r * targets + k``, as `biomotion eval generation` repeats), each read through
    the target's coordinate mask. `score_generated` of the generated clips against the real targets, both with the
    target's label text (multimodality: over the samples of each text). ``knee_range_ratio_median``: the median over
    generated clips of the right knee angle's range over the range in its target (both as long as the target), a
    check that the clips move as much as the real ones."""
    from biomotion.evaluation.generation import unseen_targets
    from biomotion.generation.pipeline import CHECKPOINTS, Generator
    from biomotion.models.actions import ActionRequest

    generator = Generator.load(data_root, Path(checkpoints or CHECKPOINTS))
    sources = sorted({key.split("/", 1)[0] for key in generator.bundle.train_subjects})
    targets = [
        t
        for t in unseen_targets(cache, generator.bundle.train_subjects, max_seconds, per_subject=10**6)
        if cache.records[t.index]["source"] in sources
    ]
    if len(targets) < 4:
        raise BiomotionError(f"{len(targets)} unseen clips of the generator's sources {sources}: too few to score")
    real, generated = [], []
    for target in targets:
        labels = cache.records[target.index]["labels"]
        text, name = clip_text(labels), cache.records[target.index]["clip_id"]
        real.append(text_clip(target.motion, text, name=name))
    for r in range(samples):
        for k, target in enumerate(targets):
            labels = cache.records[target.index]["labels"]
            request = ActionRequest(
                labels["action"], labels.get("style"), labels.get("speed"), labels.get("text") or ""
            )
            out = generator.generate(
                request,
                profile=cache.profile(target.index),
                references=target.references,
                reference_actions=target.reference_actions,
                reference_speeds=target.reference_speeds,
                seconds=target.motion.n_frames / generator.rate,
                seed=seed + r * len(targets) + k,
            )
            values = out.q[0].detach().double().numpy()
            generated.append(TextClip(values, real[k].text, real[k].mask, generator.rate, real[k].name))
        if progress:
            print(f"PG-BIG sample {r + 1}/{samples} of {len(targets)} targets generated", flush=True)
    knee = CANONICAL_COORDINATES.index("knee_angle_r")
    knee_ratios = [
        float(np.ptp(g.values[:, knee]) / max(float(np.ptp(real[k % len(real)].values[: len(g.values), knee])), 1e-3))
        for k, g in enumerate(generated)
    ]
    real_motions, _ = embed(evaluator, real)
    generated_motions, _ = embed(evaluator, generated)
    rounds = generated_motions.reshape(samples, len(targets), -1)
    per_sample = np.asarray([fid(rounds[r], real_motions) for r in range(samples)])
    return {
        "generator_sources": sources,
        "targets": len(targets),
        "subjects": len({t.subject for t in targets}),
        "samples_per_target": samples,
        "max_seconds": max_seconds,
        "seed": seed,
        **score_generated(evaluator, real, generated, repeats=repeats),
        "knee_range_ratio_median": float(np.median(knee_ratios)),
        "fid_generated_to_real_one_sample_per_clip": {
            "mean": float(per_sample.mean()),
            "std": float(per_sample.std()),
        },
    }


_ROWS = (
    ("r_precision_top1", "R-precision top-1 ↑"),
    ("r_precision_top2", "R-precision top-2 ↑"),
    ("r_precision_top3", "R-precision top-3 ↑"),
    ("matching_score", "Matching score (MM-Dist) ↓"),
    ("diversity_evaluator", "Diversity →"),
    ("multimodality", "Multimodality (real: spread within a text)"),
)


def _cell(value) -> str:
    if isinstance(value, dict):
        return f"{value['mean']:.3f} ± {value['std']:.3f}"
    return "–" if value is None else f"{value:.3f}"


def markdown(report: dict) -> str:
    """The real-clip report as Markdown."""
    held, figures = report["held_out"], report["real_held_out"]
    lines = [
        "# Distribution metrics: the motion-text evaluator on held-out real clips",
        "",
        f"Command: `{report['command']}`",
        "",
        f"Evaluator `{report['evaluator']['weights']}` (SHA-256 `{report['evaluator']['sha256'][:16]}…`), trained "
        f"on the {report['evaluator']['trained_on'] or 'training split'} ({report['evaluator']['train_clips']} "
        "clips); card: checkpoints/evaluator.md. Scored here: the "
        f"{held['clips']} real clips of the {held['subjects']} {' + '.join(held['splits'])} subjects it never saw "
        f"({', '.join(f'{k} {v}' for k, v in held['clips_per_source'].items())}; {held['distinct_texts']} distinct "
        "label texts). Definitions: `biomotion.metrics.distribution` (T2M, Guo et al. 2022, Sec. 5); R-precision "
        f"ranks each clip's text among itself and {figures['r_precision_pool'] - 1} distinct other texts; mean ± "
        f"std over {report['repeats']} seeds of the random draws.",
        "",
        "| figure | held-out real clips |",
        "|---|---|",
        *(f"| {label} | {_cell(figures.get(key))} |" for key, label in _ROWS),
        f"| FID between two random halves ↓ | {_cell(report['fid_real_halves'])} |",
        "",
        "The half-split FID is the floor of a generator's FID against these clips (two draws of the real "
        "distribution already differ by this much); the real clips' R-precision is the ceiling a generator's "
        "clips can be expected to reach with the same prompts. Embedding distances are in the evaluator's "
        "unit-sphere units: comparable between generators scored by this evaluator only, not with published "
        "figures of T2M's.",
        "",
    ]
    pgbig = report.get("pgbig")
    if pgbig:
        n, n_gen = pgbig["targets"], pgbig["targets"] * pgbig["samples_per_target"]
        lines += [
            "## PG-BIG on the same evaluator",
            "",
            f"{pgbig['targets']} held-out clips of {pgbig['subjects']} subjects of the sources the shipped lab "
            f"generator learnt ({', '.join(pgbig['generator_sources'])}), cut to {pgbig['max_seconds']:g} s; "
            f"{pgbig['samples_per_target']} personalised, guided generations per clip (its profile, the subject's "
            "other clips as references, its label; seeds as `biomotion eval generation` repeats), read through the "
            "real clip's coordinate mask (`pgbig_report`). With this few clips in 64 dimensions the covariances are "
            "rank-deficient and every FID here is dominated by its sample sizes: compare generators on these same "
            "clips and sample counts only (e.g. FlexMotion against PG-BIG), never across rows of different sizes. "
            f"These clips have {pgbig['real']['texts']} distinct texts, so R-precision ranks each clip against all "
            f"{pgbig['real']['r_precision_pool']} (no random draw, hence std 0): far easier than a pool of 32.",
            "",
            "| figure | real clips | PG-BIG |",
            "|---|---|---|",
            *(
                f"| {label} | {_cell(pgbig['real'].get(key))} | {_cell(pgbig['generated'].get(key))} |"
                for key, label in _ROWS
            ),
            f"| FID to the real clips, all samples ({n_gen} vs {n}) ↓ | – | {_cell(pgbig['fid_generated_to_real'])} |",
            f"| FID to the real clips, one sample per clip ({n} vs {n}) ↓ | – | "
            f"{_cell(pgbig['fid_generated_to_real_one_sample_per_clip'])} |",
            f"| FID between two halves of the real clips ({n // 2} vs {n // 2}) | "
            f"{_cell(pgbig['fid_real_halves'])} | – |",
            "",
        ]
    return "\n".join(lines)


def write_report(report: dict, out: str | Path) -> None:
    """``report`` as ``<out>.json`` and ``<out>.md`` (written atomically)."""
    from biomotion.io.atomic import atomic_write

    out = Path(out)
    with atomic_write(out.with_suffix(".json")) as handle:
        json.dump(report, handle, indent=1)
        handle.write("\n")
    with atomic_write(out.with_suffix(".md")) as handle:
        handle.write(markdown(report))


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m biomotion.evaluation.distribution``: write the held-out real-clip report."""
    import shlex
    import sys

    import torch

    from biomotion.io.paths import portable

    parser = argparse.ArgumentParser(prog="python -m biomotion.evaluation.distribution", description=__doc__)
    parser.add_argument("--cache", type=Path, required=True, help="dataset cache folder (`biomotion data build`)")
    parser.add_argument("--evaluator", type=Path, required=True, help="evaluator weights (.safetensors)")
    parser.add_argument("--out", type=Path, required=True, help="report path without suffix (.json and .md)")
    parser.add_argument("--repeats", type=int, default=REPEATS, help="seeds of the random draws (default: %(default)s)")
    parser.add_argument(
        "--pgbig-data-root",
        type=Path,
        help="also generate PG-BIG clips for the held-out clips of its sources and score them (`pgbig_report`); "
        "the data root holds the canonical body model",
    )
    args = parser.parse_args(argv)
    # a recorded command quotes "~/..." (shlex): expand it here so the command runs as written
    args.cache, args.evaluator = args.cache.expanduser(), args.evaluator.expanduser()
    torch.set_num_threads(1)
    words = ["python", "-m", "biomotion.evaluation.distribution", *(sys.argv[1:] if argv is None else argv)]
    command = " ".join(shlex.quote(portable(word)) for word in words)
    report = real_report(
        args.evaluator, args.cache, repeats=args.repeats, command=command, pgbig_data_root=args.pgbig_data_root
    )
    write_report(report, args.out)
    print(markdown(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
