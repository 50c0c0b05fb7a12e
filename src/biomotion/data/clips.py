"""Load the inputs of an evaluation (dataset cache, OpenSim coordinate files, BVH) as batched kinematics.

Every clip becomes, at one common rate (default the cache rate, 30 Hz), the points the metrics need:
- ``points`` [N, T, J, 3]: body points (joint centres) for jerk, entropy, reconstruction and fidelity;
- ``feet`` [N, T, K, 3]: foot contact points on the sole for the contact family and the support;
- ``com`` [N, T, 3] and ``masses``: the whole-body COM for the point-mass energy;
- ``q`` [N, T, n] with ``mask`` [N, n]: canonical coordinates (coordinate inputs only) for joint ranges.
Clips are padded to the longest one; ``valid`` [N, T] marks real frames.

Coordinate clips go through the Rajagopal 2016 body model (one forward-kinematics call for all frames of all
clips); absent coordinates take the model default. BVH clips use their joint centres; the toe and ankle joints are
lowered to the sole by their heights above it with the foot flat (docs/metrics.md: 4.2 cm and 11.7 cm on the
Bandai-Namco skeleton), and the COM comes from Winter's segment table (Winter 2009, Table 4.1).
"""

from __future__ import annotations

import tempfile
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES, DEFAULT_RATE
from biomotion.errors import BiomotionError, DataFormatError
from biomotion.metrics.clip_set import ClipSet
from biomotion.motion import Motion

MODEL_FILE = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
COORDINATE_SUFFIXES = (".mot", ".sto")
BVH_SUFFIXES = (".bvh", ".bvh.gz")
BVH_FEET = ("Toes_L", "Toes_R", "Foot_L", "Foot_R")
BVH_SOLE_HEIGHTS = (0.042, 0.042, 0.117, 0.117)  # m, toe and ankle joint centres above the sole (docs/metrics.md)
BVH_ROOT = "Hips"  # the pelvis; Bandai-Namco's first joint, joint_Root, is its ground projection
BVH_MASS = 70.0  # kg, a nominal body mass for the point-mass energy of skeleton-only clips
# Winter (2009) Table 4.1: (proximal, distal, mass fraction, COM fraction from proximal); trunk 0.497 at 0.50.
WINTER_SEGMENTS = (
    ("Hand_L", "Hand_L", 0.006, 0.0),
    ("Hand_R", "Hand_R", 0.006, 0.0),
    ("LowerArm_L", "Hand_L", 0.016, 0.430),
    ("LowerArm_R", "Hand_R", 0.016, 0.430),
    ("UpperArm_L", "LowerArm_L", 0.028, 0.436),
    ("UpperArm_R", "LowerArm_R", 0.028, 0.436),
    ("Foot_L", "Toes_L", 0.0145, 0.5),
    ("Foot_R", "Toes_R", 0.0145, 0.5),
    ("LowerLeg_L", "Foot_L", 0.0465, 0.433),
    ("LowerLeg_R", "Foot_R", 0.0465, 0.433),
    ("UpperLeg_L", "LowerLeg_L", 0.100, 0.433),
    ("UpperLeg_R", "LowerLeg_R", 0.100, 0.433),
    ("Head", "Head", 0.081, 0.0),
)
TRUNK_FRACTION = 0.497


@dataclass(frozen=True)
class CoordinateClip:
    """One coordinate clip before batching: name, group label ("source/action"), motion in canonical coordinates."""

    name: str
    group: str
    motion: Motion


