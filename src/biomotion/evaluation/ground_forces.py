"""``biomotion eval ground-forces``: the learned ground reaction (`biomotion.models.ground_forces`) on people it never
saw, beside Newton's m(g + a_COM) and the physics-only contact solve (PhysPT Eq. 4-5) on the same frames.

1. Leave-subject-out k-fold over the Fukuchi runners found under the data root: runners sorted by name go to fold
   ``i mod k``; each fold's model is trained on the other folds' runners with the same config and seed as the
   shipped weights (`biomotion.models.ground_forces_fit.fit`) and scored on the fold's runners, all three speeds.
   Per fold the vertical GRF RMSE in body weights is pooled over the compared frames
   (`biomotion.analysis.chain.plate_frames`) of its runners; the report gives every fold, their mean and the worst.
   ``grf_learned_to_com_baseline`` is the learned RMSE over the m(g + a_COM) RMSE on the same frames, worst fold.
   Fold models are cached under ``~/.cache/biomotion/ground_forces/folds`` keyed by the config, the seed, the
   training trials' cached samples and the code of the model, its features and its fit.
2. The shipped weights (trained on every Fukuchi runner of ../shared/data) on OpenCap's subjects, never trained on,
   per activity: walking (``grf_learned_vertical_rmse_bw_opencap``), drop jumps, squats, sit-to-stand (the chair
   carries weight no plate measures, so no estimate of the total can match the plates there), with the baseline
   and the contact solve.
3. The shipped weights on any Fukuchi runner under the data root that they were not trained on (their metadata's
   ``train_subjects``): on a data root of reserved runners, an independent held-out figure.

Vertical GRF is compared against the raw plates on the motion's frames, coordinates low-passed at 10 Hz as in
``biomotion validate dynamics``. Nothing is fitted on a scored runner or trial.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from biomotion.data.plate_trials import (
    PlateTrial,
    TrialSamples,
    cache_folder,
    fukuchi_trials,
    opencap_trials,
    samples_key,
    trial_samples,
)
from biomotion.errors import ConfigError
from biomotion.io.atomic import atomic_write
from biomotion.io.paths import portable
from biomotion.models import ground_forces, ground_forces_fit
from biomotion.models.ground_forces import SHIPPED, GroundForcesConfig, LearnedGroundReaction
from biomotion.models.ground_forces_fit import FitSettings, fit, parse_config

#: bars on held-out people (keys of the report)
BARS = {
    "grf_learned_vertical_rmse_bw": 0.13,
    "grf_learned_to_com_baseline": 0.75,
    "grf_learned_vertical_rmse_bw_opencap": 0.15,
}
CATEGORIES = ("walking", "drop jump", "squat", "sit-to-stand")


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(x**2))) if x.size else None


#: feet carrying less than this (body weights) on the plates are left out of the CoP error
COP_LOAD_BW = 0.2


def trial_errors(model: LearnedGroundReaction, samples: TrialSamples) -> dict[str, np.ndarray]:
    """Per compared frame of a trial, in body weights: vertical error of the learned model, of m(g + a_COM) and
    of the contact solve; forward (horizontal, along the heading) error of the learned model and of m·a_COM; and
    per loaded foot (over `COP_LOAD_BW` on the plates) the horizontal distance (m) between the learned and the
    plates' centre of pressure."""
    from biomotion.analysis.ground_features import to_heading

    keep = samples.keep & np.isfinite(samples.measured).all((1, 2))
    weight = samples.body_weight
    measured = to_heading(samples.forward, np.nan_to_num(samples.measured).sum(1))[keep] / weight
    prediction = model.predict(samples.ground)
    predicted = to_heading(samples.forward, prediction.total_bw)[keep]
    loaded = keep[:, None] & (np.nan_to_num(samples.measured[..., 1]) > COP_LOAD_BW * weight)
    loaded &= np.isfinite(samples.measured_cop).all(-1) & np.isfinite(prediction.cop).all(-1)
    cop = np.linalg.norm((prediction.cop - samples.measured_cop)[loaded][:, [0, 2]], axis=-1)
    return {
        "cop": cop,
        "learned": predicted[:, 1] - measured[:, 1],
        "baseline": samples.baseline[keep, 1] - measured[:, 1],
        "contact": samples.inferred[keep, :, 1].sum(1) / weight - measured[:, 1],
        "learned_forward": predicted[:, 0] - measured[:, 0],
        "baseline_forward": samples.baseline[keep, 0] - measured[:, 0],
    }


