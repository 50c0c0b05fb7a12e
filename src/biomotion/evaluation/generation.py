"""`biomotion eval generation`: PG-BIG Tables 2-3 for our generator on subjects it never saw, plus the identity
probe and the profile-manipulation study (Sec. 4.3-4.5, App. B.1).

Protocol (few-shot, unseen subjects). The subjects of ``--data-root`` that the shipped generator was not trained
on are evaluated (with the shared data that is the val and test splits; a folder of new people in the same layout
makes every subject unseen). For each clip of such a subject, the *target*, the generator receives the subject's
profile, the subject's *other* clips as references (e.g. the runs at the two other speeds) and the target's action
label, and generates a clip as long as the target (at most ``max_seconds``). Variants, all from the same seed:

- ``reference``: the real target clips;
- ``full``: profile + references, with guidance (PG-BIG);
- ``no_planting``: the same sample after latent guidance, before foot planting (`biomotion.guidance.planting`),
  which shows what the coordinate-space stage adds;
- ``no_guidance``: the same sample before guidance (w/o Guidance);
- ``no_priming``: profile + references through the subject profiler only, the prior's context not primed with
  the reference's codes, with guidance;
- ``no_posture``: as ``full`` without the person's posture offset (`biomotion.generation.posture`);
- ``no_personalization``: profile and references dropped, with guidance (w/o Personalization);
- ``population``: the action-only prior trained with ``--population`` (same tokens), no guidance: a
  population-level baseline of the T2M-GPT kind.

Every variant is scored with the per-clip metrics of `biomotion eval` on the canonical model (contact, jerk,
energy, joint range, ZMP in support), the paired fidelity metrics against the target (MJE, DTW fidelity, W2),
and the share of frames x muscles whose surrogate activation leaves the training 5-95 % band (muscle-limit
violations, PG-BIG Table 1's activation bounds). ZMP in support is also given over the targets whose real clip
carries its trunk's motion (`measured_trunk`), the only ones where the whole-body ZMP of the reference means
something; the bar stays on all targets. Identity probe: a logistic regression on pooled tokenizer
latents; for each target, one probe is trained on the real clips of the unseen subjects other than the target's
own clip (a subject's clips are each other's references, so a probe trained on all references would have seen
every real target) and tested on the real target and on each variant's generated target (chance = 1 / subjects).
A generated clip is embedded through the target's coordinate mask, the coordinates the person's data has (the
probe learnt the person from those alone; the Fukuchi runners have no trunk or arms, whatever the generator
draws there is not theirs to recognise).

Repeats (``repeats``, default 3). Generation is sampling, so one pass scores one draw: on 24 targets the identity
probe moves by 1/24 per clip recognised and the contact means by a few per cent between seeds. As T2M-GPT and
HumanML3D evaluate (Guo et al. 2022, 20 repeats, mean and 95 % interval), the whole generation and scoring is run
``repeats`` times with disjoint seeds (repeat r gives target k the seed ``seed + r * targets + k``). The report's
table pools the per-clip values of every repeat (mean and std over clips x repeats; the reference's clips are the
same in each repeat, so its figures do not change), the identity accuracy is the mean over repeats, and each
figure carries its per-repeat means and the 95 % interval of their mean (1.96 s / sqrt(R), s the sample standard
deviation across repeats). The bars are judged on these pooled means. The profile-manipulation study draws its
own 8 samples per profile and is run once; beside it, the report gives the direction in which the real clips of the
same action under the data root move with each manipulated field (`biomotion.evaluation.manipulation_data`), since
the generator can only learn what its data shows.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from biomotion.body.canonical import CANONICAL_COORDINATES, COUPLED_COORDINATES
from biomotion.data.placement import GENERIC_HEIGHT
from biomotion.errors import BiomotionError
from biomotion.metrics.base import Metric
from biomotion.metrics.stability import ZMPInsideSupport
from biomotion.models.actions import ActionRequest
from biomotion.motion import Motion

VARIANTS = (
    "reference",
    "full",
    "no_planting",
    "no_guidance",
    "no_priming",
    "no_posture",
    "no_personalization",
    "population",
)
LABELS = {
    "reference": "Reference (real)",
    "full": "PG-BIG (full)",
    "no_planting": "w/o Foot planting",
    "no_guidance": "w/o Guidance",
    "no_priming": "w/o Reference priming",
    "no_posture": "w/o Posture offset",
    "no_personalization": "w/o Personalization",
    "population": "Population (T2M-GPT-kind)",
}


@dataclass
class Target:
    """One evaluated clip: cache index, subject key, its real motion, its references' motions, cache indices,
    action labels and speed labels (m/s, None where unlabelled)."""

    index: int
    subject: str
    motion: Motion
    references: list[Motion]
    reference_indices: list[int]
    reference_actions: list[str]
    reference_speeds: list[float | None]


MAX_TARGETS_PER_SUBJECT = 4
MAX_REFERENCES = 8


def _evenly(indices: list[int], count: int) -> list[int]:
    """At most ``count`` of ``indices``, evenly spaced (first and last included), in order."""
    if len(indices) <= count:
        return list(indices)
    return [indices[int(round(k))] for k in np.linspace(0, len(indices) - 1, count)]


def unseen_targets(
    cache, train_subjects: Sequence[str], max_seconds: float, per_subject: int = MAX_TARGETS_PER_SUBJECT
) -> list[Target]:
    """Clips of every subject not in ``train_subjects`` (at most ``per_subject`` each, evenly spaced over the
    subject's clips), cut to ``max_seconds``, with up to `MAX_REFERENCES` of the subject's other clips as
    references."""
    seen = set(train_subjects)
    by_subject: dict[str, list[int]] = {}
    for i, r in enumerate(cache.records):
        key = f"{r['source']}/{r['subject']}"
        if key not in seen and r["n_frames"] >= 8:
            by_subject.setdefault(key, []).append(i)
    targets = []
    limit = round(max_seconds * cache.rate)
    for subject, indices in by_subject.items():
        for i in _evenly(indices, per_subject):
            motion = cache.motion(i)
            if motion.n_frames > limit:
                motion = motion.frames(slice(0, limit))
            others = _evenly([j for j in indices if j != i], MAX_REFERENCES)
            labels = [cache.records[j]["labels"] for j in others]
            targets.append(
                Target(
                    i,
                    subject,
                    motion,
                    [cache.motion(j) for j in others],
                    others,
                    [label["action"] for label in labels],
                    [label.get("speed") for label in labels],
                )
            )
    return targets


def _request(cache, index: int) -> ActionRequest:
    labels = cache.records[index]["labels"]
    return ActionRequest(labels["action"], labels.get("style"), labels.get("speed"), labels.get("text") or "")


def _motion(q: torch.Tensor, rate: float) -> Motion:
    values = q.detach().double().numpy()
    return Motion(times=np.arange(len(values)) / rate, values=values, names=CANONICAL_COORDINATES)


def generate_variants(
    targets: list[Target], cache, generator, population, *, seed: int = 0, progress: bool = True
) -> dict[str, list[Motion]]:
    """The motions of every variant, aligned with ``targets``."""
    out: dict[str, list[Motion]] = {v: [] for v in VARIANTS}
    for k, t in enumerate(tqdm(targets, desc="generating", unit="clip", disable=not progress)):
        request = _request(cache, t.index)
        seconds = t.motion.n_frames / generator.rate
        profile = cache.profile(t.index)
        personal = {
            "profile": profile,
            "references": t.references,
            "reference_actions": t.reference_actions,
            "reference_speeds": t.reference_speeds,
            "seconds": seconds,
            "seed": seed + k,
        }
        full = generator.generate(request, **personal)
        unprimed = generator.generate(request, **personal, prime=False)
        unshifted = generator.generate(request, **personal, posture=False)
        generic = generator.generate(request, seconds=seconds, seed=seed + k, personalised=False)
        baseline = population.generate(request, seconds=seconds, seed=seed + k, guidance=False)
        out["reference"].append(t.motion)
        out["full"].append(_motion(full.q[0], generator.rate))
        out["no_planting"].append(_motion(full.unplanted[0], generator.rate))
        out["no_guidance"].append(_motion(full.unguided[0], generator.rate))
        out["no_priming"].append(_motion(unprimed.q[0], generator.rate))
        out["no_posture"].append(_motion(unshifted.q[0], generator.rate))
        out["no_personalization"].append(_motion(generic.q[0], generator.rate))
        out["population"].append(_motion(baseline.q[0], generator.rate))
    return out


@torch.no_grad()
def muscle_violation_share(motions: list[Motion], surrogate) -> list[float]:
    """Per clip, the share of frames x muscles whose surrogate activation is outside the training 5-95 % band."""
    shares = []
    for m in motions:
        q = torch.tensor(np.where(m.mask[None], m.values, 0.0), dtype=torch.float32)[None]
        a = surrogate(q, torch.from_numpy(m.mask.copy())[None])
        outside = (a > surrogate.high) | (a < surrogate.low)
        shares.append(float(outside.float().mean()))
    return shares


@torch.no_grad()
def embedding(tokenizer, motion: Motion) -> np.ndarray:
    """Mean and std over time of the tokenizer's pre-quantisation latents (the probe's clip embedding), with the
    coupled coordinates (`COUPLED_COORDINATES`) masked: generated clips carry the canonical coupler's value there,
    real clips their source's (the Schreiber-Moissenet models leave knee ``_beta`` free, near 0.01 rad), and a probe
    that read them would tell sources apart, not people (docs/decisions/identity-probe.md)."""
    n = motion.n_frames // 4 * 4
    mask = motion.mask & ~np.isin(np.asarray(motion.names), COUPLED_COORDINATES)
    q = torch.tensor(np.where(mask[None], motion.values[:n], 0.0), dtype=torch.float32)[None]
    z = tokenizer.encode_continuous(q, torch.from_numpy(mask.copy())[None])[0]
    return torch.cat([z.mean(0), z.std(0)]).double().numpy()


def identity_accuracy(tokenizer, targets: list[Target], variants: dict[str, list[Motion]]) -> dict:
    """Identity-probe accuracy per variant: for each target a probe trained on every real reference clip of the
    unseen subjects except the target's own clip, tested on the target of each variant seen through the real
    target's coordinate mask."""
    from biomotion.metrics.probes import IdentityProbe

    clips: dict[int, tuple[np.ndarray, str]] = {}
    for t in targets:
        for j, r in zip(t.reference_indices, t.references):
            if j not in clips:
                clips[j] = (embedding(tokenizer, r), t.subject)
    subjects = sorted({t.subject for t in targets})
    if len(subjects) < 2 or not clips:
        return {"skipped": "needs at least two unseen subjects with reference clips"}
    keep = [k for k, t in enumerate(targets) if t.references]
    result = {
        "subjects": len(subjects),
        "chance": 1.0 / len(subjects),
        "train_clips": len(clips),
        "probe": "logistic regression, one per target, trained without the target's own clip; generated "
        "clips seen through the target's coordinate mask",
    }
    hits: dict[str, list[bool]] = {v: [] for v in variants}
    for k in keep:
        train = [clips[j] for j in clips if j != targets[k].index]
        if len({subject for _, subject in train}) < 2:
            continue
        probe = IdentityProbe(("logistic_regression",))
        probe.update(np.stack([x for x, _ in train]), np.array([subject for _, subject in train]), train=True)
        seen = [replace(motions[k], mask=motions[k].mask & targets[k].motion.mask) for motions in variants.values()]
        probe.update(
            np.stack([embedding(tokenizer, m) for m in seen]), np.array([targets[k].subject] * len(seen)), train=False
        )
        for variant, label in zip(variants, probe.predict()["logistic_regression"]):
            hits[variant].append(label == targets[k].subject)
    for variant, h in hits.items():
        result[variant] = float(np.mean(h)) if h else float("nan")
    return result


