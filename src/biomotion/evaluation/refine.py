"""`biomotion eval refine`: the PhysPT refiner on people it never saw (PhysPT Sec. 4, Table 1 layout), on generated
clips, and its speed.

1. **Corrupted real clips.** The subjects under ``--data-root`` that the refiner was neither trained nor validated
   on (its weights name them; with the shared data: the test split and OpenCap, which training leaves out), at most
   ``per_subject`` clips each (evenly spaced over the subject's clips), cut to ``max_seconds``, at the refiner's
   rate and placed as the training clips (`biomotion.data.placement`). Each clip is corrupted with every kind of
   noise of `biomotion.data.noise` at once (the levels stored with the weights, seed ``seed``), then refined, and
   low-pass filtered (4th-order zero-lag Butterworth, the field's default, at the cutoff chosen on the validation
   subjects by `biomotion.training.train_refiner` and stored with the weights: nothing here is fitted on these
   clips). Scores against the clean clip (`biomotion.models.refiner.refinement_scores`): ACCL, FS over the clean
   clip's contact frames, root-relative MJE (and the ground-frame MJE). Figures are means over clips; reductions are
   1 − refined / noisy.
2. **Generated clips.** PG-BIG's shared evaluation set (`biomotion.evaluation.generation.unseen_targets`: the
   clips of the subjects the shipped generator never saw, cut to 6 s), generated once with the full model
   (profile, references, guidance; seed ``seed + k`` for target k, as one repeat of `biomotion eval generation`),
   then refined. Against the real target clip (the same action): the root residual of the contact QP
   (`biomotion.body.contact.infer_ground_reaction`: the pelvis's generalized force the feet cannot supply, force in
   body weights and moment in body weight x m, their Euclidean norm per frame, mean over frames), the share of
   supported frames whose ZMP lies in the support polygon and the full-body energy fluctuation (`biomotion eval`'s
   ``zmp_in_support`` and ``energy_body``). Derivatives are the quintic splines `biomotion eval` uses.
3. **Speed.** Seconds `biomotion.generation.refinement.refine` takes, end to end, for a 10 s trial sampled at 100 Hz
   (a held-out clip stretched to 10 s and resampled) with one torch thread, as the CLI runs (on a shared 2-core
   machine one thread is the faster: docs/decisions/refiner.md): median of 5 runs after a warm-up.
"""

from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from biomotion.data.noise import NoiseLevels, corrupt
from biomotion.errors import BiomotionError
from biomotion.evaluation.generation import _evenly
from biomotion.models.refiner import Refiner, refinement_scores
from biomotion.motion import Motion, lowpass

#: The issue's bars: key -> (direction, threshold, PhysPT's figure where it has one).
BARS = {
    "refine_accl_reduction": (">=", 0.6, 0.84),
    "refine_fs_reduction": (">=", 0.5, 0.69),
    "refine_mje_ratio": ("<=", 1.05, None),
    "refine_accl_ratio_to_lowpass": ("<=", 0.8, None),
    "refine_generated_residual_ratio": ("<=", 0.5, None),
    "refine_generated_zmp_gap_points": ("<=", 10.0, None),
    "refine_generated_energy_ratio_to_real": ("<=", 1.5, None),
    "refine_seconds_per_10s_trial": ("<=", 0.5, None),
}
PER_SUBJECT = 8
SPEED_RUNS = 5


@dataclass
class HeldOutClip:
    """A held-out clip at the refiner's rate, placed: id, subject, canonical coordinates [T, 39], mask [39]."""

    clip_id: str
    subject: str
    q: torch.Tensor
    mask: torch.Tensor


