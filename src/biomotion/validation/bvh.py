"""Retargeting every Bandai-Namco BVH clip under a data root onto the Rajagopal 2016 model: the IK check's BVH
figures (`biomotion validate ik`).

Per clip `biomotion.ik.skeleton.retarget_skeleton` with the default rules, then:

- ``bvh_joint_err_m``: the largest per-clip mean joint-centre error (m), so "every clip ≤ 2 cm" reads off one
  number; ``bvh_joint_err_mean_m`` is the mean over clips and ``bvh_clips_over_2cm`` lists the clips above;
- ``bvh_range_violations``: (frame, coordinate) samples of the result outside the model's range, over the
  clamped joint coordinates (the root's are free: a walk leaves the ±5 m pelvis_tx range);
- ``bvh_skate_ratio``: foot skating of the result over that of the source, pooled over all clips (frame pairs
  that skate, summed, over the same in the source; `retarget_skeleton` says how skating is measured), and
  ``bvh_skate_ratio_filtered`` the same when the 10 Hz filter is forced on at the clips' 30 fps.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from biomotion.body.contact import GROUND_PERCENTILE
from biomotion.body.model import BodyModel
from biomotion.ik.skeleton import FILTER_HZ, filtered_in_range, joint_map_for, joint_positions, retarget_skeleton, score
from biomotion.io.bvh import read_bvh
from biomotion.metrics.contact import CONTACT_HEIGHT, skate_ratio

BANDAI = "bandai-namco"
RAJAGOPAL_MODEL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
ERROR_BAR = 0.02

_generic: BodyModel | None = None


def _load(model_path: str) -> None:
    global _generic
    torch.set_num_threads(1)
    _generic = BodyModel.from_osim(model_path)


def _clip(path: str) -> dict:
    source = joint_positions(read_bvh(path))
    result = retarget_skeleton(source, _generic)
    model, values = result.model, result.motion.values
    clamped = model.clamped.numpy()
    lower, upper = model.ranges[clamped, 0].numpy(), model.ranges[clamped, 1].numpy()
    outside = (values[:, clamped] < lower - 1e-9) | (values[:, clamped] > upper + 1e-9)
    forced = filtered_in_range(result.ik_motion, model, FILTER_HZ, always=True)
    forced_errors, forced_feet = score(model, forced, result.tracked, joint_map_for(source.names))
    return {
        "clip": Path(path).name.removesuffix(".bvh.gz"),
        "frames": result.motion.n_frames,
        "mean_err_m": round(result.mean_error, 5),
        "max_err_m": round(result.max_error, 5),
        "range_violations": int(outside.sum()),
        "skate_source": foot_skate(result.feet_source, source.rate),
        "skate_result": foot_skate(result.feet_result, source.rate),
        "skate_filtered": foot_skate(forced_feet, source.rate),
        "mean_err_filtered_m": round(float(np.nanmean(forced_errors)), 5),
    }


def foot_skate(points: np.ndarray, rate: float) -> float:
    """Skate ratio (`biomotion.metrics.contact.skate_ratio`) of ankle and toe points [T, K, 3], each point's contact
    height 5 cm above its own 5th-percentile height, so that the comparison of source and result is not moved by
    the floor shift or by a joint centre's height above the sole."""
    height = np.nanpercentile(points[..., 1], GROUND_PERCENTILE, axis=0) + CONTACT_HEIGHT
    return float(skate_ratio(torch.as_tensor(points), rate, height=torch.as_tensor(height)))


def bvh_clips(data_root: Path) -> list[Path]:
    return sorted((data_root / BANDAI).glob("dataset-*/*.bvh.gz"))


def validate_bvh(data_root: str | Path, *, progress: bool = True, workers: int | None = None) -> dict:
    """The BVH figures (module docstring) over every clip present; empty when there is none."""
    root = Path(data_root)
    clips = bvh_clips(root)
    if not clips or not (root / RAJAGOPAL_MODEL).exists():
        return {}
    workers = workers or min(os.cpu_count() or 1, 8)
    with ProcessPoolExecutor(workers, initializer=_load, initargs=(str(root / RAJAGOPAL_MODEL),)) as pool:
        rows = list(
            tqdm(
                pool.map(_clip, [str(c) for c in clips], chunksize=4),
                total=len(clips),
                desc="retargeting BVH",
                unit="clip",
                disable=not progress,
            )
        )
    pairs = np.array([r["frames"] - 1 for r in rows], dtype=float)

    def pooled(key: str) -> float:
        return float(np.sum([r[key] for r in rows] * pairs) / np.sum([r["skate_source"] for r in rows] * pairs))

    errors = np.array([r["mean_err_m"] for r in rows])
    return {
        "bvh_clips": len(rows),
        "bvh_joint_err_m": float(errors.max()),
        "bvh_joint_err_mean_m": round(float(errors.mean()), 5),
        "bvh_clips_over_2cm": [r["clip"] for r in rows if r["mean_err_m"] > ERROR_BAR],
        "bvh_range_violations": int(sum(r["range_violations"] for r in rows)),
        "bvh_skate_ratio": round(pooled("skate_result"), 4),
        "bvh_skate_ratio_filtered": round(pooled("skate_filtered"), 4),
        "bvh_joint_err_mean_filtered_m": round(float(np.mean([r["mean_err_filtered_m"] for r in rows])), 5),
        "bvh_per_clip": rows,
    }
