"""Settings of the kinematics-only ground reaction on the two tuning trials; writes docs/results/grf.md.

    python benchmarks/grf_settings.py [--data-root ../shared/data] [--out docs/results/grf.md]

`biomotion.body.contact.ContactSettings` says its gate values were chosen on two trials that no evaluation of the
inferred forces uses — Hamner 2013 subject01 running at 5 m/s (``Run_5``, its scaled full-body model and
``Run_5_grf.mot``) and the gait2392 subject01 walk (``subject01_walk1_ik.mot``, ``subject01_walk1_grf.mot``) —
and this script is that check, repeatable: vertical GRF RMSE (body weights) against the plates on the frames
`biomotion.analysis.chain.plate_frames` keeps, for

1. the low-pass cutoff of the coordinates (4-20 Hz), with the default contact settings, beside the whole-body
   estimate m(g + a_COM,y) on the same frames and filtering;
2. each contact setting varied alone around its default (the rest at their defaults) at the evaluation's cutoff,
   10 Hz (`biomotion validate dynamics`; the issue measures its baseline at 10 Hz).

The score of a setting is the mean of the two trials' RMSE. The evaluation trials (Fukuchi T35 runners, OpenCap
Subject4) never enter this script; their figures come from ``biomotion validate dynamics``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
import torch

from biomotion.analysis.chain import analyze, model_motion, plate_frames, unwrapped, vertical_agreement
from biomotion.body.contact import ContactSettings, infer_ground_reaction
from biomotion.body.model import BodyModel
from biomotion.io.atomic import atomic_write
from biomotion.io.mot import read_ground_reaction, read_motion

REPO = Path(__file__).resolve().parents[1]
GAIT = "opensim-models/Pipelines/Gait2392_Simbody"
TRIALS = {
    "Hamner subject01 run 5 m/s": (
        "Hamner2013/subject01/subject01_adjusted_scaled.osim",
        "Hamner2013/subject01/Run_5.mot",
        "Hamner2013/subject01/Run_5_grf.mot",
    ),
    "gait2392 subject01 walk": (
        f"{GAIT}/OutputReference/subject01_simbody.osim",
        f"{GAIT}/subject01_walk1_ik.mot",
        f"{GAIT}/subject01_walk1_grf.mot",
    ),
}
CUTOFFS = (4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0)
EVALUATION_CUTOFF = 10.0
#: each setting's values, the default among them
SWEEP = {
    "height_offset": (0.01, 0.02, 0.03, 0.05),
    "height_scale": (0.005, 0.01, 0.02, 0.04),
    "speed_offset": (0.1, 0.2, 0.3, 0.5, 1.0),
    "speed_scale": (0.05, 0.1, 0.2),
    "prior_weight": (1e-4, 1e-3, 1e-2, 1e-1),
    "moment_length": (0.25, 0.5, 1.0, 2.0, 4.0),
    "friction": (0.5, 0.8, 1.0),
}


@dataclasses.dataclass
class Trial:
    """One tuning trial filtered at one cutoff: what the force solve needs and the plates to score against."""

    model: BodyModel
    q: torch.Tensor
    qd: torch.Tensor
    qdd: torch.Tensor
    keep: np.ndarray
    plates: np.ndarray
    baseline: np.ndarray
    weight: float

    def rmse(self, settings: ContactSettings) -> float:
        vertical = infer_ground_reaction(self.model, self.q, self.qd, self.qdd, settings).foot_force[..., 1].sum(1)
        return vertical_agreement(vertical.numpy()[self.keep], self.plates, self.weight)["rmse_bw"]


def load(root: Path, paths: tuple[str, str, str], cutoff: float) -> Trial:
    model = BodyModel.from_osim(root / paths[0])
    motion = read_motion(root / paths[1])
    forces = read_ground_reaction(root / paths[2]).slice(motion.times[0] - 0.1, motion.times[-1] + 0.1)
    result = analyze(motion, model, forces, cutoff_hz=cutoff)
    keep = plate_frames(result)
    coordinates, qd, qdd = unwrapped(model_motion(motion, model), model).smoothed(cutoff)
    q, qd, qdd = (torch.tensor(np.ascontiguousarray(a), dtype=model.dtype) for a in (coordinates.values, qd, qdd))
    baseline = float(model.total_mass) * (9.80665 + result.com_acceleration[keep, 1])
    return Trial(model, q, qd, qdd, keep, result.measured.force[keep, :, 1].sum(1), baseline, result.body_weight)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data-root", default=str(REPO.parent / "shared" / "data"))
    parser.add_argument("--out", default=str(REPO / "docs" / "results" / "grf.md"))
    args = parser.parse_args(argv)
    root = Path(args.data_root)
    started = time.perf_counter()
    default = ContactSettings()
    names = list(TRIALS)
    lines = [
        "# Kinematics-only ground reaction: settings on the tuning trials",
        "",
        "Produced by `python benchmarks/grf_settings.py` (see its docstring). Vertical GRF RMSE in body weights "
        f"against the plates; tuning trials: {' and '.join(names)}. The evaluation trials (Fukuchi, OpenCap) are "
        "not used here.",
        "",
        "## Low-pass cutoff of the coordinates (default contact settings)",
        "",
        "| cutoff (Hz) | " + " | ".join(f"{n}: ours / m(g + a_COM)" for n in names) + " | mean of ours |",
        "|---|" + "---|" * (len(names) + 1),
    ]
    trials_at = {}
    best_cutoff, best_score = None, np.inf
    for cutoff in CUTOFFS:
        trials = [load(root, TRIALS[n], cutoff) for n in names]
        trials_at[cutoff] = trials
        ours = [t.rmse(default) for t in trials]
        base = [vertical_agreement(t.baseline, t.plates, t.weight)["rmse_bw"] for t in trials]
        score = float(np.mean(ours))
        if score < best_score:
            best_cutoff, best_score = cutoff, score
        lines.append(
            f"| {cutoff:g} | " + " | ".join(f"{o:.3f} / {b:.3f}" for o, b in zip(ours, base)) + f" | {score:.3f} |"
        )
    lines += [
        "",
        f"Lowest mean: {best_cutoff:g} Hz. `biomotion validate dynamics` keeps the issue's {EVALUATION_CUTOFF:g} Hz "
        "(the cutoff at which issue 3 states its whole-body baseline); on its evaluation trials 6 Hz scores 0.207 BW "
        "against 0.200 at 10 Hz (measured once, 2026-12-03, with `height_scale` 0.02), so the tuning trials' "
        "preference does not carry over.",
        "",
        f"## Contact settings, one at a time, at {EVALUATION_CUTOFF:g} Hz",
        "",
        "| setting | value | " + " | ".join(names) + " | mean |",
        "|---|---|" + "---|" * (len(names) + 1),
    ]
    trials = trials_at[EVALUATION_CUTOFF]
    for field, values in SWEEP.items():
        scores = {}
        for value in values:
            rmse = [t.rmse(dataclasses.replace(default, **{field: value})) for t in trials]
            scores[value] = (rmse, float(np.mean(rmse)))
        best = min(scores, key=lambda v: scores[v][1])
        for value, (rmse, mean) in scores.items():
            mark = " (default)" if value == getattr(default, field) else ""
            mark += " **lowest**" if value == best else ""
            lines.append(
                f"| `{field}` | {value:g}{mark} | " + " | ".join(f"{r:.4f}" for r in rmse) + f" | {mean:.4f} |"
            )
    lines += [
        "",
        "Where another value lowers the mean by more than 2 %, the default moves to it. The 2026-12-03 "
        "run moved `height_scale` from 0.02 to 0.01 (mean 0.0996 -> 0.0916 BW); `biomotion validate dynamics` "
        "then measured the evaluation trials once: `grf_vertical_rmse_bw` 0.1996 -> 0.1978 (R² 0.9451 -> 0.9461), "
        "the baseline unchanged at 0.2003. The muscle surrogate's labels keep 0.02 "
        "(`LabelSettings.contact_height_scale`), the value its shipped weights were trained on.",
        "",
        f"{time.perf_counter() - started:.0f} s on this machine.",
        "",
    ]
    text = "\n".join(lines)
    with atomic_write(args.out) as handle:
        handle.write(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