def speed_errors(motions: list[Motion], speeds: list[float | None], heights: list[float | None]) -> list[float]:
    """Per clip with a labelled speed, |mean horizontal pelvis speed - label speed| (m/s) at the person's size (the
    canonical clip's speed x height / 1.70 m, `biomotion.data.placement`); NaN where no speed is labelled."""
    out = []
    for motion, speed, height in zip(motions, speeds, heights):
        tx, tz = motion["pelvis_tx"], motion["pelvis_tz"]
        achieved = math.hypot(tx[-1] - tx[0], tz[-1] - tz[0]) / max(motion.times[-1] - motion.times[0], 1e-9)
        achieved *= (height / GENERIC_HEIGHT) if height else 1.0
        out.append(math.nan if speed is None else abs(achieved - speed))
    return out


TRUNK_COORDINATES = ("lumbar_extension", "lumbar_bending", "lumbar_rotation")


def measured_trunk(motion: Motion) -> bool:
    """Whether a clip carries its trunk's own motion (every lumbar coordinate present). Without it the canonical
    trunk rides rigidly on the pelvis (the Fukuchi runners' models lump head, arms and trunk into the pelvis), and the
    whole-body ZMP of the clip measures that more than the motion (`benchmarks/zmp_real_clips.py`)."""
    present = dict(zip(motion.names, motion.mask))
    return all(bool(present.get(name, False)) for name in TRUNK_COORDINATES)


