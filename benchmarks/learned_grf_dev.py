"""Design checks of the learned ground reaction, off the scored folds: inner validation runners and development trials.

    python benchmarks/learned_grf_dev.py [--config configs/ground_forces.yaml] [--set model.zero_mean_s=2.0 ...]
        [--iterations N] [--folds 0 1 2 3 4] [--development] [--data-root ../shared/data]

`biomotion eval ground-forces` scores leave-subject-out folds (runners sorted by name, runner i in fold i mod 5).
Hyperparameters must not be chosen on those folds, so this script never scores them: for each outer fold asked for,
its training runners are split again — every fourth of them, starting at the fold's index, up to four, are the
inner validation runners — a model is trained on the rest with the config (and ``--set`` overrides) and scored on
the inner validation runners (vertical GRF RMSE, body weights, pooled over their frames on the network's clock,
beside m(g + a_COM) on the same frames). With ``--development`` a model trained on every runner is also scored on
the development trials (`biomotion.data.plate_trials.development_trials`: gait2392 subject01 walking, Hamner
subject01 running at 5 m/s), the check of motions and models unlike the runners. OpenCap is never read.
docs/decisions/learned-grf.md records the runs that chose the shipped config.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
import yaml

from biomotion.data.plate_trials import development_trials, fukuchi_trials, trial_samples
from biomotion.evaluation.ground_forces import fold_assignment
from biomotion.models.ground_forces_fit import fit, fit_sequence, parse_config, vertical_rmse

REPO = Path(__file__).resolve().parents[1]


def _override(config: dict, assignments: list[str]) -> dict:
    for text in assignments:
        key, value = text.split("=", 1)
        section, name = key.split(".", 1)
        config.setdefault(section, {})[name] = yaml.safe_load(value)
    return config


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=REPO / "configs/ground_forces.yaml")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    parser.add_argument("--iterations", type=int)
    parser.add_argument("--folds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--outer", type=int, default=5, help="folds of the evaluation (default: %(default)s)")
    parser.add_argument("--development", action="store_true")
    parser.add_argument("--data-root", type=Path, default=REPO.parent / "shared" / "data")
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = _override(yaml.safe_load(args.config.read_text()), args.set)
    if args.iterations:
        config.setdefault("train", {})["iterations"] = args.iterations
    model_config, settings, speeds = parse_config(config)
    trials, _ = fukuchi_trials(args.data_root, speeds)
    items = [(t, trial_samples(t, model_config.cutoff_hz)) for t in trials]
    runners = sorted({t.subject for t, _ in items})
    outer = fold_assignment(runners, args.outer)
    scores = []
    for fold in args.folds:
        training = [r for r in runners if outer[r] != fold]
        inner = training[fold::4][:4]
        train = [s for t, s in items if t.subject in training and t.subject not in inner]
        held = [fit_sequence(s, model_config, settings) for t, s in items if t.subject in inner]
        started = time.perf_counter()
        model, _ = fit(train, model_config, settings, seed=0)
        learned = vertical_rmse(model, held)
        errors = np.concatenate([(h.baseline[:, 1] - h.total[:, 1])[h.valid] for h in held])
        baseline = float(np.sqrt(np.mean(errors**2)))
        scores.append(learned)
        print(
            f"outer fold {fold}, inner validation {', '.join(inner)}: learned {learned:.4f} BW, "
            f"m(g + a_COM) {baseline:.4f} ({time.perf_counter() - started:.0f} s)",
            flush=True,
        )
    if scores:
        print(f"inner validation: mean {np.mean(scores):.4f}, worst {np.max(scores):.4f} BW")
    if args.development:
        model, _ = fit([s for _, s in items], model_config, settings, seed=0)
        for trial in development_trials(args.data_root):
            s = trial_samples(trial, model_config.cutoff_hz)
            keep = s.keep
            measured = np.nan_to_num(s.measured[..., 1]).sum(1)[keep] / s.body_weight
            estimates = {
                "learned": model.predict(s.ground).vertical_bw[keep],
                "m(g + a_COM)": s.baseline[keep, 1],
                "contact model": s.inferred[keep, :, 1].sum(1) / s.body_weight,
            }
            figures = ", ".join(f"{k} {np.sqrt(np.mean((v - measured) ** 2)):.4f}" for k, v in estimates.items())
            print(f"{trial.name} (BW): {figures}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