def held_out_clips(
    data_root: str | Path, refiner: Refiner, max_seconds: float, per_subject: int = PER_SUBJECT, progress: bool = True
) -> list[HeldOutClip]:
    """Clips of every subject under ``data_root`` the refiner's metadata does not list as trained or validated on
    (module docstring, part 1); loaded, resampled and placed as `biomotion.data.registry.build_cache` does."""
    from biomotion.data.placement import place_clip
    from biomotion.data.sources import SOURCES, discover_all, forward_speed

    seen = set(refiner.metadata.get("train_subjects", ())) | set(refiner.metadata.get("val_subjects", ()))
    specs, _ = discover_all(Path(data_root))
    by_subject: dict[str, list] = {}
    for spec in specs:
        key = f"{spec.source}/{spec.subject}"
        if key not in seen:
            by_subject.setdefault(key, []).append(spec)
    chosen = [spec for group in by_subject.values() for spec in _evenly(group, per_subject)]
    rate, limit = refiner.config.rate, int(round(max_seconds * refiner.config.rate))
    clips = []
    body = refiner.body.to(torch.float64)
    for spec in tqdm(chosen, desc="held-out clips", unit="clip", disable=not progress):
        source = SOURCES[spec.source]
        motion = source.load_motion(spec)
        speed = spec.labels.speed
        if source.treadmill and speed is None and spec.labels.action in ("walk", "run"):
            speed = forward_speed(motion)
        clip = motion.resample(rate) if abs(motion.rate - rate) > 1e-6 else motion
        clip = place_clip(clip, body, height=spec.profile.height, treadmill_speed=speed if source.treadmill else None)
        if clip.n_frames < 8 or not np.all(np.isfinite(clip.values[:, clip.mask])):
            continue
        clip = clip.frames(slice(0, limit))
        values = np.where(clip.mask[None], clip.values, 0.0)
        clips.append(
            HeldOutClip(
                spec.clip_id,
                f"{spec.source}/{spec.subject}",
                torch.from_numpy(values).float(),
                torch.from_numpy(clip.mask.copy()),
            )
        )
    return clips


def corrupted_real(refiner: Refiner, clips: list[HeldOutClip], seed: int, progress: bool = True) -> dict:
    """Part 1: per clip and on average, the scores of the noisy, refined and low-passed clips."""
    levels = NoiseLevels.from_dict(refiner.metadata.get("eval_noise", {"probability": 1.0}))
    cutoff = float(refiner.metadata.get("lowpass_cutoff_hz", 6.0))
    rate = refiner.config.rate
    generator = torch.Generator().manual_seed(seed)
    rows = []
    for clip in tqdm(clips, desc="refining corrupted clips", unit="clip", disable=not progress):
        noisy = corrupt(clip.q[None], clip.mask[None], rate, levels, generator)[0]
        refined = refiner.refine(noisy, clip.mask).q
        filtered = noisy
        if len(noisy) > 15:
            smooth = np.ascontiguousarray(lowpass(noisy.double().numpy(), rate, cutoff, order=4))
            filtered = torch.where(clip.mask, torch.from_numpy(smooth).float(), noisy)
        rows.append(
            {
                "clip": clip.clip_id,
                "subject": clip.subject,
                "frames": len(clip.q),
                **{
                    name: refinement_scores(refiner, clip.q, pred, clip.mask)
                    for name, pred in (("noisy", noisy), ("refined", refined), ("lowpass", filtered))
                },
            }
        )
    means = {
        name: {m: float(np.mean([r[name][m] for r in rows])) for m in ("accl", "fs", "mje", "mje_global")}
        for name in ("noisy", "refined", "lowpass")
    }
    return {"clips": len(rows), "subjects": sorted({r["subject"] for r in rows}), "lowpass_cutoff_hz": cutoff,
            "noise": levels.__dict__, "seed": seed, "means": means, "per_clip": rows}  # fmt: skip


# ---- generated clips ------------------------------------------------------------------------------------------