def score_variants(
    variants: dict[str, list[Motion]],
    model,
    surrogate,
    rate: float,
    names: list[str],
    speeds: list[float | None],
    heights: list[float | None],
) -> dict:
    """Per-variant records: `biomotion eval` set metrics, paired metrics against the references, muscle limits,
    and the error of the requested locomotion speed."""
    from biomotion.data.clips import CoordinateClip, coordinate_set
    from biomotion.metrics.registry import record, score_pairs, score_set, summarize_set

    reference = coordinate_set(
        [CoordinateClip(n, "reference", m) for n, m in zip(names, variants["reference"])], model, rate, derivatives=True
    )
    muscle, speed, trunk = MuscleLimitViolations(), SpeedError(), MeasuredTrunkZMP()
    measured = torch.tensor([measured_trunk(m) for m in variants["reference"]])
    table = {}
    for variant, motions in variants.items():
        clips = coordinate_set(
            [CoordinateClip(n, variant, m) for n, m in zip(names, motions)], model, rate, derivatives=True
        )
        scores = score_set(clips, model, physics=True)
        records = summarize_set(clips, model, physics=True, scores=scores)
        records[muscle.name] = record(muscle, muscle.score(motions, surrogate))
        records[speed.name] = record(speed, speed.score(motions, speeds, heights))
        if trunk.of in scores:  # the whole-body ZMP only means something where the trunk was measured
            shares = scores[trunk.of].to(torch.float64)
            records[trunk.name] = record(trunk, torch.where(measured, shares, torch.full_like(shares, math.nan)))
        if variant != "reference":
            records.update(score_pairs(clips, reference)[1])
        table[variant] = records
    return table


