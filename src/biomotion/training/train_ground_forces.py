"""Train the learned ground reaction (`biomotion.models.ground_forces`) on the Fukuchi treadmill trials with force
plates; write the weights and a model card.

    biomotion train ground-forces --config configs/ground_forces.yaml --data-root ../shared/data \\
        --out checkpoints/ground_forces.safetensors [--exclude-subjects RBDS001 ...] [--iterations N] [--seed N]

Data: every Fukuchi running trial under the data root with its plate (`biomotion.data.plate_trials.fukuchi_trials`:
2.5, 3.5 and 4.5 m/s unless the config's ``data.speeds`` says otherwise), analysed once and cached
(`trial_samples`); runners named by ``--exclude-subjects`` are left out. OpenCap is never trained on: it is the
cross-dataset test of ``biomotion eval ground-forces``. The weights record their config (``model`` and ``train``)
and the ``source/subject`` of every runner trained on in their metadata, so the evaluation can tell held-out
people from trained ones. Held-out figures come from ``biomotion eval ground-forces`` (leave-subject-out folds
trained with this very config), not from this command, which reports the fit on its own training frames.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from biomotion.data.plate_trials import SPEEDS, PlateTrial, TrialSamples, fukuchi_trials, trial_samples
from biomotion.errors import DataSourceMissing
from biomotion.models.ground_forces import LearnedGroundReaction
from biomotion.models.ground_forces_fit import FitSettings, fit, parse_config
from biomotion.training.cards import environment, write_card


def training_trials(
    data_root: Path, speeds: Sequence[str] = SPEEDS, exclude: Sequence[str] = ()
) -> tuple[list[PlateTrial], list[str]]:
    """The Fukuchi trials to train on (runners in ``exclude`` left out), and what was skipped; a
    `DataSourceMissing` when none is found."""
    trials, skipped = fukuchi_trials(Path(data_root), tuple(speeds))
    known = {t.subject for t in trials}
    absent = sorted(set(exclude) - known)
    if absent:
        skipped.append(f"--exclude-subjects {', '.join(absent)}: no such runner under the data root")
    trials = [t for t in trials if t.subject not in set(exclude)]
    if not trials:
        raise DataSourceMissing(
            f"{data_root}: no Fukuchi running trial with a force plate and a motion under fukuchi-running/ "
            "(c3d/<runner>runT35.c3d with <runner>/<runner>_simple.osim and ik/ or the chain's files)"
        )
    return trials, skipped


def in_sample_figures(model: LearnedGroundReaction, samples: Sequence[TrialSamples]) -> dict:
    """Vertical RMSE (BW) of the model, of m(g + a_COM) and of the contact solve on the compared frames of the
    trials it was trained on (not held-out figures)."""
    errors: dict[str, list[np.ndarray]] = {"learned": [], "baseline": [], "physics": []}
    for s in samples:
        keep = s.keep
        measured = np.nan_to_num(s.measured[..., 1]).sum(1)[keep] / s.body_weight
        errors["learned"].append(model.predict(s.ground).vertical_bw[keep] - measured)
        errors["baseline"].append(s.baseline[keep, 1] - measured)
        errors["physics"].append(s.inferred[keep, :, 1].sum(1) / s.body_weight - measured)
    rmse = {k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for k, v in errors.items()}
    return {
        "frames": int(sum(s.keep.sum() for s in samples)),
        "vertical_rmse_bw": rmse["learned"],
        "com_baseline_rmse_bw": rmse["baseline"],
        "contact_model_rmse_bw": rmse["physics"],
    }


def train(
    config: dict,
    data_root: Path,
    out: Path,
    *,
    exclude_subjects: Sequence[str] = (),
    iterations: int | None = None,
    seed: int = 0,
    command: str = "",
    log: Callable[[str], None] | None = None,
) -> dict:
    """Train on the Fukuchi trials of ``data_root`` (module docstring), save to ``out`` with the card beside it
    (``.json``, ``.md``); returns the card."""
    model_config, settings, speeds = parse_config(config)
    if iterations is not None:
        settings = FitSettings.from_dict({**_asdict(settings), "iterations": int(iterations)})
    trials, skipped = training_trials(data_root, speeds, exclude_subjects)
    samples = [trial_samples(t, model_config.cutoff_hz) for t in trials]
    model, record = fit(samples, model_config, settings, seed=seed, log=log)
    subjects = sorted({f"{t.source}/{t.subject}" for t in trials})
    training = {"model": _asdict(model_config), "train": _asdict(settings), "data": {"speeds": list(speeds)}}
    model.save(
        out,
        metadata={
            "train_subjects": json.dumps(subjects),
            "training": json.dumps(training),
            "seed": str(seed),
        },
    )
    card = {
        "model": "biomotion LearnedGroundReaction: correction of m(g + a_COM) and per-foot forces and CoPs from "
        "kinematics, trained on force plates (biomotion.models.ground_forces)",
        "weights": Path(out).name,
        "sha256": hashlib.sha256(Path(out).read_bytes()).hexdigest(),
        "size_bytes": Path(out).stat().st_size,
        "parameters": record["parameters"],
        "command": command,
        "config": training,
        "seed": seed,
        "iterations": record["iterations"],
        "train_seconds": record["seconds"],
        "data": {
            "data_root": str(data_root),
            "trials": [t.name for t in trials],
            "train_subjects": subjects,
            "excluded_subjects": sorted(exclude_subjects),
            "frames": record["train_frames"],
            "skipped": skipped,
        },
        "metrics_train": in_sample_figures(model, samples),
        "history": record["history"],
        "environment": environment(),
    }
    write_card(Path(out), card, _markdown(card))
    return card


def _asdict(value) -> dict:
    from dataclasses import asdict

    return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(value).items()}


def _markdown(card: dict) -> str:
    data, metrics = card["data"], card["metrics_train"]
    speeds, excluded = ", ".join(card["config"]["data"]["speeds"]), ", ".join(data["excluded_subjects"]) or "none"
    return (
        f"# Learned ground reaction: {card['weights']}\n\n{card['model']}.\n\n"
        f"- SHA-256: `{card['sha256']}` ({card['size_bytes'] / 1e3:.1f} kB, {card['parameters']} parameters)\n"
        f"- command: `{card['command']}`\n"
        f"- seed {card['seed']}, {card['iterations']} iterations, {card['train_seconds']} s of training (CPU, "
        "one thread)\n"
        f"- data: {len(data['trials'])} Fukuchi treadmill trials with force plates ({speeds}), "
        f"{data['frames']} frames at {card['config']['model']['rate_hz']:g} Hz, {len(data['train_subjects'])} "
        f"runners (`data.train_subjects` in the JSON card); excluded: {excluded}\n"
        "- split: every runner under the data root is trained on, so on those runners these weights are not "
        "held out. Held-out figures: `biomotion eval ground-forces` (leave-subject-out folds trained with this "
        "config; docs/results/eval_ground_forces.md), which also scores these weights on OpenCap Subject4 "
        "(never trained on) and on any Fukuchi runner under its data root that is not in `data.train_subjects`.\n\n"
        "Fit on the training frames (vertical GRF RMSE in body weights; not held-out):\n\n"
        "| learned | m(g + a_COM) | contact model | frames |\n|---|---|---|---|\n"
        f"| {metrics['vertical_rmse_bw']:.4f} | {metrics['com_baseline_rmse_bw']:.4f} | "
        f"{metrics['contact_model_rmse_bw']:.4f} | {metrics['frames']} |\n"
    )
