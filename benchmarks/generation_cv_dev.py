"""Guidance settings on each cross-validation fold's *dev* subjects: the figures that diagnose and choose.

    python benchmarks/generation_cv_dev.py [--data-root ../shared/data] [--guidance NAME:KEY=VALUE,...]
        [--repeats R] [--folds K] [--targets dev|held_out] --out docs/results/generation_cv_dev.md

Every fold of `biomotion eval generation --folds K` (the same fold models, found in the cache, trained when
missing) generates for its dev subjects: the training subjects its prior's early stopping set aside, never learnt
from by the prior and never a held-out subject of that fold, so what is chosen here for a fold is chosen without
its held-out subjects (`biomotion.evaluation.generation_cv`). Each ``--guidance`` is a named `GuidanceConfig`
(the syntax of ``benchmarks/dev_subjects.py``: ``NAME:KEY=VALUE,...``, ``planting.FIELD`` for planting,
``none`` for None). The table gives, per variant, pooled over folds: identity (mean of the folds), its difference
from the unguided sample (per fold, the worst), the energy ratio to the real clips, ZMP in support, foot contact
velocity, skate, jerk, muscle-limit violations, speed error, and the person-feature errors
(`biomotion.evaluation.generation_cv.feature_errors`: 1 = as far from the person as one person from another).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from biomotion.evaluation.generation_cv import CVSettings, eval_generation_cv
from biomotion.io.atomic import atomic_write
from biomotion.training.folds import train_fold

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dev_subjects import guidance_variant  # noqa: E402


def _row(name: str, folds: list[dict]) -> dict:
    def per_fold(getter):
        values = [getter(f) for f in folds]
        return [v for v in values if v is not None and math.isfinite(v)]

    identity = per_fold(lambda f: f["identity"].get(name))
    delta = per_fold(lambda f: f["identity"].get(name, math.nan) - f["identity"]["no_guidance"])
    energy = per_fold(lambda f: f["energy"].get(name, math.nan) / f["energy"]["reference"])
    mean = lambda v: float(np.mean(v)) if v else math.nan
    table = lambda key: mean(per_fold(lambda f: f["table"].get(name, {}).get(key, {}).get("mean") or math.nan))
    features = {
        k: mean(per_fold(lambda f, k=k: f["feature_errors"].get(name, {}).get(k, math.nan)))
        for k in folds[0]["feature_errors"].get("full", {})
    }
    return {
        "identity": mean(identity),
        "identity_minus_unguided_worst": min(delta) if delta else math.nan,
        "energy_ratio": mean(energy),
        "energy_ratio_worst": max(energy) if energy else math.nan,
        "zmp": table("zmp_in_support"),
        "foot_contact_velocity": table("foot_contact_velocity"),
        "skate": table("skate_ratio"),
        "jerk": table("jerk"),
        "muscle": table("muscle_violations"),
        "speed_error": table("speed_error"),
        "features": features,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-root", type=Path, default=Path("../shared/data"))
    parser.add_argument("--guidance", action="append", default=[], help="NAME:KEY=VALUE,... (repeatable)")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--targets", choices=("dev", "held_out"), default="dev")
    parser.add_argument("--cache-dir", type=Path, default=None)
    parser.add_argument("--only", type=int, action="append", help="fold index to run (repeatable; default all)")
    parser.add_argument("--out", type=Path, required=True, help="Markdown table (the JSON report beside it)")
    args = parser.parse_args(argv)
    guidance = {}
    for spec in args.guidance:
        name, config = guidance_variant(spec)
        if config is None:
            raise SystemExit(f"{spec}: the unguided sample is already a variant (no_guidance)")
        guidance[name] = config
    started = time.monotonic()
    report = eval_generation_cv(
        args.data_root,
        args.out.with_suffix(".json"),
        None,
        settings=CVSettings(folds=args.folds, repeats=args.repeats),
        cache_dir=args.cache_dir,
        trainer=train_fold,
        guidance=guidance,
        targets=args.targets,
        only=args.only,
        command="python benchmarks/generation_cv_dev.py " + " ".join(sys.argv[1:] if argv is None else argv),
    )
    folds = report["fold_results"]
    names = [v for v in folds[0]["identity"] if v != "reference"]
    rows = {name: _row(name, folds) for name in names}
    real = float(np.mean([f["identity"]["reference"] for f in folds]))
    feature_names = list(next(iter(rows.values()))["features"])
    lines = [
        f"# Guidance on the folds' {args.targets.replace('_', '-')} subjects\n",
        f"Command: `{report['command']}` ({(time.monotonic() - started) / 60:.1f} min; {args.repeats} draws per "
        f"target). Identity of the real clips: {real:.2f} (mean of folds). Per variant, pooled over folds: identity "
        "(mean of folds), its worst fold's difference from the unguided sample, the COM energy fluctuation over "
        "the real clips' (mean of folds, worst), ZMP in support (%), foot contact velocity (m/s), skate (%), jerk "
        "(m/s³), muscle-limit violations (%), speed error (m/s).\n",
        "| variant | identity | − unguided (worst) | energy ratio | (worst) | ZMP | foot contact vel. | skate | jerk | "
        "muscle | speed err. |",
        "|---" * 11 + "|",
    ]
    fmt = lambda v, d=".2f": "–" if v is None or not math.isfinite(v) else f"{v:{d}}"
    for name, r in rows.items():
        lines.append(
            f"| {name} | {fmt(r['identity'])} | {fmt(r['identity_minus_unguided_worst'], '+.2f')} | "
            f"{fmt(r['energy_ratio'])} | {fmt(r['energy_ratio_worst'])} | {fmt(r['zmp'], '.1f')} | "
            f"{fmt(r['foot_contact_velocity'])} | {fmt(r['skate'], '.1f')} | {fmt(r['jerk'], '.0f')} | "
            f"{fmt(r['muscle'], '.1f')} | {fmt(r['speed_error'], '.3f')} |"
        )
    lines += [
        "",
        "Person-feature errors (|generated - real| over the spread of the feature across the real targets of the "
        "same action; mean over targets and folds):\n",
        "| variant | " + " | ".join(feature_names) + " |",
        "|---" * (len(feature_names) + 1) + "|",
    ]
    for name, r in rows.items():
        lines.append(f"| {name} | " + " | ".join(fmt(r["features"][k]) for k in feature_names) + " |")
    with atomic_write(args.out) as handle:
        handle.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    with atomic_write(args.out.with_suffix(".rows.json")) as handle:
        json.dump(rows, handle, indent=1, default=str)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