class MuscleLimitViolations(Metric):
    """`muscle_violation_share` per clip: the activation bounds of PG-BIG Table 1 as a violation rate."""

    name, label, unit, display_unit, display_scale = "muscle_violations", "Muscle-limit violations", "1", "%", 100.0
    higher_is_better = False
    paper = 'PG-BIG Sec. 3.3, Table 1 L_act (5-95th percentile bounds); FlexMotion Sec. 4 "Muscle Limit"'
    equation = "share of frames x muscles whose surrogate activation a_tm lies outside [a_m^low, a_m^high]"

    def score(self, motions: list[Motion], surrogate) -> torch.Tensor:
        return torch.tensor(muscle_violation_share(motions, surrogate))


class SpeedError(Metric):
    """`speed_errors` per clip: how far the generated locomotion speed is from the requested one."""

    name, label, unit = "speed_error", "Speed error vs label", "m/s"
    higher_is_better = False
    paper = "no paper metric: the speed of the action request (docs/generation.md)"
    equation = "|mean horizontal pelvis speed x height / 1.70 m - labelled speed|"

    def score(self, motions: list[Motion], speeds: list[float | None], heights: list[float | None]) -> torch.Tensor:
        return torch.tensor(speed_errors(motions, speeds, heights))


class MeasuredTrunkZMP(ZMPInsideSupport):
    """ZMP in support (the registry's ``zmp_in_support``, scored ``of`` it) over the targets whose real clip
    carries its trunk's motion (`measured_trunk`); NaN on the others."""

    name, label = "zmp_in_support_measured_trunk", "ZMP in support, targets with a measured trunk"
    of = ZMPInsideSupport.name


def interval95(means: Sequence[float]) -> float | None:
    """Half-width of the 95 % normal interval of the mean of per-repeat means: 1.96 s / sqrt(R) (None for R < 2)."""
    finite = [m for m in means if m is not None and math.isfinite(m)]
    return None if len(finite) < 2 else float(1.96 * np.std(finite, ddof=1) / math.sqrt(len(finite)))


def combine_repeats(tables: list[dict]) -> dict:
    """One table from the `score_variants` tables of several repeats: per variant and metric, the per-clip values
    of all repeats pooled (mean, std and count over them, as `biomotion.metrics.base.summarize` computes them;
    set-level records without per-clip values, such as diversity, take the mean of the repeats' means and stds),
    with ``repeat_means`` and ``ci95`` (`interval95`) added."""
    from biomotion.metrics.base import summarize

    combined: dict = {}
    for variant, records in tables[0].items():
        combined[variant] = {}
        for key, first in records.items():
            parts = [table[variant][key] for table in tables]
            means = [part["mean"] for part in parts]
            record = {k: first[k] for k in ("label", "unit", "better")}
            if all("values" in part for part in parts):
                values = [math.nan if v is None else v for part in parts for v in part["values"]]
                result = summarize(key, first["unit"], torch.tensor(values, dtype=torch.float64))
                record.update(
                    mean=_finite(result.mean),
                    std=_finite(result.std),
                    count=result.count,
                    values=[None if not math.isfinite(v) else v for v in values],
                )
            else:
                finite = [m for m in means if m is not None]
                stds = [part["std"] for part in parts if part.get("std") is not None]
                record.update(
                    mean=float(np.mean(finite)) if finite else None,
                    std=float(np.mean(stds)) if stds else None,
                    count=sum(p["count"] for p in parts),
                )
            record.update(repeat_means=means, ci95=interval95(means))
            combined[variant][key] = record
    return combined


def combine_identity(results: list[dict]) -> dict:
    """The identity-probe result of several repeats: accuracy per variant averaged, with ``per_repeat`` accuracies
    and ``ci95`` per variant."""
    first = results[0]
    if "full" not in first:
        return first
    variants = [v for v in first if isinstance(first[v], float) and v != "chance"]
    combined = {k: v for k, v in first.items() if k not in variants}
    for variant in variants:
        combined[variant] = float(np.mean([r[variant] for r in results]))
    combined["per_repeat"] = {v: [r[v] for r in results] for v in variants}
    combined["ci95"] = {v: interval95(combined["per_repeat"][v]) for v in variants}
    return combined


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _mean(table: dict, variant: str, key: str) -> float:
    value = table[variant].get(key, {}).get("mean")
    return math.nan if value is None else value