def pooled(errors: Sequence[dict[str, np.ndarray]]) -> dict:
    """RMSE (BW) of each estimate over the frames of several trials, with the frame count and the learned/baseline
    ratio."""
    out: dict = {"frames": int(sum(len(e["learned"]) for e in errors))}
    for key in ("learned", "baseline", "contact", "learned_forward", "baseline_forward"):
        out[f"{key}_rmse_bw"] = _rms(np.concatenate([e[key] for e in errors])) if errors else None
    cop = np.concatenate([e["cop"] for e in errors]) if errors else np.zeros(0)
    out["learned_cop_rms_m"], out["cop_foot_frames"] = _rms(cop), int(cop.size)
    learned, baseline = out["learned_rmse_bw"], out["baseline_rmse_bw"]
    out["learned_to_baseline"] = learned / baseline if learned is not None and baseline else None
    return out


def fold_assignment(runners: Sequence[str], folds: int) -> dict[str, int]:
    """Runner -> fold: sorted by name, runner i to fold i mod k (k = min(folds, runners))."""
    k = min(folds, len(runners))
    return {runner: i % k for i, runner in enumerate(sorted(runners))}


def _code_digest() -> str:
    from biomotion.analysis import ground_features
    from biomotion.data import plate_trials

    text = "".join(inspect.getsource(m) for m in (ground_forces, ground_forces_fit, ground_features, plate_trials))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def fold_model(
    train: Sequence[PlateTrial],
    samples: Sequence[TrialSamples],
    config: GroundForcesConfig,
    settings: FitSettings,
    seed: int,
    cache: bool = True,
    log: Callable[[str], None] | None = None,
) -> LearnedGroundReaction:
    """A model trained on ``samples`` (of the trials ``train``), from the fold cache when an identical one was
    trained before (module docstring)."""
    from dataclasses import asdict

    key = hashlib.sha256(
        json.dumps(
            {
                "config": asdict(config),
                "settings": asdict(settings),
                "seed": seed,
                "trials": sorted(samples_key(t, config.cutoff_hz) for t in train),
                "code": _code_digest(),
            },
            sort_keys=True,
        ).encode()
    ).hexdigest()[:24]
    path = cache_folder() / "folds" / f"{key}.safetensors"
    if cache and path.is_file():
        return LearnedGroundReaction.load(path)
    model, _ = fit(samples, config, settings, seed=seed, log=log)
    if cache:
        model.save(path, metadata={"train_subjects": json.dumps(sorted({f"{t.source}/{t.subject}" for t in train}))})
    return model


def training_config(
    checkpoint: Path | None, config: dict | None
) -> tuple[GroundForcesConfig, FitSettings, tuple[str, ...], dict]:
    """The fold models' config, settings and Fukuchi speeds: ``config`` (a YAML's dict) when given, else the one
    recorded in the checkpoint's metadata (``training``), so the folds are trained as the shipped weights were."""
    if config is None:
        model = LearnedGroundReaction.load(checkpoint)
        if "training" not in model.metadata:
            raise ConfigError(f"{model.path}: its metadata records no training config; give --config")
        config = json.loads(model.metadata["training"])
    return (*parse_config(config), config)


def _scored(model: LearnedGroundReaction, items: Sequence[tuple[PlateTrial, TrialSamples]]) -> dict:
    errors = [trial_errors(model, s) for _, s in items]
    return {
        **pooled(errors),
        "trials": {t.name: {k: v for k, v in pooled([e]).items()} for (t, _), e in zip(items, errors)},
    }


def cross_validate(
    items: Sequence[tuple[PlateTrial, TrialSamples]],
    folds: int,
    config: GroundForcesConfig,
    settings: FitSettings,
    seed: int = 0,
    cache: bool = True,
    log: Callable[[str], None] | None = None,
) -> tuple[list[dict], dict[int, LearnedGroundReaction]]:
    """Leave-subject-out k-fold over the runners of ``items`` (module docstring, step 1): one dict per fold with
    its runners and the pooled figures of `pooled`, per runner too; and each fold's model."""
    assignment = fold_assignment(sorted({t.subject for t, _ in items}), folds)
    out, models = [], {}
    for fold in sorted(set(assignment.values())):
        held = [(t, s) for t, s in items if assignment[t.subject] == fold]
        train = [(t, s) for t, s in items if assignment[t.subject] != fold]
        started = time.perf_counter()
        model = fold_model([t for t, _ in train], [s for _, s in train], config, settings, seed, cache)
        models[fold] = model
        runners = sorted({t.subject for t, _ in held})
        row = {
            "fold": fold,
            "runners": runners,
            "train_runners": len({t.subject for t, _ in train}),
            **{k: v for k, v in _scored(model, held).items() if k != "trials"},
            "per_runner": {r: _scored(model, [(t, s) for t, s in held if t.subject == r]) for r in runners},
            "seconds": round(time.perf_counter() - started, 1),
        }
        for detail in row["per_runner"].values():
            detail.pop("trials")
        out.append(row)
        if log is not None:
            log(
                f"fold {fold} ({', '.join(runners)}): learned {row['learned_rmse_bw']:.4f} BW, m(g + a_COM) "
                f"{row['baseline_rmse_bw']:.4f}, contact model {row['contact_rmse_bw']:.4f} ({row['seconds']} s)"
            )
    return out, models