def root_residual(model, motion: Motion) -> tuple[float, float, float]:
    """Mean over frames of the contact QP's root residual: force (body weights), moment (body weight x m) and the
    norm of the two together, for canonical ``motion`` (absent coordinates at the model's defaults)."""
    from biomotion.body.contact import infer_ground_reaction
    from biomotion.body.kinematics import apply_couplers

    q = np.where(motion.mask[None], motion.values, model.defaults.numpy()[None])
    qd, qdd = motion.with_values(q).derivatives()
    q_t = apply_couplers(model, torch.from_numpy(q))
    inferred = infer_ground_reaction(model, q_t, torch.from_numpy(qd), torch.from_numpy(qdd))
    weight = float(model.total_mass) * 9.80665
    moment = inferred.root_residual[:, :3].norm(dim=-1) / weight
    force = inferred.root_residual[:, 3:].norm(dim=-1) / weight
    return float(force.mean()), float(moment.mean()), float(torch.hypot(force, moment).mean())


def generated_clips(
    data_root: str | Path,
    refiner: Refiner,
    checkpoints: str | Path | None,
    seed: int,
    max_seconds: float,
    progress: bool = True,
) -> dict:
    """Part 2: real, generated and refined clips of the shared evaluation set, scored."""
    from biomotion.data.clips import CoordinateClip, body_model, build_temporary_cache, coordinate_set
    from biomotion.evaluation.generation import _motion, _request, unseen_targets
    from biomotion.generation.pipeline import CHECKPOINTS, Generator
    from biomotion.metrics.registry import score_set

    generator = Generator.load(data_root, Path(checkpoints or CHECKPOINTS), surrogate=False)
    trained = sorted({key.split("/", 1)[0] for key in generator.bundle.train_subjects})
    try:
        handle, cache = build_temporary_cache(
            data_root, sources=trained, exclude_subjects=generator.bundle.train_subjects
        )
    except BiomotionError as error:
        return {"skipped": f"no subject the generator never saw under {data_root}: {error}"}
    model = body_model(data_root)
    with handle:
        targets = unseen_targets(cache, generator.bundle.train_subjects, max_seconds)
        variants: dict[str, list[Motion]] = {"real": [], "generated": [], "refined": []}
        names = []
        for k, target in enumerate(tqdm(targets, desc="generating and refining", unit="clip", disable=not progress)):
            out = generator.generate(
                _request(cache, target.index),
                profile=cache.profile(target.index),
                references=target.references,
                reference_actions=target.reference_actions,
                reference_speeds=target.reference_speeds,
                seconds=target.motion.n_frames / generator.rate,
                seed=seed + k,
            )
            generated = _motion(out.q[0], generator.rate)
            refined = refiner.refine(torch.from_numpy(generated.values).float(), torch.ones(39, dtype=torch.bool)).q
            variants["real"].append(target.motion)
            variants["generated"].append(generated)
            variants["refined"].append(generated.with_values(refined.double().numpy()))
            names.append(cache.records[target.index]["clip_id"])
    table: dict[str, dict] = {}
    for variant, motions in variants.items():
        clips = coordinate_set([CoordinateClip(n, variant, m) for n, m in zip(names, motions)], model,
                               generator.rate, derivatives=True)  # fmt: skip
        scores = score_set(clips, model, physics=True)
        residuals = np.array([root_residual(model, m) for m in motions])
        table[variant] = {
            "zmp_in_support": _values(scores["zmp_in_support"]),
            "energy_body": _values(scores["energy_body"]),
            "foot_contact_velocity": _values(scores["foot_contact_velocity"]),
            "residual_force_bw": residuals[:, 0].tolist(),
            "residual_moment_bw_m": residuals[:, 1].tolist(),
            "residual_bw": residuals[:, 2].tolist(),
        }
    means = {v: {k: _nanmean(x) for k, x in rows.items()} for v, rows in table.items()}
    return {"targets": len(names), "clips": names, "seed": seed, "means": means, "per_clip": table}


def _values(x: torch.Tensor) -> list[float | None]:
    return [None if not math.isfinite(v) else float(v) for v in x.double().tolist()]


