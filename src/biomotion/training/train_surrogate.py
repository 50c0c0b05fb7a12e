"""Train the muscle-activation surrogate (`MuscleSurrogate`) on static-optimization labels; write weights + card.

    biomotion train surrogate --config configs/surrogate.yaml --cache build/dataset \\
        --out checkpoints/surrogate.safetensors [--minutes N] [--labels FILE] [--data-root DIR] [--seed N]

Labels come from `biomotion.training.surrogate_labels` (``--labels``, default ``<cache>/surrogate_labels.safetensors``;
computed and written there when missing or made from another cache). Training uses the train split only:
windows of ``data.window`` frames, L1 loss on the activations (BIGE's surrogate loss; ``train.activation_loss:
mse`` the squared error, the error R^2 counts) over frames whose static optimization converged (with
``train.per_muscle_scale: true`` each muscle's error divided by the standard deviation of its train-split labels,
floored at ``data.min_label_std``, `muscle_loss_weights`) plus
``train.com_weight`` times the smooth-L1 (PG-BIG A.8's loss) of the standardised COM velocity and acceleration
over all real frames, AdamW with linear warm-up then cosine decay over the run (the run's progress is the larger
of iterations done and time used when ``--minutes`` is given), gradient clipping; with ``train.ema_decay`` > 0
the weights evaluated and saved are an exponential moving average of the trained ones (`weight_average`).
The ``low``/``high`` bounds are the 5th/95th percentiles of the train-split labels (PG-BIG Table 1).

Validation (PG-BIG A.8, Table 7) runs the surrogate on each whole val clip and compares with the labels on
converged frames: pooled R^2 (1 - SSE / SST summed over all muscles, SST around each muscle's mean), RMSE and
MAE, the mean of per-muscle R^2 over muscles whose label std exceeds ``data.min_label_std``, and the per-muscle
R^2/RMSE of the muscles PG-BIG lists (soleus and vasti); for the COM head, R^2 per component of velocity and
acceleration over all frames and their mean over the three axes (PG-BIG A.8 reports 0.94 and 0.91), with RMSE.
Pooled R^2 over all clips also credits the variation between clips (speeds, subjects), so the card adds the
stricter within-clip R^2 (SST around each clip's own muscle means), averaged over clips with at least 30
converged frames. The card also times a 3 s clip (90
frames): the surrogate (forward, and forward + backward as guidance uses it) against the static-optimization
solve and the whole label pipeline (inverse dynamics with inferred ground reaction + static optimization), one
CPU thread.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from biomotion.analysis.activation_labels import Labeler
from biomotion.body.mirror import mirror_coordinates, mirror_ground_vectors, mirror_labels
from biomotion.data.clips import body_model
from biomotion.data.registry import DatasetCache
from biomotion.errors import BiomotionError, ConfigError, SettingsError
from biomotion.guidance.losses import activation
from biomotion.muscles.surrogate import COM_OUTPUTS, MuscleSurrogate, SurrogateConfig
from biomotion.muscles.surrogate_scores import COM_LABEL_COLUMNS, evaluate
from biomotion.training.cards import environment, write_card
from biomotion.training.surrogate_labels import DEFAULT_NAME, SurrogateLabels, labels_for_cache

CLIP_FRAMES = 90  # a 3 s clip at 30 Hz (PG-BIG A.8 timing)


def make_windows(
    cache: DatasetCache, labels: SurrogateLabels, split: str, length: int, stride: int, cut_margin: int = 0
) -> tuple[torch.Tensor, ...]:
    """Training windows of ``split``: q [N, length, 39], masks [N, 39], target activations [N, length, M],
    activation weights [N, length] (1 on converged real frames), COM targets [N, length, 6] (`COM_OUTPUTS`) and
    COM weights [N, length] (1 on real frames). Window starts every ``stride`` frames, the last flush with the
    clip's end; a clip shorter than ``length`` gives one window padded by repeating its last frame (weight 0 on
    the padding).

    ``cut_margin`` > 0 also gives weight 0 to the frames within that many frames of a window edge that cuts a clip
    (not the clip's own start or end): the network, run on the window, sees a padded edge there, but the labels
    come from the whole clip, while at a clip's own ends both the network and the labels (filtered and
    differentiated over the clip) see an end. Inference runs on whole clips, so every edge it meets is a clip's
    own; with the surrogate's context (`SurrogateConfig.context`) as the margin, the loss falls only on frames
    that the network sees as inference would, and a stride no longer than ``length - 2 cut_margin`` still
    covers every frame."""
    if labels.com is None:
        raise BiomotionError("the surrogate labels hold no COM terms; recompute them with `biomotion train labels`")
    qs, masks, targets, weights, coms, reals = [], [], [], [], [], []
    for i in cache.indices(split=split):
        record = cache.records[i]
        n, offset = record["n_frames"], record["offset"]
        if n >= length:
            starts = np.unique(np.append(np.arange(0, n - length + 1, stride), n - length))
            rows = offset + starts[:, None] + np.arange(length)
            real = np.ones(rows.shape, dtype=bool)
            frame = np.arange(length)[None]
            real &= ~(
                ((starts > 0)[:, None] & (frame < cut_margin))
                | ((starts + length < n)[:, None] & (frame >= length - cut_margin))
            )
        else:
            rows = offset + np.minimum(np.arange(length), n - 1)[None]
            real = (np.arange(length) < n)[None]
        qs.append(cache.values[rows])
        targets.append(labels.activations[rows])
        weights.append(labels.converged[rows] & real)
        coms.append(labels.com[rows][..., COM_LABEL_COLUMNS])
        reals.append(real)
        masks.append(np.repeat(cache.masks[i][None], len(rows), 0))
    if not qs:
        raise BiomotionError(f"no {split} clips in {cache.folder}")
    as_tensor = lambda parts, dtype: torch.from_numpy(np.ascontiguousarray(np.concatenate(parts), dtype=dtype))
    return (
        as_tensor(qs, np.float32),
        as_tensor(masks, bool),
        as_tensor(targets, np.float32),
        as_tensor(weights, np.float32),
        as_tensor(coms, np.float32),
        as_tensor(reals, np.float32),
    )


def clip_arrays(cache: DatasetCache, labels: SurrogateLabels, split: str) -> list[tuple]:
    """Per clip of ``split``: (q [1, T, 39], mask [1, 39], target [T, M], converged [T] bool, COM [T, 6])."""
    out = []
    for i in cache.indices(split=split):
        record = cache.records[i]
        rows = slice(record["offset"], record["offset"] + record["n_frames"])
        out.append(
            (
                torch.from_numpy(cache.values[rows].astype(np.float32))[None],
                torch.from_numpy(cache.masks[i])[None],
                torch.from_numpy(labels.activations[rows]),
                torch.from_numpy(labels.converged[rows]),
                torch.from_numpy(labels.com[rows][:, COM_LABEL_COLUMNS].astype(np.float32)),
            )
        )
    return out


def _median_ms(run, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        tic = time.perf_counter()
        run()
        times.append(1000 * (time.perf_counter() - tic))
    return float(np.median(times))


def time_clip(model: MuscleSurrogate, labeler: Labeler, cache: DatasetCache, split: str = "val") -> dict:
    """Milliseconds for one 3 s clip (the first ``CLIP_FRAMES`` frames of the first long enough ``split``
    clip), one CPU thread: surrogate forward (no grad), surrogate forward + backward to q, the static
    optimization solve alone, and the whole label pipeline (inverse dynamics + static optimization)."""
    index = next(
        (i for i in cache.indices(split=split) if cache.records[i]["n_frames"] >= CLIP_FRAMES),
        next(i for i in range(len(cache)) if cache.records[i]["n_frames"] >= CLIP_FRAMES),
    )
    motion = cache.motion(index).frames(slice(0, CLIP_FRAMES))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        model.eval()
        q = torch.tensor(motion.values, dtype=torch.float32)[None]
        mask = torch.tensor(motion.mask)[None]
        with torch.no_grad():
            model(q, mask)  # warm-up
            forward = _median_ms(lambda: model(q, mask), 20)

        def backward():
            x = q.clone().requires_grad_(True)
            activation(model(x, mask), model.low, model.high).sum().backward()  # the guidance term

        backward()
        forward_backward = _median_ms(backward, 20)
        inputs = labeler.kinematics_and_torques(motion)
        labeler.solve(*inputs)  # warm-up
        solve = _median_ms(lambda: labeler.solve(*inputs), 3)
        pipeline = _median_ms(lambda: labeler(motion), 3)
    finally:
        torch.set_num_threads(threads)
    return {
        "clip": cache.records[index]["clip_id"],
        "frames": CLIP_FRAMES,
        "threads": 1,
        "surrogate_forward_ms": round(forward, 2),
        "surrogate_forward_backward_ms": round(forward_backward, 2),
        "so_solve_ms": round(solve, 1),
        "inverse_dynamics_plus_so_ms": round(pipeline, 1),
        "speedup_vs_so_solve": round(solve / forward, 1),
        "speedup_vs_pipeline": round(pipeline / forward, 1),
    }


@torch.no_grad()
def window_heights(
    model: MuscleSurrogate, q: torch.Tensor, mask: torch.Tensor, chunk: int = 1024
) -> torch.Tensor | None:
    """Foot heights [N, T, K] of every training window, computed once (`MuscleSurrogate.foot_heights`, in chunks of
    ``chunk`` windows), so the training loop does not repeat the forward kinematics of fixed data; None for a
    surrogate without contact features."""
    if not model.config.contact:
        return None
    return torch.cat([model.foot_heights(q[i : i + chunk], mask[i : i + chunk]) for i in range(0, len(q), chunk)])


def learning_rate(progress: float, step: int, lr: float, warmup: int) -> float:
    """Linear warm-up over ``warmup`` steps, then cosine decay to 0 at progress 1."""
    return lr * min(1.0, (step + 1) / max(warmup, 1)) * 0.5 * (1 + math.cos(math.pi * min(progress, 1.0)))


def weight_average(model: MuscleSurrogate, decay: float) -> torch.optim.swa_utils.AveragedModel | None:
    """An exponential moving average of ``model``'s weights (Polyak and Juditsky 1992), updated after every
    optimiser step, whose weights are the ones evaluated and saved; None when ``decay`` is 0 (train.ema_decay).
    Buffers (normalisation, bounds; fixed before training) are copied from ``model``, not averaged."""
    if not 0.0 <= decay < 1.0:
        raise ConfigError(f"train.ema_decay must lie in [0, 1), got {decay}")
    if decay == 0.0:
        return None
    return torch.optim.swa_utils.AveragedModel(model, multi_avg_fn=torch.optim.swa_utils.get_ema_multi_avg_fn(decay))


def activation_loss(kind: str) -> Callable[[torch.Tensor], torch.Tensor]:
    """The per-element penalty of the activation error: ``"l1"`` its absolute value (BIGE), ``"mse"`` its square."""
    penalties = {"l1": torch.abs, "mse": torch.square}
    if kind not in penalties:
        raise ConfigError(f"train.activation_loss must be one of {', '.join(penalties)}, got {kind!r}")
    return penalties[kind]


def muscle_loss_weights(activations: torch.Tensor, per_muscle_scale: bool, min_std: float) -> torch.Tensor:
    """[M] weight of each muscle's L1 error, from the train-split labels ``activations`` [N, M]: ones, or with
    ``per_muscle_scale`` 1 / std of the muscle's labels (floored at ``min_std``), normalised to mean 1 so the
    learning rate carries over. Scaled so, the loss weighs muscles as the mean per-muscle R^2 of the surrogate's
    validation does; unscaled, the large, variable muscles dominate it. Off in the shipped configuration: its gain
    was under the seed-to-seed spread (docs/decisions/surrogate-recipe.md)."""
    if not per_muscle_scale:
        return torch.ones(activations.shape[-1], dtype=activations.dtype)
    weight = 1.0 / activations.std(0).clamp_min(min_std)
    return weight / weight.mean()


def training_subjects(cache) -> list[str]:
    """``source/subject`` of every person whose clips the surrogate trains on (the cache's train split): what
    `biomotion validate muscles` leaves out of its held-out figures, whoever the data root holds."""
    return sorted({f"{r['source']}/{r['subject']}" for r in (cache.records[i] for i in cache.indices(split="train"))})


def train(
    config: dict,
    cache_dir: str | Path,
    out: str | Path,
    *,
    data_root: str | Path = "../shared/data",
    labels_path: str | Path | None = None,
    minutes: float | None = None,
    iterations: int | None = None,
    seed: int = 0,
    progress: bool = True,
    command: str = "",
) -> dict:
    """Train from ``config`` (the YAML's dict); save weights and card (``.json``, ``.md``) next to ``out``."""
    try:
        model_cfg = SurrogateConfig.from_dict(config.get("model", {}))
        data_cfg, train_cfg = config["data"], config["train"]
        window, stride = int(data_cfg["window"]), int(data_cfg["stride"])
        cut_margin = model_cfg.context if data_cfg.get("trim_window_cuts", False) else 0
        min_std = float(data_cfg.get("min_label_std", 0.02))
        batch, lr, warmup = int(train_cfg["batch_size"]), float(train_cfg["lr"]), int(train_cfg["warmup"])
    except KeyError as missing:
        raise SettingsError(f"surrogate config lacks the setting {missing}") from None
    except (AttributeError, TypeError, ValueError) as error:  # a section that is no mapping, a word for a number
        raise SettingsError(f"surrogate config: a setting of the wrong type ({error})") from None
    torch.manual_seed(seed)
    np.random.seed(seed)
    cache = DatasetCache(cache_dir)
    if abs(cache.rate - model_cfg.rate) > 1e-6:
        raise ConfigError(f"surrogate rate {model_cfg.rate} Hz differs from the cache's {cache.rate} Hz")
    labels = labels_for_cache(cache, data_root, labels_path, progress=progress)
    if window - 2 * cut_margin < stride:
        raise ConfigError(
            f"surrogate window {window} less twice the trimmed context {cut_margin} is shorter than the "
            f"stride {stride}: some frames would never be trained on"
        )
    q, mask, target, weight, com, com_weight = make_windows(cache, labels, "train", window, stride, cut_margin)
    if data_cfg.get("mirror", False):  # left-right mirror images with left-right swapped labels
        q_m, mask_m = mirror_coordinates(q.numpy(), mask.numpy())
        as_tensor = lambda array: torch.from_numpy(np.ascontiguousarray(array))
        q = torch.cat([q, as_tensor(q_m)])
        mask = torch.cat([mask, as_tensor(mask_m)])
        target = torch.cat([target, as_tensor(mirror_labels(target.numpy(), labels.muscle_names))])
        com = torch.cat([com, as_tensor(mirror_ground_vectors(com.numpy()))])
        weight = torch.cat([weight, weight])
        com_weight = torch.cat([com_weight, com_weight])
    val_clips = clip_arrays(cache, labels, "val")
    train_clips = clip_arrays(cache, labels, "train")
    model = MuscleSurrogate(labels.muscle_names, model_cfg, body_model(data_root) if model_cfg.contact else None)
    heights = window_heights(model, q, mask)
    model.set_normalisation(q, mask, weight, heights)
    train_rows = np.concatenate(
        [
            np.arange(r["offset"], r["offset"] + r["n_frames"])
            for r in (cache.records[i] for i in cache.indices(split="train"))
        ]
    )
    train_rows = train_rows[labels.converged[train_rows]]
    model.set_bounds(torch.from_numpy(labels.activations[train_rows]))
    model.set_com_scale(com[com_weight > 0])
    com_loss_weight = float(train_cfg.get("com_weight", 1.0))
    activation_error = activation_loss(str(train_cfg.get("activation_loss", "l1")))
    muscle_weight = muscle_loss_weights(
        torch.from_numpy(labels.activations[train_rows]).to(target.dtype),
        bool(train_cfg.get("per_muscle_scale", False)),
        min_std,
    )
    optimiser = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=float(train_cfg["weight_decay"]))
    averaged = weight_average(model, float(train_cfg.get("ema_decay", 0.0)))
    total = int(iterations or train_cfg["iterations"])
    budget = 60 * minutes if minutes else math.inf
    generator = torch.Generator().manual_seed(seed)
    before = evaluate(model, val_clips, min_std)
    history = []
    started = time.monotonic()
    bar = tqdm(range(total), desc="surrogate", unit="it", disable=not progress)
    step = 0
    for step in bar:
        elapsed = time.monotonic() - started
        if elapsed > budget:
            break
        for group in optimiser.param_groups:
            group["lr"] = learning_rate(max(step / total, elapsed / budget), step, lr, warmup)
        pick = torch.randint(len(q), (batch,), generator=generator)
        # every member of an ensemble fits the labels on its own: [B, members, T, .] against [B, 1, T, .]
        predicted, com_hat = model.predict_members(q[pick], mask[pick], None if heights is None else heights[pick])
        members = predicted.shape[1]
        w, w_com = weight[pick][:, None, :, None], com_weight[pick][:, None, :, None]
        loss_activation = (activation_error(predicted - target[pick][:, None]) * muscle_weight * w).sum() / (
            w.sum() * members * model.n_muscles
        ).clamp_min(1)
        com_error = F.smooth_l1_loss(
            (com_hat - com[pick][:, None]) / model.com_std, torch.zeros_like(com_hat), reduction="none"
        )
        loss_com = (com_error * w_com).sum() / (w_com.sum() * members * len(COM_OUTPUTS)).clamp_min(1)
        loss = loss_activation + com_loss_weight * loss_com
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), float(train_cfg["grad_clip"]))
        optimiser.step()
        if averaged is not None:
            averaged.update_parameters(model)
        if step % 20 == 0:
            bar.set_postfix(act=f"{loss_activation.item():.4f}", com=f"{loss_com.item():.4f}")
        if (step + 1) % int(train_cfg["eval_every"]) == 0:
            m = evaluate(model if averaged is None else averaged.module, val_clips, min_std)
            history.append(
                {
                    "step": step + 1,
                    "seconds": round(time.monotonic() - started, 1),
                    "train_activation": loss_activation.item(),
                    "train_com": loss_com.item(),
                    "val_r2_pooled": m["r2_pooled"],
                    "val_rmse": m["rmse"],
                    "val_com_vel_r2": m["com_vel_r2"],
                }
            )
            bar.set_postfix(
                act=f"{loss_activation.item():.4f}", val_r2=f"{m['r2_pooled']:.3f}", com_vel_r2=f"{m['com_vel_r2']:.3f}"
            )
    else:
        step = total
    train_seconds = time.monotonic() - started
    if averaged is not None:
        model.load_state_dict(averaged.module.state_dict())
    model.eval()
    after = evaluate(model, val_clips, min_std)
    on_train = evaluate(model, train_clips, min_std)
    out = Path(out)
    subjects = training_subjects(cache)
    model.save(
        out,
        metadata={
            "labels_cache_sha256": labels.info.get("cache_sha256", ""),
            "muscle_curves": labels.info.get("muscle_curves", ""),
            "train_subjects": json.dumps(subjects),
        },
    )
    speed = time_clip(model, Labeler.from_data_root(data_root), cache)
    card = {
        "model": "biomotion MuscleSurrogate (PG-BIG Sec. 3.3 / A.8 muscle-activation surrogate)",
        "weights": out.name,
        "sha256": hashlib.sha256(out.read_bytes()).hexdigest(),
        "size_bytes": out.stat().st_size,
        "parameters": sum(p.numel() for p in model.parameters()),
        "command": command or "biomotion.training.train_surrogate.train (Python API)",
        "config": config,
        "seed": seed,
        "iterations": step,
        "train_seconds": round(train_seconds, 1),
        "labels": {
            "file": str(labels_path or Path(cache_dir) / DEFAULT_NAME),
            **{
                k: labels.info.get(k)
                for k in (
                    "settings",
                    "balanced_coordinates",
                    "muscle_curves",
                    "ground_reaction",
                    "absent_coordinates",
                    "converged_share",
                    "reserve_rms_nm",
                    "seconds",
                    "so_seconds",
                    "cache_sha256",
                )
            },
        },
        "data": {
            "cache_format": cache.manifest.get("format"),
            "rate_hz": cache.rate,
            "train_windows": len(q),
            "train_clips": len(train_clips),
            "train_frames": int(sum(len(c[2]) for c in train_clips)),
            "val_clips": len(val_clips),
            "val_frames": int(sum(len(c[2]) for c in val_clips)),
            "val_frames_converged": int(sum(int(c[3].sum()) for c in val_clips)),
            "clips_per_split": cache.manifest["counts"]["per_split"],
            "clips_per_source": cache.manifest["counts"]["per_source"],
            "train_subjects": subjects,
        },
        "bounds": {"low_mean": float(model.low.mean()), "high_mean": float(model.high.mean())},
        "metrics_val_before": {k: v for k, v in before.items() if k not in ("per_muscle_r2", "key_muscles")},
        "metrics_val": after,
        "metrics_train": {k: v for k, v in on_train.items() if k != "per_muscle_r2"},
        "speed_3s_clip": speed,
        "history": history,
        "environment": environment(torch_threads_training=torch.get_num_threads()),
    }
    write_card(out, card, _markdown(card))
    return card


