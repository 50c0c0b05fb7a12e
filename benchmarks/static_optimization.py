"""Static optimization, side by side with OpenSim 4.6 on the gait2392 subject01 walk; writes
docs/results/static_optimization.md.

    python benchmarks/static_optimization.py [--data-root ../shared/data] [--start 0.5] [--end 2.5] [--repeats 5]

OpenSim: ``AnalyzeTool`` with the ``StaticOptimization`` analysis (IK motion filtered at 6 Hz, step interval 1,
squared activations, ``gait2392_SO_Residual_Actuators.xml``), timed around ``run()``. biomotion: path geometry,
muscle forces and the batched solve on the same states and OpenSim inverse-dynamics torques, best of
``--repeats`` runs (torch threads as configured, 2 on the reference machine).
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np
import torch

from biomotion.io.atomic import atomic_write
from biomotion.validation.muscles import gait_static_optimization, opensim_gait_static_optimization, r_squared

REPO = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data-root", default=str(REPO.parent / "shared" / "data"))
    parser.add_argument("--start", type=float, default=0.5)
    parser.add_argument("--end", type=float, default=2.5)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default=str(REPO / "docs" / "results" / "static_optimization.md"))
    args = parser.parse_args(argv)

    reference = opensim_gait_static_optimization(args.data_root, args.start, args.end)
    runs = [gait_static_optimization(args.data_root, reference) for _ in range(args.repeats)]
    result = runs[0][0]
    seconds = min(s for _, s in runs)
    frames = len(reference.times)
    ours = result.activations.numpy()[:, [result.muscle_names.index(m) for m in reference.muscle_names]]
    r2 = r_squared(ours, reference.activations)
    rmse = np.sqrt(((ours - reference.activations) ** 2).mean(0))
    order = np.argsort(r2)
    usage = result.reserve_usage()
    lines = [
        "# Static optimization vs OpenSim 4.6",
        "",
        f"gait2392 subject01 walk, {args.start}-{args.end} s, {frames} frames (IK motion at 60 Hz filtered at 6 Hz, "
        "subject01_simbody.osim + gait2392_SO_Residual_Actuators.xml, GRF from subject01_walk1_grf.xml, "
        "squared activations). Produced by `python benchmarks/static_optimization.py`.",
        "",
        "| | OpenSim 4.6 StaticOptimization | biomotion (batched, torch) |",
        "|---|---|---|",
        f"| wall time | {reference.seconds:.2f} s ({1000 * reference.seconds / frames:.1f} ms/frame) | "
        f"{seconds:.3f} s ({1000 * seconds / frames:.2f} ms/frame) |",
        f"| speed-up | 1 | {reference.seconds / seconds:.0f}x |",
        f"| converged frames | - | {int(result.converged.sum())}/{frames} |",
        "",
        f"Activations vs OpenSim: mean R^2 over the 92 muscles **{r2.mean():.4f}** (min {r2.min():.4f}, "
        f"{reference.muscle_names[order[0]]}); RMSE {np.sqrt((rmse**2).mean()):.4f} overall, max per muscle "
        f"{rmse.max():.4f} ({reference.muscle_names[int(rmse.argmax())]}).",
        "",
        "Lowest R^2: " + ", ".join(f"{reference.muscle_names[i]} {r2[i]:.3f}" for i in order[:5]) + ".",
        "",
        "Generalized force the pelvis reserves supply (OpenSim's FX..MZ residuals act only there), N·m or N:",
        "",
        "| coordinate | RMS | max |",
        "|---|---|---|",
        *(f"| {name} | {u['rms']:.1f} | {u['max']:.1f} |" for name, u in usage.items() if u["max"] > 0),
        "",
        f"Machine: {platform.processor() or platform.machine()}, torch {torch.__version__}, "
        f"{torch.get_num_threads()} threads; {time.strftime('%Y-%m-%d')}.",
        "",
    ]
    with atomic_write(args.out) as handle:
        handle.write("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
