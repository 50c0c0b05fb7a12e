"""Time-warped and posture-offset copies of a cache's training clips, for training the muscle-activation surrogate
on more motions.

The surrogate's labels are a deterministic function of the kinematics (`biomotion.training.surrogate_labels`:
inverse dynamics with the ground reaction inferred from the motion, then static optimization), so any plausible
motion with its own labels is a valid training pair. Playing a clip ``f`` times faster (its pelvis travels the
same path in 1/f of the time) gives new velocities and accelerations — and so new torques and activations — from
the same poses; with f in 0.8-1.25 the clips stay within the speeds people move at. The surrogate's recipe
(docs/decisions/surrogate-recipe.md) has what the copies gained.

Only clips of the ``split`` (default the training split) are copied, so validation and test clips stay the real
ones; copies keep their subject, hence their split. Each copy is the clip's values on the time axis divided by
``f``, resampled at the cache rate by `biomotion.motion.Motion.resample` (anti-alias low-pass when the copy is
faster, as `biomotion.data.registry.build_cache` resamples the sources). A copy's ``clip_id`` is
``<clip_id>@x<f>``; its record keeps the original's fields, with ``labels.speed`` multiplied by ``f``, the text
label marked, and ``augmentation`` = {"time_warp": f, "from": clip_id}. The bounds files are the original
cache's (the real clips' percentiles); the surrogate's activation bounds come from its own labels.

Posture copies (``posture_copies`` per clip) give the clip a random marker-placement offset
(`biomotion.data.posture`: the pelvis turned with the thighs and trunk kept in the ground, the hips' axial
rotation offset), the way another lab's markers would have reported the same movement; ``clip_id``
``<clip_id>@posture<k>``, ``augmentation`` = {"posture_deg": offsets, "from": clip_id}. The shipped surrogate is
trained with two posture copies per clip on top of the four time warps (`checkpoints/surrogate.md`).
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from biomotion.data.registry import ARRAYS, MANIFEST, ClipRecord, DatasetCache, _counts
from biomotion.errors import ConfigError
from biomotion.io.atomic import atomic_write

if TYPE_CHECKING:
    from biomotion.body.model import BodyModel

POSTURE_DRAWS = 5
"""Draws of a posture offset per copy before the copy is given up (each must keep every joint in its range)."""
MIN_FRAMES = 20
"""Copies shorter than this (frames) are not written: too short for the surrogate's training windows to mean much."""


def augmented_cache(
    cache: str | Path,
    out: str | Path,
    factors: Sequence[float] = (),
    *,
    posture_copies: int = 0,
    model: BodyModel | None = None,
    seed: int = 0,
    split: str = "train",
    sources: Sequence[str] = (),
    progress: bool = True,
) -> dict:
    """Write to ``out`` the clips of ``cache`` followed by copies of its ``split`` clips (of ``sources`` only, when
    given; the other clips are kept as they are): played ``factors`` times
    faster, and ``posture_copies`` with random marker-placement offsets (`biomotion.data.posture`, needs the
    canonical ``model``; offsets drawn from ``seed``, a draw that would leave a joint range is drawn again, at
    most `POSTURE_DRAWS` times). Returns the new manifest. Files are written atomically, the manifest last."""
    from biomotion.data.posture import keeps_ranges, posture_offset, random_offsets

    factors = tuple(float(f) for f in factors)
    if any(not np.isfinite(f) or f <= 0 or f == 1.0 for f in factors):
        raise ConfigError(f"time-warp factors must be positive and not 1, got {list(factors)}")
    if not factors and posture_copies <= 0:
        raise ConfigError("nothing to add: give time-warp factors or posture copies")
    if posture_copies > 0 and model is None:
        raise ConfigError("posture copies need the canonical body model")
    source, out = DatasetCache(cache), Path(out)
    if out.resolve() == source.folder.resolve():
        raise ConfigError(f"--out must differ from --cache ({out})")
    started = time.perf_counter()
    values, masks = [source.values], [source.masks.astype(np.uint8)]
    records = list(source.records)
    offset = int(source.values.shape[0])
    unknown = sorted(set(sources) - {r["source"] for r in source.records})
    if unknown:
        raise ConfigError(f"the cache {source.folder} has no clips of source(s) {', '.join(unknown)}")
    chosen = [i for i in source.indices(split=split) if not sources or source.records[i]["source"] in sources]
    if not chosen:
        raise ConfigError(f"the cache {source.folder} has no {split!r} clips to augment")
    rng = np.random.default_rng(seed)
    defaults = None if model is None else model.defaults.numpy()
    for index in tqdm(chosen, desc="augment", unit="clip", disable=not progress):
        motion, record = source.motion(index), source.records[index]
        copies = []
        for factor in factors:
            warped = replace(motion, times=motion.times[0] + (motion.times - motion.times[0]) / factor)
            copies.append(
                (
                    warped.resample(source.rate),
                    f"@x{factor:g}",
                    {"time_warp": factor},
                    factor,
                    f" (time-warped x{factor:g})",
                )
            )
        filled = (
            motion if model is None else motion.with_values(np.where(motion.mask[None], motion.values, defaults[None]))
        )
        for k in range(posture_copies):
            for _ in range(POSTURE_DRAWS):
                offsets = random_offsets(rng)
                moved = posture_offset(filled, model, offsets)
                if keeps_ranges(filled, moved, model):
                    kept = np.where(motion.mask[None], moved.values, motion.values)
                    copies.append(
                        (
                            motion.with_values(kept),
                            f"@posture{k + 1}",
                            {"posture_deg": {n: round(v, 3) for n, v in offsets.items()}},
                            1.0,
                            f" (posture offset {k + 1})",
                        )
                    )
                    break
        for copy, suffix, how, factor, note in copies:
            if copy.n_frames < MIN_FRAMES:
                continue
            labels = dict(record["labels"])
            if labels.get("speed") is not None:
                labels["speed"] = round(labels["speed"] * factor, 4)
            if labels.get("text"):
                labels["text"] = f"{labels['text']}{note}"
            records.append(
                {
                    **record,
                    "clip_id": f"{record['clip_id']}{suffix}",
                    "labels": labels,
                    "offset": offset,
                    "n_frames": copy.n_frames,
                    "start_time": float(copy.times[0]),
                    "augmentation": {**how, "from": record["clip_id"]},
                }
            )
            values.append(copy.values.astype(np.float32))
            masks.append(source.masks[index].astype(np.uint8)[None])
            offset += copy.n_frames
    from safetensors.numpy import save_file

    out.mkdir(parents=True, exist_ok=True)
    tmp = out / f".{ARRAYS}.tmp"
    save_file({"values": np.concatenate(values), "masks": np.concatenate(masks)}, str(tmp))
    tmp.replace(out / ARRAYS)
    for bounds in source.folder.glob("bounds_*.json"):
        if bounds.name != "bounds_muscle_activations.json":  # written with the labels of this cache
            shutil.copyfile(bounds, out / bounds.name)
    fields = ClipRecord.__dataclass_fields__
    manifest = {
        **source.manifest,
        "clips": records,
        "counts": _counts([ClipRecord(**{k: r[k] for k in fields}) for r in records]),
        "augmentation": {
            "time_warp": list(factors),
            "posture_copies": posture_copies,
            "seed": seed,
            "split": split,
            "sources": sorted(sources) or "all",
            "from": str(source.folder),
            "copies": len(records) - len(source.records),
        },
        "build_seconds": round(time.perf_counter() - started, 2),
    }
    with atomic_write(out / MANIFEST) as handle:
        json.dump(manifest, handle, indent=1)
    return manifest