def _markdown(card: dict) -> str:
    m, t, s, d, lab = (card["metrics_val"], card["metrics_train"], card["speed_3s_clip"], card["data"], card["labels"])
    rows = (
        "r2_pooled",
        "rmse",
        "mae",
        "r2_mean_per_muscle",
        "r2_median_per_muscle",
        "muscles_in_mean",
        "r2_within_clip_mean",
        "r2_within_clip_median",
        "clips_within",
        "com_vel_r2",
        "com_vel_rmse",
        "com_acc_r2",
        "com_acc_rmse",
        *(f"{name}_r2" for name in COM_OUTPUTS),
    )
    worst = sorted(m["per_muscle_r2"].items(), key=lambda kv: kv[1])[:5]
    return (
        f"# Muscle-activation surrogate: {card['weights']}\n\n{card['model']}.\n\n"
        f"- SHA-256: `{card['sha256']}` ({card['size_bytes'] / 1e6:.2f} MB, {card['parameters']} parameters)\n"
        f"- command: `{card['command']}`\n"
        f"- seed {card['seed']}, {card['iterations']} iterations, {card['train_seconds']} s of training\n"
        f"- data: {d['train_windows']} train windows from {d['train_clips']} clips ({d['train_frames']} frames); "
        f"val {d['val_clips']} clips, {d['val_frames']} frames ({d['val_frames_converged']} with converged labels)\n"
        + (
            f"- trained on {len(d['train_subjects'])} subjects (`data.train_subjects` in the JSON card; `biomotion "
            "validate muscles` scores only the others)\n"
            if "train_subjects" in d
            else ""
        )
        + f"- labels: static optimization on the generic Rajagopal 2016 model, {lab['ground_reaction']}; "
        f"muscle curves {lab['muscle_curves']}; absent coordinates {lab['absent_coordinates']}; "
        f"{100 * lab['converged_share']:.2f} % of frames converged, reserve RMS {lab['reserve_rms_nm']:.1f} N·m; "
        f"computed in {lab['seconds']} s ({lab['so_seconds']} s in the solver)\n\n"
        "Agreement with the static-optimization labels (converged frames, whole clips; COM rows: all frames, "
        "m/s and m/s²):\n\n"
        "| metric | val before training | val | train |\n|---|---|---|---|\n"
        + "".join(f"| {k} | {card['metrics_val_before'][k]:.4g} | {m[k]:.4g} | {t[k]:.4g} |\n" for k in rows)
        + "\n| key muscle (PG-BIG Table 7) | val R² | val RMSE |\n|---|---|---|\n"
        + "".join(f"| {n} | {v['r2']:.3f} | {v['rmse']:.3f} |\n" for n, v in m["key_muscles"].items())
        + f"\nLowest per-muscle val R²: {', '.join(f'{n} {v:.2f}' for n, v in worst)}.\n\n"
        f"Speed on a 3 s clip ({s['frames']} frames of {s['clip']}, one CPU thread): surrogate "
        f"{s['surrogate_forward_ms']} ms forward, {s['surrogate_forward_backward_ms']} ms forward + backward; "
        f"static-optimization solve {s['so_solve_ms']} ms ({s['speedup_vs_so_solve']}x the surrogate), inverse "
        f"dynamics + static optimization {s['inverse_dynamics_plus_so_ms']} ms ({s['speedup_vs_pipeline']}x).\n"
    )