def _pad(arrays: Sequence[np.ndarray], fill: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Stack [T_i, ...] arrays into [N, T_max, ...] (padding = ``fill``) and the [N, T_max] validity mask."""
    longest = max(a.shape[0] for a in arrays)
    out = np.empty((len(arrays), longest, *arrays[0].shape[1:]))
    out[...] = fill
    valid = np.zeros((len(arrays), longest), dtype=bool)
    for i, a in enumerate(arrays):
        out[i, : a.shape[0]] = a
        valid[i, : a.shape[0]] = True
    return out, valid


def body_model(data_root: str | Path):
    """The canonical Rajagopal 2016 `BodyModel` from ``data_root``."""
    from biomotion.body.model import BodyModel

    path = Path(data_root) / MODEL_FILE
    if not path.exists():
        raise BiomotionError(
            f"canonical model not found: {path} (pass --data-root, or set BIOMOTION_DATA_ROOT, to a folder with "
            "opensim-models/)"
        )
    return BodyModel.from_osim(path)


def coordinate_set(
    clips: Sequence[CoordinateClip], model, rate: float = DEFAULT_RATE, *, derivatives: bool = False
) -> ClipSet:
    """Kinematics of coordinate clips through ``model``: one forward-kinematics call over every valid frame.
    ``derivatives`` adds qd and qdd (quintic spline, `Motion.derivatives`) for the full-body energy and ZMP."""
    from biomotion.body.contact import foot_points
    from biomotion.body.kinematics import (
        center_of_mass,
        forward_kinematics,
        joint_centers,
        points_in_ground,
        torch_threads,
    )

    if not clips:
        raise BiomotionError("no clip to evaluate")
    defaults = model.defaults.numpy()
    motions = [c.motion.resample(rate) if abs(c.motion.rate - rate) > 1e-6 else c.motion for c in clips]
    values = [np.where(m.mask[None, :], m.values, defaults[None, :]) for m in motions]
    q, valid = _pad(values, defaults)
    q_t, valid_t = torch.from_numpy(q), torch.from_numpy(valid)
    frames = q_t[valid_t]
    feet_spec = foot_points(model)
    with torch_threads(1), torch.no_grad():
        poses = forward_kinematics(model, frames)
        flat = {
            "points": joint_centers(model, frames, poses),
            "feet": points_in_ground(poses, feet_spec.bodies, feet_spec.offsets),
            "com": center_of_mass(model, frames, poses),
        }
    padded = {}
    for key, value in flat.items():
        out = value.new_zeros(*valid_t.shape, *value.shape[1:])
        out[valid_t] = value
        padded[key] = out
    mask = torch.from_numpy(np.stack([m.mask for m in motions]))
    qd = qdd = None
    if derivatives:
        rates = [m.with_values(v).derivatives() for m, v in zip(motions, values)]
        qd, qdd = (torch.from_numpy(_pad([r[k] for r in rates])[0]) for k in (0, 1))
    return ClipSet(
        "coordinates",
        tuple(c.name for c in clips),
        tuple(c.group for c in clips),
        rate,
        valid_t,
        padded["points"],
        padded["feet"],
        padded["com"],
        float(model.total_mass),
        q_t,
        mask,
        qd,
        qdd,
    )


def _winter_com(joints: np.ndarray, names: Sequence[str]) -> np.ndarray:
    def joint(name: str) -> np.ndarray:
        return joints[:, names.index(name)]

    com = sum(w * (joint(a) + c * (joint(b) - joint(a))) for a, b, w, c in WINTER_SEGMENTS)
    hips = 0.5 * (joint("UpperLeg_L") + joint("UpperLeg_R"))
    shoulders = 0.5 * (joint("UpperArm_L") + joint("UpperArm_R"))
    return com + TRUNK_FRACTION * (hips + 0.5 * (shoulders - hips))


def bvh_set(paths: Sequence[Path], rate: float = DEFAULT_RATE) -> ClipSet:
    """Kinematics of BVH clips (one skeleton): joint centres, soles of toes and ankles, Winter COM."""
    from biomotion.io.bvh import read_bvh

    joints, feet, coms, names = [], [], [], None
    for path in paths:
        motion = read_bvh(path)
        markers = motion.to_markers(end_sites=False)
        if abs(markers.rate - rate) > 1e-6:
            markers = markers.resample(rate)
        if names is None:
            names = markers.names
        elif markers.names != names:
            raise DataFormatError(path, "skeleton differs from the first BVH of the set", field="HIERARCHY")
        missing = [n for n in BVH_FEET if n not in names]
        if missing:
            raise DataFormatError(
                path, f"no joint {', '.join(missing)} to place the foot contact points", field="HIERARCHY"
            )
        positions = markers.positions
        sole = positions[:, [names.index(n) for n in BVH_FEET]].copy()
        sole[..., 1] -= np.asarray(BVH_SOLE_HEIGHTS)
        joints.append(positions)
        feet.append(sole)
        coms.append(_winter_com(positions, names))
    if names is None:
        raise BiomotionError("no clip to evaluate")
    points, valid = _pad(joints)
    feet_padded, _ = _pad(feet)
    com, _ = _pad(coms)
    labels = tuple(_stem(p) for p in paths)
    return ClipSet(
        "bvh",
        labels,
        tuple(_bvh_group(n) for n in labels),
        rate,
        torch.from_numpy(valid),
        torch.from_numpy(points),
        torch.from_numpy(feet_padded),
        torch.from_numpy(com),
        BVH_MASS,
        root=names.index(BVH_ROOT) if BVH_ROOT in names else 0,
    )


def _stem(path: Path) -> str:
    name = Path(path).name
    for suffix in (*BVH_SUFFIXES, *COORDINATE_SUFFIXES):
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return Path(path).stem


def _bvh_group(name: str) -> str:
    """ "bandai-namco/<content>" from a Bandai-Namco clip name (``dataset-N_<content>_<style>_<take>``), else "bvh"."""
    parts = name.split("_")
    return f"bandai-namco/{parts[1]}" if len(parts) >= 4 and parts[0].startswith("dataset-") else "bvh"


def cache_clips(cache, indices: Sequence[int] | None = None) -> list[CoordinateClip]:
    """Clips of a `DatasetCache` (all, or ``indices``), grouped by "source/action"."""
    indices = range(len(cache)) if indices is None else indices
    return [
        CoordinateClip(
            cache.records[i]["clip_id"],
            f"{cache.records[i]['source']}/{cache.records[i]['labels']['action']}",
            cache.motion(i),
        )
        for i in indices
    ]


def coordinate_file_clips(paths: Sequence[Path]) -> list[CoordinateClip]:
    """OpenSim coordinate files mapped onto the canonical coordinates (absent ones masked)."""
    from biomotion.data.sources import to_canonical
    from biomotion.io.mot import read_motion

    clips = []
    for path in paths:
        motion = to_canonical(read_motion(path))
        if not motion.mask.any():
            raise DataFormatError(
                path,
                f"no canonical coordinate among its columns (expects {', '.join(CANONICAL_COORDINATES[:3])} ...)",
                field="columns",
            )
        clips.append(CoordinateClip(_stem(path), "mot", motion))
    return clips


def _files(spec: str | Path | Sequence[str | Path]) -> list[Path]:
    items = [spec] if isinstance(spec, (str, Path)) else list(spec)
    files: list[Path] = []
    for item in map(Path, items):
        if item.is_dir():
            files += sorted(
                p for p in item.rglob("*") if p.is_file() and p.name.endswith((*COORDINATE_SUFFIXES, *BVH_SUFFIXES))
            )
        elif item.is_file():
            files.append(item)
        else:
            raise BiomotionError(f"no such file or folder: {item}")
    return files


def load_clip_set(
    spec: str | Path | Sequence[str | Path],
    data_root: str | Path,
    *,
    model=None,
    rate: float = DEFAULT_RATE,
    derivatives: bool = False,
) -> ClipSet:
    """A folder or files as a `ClipSet`: a dataset cache folder (with ``manifest.json``), OpenSim ``.mot``/``.sto``
    files or BVH files (one kind per set; folders are searched recursively)."""
    from biomotion.data.registry import MANIFEST, DatasetCache

    items = [spec] if isinstance(spec, (str, Path)) else list(spec)
    if len(items) == 1 and Path(items[0]).is_dir() and (Path(items[0]) / MANIFEST).exists():
        model = body_model(data_root) if model is None else model
        return coordinate_set(cache_clips(DatasetCache(items[0])), model, rate, derivatives=derivatives)
    files = _files(items)
    if not files:
        raise BiomotionError(f"no .mot, .sto or .bvh file in {', '.join(map(str, items))}")
    bvh = [f for f in files if f.name.endswith(BVH_SUFFIXES)]
    if bvh and len(bvh) != len(files):
        raise BiomotionError("a set mixes BVH and coordinate files; evaluate them as separate sets")
    if bvh:
        return bvh_set(bvh, rate)
    model = body_model(data_root) if model is None else model
    return coordinate_set(coordinate_file_clips(files), model, rate, derivatives=derivatives)


def build_temporary_cache(
    data_root: str | Path, sources: Sequence[str] | None = None, exclude_subjects: Collection[str] = ()
) -> tuple[tempfile.TemporaryDirectory, object]:
    """A dataset cache of every registered source under ``data_root`` (or only ``sources``), without the
    ``exclude_subjects`` ("source/subject"), in a temporary folder (kept alive by the returned handle)."""
    from biomotion.data.registry import DatasetCache, build_cache

    folder = tempfile.TemporaryDirectory(prefix="biomotion-eval-")
    build_cache(data_root, folder.name, sources=sources, progress=False, exclude_subjects=exclude_subjects)
    return folder, DatasetCache(folder.name)