def plot_examples(
    examples: Sequence[tuple[str, LearnedGroundReaction, TrialSamples]], path: Path, seconds: float = 2.5
) -> Path:
    """Vertical GRF (BW) over the first ``seconds`` of each example trial: plates, learned, m(g + a_COM) and the
    contact model; frames left out of the comparison shaded. Written as ``<path>.png`` and ``.svg``."""
    from matplotlib.figure import Figure

    from biomotion.viz.plots import save_figure

    figure = Figure(figsize=(4.2 * len(examples), 3.4), dpi=110, layout="constrained")
    axes = figure.subplots(1, len(examples), squeeze=False)[0]
    for ax, (title, model, samples) in zip(axes, examples):
        window = samples.times <= samples.times[0] + seconds
        t = samples.times[window] - samples.times[0]
        weight = samples.body_weight
        curves = (
            ("plates", np.nan_to_num(samples.measured[..., 1]).sum(1), "black", "-"),
            ("learned", model.predict(samples.ground).vertical_bw * weight, "tab:blue", "-"),
            ("m(g + a_COM)", samples.baseline[:, 1] * weight, "tab:orange", "--"),
            ("contact model", samples.inferred[..., 1].sum(1), "tab:green", ":"),
        )
        for label, values, color, style in curves:
            ax.plot(t, values[window] / weight, color=color, linestyle=style, linewidth=1.3, label=label)
        left_out = ~samples.keep[window]
        if left_out.any():
            ax.fill_between(t, 0, 1, where=left_out, color="grey", alpha=0.15, transform=ax.get_xaxis_transform())
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("vertical GRF (BW)")
    axes[0].legend(fontsize=7)
    return save_figure(figure, path)[0]