def done_when(table: dict, identity: dict, manipulation: dict | None) -> dict[str, bool | None]:
    """The generation bars (README, status), each True/False (None where it could not be measured)."""
    m = lambda v, k: _mean(table, v, k)
    fid = "fidelity"
    checks = {
        "fidelity_full_beats_no_personalization": m("full", fid) < m("no_personalization", fid),
        "fidelity_full_beats_population": m("full", fid) < m("population", fid),
    }
    for key in ("penetration", "floating", "skate_ratio", "foot_contact_velocity", "muscle_violations"):
        checks[f"{key}_full_beats_no_guidance"] = m("full", key) < m("no_guidance", key)
    for key in ("penetration", "floating", "skate_ratio", "foot_contact_velocity"):
        checks[f"{key}_full_no_worse_than_reference"] = m("full", key) <= m("reference", key)
    checks["jerk_within_2x_reference"] = m("full", "jerk") <= 2 * m("reference", "jerk")
    checks["zmp_in_support_at_least_90"] = m("full", "zmp_in_support") >= 90.0
    if "full" in identity:
        # accuracies are shares of clips (84/120 = 0.70): exactly 5 points apart must not fail by float rounding
        checks["identity_within_5_points_of_real"] = abs(identity["full"] - identity["reference"]) <= 0.05 + 1e-9
    else:
        checks["identity_within_5_points_of_real"] = None
    if manipulation is not None:
        moved = [row["as_documented"] for row in manipulation["fields"].values()]
        checks["manipulation_moves_every_field_as_documented"] = (
            False if not all(moved) else None if manipulation.get("skipped") else True
        )
    return checks


def markdown(report: dict) -> str:
    """The report as Markdown: Table 2/3 layout, identity probe, manipulation, bars."""
    table = report["table"]
    keys = [k for k in table["full"] if k != "diversity"] + ["diversity"]
    head = "| Metric | " + " | ".join(LABELS[v] for v in VARIANTS) + " |\n|---|" + "---|" * len(VARIANTS) + "\n"
    rows = []
    for key in keys:
        cells = []
        label = unit = ""
        for v in VARIANTS:
            r = table[v].get(key)
            if r is None:
                cells.append("–")
                continue
            label, unit = r["label"], r["unit"]
            cells.append(
                "–"
                if r["mean"] is None
                else f"{r['mean']:.3g} ± {r['std']:.2g}"
                if r.get("std") is not None
                else f"{r['mean']:.3g}"
            )
        rows.append(f"| {label} ({unit}) | " + " | ".join(cells) + " |")
    ident = report["identity"]
    lines = [
        f"# Generation evaluation\n\nCommand: `{report['command']}`\n",
        f"{report['targets']} target clips of {report['subjects']} unseen subjects; {_repeats_line(report)}\n",
        head + "\n".join(rows) + "\n",
    ]
    if report.get("repeats", 1) > 1:
        lines.append(_spread(report))
    if "full" in ident:
        lines.append(
            "## Identity probe (logistic regression on pooled tokenizer latents)\n\n"
            f"{ident['subjects']} subjects (chance {ident['chance']:.2f}); one probe per target, trained "
            f"on the {ident['train_clips']} real clips of these subjects other than the target's own; "
            "generated clips seen through the target's coordinates"
            + (f"; accuracy averaged over the {report['repeats']} repeats" if report.get("repeats", 1) > 1 else "")
            + ".\n\n"
            "| Variant | accuracy |\n|---|---|\n"
            + "".join(f"| {LABELS[v]} | {ident[v]:.2f} |\n" for v in VARIANTS)
            + "\n"
        )
    if report.get("manipulation"):
        man = report["manipulation"]
        styled_by = f", by the bundle in {man['style_checkpoints']}" if man.get("style_checkpoints") else ""
        lines.append(
            f"## Profile manipulation ({man['action']}, {man['samples']} samples per profile; the style rows "
            f"vary the action's style, without a profile{styled_by})\n\n"
            "| Field | change | measure | low value | high value | expected | as documented |\n"
            "|---|---|---|---|---|---|---|\n"
            + "".join(
                f"| {f} | {r['change']} | {r['measure']} | {r['low']:.4g} | {r['high']:.4g} | "
                f"{r['expected']} | {'yes' if r['as_documented'] else 'no'} |\n"
                for f, r in man["fields"].items()
            )
            + "".join(f"\n{f}: not measured, {why}.\n" for f, why in man.get("skipped", {}).items())
            + "\n"
        )
        if man.get("real_data"):
            lines.append(_real_data_table(man["real_data"]))
    lines.append(
        "## Bars (issue 7)\n\n| Bar | met |\n|---|---|\n"
        + "".join(f"| {k} | {'–' if v is None else 'yes' if v else 'no'} |\n" for k, v in report["bars"].items())
    )
    return "\n".join(lines)


def _real_data_table(real: dict) -> str:
    """The manipulated fields against the real clips of the same action (`biomotion.evaluation.manipulation_data`)."""

    def values(row: dict) -> str:
        v = row["values"]
        if "from" in v:
            return f"{v['from']:.3g} to {v['to']:.3g}"
        return ", ".join(f"{value}: {n}" for value, n in v.items()) or "–"

    def reading(row: dict) -> str:
        if row["direction"] is None:
            return "none: every subject has the same value" if len(row["values"]) == 1 else "none: too few subjects"
        strength = "p < 0.05" if row["p"] < 0.05 else "not significant"
        return f"{row['direction']} ({strength}; {'as' if row['agrees'] else 'against'} the documented direction)"

    return (
        "What the real clips of the same action under the data root show (Spearman's rank correlation across "
        "subjects between the field and the subject's mean measure; level on the generator's ordinal scale, "
        "injury 1 for an injury at the manipulated location and 0 for none; "
        "`biomotion.evaluation.manipulation_data`):\n\n"
        "| Field | measure | subjects | field values (subjects) | Spearman ρ | p | the data's direction |\n"
        "|---|---|---|---|---|---|---|\n"
        + "".join(
            f"| {f} | {r['measure']} | {r['subjects']} | {values(r)} | "
            + ("–" if r["rho"] is None else f"{r['rho']:+.2f}")
            + " | "
            + ("–" if r["p"] is None else f"{r['p']:.2f}")
            + f" | {reading(r)} |\n"
            for f, r in real.items()
        )
        + "\n"
    )


