"""Generation on the generator's dev subjects: the figures that choose settings; writes docs/results/dev_subjects.md.

    python benchmarks/dev_subjects.py [--cache build/dataset_lab] [--bundle checkpoints] [--bundle DIR ...]
        [--contact kinematic] [--contact decoded] [--guidance NAME:KEY=VALUE,...] [--repeats R] [--source S ...]
        [--out docs/results/dev_subjects.md]

The dev subjects are the training subjects the generator's training sets aside for early stopping
(`biomotion.training.train_generator.dev_subject`, 15 %): the prior never learns from their clips, and they are never
evaluation subjects, so settings can be chosen on them without touching `biomotion eval generation`'s unseen
subjects. Targets are chosen as the evaluation chooses them (`unseen_targets`: up to 4 clips of at most 6 s per
subject, the person's other clips as references); each is generated with every bundle and every variant asked for,
and scored as the evaluation scores (`score_variants`, `identity_accuracy` with the bundle's own tokenizer, so the
identity column is comparable within a bundle and against its real row, less so across bundles). With
``--repeats R`` every target is generated R times (repeat r, target k: seed r * targets + k), the scores pool the
clips of all repeats and the identity is the mean over repeats, as `biomotion eval generation` does.

Variants: ``--contact decoded`` reads guidance's contact mask from the tokenizer's contact channels (bundles whose
tokenizer has none fall back to the kinematic rule), ``kinematic`` is `biomotion.models.foot_contact.stance_mask`;
``--guidance NAME:KEY=VALUE,...`` is the default guidance with those `GuidanceConfig` fields changed (``none``
as a value: the field set to None; ``planting.FIELD`` a field of its `PlantingConfig`), ``NAME:`` the default
guidance itself and ``NAME:-`` the sample before guidance.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from biomotion.body.kinematics import torch_threads
from biomotion.data.clips import body_model
from biomotion.data.registry import DatasetCache
from biomotion.evaluation.generation import (
    _motion,
    _request,
    combine_identity,
    combine_repeats,
    identity_accuracy,
    score_variants,
    unseen_targets,
)
from biomotion.evaluation.refine import root_residual
from biomotion.generation.pipeline import Generator
from biomotion.guidance.planting import PlantingConfig
from biomotion.guidance.refine import GuidanceConfig
from biomotion.io.atomic import atomic_write
from biomotion.training.train_generator import dev_subject

COLUMNS = (
    ("foot_contact_velocity", "foot contact vel. (m/s)"),
    ("skate_ratio", "skate (%)"),
    ("floating", "floating (cm)"),
    ("penetration", "penetration (cm)"),
    ("jerk", "jerk (m/s³)"),
    ("muscle_violations", "muscle-limit violations (%)"),
    ("fidelity", "DTW fidelity (cm)"),
    ("speed_error", "speed error (m/s)"),
    ("zmp_in_support", "ZMP in support (%)"),
    ("zmp_in_support_measured_trunk", "ZMP in support, measured trunk (%)"),
    ("energy_body", "body energy std (J)"),
    ("root_residual", "root residual (BW)"),
)


def guidance_variant(spec: str) -> tuple[str, GuidanceConfig | None]:
    """``NAME:KEY=VALUE,...`` -> (NAME, the default `GuidanceConfig` with those fields); ``NAME:`` -> (NAME, the
    default); ``NAME:-`` -> (NAME, None), the unguided sample."""
    name, _, settings = spec.partition(":")
    if settings == "-":
        return name, None
    if not settings:
        return name, GuidanceConfig()
    changes: dict[str, object] = {}
    planting: dict[str, object] = {}
    for item in settings.split(","):
        key, _, value = item.partition("=")
        owner, field = (PlantingConfig, key.split(".", 1)[1]) if key.startswith("planting.") else (GuidanceConfig, key)
        kinds = {f.name: str(f.type) for f in dataclasses.fields(owner)}
        if field not in kinds:
            raise SystemExit(f"--guidance {spec}: {owner.__name__} has no field {field!r}")
        kind = kinds[field]
        parsed = (
            None
            if value == "none"
            else value.lower() in ("1", "true")
            if kind == "bool"
            else int(value)
            if kind.startswith("int")
            else float(value)
        )
        (planting if owner is PlantingConfig else changes)[field] = parsed
    if planting:
        changes["planting"] = dataclasses.replace(PlantingConfig(), **planting)
    return name, dataclasses.replace(GuidanceConfig(), **changes)


def dev_rows(
    bundle: Path,
    cache: DatasetCache,
    data_root: str,
    configs: dict[str, GuidanceConfig | None],
    repeats: int = 1,
    sources: Sequence[str] = (),
    refine: bool = False,
) -> tuple[list[str], dict]:
    """Per variant ("reference" and each named guidance config; None: unguided): the identity probe (mean over
    repeats) and the mean of each column over the clips of all repeats; only targets of ``sources`` when given."""
    generator = Generator.load(data_root, bundle)
    train = generator.bundle.train_subjects
    seen = [s for s in train if not dev_subject(s, 0.15)]
    targets = [
        t
        for t in unseen_targets(cache, seen, 6.0)
        if t.subject in train and (not sources or cache.records[t.index]["source"] in sources)
    ]
    if refine:
        from biomotion.generation.refinement import load_refiner

        refiner, every = load_refiner(None, data_root), torch.ones(39, dtype=torch.bool)
    tables, identities, residuals = [], [], {}
    model = body_model(data_root)
    for r in range(repeats):
        variants = {"reference": [t.motion for t in targets]}
        for name, config in configs.items():
            variants[name] = [
                _motion(
                    generator.generate(
                        _request(cache, t.index),
                        profile=cache.profile(t.index),
                        references=t.references,
                        reference_actions=t.reference_actions,
                        reference_speeds=t.reference_speeds,
                        seconds=t.motion.n_frames / generator.rate,
                        seed=r * len(targets) + k,
                        guidance=config is not None,
                        guidance_config=config,
                    ).q[0],
                    generator.rate,
                )
                for k, t in enumerate(targets)
            ]
            if refine:
                variants[f"{name}+refine"] = [
                    m.with_values(refiner.refine(torch.from_numpy(m.values).float(), every).q.double().numpy())
                    for m in variants[name]
                ]
        identities.append(identity_accuracy(generator.tokenizer, targets, variants))
        records = [cache.records[t.index] for t in targets]
        for name, motions in variants.items():
            residuals.setdefault(name, []).extend(root_residual(model, m)[2] for m in motions)
        tables.append(
            score_variants(
                variants,
                model,
                generator.surrogate,
                generator.rate,
                [rec["clip_id"] for rec in records],
                [rec["labels"].get("speed") for rec in records],
                [rec["profile"].get("height") for rec in records],
            )
        )
    table, identity = combine_repeats(tables), combine_identity(identities)
    rows = {
        v: {
            "identity": identity.get(v),
            **{k: table[v][k]["mean"] for k, _ in COLUMNS if k in table[v]},
            "root_residual": float(np.mean(residuals[v])),
        }
        for v in table
    }
    subjects = sorted({t.subject for t in targets})
    repeated = f", {repeats} repeats" if repeats > 1 else ""
    return [
        f"{tokenizer_summary(bundle)}; {len(targets)} clips of {len(subjects)} subjects{repeated} "
        f"({', '.join(subjects)})"
    ], rows


def tokenizer_summary(bundle: Path) -> str:
    """The bundle's tokenizer as its model card records it: contact settings and training iterations."""
    card = json.loads((bundle / "tokenizer.json").read_text())
    model = card["config"].get("model", {})
    contact = (
        "contact channels (w_contact {w}), penetration weight {p}".format(
            w=model.get("w_contact"), p=model.get("w_penetration", 0.0)
        )
        if model.get("foot_contact")
        else "no contact channels"
    )
    return f"tokenizer with {contact}, {card['iterations']} iterations"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cache", default="build/dataset_lab")
    parser.add_argument("--bundle", action="append", type=Path, help="checkpoint folder (repeatable)")
    parser.add_argument("--contact", action="append", choices=("kinematic", "decoded"))
    parser.add_argument(
        "--guidance",
        action="append",
        default=[],
        metavar="NAME:KEY=VALUE,...",
        help="a variant: default guidance with these GuidanceConfig fields changed (repeatable)",
    )
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--refine", action="store_true", help="also every variant through the PhysPT refiner")
    parser.add_argument(
        "--source",
        action="append",
        default=[],
        help="only the targets of this source, e.g. fukuchi (repeatable; default: every source)",
    )
    parser.add_argument("--data-root", default="../shared/data")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", default="docs/results/dev_subjects.md")
    args = parser.parse_args(argv)
    bundles = args.bundle or [Path("checkpoints")]
    contacts = args.contact or ([] if args.guidance else ["kinematic"])
    configs = {c: GuidanceConfig(decoded_contact=c == "decoded") for c in contacts}
    configs.update(guidance_variant(spec) for spec in args.guidance)
    cache = DatasetCache(args.cache)
    lines = [
        "# Generation on the generator's dev subjects",
        "",
        f"Command: `python {' '.join(['benchmarks/dev_subjects.py', *(argv or sys.argv[1:])])}`",
        "",
    ]
    header = "| bundle | variant | identity | " + " | ".join(label for _, label in COLUMNS) + " |"
    table = [header, "|" + "---|" * (3 + len(COLUMNS))]
    started = time.perf_counter()
    with torch_threads(args.threads):
        for bundle in bundles:
            notes, rows = dev_rows(bundle, cache, args.data_root, configs, args.repeats, args.source, args.refine)
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