def eval_ground_forces(
    data_root: Path,
    json_path: Path,
    md_path: Path | None = None,
    *,
    folds: int = 5,
    checkpoint: Path | None = None,
    config: dict | None = None,
    seed: int = 0,
    cache: bool = True,
    command: str = "biomotion eval ground-forces",
    plots: Path | None = None,
    log: Callable[[str], None] | None = None,
) -> dict:
    """Run the evaluation of the module docstring on ``data_root``; write the JSON report (and Markdown tables;
    with ``plots`` a figure of example trials, `plot_examples`, into that folder)."""
    started = time.perf_counter()
    data_root = Path(data_root)
    checkpoint = Path(checkpoint) if checkpoint is not None else SHIPPED
    model_config, settings, speeds, recorded = training_config(checkpoint, config)
    runners_trials, skipped = fukuchi_trials(data_root, speeds)
    opencap, opencap_skipped = opencap_trials(data_root)
    skipped += opencap_skipped
    say = log or (lambda _: None)
    say(f"{len(runners_trials)} Fukuchi trials, {len(opencap)} OpenCap trials: analysing (cached after the first run)")
    fukuchi_items = [(t, trial_samples(t, model_config.cutoff_hz)) for t in runners_trials]
    report: dict = {
        "check": "ground-forces",
        "data_root": str(data_root),
        "command": command,
        "config": recorded,
        "seed": seed,
        "folds_requested": folds,
    }
    runners = sorted({t.subject for t, _ in fukuchi_items})
    fold_rows: list[dict] = []
    fold_models: dict[int, LearnedGroundReaction] = {}
    if len(runners) >= 2:
        fold_rows, fold_models = cross_validate(fukuchi_items, folds, model_config, settings, seed, cache, say)
    else:
        skipped.append(f"leave-subject-out folds: {len(runners)} Fukuchi runner(s) under the data root, need 2")
    learned = [r["learned_rmse_bw"] for r in fold_rows if r["learned_rmse_bw"] is not None]
    ratios = [r["learned_to_baseline"] for r in fold_rows if r["learned_to_baseline"] is not None]
    worst = max(fold_rows, key=lambda r: r["learned_rmse_bw"]) if learned else None
    report.update(
        {
            "folds": len(fold_rows),
            "runners": runners,
            "grf_learned_vertical_rmse_bw": max(learned) if learned else None,
            "grf_learned_vertical_rmse_bw_mean": float(np.mean(learned)) if learned else None,
            "grf_learned_to_com_baseline": max(ratios) if ratios else None,
            "grf_learned_to_com_baseline_mean": float(np.mean(ratios)) if ratios else None,
            "grf_com_baseline_vertical_rmse_bw_worst_fold": worst["baseline_rmse_bw"] if worst else None,
            "grf_contact_model_vertical_rmse_bw_worst_fold": worst["contact_rmse_bw"] if worst else None,
            "grf_com_baseline_vertical_rmse_bw_mean": float(np.mean([r["baseline_rmse_bw"] for r in fold_rows]))
            if fold_rows
            else None,
            "grf_contact_model_vertical_rmse_bw_mean": float(np.mean([r["contact_rmse_bw"] for r in fold_rows]))
            if fold_rows
            else None,
            "fold_results": fold_rows,
        }
    )
    shipped = LearnedGroundReaction.load(checkpoint)
    trained_on = shipped.train_subjects or set()
    report["shipped"] = {
        "weights": portable(checkpoint),
        "sha256": hashlib.sha256(checkpoint.read_bytes()).hexdigest(),
        "train_subjects": len(trained_on),
    }
    unseen = [(t, s) for t, s in fukuchi_items if f"{t.source}/{t.subject}" not in trained_on]
    if unseen:
        scored = _scored(shipped, unseen)
        report["grf_shipped_vertical_rmse_bw_unseen_runners"] = scored["learned_rmse_bw"]
        report["grf_shipped_to_com_baseline_unseen_runners"] = scored["learned_to_baseline"]
        report["shipped_unseen_runners"] = {
            "runners": sorted({t.subject for t, _ in unseen}),
            **scored,
        }
    say(f"shipped weights on {len(opencap)} OpenCap trials")
    categories: dict[str, dict] = {}
    for category in CATEGORIES:
        items = [(t, trial_samples(t, shipped.config.cutoff_hz)) for t in opencap if t.category == category]
        if items:
            categories[category] = _scored(shipped, items)
    report["opencap"] = categories
    walking = categories.get("walking")
    report["grf_learned_vertical_rmse_bw_opencap"] = walking["learned_rmse_bw"] if walking else None
    for category, figures in categories.items():
        slug = category.replace(" ", "_").replace("-", "_")
        report[f"grf_learned_vertical_rmse_bw_opencap_{slug}"] = figures["learned_rmse_bw"]
        report[f"grf_com_baseline_vertical_rmse_bw_opencap_{slug}"] = figures["baseline_rmse_bw"]
        report[f"grf_contact_model_vertical_rmse_bw_opencap_{slug}"] = figures["contact_rmse_bw"]
    if plots is not None:
        examples = []
        if fold_rows:
            worst_fold = max(fold_rows, key=lambda r: r["learned_rmse_bw"])
            runner = worst_fold["runners"][0]
            trial, samples = next((t, s) for t, s in fukuchi_items if t.subject == runner)
            examples.append(
                (f"{trial.name} (held out, fold {worst_fold['fold']})", fold_models[worst_fold["fold"]], samples)
            )
        for category in ("walking", "drop jump"):
            trial = next((t for t in opencap if t.category == category), None)
            if trial is not None:
                examples.append(
                    (f"{trial.name} (shipped weights)", shipped, trial_samples(trial, shipped.config.cutoff_hz))
                )
        if examples:
            report["figure"] = str(plot_examples(examples, Path(plots) / "eval_ground_forces_examples"))
    report["bars"] = {
        key: (report.get(key) <= bar) if report.get(key) is not None else None for key, bar in BARS.items()
    }
    report["skipped"] = skipped
    report["seconds"] = round(time.perf_counter() - started, 1)
    with atomic_write(json_path) as handle:
        json.dump(report, handle, indent=1)
    if md_path is not None:
        with atomic_write(md_path) as handle:
            handle.write(markdown(report))
    return report


def _bw(value: float | None, digits: int = 3) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def _cm(value: float | None) -> str:
    return "–" if value is None else f"{100.0 * value:.1f}"


