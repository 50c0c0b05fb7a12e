"""Generation on the generator's dev subjects: the figures that choose settings; writes docs/results/dev_subjects.md.

    python benchmarks/dev_subjects.py [--cache build/dataset_lab] [--bundle checkpoints] [--bundle DIR ...]
        [--contact kinematic] [--contact decoded] [--out docs/results/dev_subjects.md]

The dev subjects are the training subjects the generator's training sets aside for early stopping
(`biomotion.models.train_generator.dev_subject`, 15 %): the prior never learns from their clips, and they are never
evaluation subjects, so settings can be chosen on them without touching `biomotion eval generation`'s unseen
subjects. Targets are chosen as the evaluation chooses them (`unseen_targets`: up to 4 clips of at most 6 s per
subject, the person's other clips as references); each is generated once (seed = its index) with every bundle and
every guidance contact mask asked for, and scored as the evaluation scores (`score_variants`,
`identity_accuracy` with the bundle's own tokenizer, so the identity column is comparable within a bundle and
against its real row, less so across bundles). ``--contact decoded`` reads guidance's contact mask from the
tokenizer's contact channels (bundles whose tokenizer has none fall back to the kinematic rule); ``kinematic`` is
`biomotion.models.foot_contact.stance_mask`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from biomotion.body.kinematics import torch_threads
from biomotion.data.registry import DatasetCache
from biomotion.evaluation.clips import body_model
from biomotion.evaluation.generation import _motion, _request, identity_accuracy, score_variants, unseen_targets
from biomotion.generation.pipeline import Generator
from biomotion.guidance.refine import GuidanceConfig
from biomotion.io.atomic import atomic_write
from biomotion.models.train_generator import dev_subject

COLUMNS = (("foot_contact_velocity", "foot contact vel. (m/s)"), ("skate_ratio", "skate (%)"),
           ("floating", "floating (cm)"), ("penetration", "penetration (cm)"), ("jerk", "jerk (m/s³)"),
           ("muscle_violations", "muscle-limit violations (%)"), ("fidelity", "DTW fidelity (cm)"),
           ("speed_error", "speed error (m/s)"))


def dev_rows(bundle: Path, cache: DatasetCache, data_root: str, contacts: list[str]) -> tuple[list[str], dict]:
    """Per variant ("reference" and each contact mask): the identity probe and the mean of each column."""
    generator = Generator.load(data_root, bundle)
    train = generator.bundle.train_subjects
    seen = [s for s in train if not dev_subject(s, 0.15)]
    targets = [t for t in unseen_targets(cache, seen, 6.0) if t.subject in train]
    variants = {"reference": [t.motion for t in targets]}
    for contact in contacts:
        config = GuidanceConfig(decoded_contact=contact == "decoded")
        variants[contact] = [
            _motion(generator.generate(_request(cache, t.index), profile=cache.profile(t.index),
                                       references=t.references, reference_actions=t.reference_actions,
                                       reference_speeds=t.reference_speeds, seconds=t.motion.n_frames / generator.rate,
                                       seed=k, guidance_config=config).q[0], generator.rate)
            for k, t in enumerate(targets)]
    identity = identity_accuracy(generator.tokenizer, targets, variants)
    records = [cache.records[t.index] for t in targets]
    table = score_variants(variants, body_model(data_root), generator.surrogate, generator.rate,
                           [r["clip_id"] for r in records], [r["labels"].get("speed") for r in records],
                           [r["profile"].get("height") for r in records])
    rows = {v: {"identity": identity.get(v), **{k: table[v][k]["mean"] for k, _ in COLUMNS if k in table[v]}}
            for v in variants}
    subjects = sorted({t.subject for t in targets})
    return [f"{tokenizer_summary(bundle)}; {len(targets)} clips of {len(subjects)} subjects ({', '.join(subjects)})"], rows


def tokenizer_summary(bundle: Path) -> str:
    """The bundle's tokenizer as its model card records it: contact settings and training iterations."""
    card = json.loads((bundle / "tokenizer.json").read_text())
    model = card["config"].get("model", {})
    contact = ("contact channels (w_contact {w}), penetration weight {p}".format(
        w=model.get("w_contact"), p=model.get("w_penetration", 0.0)) if model.get("foot_contact") else
        "no contact channels")
    return f"tokenizer with {contact}, {card['iterations']} iterations"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cache", default="build/dataset_lab")
    parser.add_argument("--bundle", action="append", type=Path, help="checkpoint folder (repeatable)")
    parser.add_argument("--contact", action="append", choices=("kinematic", "decoded"))
    parser.add_argument("--data-root", default="../shared/data")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", default="docs/results/dev_subjects.md")
    args = parser.parse_args(argv)
    bundles, contacts = args.bundle or [Path("checkpoints")], args.contact or ["kinematic"]
    cache = DatasetCache(args.cache)
    lines = ["# Generation on the generator's dev subjects", "",
             f"Command: `python {' '.join(['benchmarks/dev_subjects.py', *(argv or sys.argv[1:])])}`", ""]
    header = "| bundle | variant | identity | " + " | ".join(label for _, label in COLUMNS) + " |"
    table = [header, "|" + "---|" * (3 + len(COLUMNS))]
    started = time.perf_counter()
    with torch_threads(args.threads):
        for bundle in bundles:
            notes, rows = dev_rows(bundle, cache, args.data_root, contacts)
            lines.append(f"- `{bundle.as_posix()}`: {notes[0]}")
            for variant, row in rows.items():
                cells = [f"{row[k]:.3g}" if row.get(k) is not None else "–" for k, _ in COLUMNS]
                ident = "–" if row["identity"] is None else f"{row['identity']:.2f}"
                table.append(f"| `{bundle.as_posix()}` | {variant} | {ident} | " + " | ".join(cells) + " |")
    lines += ["", *table, "", f"{time.perf_counter() - started:.0f} s on {args.threads} threads.", ""]
    with atomic_write(args.out, "w") as handle:
        handle.write("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