#: The figures the bars judge, shown per repeat in the Markdown report: (variant, metric key).
SPREAD_ROWS = (
    ("full", "fidelity"),
    ("no_personalization", "fidelity"),
    ("population", "fidelity"),
    *(
        (variant, key)
        for key in ("penetration", "floating", "skate_ratio", "foot_contact_velocity", "jerk")
        for variant in ("reference", "full", "no_guidance")
    ),
    ("full", "muscle_violations"),
    ("no_guidance", "muscle_violations"),
    ("full", "zmp_in_support"),
)


def _repeats_line(report: dict) -> str:
    repeats = report.get("repeats", 1)
    if repeats == 1:
        return f"seed {report['seed']}."
    return (
        f"{repeats} repeats (first seeds {', '.join(map(str, report['repeat_seeds']))}); each cell is the mean ± "
        "std over clips x repeats."
    )


def _spread(report: dict) -> str:
    """The bar figures' per-repeat means and the 95 % interval of their mean."""

    def cells(means: list, interval: float | None, digits: str = ".3g") -> str:
        shown = ", ".join("–" if m is None else f"{m:{digits}}" for m in means)
        return f"{shown} | " + ("–" if interval is None else f"± {interval:{digits}}")

    table = report["table"]
    rows = [
        f"| {table[v][k]['label']} ({table[v][k]['unit']}) | {LABELS[v]} | "
        + cells(table[v][k]["repeat_means"], table[v][k]["ci95"])
        + " |"
        for v, k in SPREAD_ROWS
        if k in table.get(v, {})
    ]
    ident = report["identity"]
    if "per_repeat" in ident:
        rows += [
            f"| Identity probe | {LABELS[v]} | " + cells(ident["per_repeat"][v], ident["ci95"][v], ".2f") + " |"
            for v in ("reference", "full", "no_guidance")
            if v in ident["per_repeat"]
        ]
    return (
        "## Spread over repeats\n\nPer-repeat means of the figures the bars judge, and the half-width of the 95 % "
        "interval of their mean (1.96 s / sqrt(R)).\n\n| Metric | Variant | per repeat | 95 % interval |\n"
        "|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )


# --- profile manipulation (PG-BIG Sec. 4.5) ----------------------------------------------------------------------


def stride_period(q: np.ndarray, rate: float, column: str = "knee_angle_r") -> float:
    """Stride period (s): lag of the highest autocorrelation of one knee angle between 0.4 and 1.6 s."""
    x = q[:, CANONICAL_COORDINATES.index(column)]
    x = x - x.mean()
    lags = np.arange(int(0.4 * rate), min(int(1.6 * rate), len(x) - 2))
    if len(lags) == 0:
        return math.nan
    corr = np.array([np.dot(x[:-lag], x[lag:]) / (len(x) - lag) for lag in lags])
    return float(lags[np.argmax(corr)] / rate)


def kinematic_measures(q: np.ndarray, rate: float) -> dict[str, float]:
    """Measures a profile change may move, from canonical coordinates [T, 39] (generic size): knee flexion range
    (deg, each side), hip flexion range (deg), stride frequency (Hz), stride length (m, pelvis speed x period) and
    vertical pelvis excursion (m, 95th - 5th percentile of pelvis_ty)."""
    col = lambda n: q[:, CANONICAL_COORDINATES.index(n)]
    rom = lambda n: float(np.degrees(np.percentile(col(n), 97.5) - np.percentile(col(n), 2.5)))
    period = stride_period(q, rate)
    speed = float(
        np.hypot(col("pelvis_tx")[-1] - col("pelvis_tx")[0], col("pelvis_tz")[-1] - col("pelvis_tz")[0])
        / ((len(q) - 1) / rate)
    )
    return {
        "knee_rom_r": rom("knee_angle_r"),
        "knee_rom_l": rom("knee_angle_l"),
        "hip_rom": (rom("hip_flexion_r") + rom("hip_flexion_l")) / 2,
        "stride_frequency": 1 / period,
        "stride_length": speed * period,
        "pelvis_excursion": float(np.percentile(col("pelvis_ty"), 95) - np.percentile(col("pelvis_ty"), 5)),
    }


#: (field, low profile change, high profile change, measure, expected sign of high - low, source of the expectation)
MANIPULATIONS = (
    (
        "age",
        {"age": 25.0},
        {"age": 65.0},
        "knee_rom_r",
        -1,
        "older runners flex the knee less (Fukuchi & Duarte 2008, J Sports Sci 26:1447)",
    ),
    (
        "level",
        {"level": "recreational"},
        {"level": "elite"},
        "pelvis_excursion",
        -1,
        "better runners oscillate less vertically (Folland et al. 2017, MSSE 49:1412)",
    ),
    (
        "experience",
        {"experience_years": 1.0},
        {"experience_years": 20.0},
        "pelvis_excursion",
        -1,
        "as level (Folland et al. 2017)",
    ),
    (
        "injury",
        {"injuries": ()},
        {"injuries": ({"location": "Left knee", "diagnosis": "ACL reconstruction"},)},
        "knee_rom_l",
        -1,
        "less knee flexion on the reconstructed side when running (Pairot-de-Fontenay et al. 2019, Sports Med 49:1411)",
    ),
)


#: (field, action text with the low style, with the high style, measure, expected sign, source): a style is part
#: of the action request (Bandai-Namco labels such as "walk, elderly"), so it is varied with the action fixed, and
#: without a profile: no styled clip has biodata, so a style with the base profile's biodata is a pair the prior
#: never saw (docs/generation.md). Skipped when the vocabulary lacks either label.
STYLE_MANIPULATIONS = (
    (
        "style",
        "walk, active",
        "walk, elderly",
        "stride_length",
        -1,
        "older adults walk with shorter strides (Winter et al. 1990, Phys Ther 70:340)",
    ),
    (
        "style (youthful)",
        "walk, youthful",
        "walk, elderly",
        "stride_length",
        -1,
        "as style: Winter et al. compared fit elderly with young adults, the issue's elderly-vs-youthful pair",
    ),
    (
        "style (exhausted)",
        "walk, youthful",
        "walk, exhausted",
        "stride_length",
        -1,
        "the issue's third style; documented by the real clips of these two styles, not a study: the Bandai-Namco "
        "exhausted walks stride 1.11 m against the youthful 1.38 m (docs/results/walking_styles.md)",
    ),
)


def _measured(
    generator, action: ActionRequest, profile, measure: str, samples: int, seconds: float, seed: int
) -> float:
    out = generator.generate(
        action, profile=profile, seconds=seconds, samples=samples, seed=seed, personalised=profile is not None
    )
    return float(np.nanmean([kinematic_measures(q, generator.rate)[measure] for q in out.q.detach().double().numpy()]))


def _row(change: str, measure: str, low: float, high: float, sign: int, source: str) -> dict:
    return {
        "change": change,
        "measure": measure,
        "low": low,
        "high": high,
        "delta": high - low,
        "expected": "decrease" if sign < 0 else "increase",
        "as_documented": bool(np.sign(high - low) == sign),
        "source": source,
    }


def manipulation_study(
    generator,
    base: dict,
    action: ActionRequest,
    *,
    samples: int = 8,
    seconds: float = 4.0,
    seed: int = 0,
    style_generator=None,
) -> dict:
    """Vary one profile field at a time with the action fixed, and the style of `STYLE_MANIPULATIONS` with the
    action fixed (no profile); measure the kinematics of ``samples`` clips per value (the same seeds for
    both values) and compare the change with the documented direction. A style is asked for as `biomotion
    generate` asks (`ActionVocabulary.resolve`: at the style's median training speed). The styles are generated by
    ``style_generator`` (default ``generator``): the shipped full-body bundle knows them, the lab one does not
    (`biomotion.generation.routing`)."""
    from biomotion.profile import Profile

    fields, skipped = {}, {}
    for name, low, high, measure, sign, source in MANIPULATIONS:
        means = [
            _measured(
                generator,
                action,
                Profile.from_dict(
                    {**base, **change, "injuries": list(change.get("injuries", base.get("injuries", ())))}
                ),
                measure,
                samples,
                seconds,
                seed,
            )
            for change in (low, high)
        ]
        fields[name] = _row(f"{_describe(low)} -> {_describe(high)}", measure, *means, sign, source)
    style_generator = style_generator or generator
    vocabulary = style_generator.bundle.vocabulary
    known = set(vocabulary.texts)
    for name, low, high, measure, sign, source in STYLE_MANIPULATIONS:
        if low not in known or high not in known:
            skipped[name] = f"the generator knows no label {low!r} or {high!r}"
            continue
        means = [
            _measured(style_generator, vocabulary.resolve(text), None, measure, samples, seconds, seed)
            for text in (low, high)
        ]
        fields[name] = _row(f"{low} -> {high}", measure, *means, sign, source)
    return {
        "action": action.text or action.action,
        "samples": samples,
        "seconds": seconds,
        "base": base,
        "fields": fields,
        "skipped": skipped,
    }


def _style_checkpoints(generator, checkpoints: Path) -> Path:
    """The bundle that generates the style rows: ``checkpoints`` when its generator knows every style label of
    `STYLE_MANIPULATIONS`, else its full-body bundle where one ships (`biomotion.generation.routing`)."""
    from biomotion.generation.routing import full_body_checkpoints

    wanted = {text for row in STYLE_MANIPULATIONS for text in row[1:3]}
    full_body = full_body_checkpoints(checkpoints)
    if wanted <= set(generator.bundle.vocabulary.texts) or full_body is None:
        return checkpoints
    return full_body


def _shown(path: Path) -> str:
    """``path`` relative to the working directory where it lies below it (reports carry no machine paths)."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def _describe(change: dict) -> str:
    ((key, value),) = change.items()
    if key == "injuries":
        return "no injury" if not value else ", ".join(f"{i['location']} {i['diagnosis']}" for i in value)
    return f"{key} {value}"


# --- the command -------------------------------------------------------------------------------------------------

MANIPULATION_BASE = {
    "age": 35.0,
    "sex": "M",
    "height": 1.76,
    "mass": 72.0,
    "sport": "running",
    "level": "competitive",
    "experience_years": 8.0,
    "injuries": [],
}


def eval_generation(
    data_root: str | Path,
    json_path: str | Path,
    md_path: str | Path | None = None,
    *,
    checkpoints: str | Path | None = None,
    max_seconds: float = 6.0,
    seed: int = 0,
    repeats: int = 3,
    manipulation_samples: int = 8,
    progress: bool = True,
    command: str = "",
) -> dict:
    """Run the whole evaluation on ``data_root``'s unseen subjects, ``repeats`` times (module docstring); write the
    JSON (and Markdown) report."""
    if repeats < 1:
        raise BiomotionError(f"--repeats must be at least 1, got {repeats}")
    from biomotion.data.clips import body_model, build_temporary_cache
    from biomotion.evaluation.harness import write_json, write_text
    from biomotion.evaluation.manipulation_data import real_data_directions, sources_with_action
    from biomotion.generation.pipeline import CHECKPOINTS, Generator

    checkpoints = Path(checkpoints or CHECKPOINTS)
    generator = Generator.load(data_root, checkpoints)
    population = Generator.load(data_root, checkpoints, population=True, surrogate=False)
    # the sources the generator learnt from: it knows their actions and how their people are described
    trained_sources = sorted({key.split("/", 1)[0] for key in generator.bundle.train_subjects})
    try:
        handle, cache = build_temporary_cache(
            data_root, sources=trained_sources, exclude_subjects=generator.bundle.train_subjects
        )
    except BiomotionError as error:  # nothing left once the training subjects are left out
        raise BiomotionError(f"no unseen subject under {data_root}: {error}") from error
    with handle:
        targets = unseen_targets(cache, generator.bundle.train_subjects, max_seconds)
        if not targets:
            raise BiomotionError(f"no unseen subject under {data_root}: every subject there was in the training set")
        names = [cache.records[t.index]["clip_id"] for t in targets]
        model = body_model(data_root)
        speeds = [cache.records[t.index]["labels"].get("speed") for t in targets]
        heights = [cache.records[t.index]["profile"].get("height") for t in targets]
        seeds = [seed + r * len(targets) for r in range(repeats)]
        tables, identities = [], []
        for r, first_seed in enumerate(seeds):
            if progress and repeats > 1:
                print(f"repeat {r + 1}/{repeats} (seeds {first_seed}-{first_seed + len(targets) - 1})")
            variants = generate_variants(targets, cache, generator, population, seed=first_seed, progress=progress)
            tables.append(score_variants(variants, model, generator.surrogate, generator.rate, names, speeds, heights))
            identities.append(identity_accuracy(generator.tokenizer, targets, variants))
        table, identity = combine_repeats(tables), combine_identity(identities)
    manipulation = None
    if manipulation_samples > 0:
        run = generator.bundle.vocabulary.parse("run at 3.5 m/s")
        style_checkpoints = _style_checkpoints(generator, checkpoints)
        style_generator = Generator.load(data_root, style_checkpoints) if style_checkpoints != checkpoints else None
        manipulation = manipulation_study(
            generator, MANIPULATION_BASE, run, samples=manipulation_samples, seed=seed, style_generator=style_generator
        )
        manipulation["style_checkpoints"] = _shown(style_checkpoints)
        # what the real clips of the action show, over every subject of the data root (trained on or not)
        sources = sources_with_action(data_root, trained_sources, run)
        if sources:
            everyone_handle, everyone = build_temporary_cache(data_root, sources=sources)
            with everyone_handle:
                manipulation["real_data"] = real_data_directions(everyone, run, MANIPULATIONS, kinematic_measures)
    report = {
        "command": command,
        "seed": seed,
        "repeats": repeats,
        "repeat_seeds": seeds,
        "targets": len(targets),
        "subjects": len({t.subject for t in targets}),
        "clips": names,
        "table": table,
        "identity": identity,
        "manipulation": manipulation,
        "bars": done_when(table, identity, manipulation),
    }
    write_json(json_path, report)
    if md_path is not None:
        write_text(md_path, markdown(report))
    return report