def _nanmean(values: list) -> float | None:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(finite)) if finite else None


# ---- speed ----------------------------------------------------------------------------------------------------


def speed(refiner: Refiner, clip: HeldOutClip, threads: int = 1, runs: int = SPEED_RUNS) -> dict:
    """Part 3: seconds to refine a 10 s, 100 Hz trial end to end (`refine` on a `Motion`)."""
    from biomotion.body.canonical import CANONICAL_COORDINATES
    from biomotion.body.kinematics import torch_threads
    from biomotion.generation.refinement import refine

    source = Motion(
        times=np.linspace(0.0, 10.0, len(clip.q)), names=CANONICAL_COORDINATES, values=clip.q.double().numpy(),
        mask=clip.mask.numpy(),
    )  # fmt: skip
    trial = source.at(np.arange(1001) / 100.0)
    seconds = []
    with torch_threads(threads):
        refine(trial, refiner)  # warm-up
        for _ in range(runs):
            started = time.perf_counter()
            refine(trial, refiner)
            seconds.append(time.perf_counter() - started)
    return {"trial": f"{clip.clip_id} stretched to 10 s at 100 Hz (1001 frames)", "threads": threads,
            "runs": seconds, "median_seconds": statistics.median(seconds)}  # fmt: skip


# ---- the command ----------------------------------------------------------------------------------------------


def bars(real: dict, generated: dict, timing: dict) -> dict:
    """The issue's figures and whether each bar is met (None where not measured)."""
    m = real["means"]
    figures = {
        "refine_accl_reduction": 1 - m["refined"]["accl"] / m["noisy"]["accl"],
        "refine_fs_reduction": 1 - m["refined"]["fs"] / m["noisy"]["fs"],
        "refine_mje_ratio": m["refined"]["mje"] / m["noisy"]["mje"],
        "refine_accl_ratio_to_lowpass": m["refined"]["accl"] / m["lowpass"]["accl"],
        "refine_seconds_per_10s_trial": timing["median_seconds"],
    }
    if "means" in generated:
        g = generated["means"]
        figures["refine_generated_residual_ratio"] = g["refined"]["residual_bw"] / g["generated"]["residual_bw"]
        figures["refine_generated_zmp_gap_points"] = 100 * (
            g["real"]["zmp_in_support"] - g["refined"]["zmp_in_support"]
        )
        figures["refine_generated_energy_ratio_to_real"] = g["refined"]["energy_body"] / g["real"]["energy_body"]
    out = {}
    for key, (direction, threshold, paper) in BARS.items():
        value = figures.get(key)
        met = None if value is None else (value >= threshold if direction == ">=" else value <= threshold)
        out[key] = {"value": value, "bar": f"{direction} {threshold:g}", "met": met, "physpt": paper}
    return out


def eval_refine(
    data_root: str | Path,
    json_path: str | Path,
    md_path: str | Path | None = None,
    *,
    refiner_path: str | Path | None = None,
    checkpoints: str | Path | None = None,
    seed: int = 0,
    max_seconds: float = 10.0,
    per_subject: int = PER_SUBJECT,
    generated: bool = True,
    progress: bool = True,
    command: str = "",
) -> dict:
    """Run the three parts (module docstring) and write the JSON (and Markdown) report."""
    from biomotion.body.kinematics import torch_threads
    from biomotion.evaluation.harness import write_json, write_text
    from biomotion.generation.refinement import load_refiner

    refiner = load_refiner(refiner_path, data_root)
    with torch_threads(1):
        clips = held_out_clips(data_root, refiner, max_seconds, per_subject, progress)
        if not clips:
            raise BiomotionError(f"no subject under {data_root} that the refiner was not trained or validated on")
        real = corrupted_real(refiner, clips, seed, progress)
        gen = (
            generated_clips(data_root, refiner, checkpoints, seed, 6.0, progress)
            if generated
            else {"skipped": "--no-generated"}
        )
    timing = speed(refiner, max(clips, key=lambda c: len(c.q)))
    report = {
        "command": command,
        "refiner": {k: v for k, v in refiner.metadata.items() if k not in ("train_subjects", "val_subjects")},
        "trained_subjects": len(refiner.metadata.get("train_subjects", ())),
        "validation_subjects": len(refiner.metadata.get("val_subjects", ())),
        "corrupted_real": real,
        "generated": gen,
        "speed": timing,
        "bars": bars(real, gen, timing),
    }
    report.update({key: row["value"] for key, row in report["bars"].items()})
    write_json(json_path, report)
    if md_path is not None:
        write_text(md_path, markdown(report))
    return report