def markdown(report: dict) -> str:
    """The report's tables, for docs/results/."""
    lines = [
        "# Learned ground reaction on people it never saw",
        "",
        f"Produced by `{report['command']}` ({report['seconds']} s). Vertical GRF RMSE in body weights against the "
        "raw plates, on the frames every supporting foot is on a plate (`plate_frames`); coordinates low-passed at "
        "10 Hz. Skipped: " + ("; ".join(report["skipped"]) or "nothing") + ".",
        "",
        "| figure | value | bar |",
        "|---|---|---|",
    ]
    for key, value in report.items():
        if (isinstance(value, float) and key != "seconds") or (value is None and key.startswith("grf_")):
            bar = BARS.get(key)
            met = report["bars"].get(key)
            verdict = "" if bar is None else f"≤ {bar} ({'met' if met else 'not met' if met is False else '–'})"
            lines.append(f"| `{key}` | {_bw(value, 4)} | {verdict} |")
    if report["fold_results"]:
        lines += [
            "",
            f"## Leave-subject-out, {report['folds']} folds over {len(report['runners'])} Fukuchi runners (all speeds)",
            "",
            "| fold | held-out runners | frames | learned | m(g + a_COM) | contact model | learned / baseline | "
            "forward: learned / m·a_COM | learned CoP RMS (cm) |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for r in report["fold_results"]:
            lines.append(
                f"| {r['fold']} | {', '.join(r['runners'])} | {r['frames']} | {_bw(r['learned_rmse_bw'])} | "
                f"{_bw(r['baseline_rmse_bw'])} | {_bw(r['contact_rmse_bw'])} | {_bw(r['learned_to_baseline'])} | "
                f"{_bw(r['learned_forward_rmse_bw'])} / {_bw(r['baseline_forward_rmse_bw'])} | "
                f"{_cm(r['learned_cop_rms_m'])} |"
            )
        lines += [
            "",
            "Per held-out runner:",
            "",
            "| runner | fold | frames | learned | m(g + a_COM) | contact model |",
            "|---|---|---|---|---|---|",
        ]
        for r in report["fold_results"]:
            for runner, d in r["per_runner"].items():
                lines.append(
                    f"| {runner} | {r['fold']} | {d['frames']} | {_bw(d['learned_rmse_bw'])} | "
                    f"{_bw(d['baseline_rmse_bw'])} | {_bw(d['contact_rmse_bw'])} |"
                )
    if report.get("figure"):
        lines += ["", f"![vertical GRF of example trials]({Path(report['figure']).name})"]
    if report.get("shipped_unseen_runners"):
        d = report["shipped_unseen_runners"]
        lines += [
            "",
            f"## Shipped weights on Fukuchi runners they were not trained on: {', '.join(d['runners'])}",
            "",
            f"Learned {_bw(d['learned_rmse_bw'])}, m(g + a_COM) {_bw(d['baseline_rmse_bw'])}, contact model "
            f"{_bw(d['contact_rmse_bw'])} BW over {d['frames']} frames.",
        ]
    if report["opencap"]:
        lines += [
            "",
            f"## Shipped weights on OpenCap (never trained on; weights SHA-256 `{report['shipped']['sha256'][:12]}`)",
            "",
            "| activity | trials | frames | learned | m(g + a_COM) | contact model | forward: learned / m·a_COM | "
            "learned CoP RMS (cm) |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for category, d in report["opencap"].items():
            lines.append(
                f"| {category} | {len(d['trials'])} | {d['frames']} | {_bw(d['learned_rmse_bw'])} | "
                f"{_bw(d['baseline_rmse_bw'])} | {_bw(d['contact_rmse_bw'])} | "
                f"{_bw(d['learned_forward_rmse_bw'])} / {_bw(d['baseline_forward_rmse_bw'])} | "
                f"{_cm(d['learned_cop_rms_m'])} |"
            )
        lines += ["", "| trial | frames | learned | m(g + a_COM) | contact model |", "|---|---|---|---|---|"]
        for d in report["opencap"].values():
            for name, t in d["trials"].items():
                lines.append(
                    f"| {name} | {t['frames']} | {_bw(t['learned_rmse_bw'])} | {_bw(t['baseline_rmse_bw'])} | "
                    f"{_bw(t['contact_rmse_bw'])} |"
                )
        if "sit-to-stand" in report["opencap"]:
            lines += [
                "",
                "Sit-to-stand: the chair carries weight that no plate measures, so while seated no estimate of the "
                "total (all three follow the whole body's motion) can match the plates.",
            ]
    return "\n".join(lines) + "\n"
