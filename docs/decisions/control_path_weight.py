"""How `biomotion.evaluation.control.PATH_WEIGHT` is chosen: path targets of the generator's *training* subjects
(never the held-out ones `biomotion eval control` scores), generated under each candidate weight, mean and max
distance to the path. Writes docs/results/dev_control_path_weight.md.

    python docs/decisions/control_path_weight.py ../shared/data [--weights 1e4 1e5 1e6] [--paths 6]
"""

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from biomotion.data.clips import build_temporary_cache
from biomotion.evaluation.control import Settings, control_targets
from biomotion.generation.pipeline import CHECKPOINTS, Generator

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("data_root", type=Path)
parser.add_argument("--weights", type=float, nargs="+", default=[1e4, 1e5, 1e6])
parser.add_argument("--paths", type=int, default=6)
parser.add_argument("--out", type=Path, default=Path("docs/results/dev_control_path_weight.md"))
args = parser.parse_args()

generator = Generator.load(args.data_root, CHECKPOINTS)
train = set(generator.bundle.train_subjects)
sources = sorted({key.split("/", 1)[0] for key in train})
handle, cache = build_temporary_cache(args.data_root, sources=sources)
with handle:
    others = sorted({f"{r['source']}/{r['subject']}" for r in cache.records} - train)  # everyone but training
    rows = []
    for weight in args.weights:
        settings = replace(Settings(), paths=args.paths, grf_caps=0, torque_caps=0, path_weight=weight)
        records, *_ = control_targets(generator, cache, settings, exclude=others, progress=False)
        errors = np.concatenate([r["errors_m"] for r in records])
        per_target = [float(np.mean(r["errors_m"])) for r in records]
        rows.append((weight, float(errors.mean()), float(errors.max()), per_target, [r["clip"] for r in records]))
        print(f"weight {weight:g}: mean {errors.mean():.4f} m, max {errors.max():.4f} m", file=sys.stderr)
lines = [
    "# Path-target weight, chosen on training subjects",
    "",
    f"`python docs/decisions/control_path_weight.py {args.data_root} --weights "
    f"{' '.join(f'{w:g}' for w in args.weights)} --paths {args.paths}`: {args.paths} path targets from clips of the "
    "shipped generator's training subjects (the held-out subjects of `biomotion eval control` are not read), the "
    "same requests and seeds under each weight.",
    "",
    f"Clips: {', '.join(rows[0][4])}.",
    "",
    "| weight | mean error (m) | max error (m) | per target mean (m) |",
    "|---|---|---|---|",
    *(f"| {w:g} | {m:.4f} | {x:.4f} | {', '.join(f'{e:.3f}' for e in p)} |" for w, m, x, p, _ in rows),
]
args.out.write_text("\n".join(lines) + "\n")
print(f"-> {args.out}", file=sys.stderr)
