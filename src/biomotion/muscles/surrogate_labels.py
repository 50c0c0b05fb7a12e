"""Static-optimization activation labels for the muscle surrogate, for every frame of a dataset cache.

PG-BIG (Sec. 3.3, App. A.3 and A.8) trains its activation surrogate on OpenSim static-optimization targets
computed on Rajagopal trajectories. Ours are computed the same way with biomotion's own, OpenSim-free tools, one
clip at a time (each clip's frames are solved together, vectorised):

1. joint torques from `biomotion.analysis.analyze` on the generic Rajagopal 2016 model
   (``opensim-models/Models/Rajagopal/Rajagopal2016.osim``) with the ground reaction inferred from the
   kinematics (no measured forces: most sources have none). ``analyze`` prepares the coordinates like OpenSim's
   inverse-dynamics tool (6 Hz zero-lag low-pass, quintic-spline derivatives; unfiltered below 16 frames);
2. `biomotion.muscles.static_optimization.optimize_activations` with the shipped Rajagopal path functions
   (``shipped_paths("rajagopal2016")``, 80 muscles) on the same filtered q, qdot, balancing the 10 unlocked
   coordinates the muscles span (hip flexion/adduction/rotation, knee, ankle per side). Subtalar and MTP are
   locked in the Rajagopal model (their joint carries the load) and the knee ``_beta`` coordinates are coupled
   to the knee angle; pelvis, lumbar and arm coordinates are not spanned by any muscle. Each balanced coordinate
   has a reserve actuator (optimal force ``reserve_optimal_force`` N·m, control bound ``reserve_bound``) that is
   penalised like a muscle, so frames whose inferred torques exceed what the muscles can produce stay solvable.

Absent coordinates (the cache mask is False: e.g. Fukuchi has no lumbar or arm coordinates) are filled with 0
(the Rajagopal default pose: trunk upright, arms hanging) for the label computation; the coupled knee ``_beta``
coordinates are always recomputed from the knee angle. The surrogate zeroes masked coordinates the same way
(`biomotion.muscles.surrogate`), so its input matches what the labels were computed from.

The Rajagopal model's muscles are ``Millard2012EquilibriumMuscle``; `biomotion.muscles.properties` reads them with
Thelen 2003 curve defaults but implements force-length-velocity curves for ``Thelen2003Muscle`` only, so where
Millard's curves are unavailable the labels use the Thelen 2003 curves with default shape parameters on the
Rajagopal muscle parameters (F0, l0, tendon slack, pennation, vmax). Which curves were used is recorded in the
labels file (``muscle_curves``). Activations are not low-pass filtered afterwards (PG-BIG filters theirs at 6 Hz;
ours come from 6 Hz-filtered kinematics already).

    python -m biomotion.muscles.surrogate_labels --cache build/dataset --data-root ../shared/data \\
        --out build/dataset/surrogate_labels.safetensors
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from biomotion.errors import BiomotionError, DataFormatError, ModelError
from biomotion.io.atomic import atomic_write
from biomotion.motion import Motion
from biomotion.muscles.geometry import MusclePaths, shipped_paths
from biomotion.muscles.properties import (
    MuscleParameters,
    max_active_force,
    read_muscles,
)
from biomotion.muscles.static_optimization import (
    StaticOptimizationResult,
    optimize_activations,
)

FORMAT = "biomotion-surrogate-labels/1"
MODEL_FILE = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
DEFAULT_NAME = "surrogate_labels.safetensors"
BOUNDS_NAME = "bounds_muscle_activations.json"


@dataclass(frozen=True)
class LabelSettings:
    """Static-optimization settings of the labels (squared activations as OpenSim's default)."""

    cutoff_hz: float = 6.0
    exponent: float = 2.0
    reserve_optimal_force: float = 10.0   # N·m per unit control
    reserve_bound: float = 100.0          # |control| <= 100: up to 1000 N·m
    tolerance: float = 1e-6               # N·m on the torque balance
    max_iterations: int = 200


def _with_curves(muscles: MuscleParameters) -> tuple[MuscleParameters, str]:
    """The muscles and the name of the curves `max_active_force` will use for them: their own type when it is
    implemented, otherwise Thelen 2003 (see the module docstring)."""
    probe = muscles.optimal_fiber_length + muscles.tendon_slack_length
    try:
        max_active_force(muscles, probe[None], torch.zeros_like(probe)[None])
        return muscles, muscles.kind
    except ModelError:
        thelen = replace(muscles, kinds=("Thelen2003Muscle",) * muscles.n_muscles)
        return thelen, f"Thelen2003Muscle (standing in for {muscles.kind})"


@dataclass(frozen=True)
class Labeler:
    """Everything needed to label one clip: the Rajagopal body model, muscle paths and parameters, settings."""

    model: object                     # biomotion.body.model.BodyModel
    paths: MusclePaths
    muscles: MuscleParameters
    coordinates: tuple[str, ...]      # balanced coordinates
    curves: str
    settings: LabelSettings

    @classmethod
    def from_data_root(cls, data_root: str | Path, settings: LabelSettings = LabelSettings()) -> Labeler:
        """The generic Rajagopal 2016 model from ``data_root`` with the shipped path functions."""
        from biomotion.body.model import BodyModel

        path = Path(data_root) / MODEL_FILE
        if not path.exists():
            raise BiomotionError(f"Rajagopal model not found: {path} (pass the data root holding opensim-models)")
        model = BodyModel.from_osim(path)
        paths = shipped_paths("rajagopal2016")
        if tuple(model.coordinate_names) != paths.coordinate_names:
            raise ModelError("the shipped Rajagopal muscle paths and the model disagree on the coordinates")
        muscles, curves = _with_curves(read_muscles(path).select(paths.muscle_names))
        spanned = paths.spanned().any(0)
        dependent = {c.dependent for c in model.couplers}
        coordinates = tuple(n for j, n in enumerate(paths.coordinate_names)
                            if bool(spanned[j]) and not bool(model.locked[j]) and j not in dependent)
        return cls(model, paths, muscles, coordinates, curves, settings)

    @property
    def muscle_names(self) -> tuple[str, ...]:
        return self.paths.muscle_names

    def prepare(self, motion: Motion) -> Motion:
        """The motion with absent coordinates filled with 0 and marked present (couplers overwrite the
        dependent knee ``_beta`` coordinates anyway)."""
        values = np.where(motion.mask[None, :], motion.values, 0.0)
        return Motion(times=motion.times, names=motion.names, values=values, mask=np.ones_like(motion.mask))

    def kinematics_and_torques(self, motion: Motion) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Filtered q, qdot [T, n_q] in model order and inverse-dynamics torques [T, n_balanced] (inferred GRF)."""
        from biomotion.analysis import analyze, model_motion

        motion = self.prepare(motion)
        cutoff = self.settings.cutoff_hz
        result = analyze(motion, self.model, cutoff_hz=cutoff)
        coordinates = model_motion(motion, self.model)    # the same preparation analyze did, for qdot
        if cutoff and coordinates.n_frames > 15:
            coordinates, qd, _ = coordinates.smoothed(cutoff)
        else:
            qd, _ = coordinates.derivatives()
        q = torch.tensor(result.motion.values, dtype=torch.float64)
        qd = torch.tensor(np.ascontiguousarray(qd), dtype=torch.float64)
        torques = torch.tensor(result.torques, dtype=torch.float64)[:, self.paths.select(self.coordinates)]
        return q, qd, torques

    def solve(self, q: torch.Tensor, qd: torch.Tensor, torques: torch.Tensor) -> StaticOptimizationResult:
        """Static optimization of every frame at once."""
        s = self.settings
        return optimize_activations(self.paths, self.muscles, q, qd, torques, self.coordinates,
                                    s.reserve_optimal_force, exponent=s.exponent, reserve_bound=s.reserve_bound,
                                    tolerance=s.tolerance, max_iterations=s.max_iterations)

    def __call__(self, motion: Motion) -> StaticOptimizationResult:
        """Labels of one clip (canonical coordinates, any frame count >= 2)."""
        return self.solve(*self.kinematics_and_torques(motion))


@dataclass(frozen=True)
class SurrogateLabels:
    """Activation labels aligned with a cache's frames (``values`` rows)."""

    activations: np.ndarray           # [N_frames_total, M] float32
    converged: np.ndarray             # [N_frames_total] bool: the frame's torque balance met the tolerance
    muscle_names: tuple[str, ...]
    info: dict                        # settings, balanced coordinates, curves, cache fingerprint, timings

    def save(self, path: str | Path, metadata: dict[str, str] | None = None) -> None:
        """safetensors (atomic) with muscle names and ``info`` in the metadata."""
        from safetensors.numpy import save

        blob = save({"activations": np.ascontiguousarray(self.activations, dtype=np.float32),
                     "converged": self.converged.astype(np.uint8)},
                    metadata={"format": FORMAT, "muscles": json.dumps(list(self.muscle_names)),
                              "info": json.dumps(self.info), **(metadata or {})})
        with atomic_write(path, "wb") as handle:
            handle.write(blob)

    @classmethod
    def load(cls, path: str | Path) -> SurrogateLabels:
        from safetensors import safe_open
        from safetensors.numpy import load_file

        with safe_open(str(path), framework="np") as handle:
            meta = handle.metadata() or {}
        if meta.get("format") != FORMAT:
            raise DataFormatError(Path(path), f"not a surrogate-labels file (format {meta.get('format')!r})",
                                  field="format")
        arrays = load_file(str(path))
        return cls(arrays["activations"], arrays["converged"].astype(bool), tuple(json.loads(meta["muscles"])),
                   json.loads(meta["info"]))


def cache_fingerprint(cache) -> str:
    """SHA-256 of a cache's coordinate array: labels belong to exactly that cache."""
    return hashlib.sha256(np.ascontiguousarray(cache.values).tobytes()).hexdigest()


def compute_labels(cache, data_root: str | Path, settings: LabelSettings = LabelSettings(), *,
                   progress: bool = True) -> SurrogateLabels:
    """Labels of every clip of ``cache`` (a `biomotion.data.registry.DatasetCache`, all splits)."""
    labeler = Labeler.from_data_root(data_root, settings)
    n_total = len(cache.values)
    activations = np.zeros((n_total, len(labeler.muscle_names)), dtype=np.float32)
    converged = np.zeros(n_total, dtype=bool)
    covered = np.zeros(n_total, dtype=bool)
    reserve_sq, started = 0.0, time.perf_counter()
    so_seconds = 0.0
    for i in tqdm(range(len(cache)), desc="surrogate labels", unit="clip", disable=not progress):
        record = cache.records[i]
        rows = slice(record["offset"], record["offset"] + record["n_frames"])
        q, qd, torques = labeler.kinematics_and_torques(cache.motion(i))
        tic = time.perf_counter()
        result = labeler.solve(q, qd, torques)
        so_seconds += time.perf_counter() - tic
        activations[rows] = result.activations.numpy()
        converged[rows] = result.converged.numpy()
        covered[rows] = True
        reserve_sq += float(result.reserve_torques.pow(2).sum())
    if not covered.all():
        raise BiomotionError(f"{cache.folder}: {int((~covered).sum())} frames belong to no clip")
    seconds = time.perf_counter() - started
    info = {
        "settings": asdict(settings),
        "balanced_coordinates": list(labeler.coordinates),
        "muscle_curves": labeler.curves,
        "model": MODEL_FILE,
        "ground_reaction": "inferred from kinematics (analyze without measured forces)",
        "absent_coordinates": "filled with 0 (knee_beta from its coupler)",
        "cache": str(cache.folder),
        "cache_sha256": cache_fingerprint(cache),
        "clips": len(cache),
        "frames": n_total,
        "converged_share": float(converged.mean()),
        "reserve_rms_nm": float(np.sqrt(reserve_sq / (n_total * len(labeler.coordinates)))),
        "seconds": round(seconds, 1),
        "so_seconds": round(so_seconds, 1),
    }
    return SurrogateLabels(activations, converged, labeler.muscle_names, info)


def labels_for_cache(cache, data_root: str | Path, path: str | Path | None = None, *,
                     progress: bool = True) -> SurrogateLabels:
    """Labels of ``cache`` from ``path`` (default ``<cache>/surrogate_labels.safetensors``) when that file
    exists and was made from this very cache; otherwise computed and written there. The muscle-activation
    bounds (`activation_bounds`) are written beside it either way."""
    path = Path(path) if path else Path(cache.folder) / DEFAULT_NAME
    labels = SurrogateLabels.load(path) if path.exists() else None
    if labels is None or labels.info.get("cache_sha256") != cache_fingerprint(cache) or len(
            labels.activations) != len(cache.values):
        labels = compute_labels(cache, data_root, progress=progress)
        labels.save(path)
    activation_bounds(cache, labels).save(path.parent / BOUNDS_NAME)
    return labels


def activation_bounds(cache, labels: SurrogateLabels):
    """5th/95th percentile of each muscle's activation over the training split's converged frames (PG-BIG Table 1
    activation bounds), as `biomotion.metrics.bounds.PercentileBounds`: written beside the cache's other bounds."""
    from biomotion.metrics.bounds import PercentileBounds

    rows = np.zeros(len(cache.values), dtype=bool)
    for i in cache.indices(split="train"):
        record = cache.records[i]
        rows[record["offset"]: record["offset"] + record["n_frames"]] = True
    keep = rows & labels.converged
    return PercentileBounds.from_samples(labels.activations[keep], labels.muscle_names,
                                         quantity="muscle_activations", unit="1")


def main(argv: list[str] | None = None) -> int:
    from biomotion.data.registry import DatasetCache

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", required=True, type=Path)
    parser.add_argument("--data-root", type=Path, default=Path("../shared/data"))
    parser.add_argument("--out", type=Path, default=None, help=f"default: <cache>/{DEFAULT_NAME}")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    try:
        cache = DatasetCache(args.cache)
        labels = compute_labels(cache, args.data_root)
        labels.save(args.out or args.cache / DEFAULT_NAME)
    except BiomotionError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(json.dumps({k: v for k, v in labels.info.items() if k != "settings"}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