def markdown(report: dict) -> str:
    """The report as Markdown: PhysPT Table 1 layout for the corrupted clips, the generated clips, speed, bars."""
    real = report["corrupted_real"]
    m = real["means"]
    lines = [
        "# Refiner evaluation (PhysPT)\n",
        f"Command: `{report['command']}`\n",
        f"## Corrupted real clips\n\n{real['clips']} clips of {len(real['subjects'])} subjects the refiner never saw "
        f"({', '.join(real['subjects'])}), every kind of noise of `biomotion.data.noise` at once "
        f"(seed {real['seed']}); "
        f"low-pass: 4th-order zero-lag Butterworth at {real['lowpass_cutoff_hz']:g} Hz (chosen on the validation "
        "subjects).\n",
        "| input | ACCL (m/s²) ↓ | FS (mm/frame) ↓ | MJE root-relative (mm) ↓ | MJE ground frame (mm) ↓ |",
        "|---|---|---|---|---|",
    ]
    for name, label in (("noisy", "corrupted"), ("lowpass", "low-pass filtered"), ("refined", "refined (PhysPT)")):
        r = m[name]
        lines.append(
            f"| {label} | {r['accl']:.3f} | {1000 * r['fs']:.2f} | {1000 * r['mje']:.1f} "
            f"| {1000 * r['mje_global']:.1f} |"
        )
    gen = report["generated"]
    if "means" in gen:
        g = gen["means"]
        lines += [
            f"\n## Generated clips (PG-BIG, the shared evaluation set)\n\n{gen['targets']} targets, one generation "
            f"each (seed {gen['seed']} + target), refined; the real clip of the same target beside them.\n",
            "| clips | root residual (BW, force and moment) ↓ | force (BW) ↓ | moment (BW·m) ↓ | ZMP in support (%) ↑ "
            "| energy std (J) ↓ | foot contact vel. (m/s) ↓ |",
            "|---|---|---|---|---|---|---|",
        ]
        for name in ("real", "generated", "refined"):
            r = g[name]
            lines.append(
                f"| {name} | {r['residual_bw']:.3f} | {r['residual_force_bw']:.3f} | {r['residual_moment_bw_m']:.3f} "
                f"| {100 * r['zmp_in_support']:.1f} | {r['energy_body']:.1f} | {r['foot_contact_velocity']:.3f} |"
            )
    else:
        lines.append(f"\n## Generated clips\n\nskipped: {gen.get('skipped')}")
    s = report["speed"]
    lines.append(
        f"\n## Speed\n\n{s['trial']}, {s['threads']} torch threads: median {s['median_seconds']:.3f} s over "
        f"{len(s['runs'])} runs.\n"
    )
    lines += ["## Bars\n", "| bar | value | target | PhysPT | met |", "|---|---|---|---|---|"]
    for key, row in report["bars"].items():
        value = "–" if row["value"] is None else f"{row['value']:.3f}"
        met = "–" if row["met"] is None else "yes" if row["met"] else "no"
        lines.append(f"| {key} | {value} | {row['bar']} | {row['physpt'] or '–'} | {met} |")
    return "\n".join(lines) + "\n"
