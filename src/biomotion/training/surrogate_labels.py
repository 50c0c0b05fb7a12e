"""Static-optimization activation labels for the muscle surrogate, for every frame of a dataset cache.

PG-BIG (Sec. 3.3, App. A.3 and A.8) trains its activation surrogate on OpenSim static-optimization targets
computed on Rajagopal trajectories. Ours are computed the same way with biomotion's own, OpenSim-free tools, one
clip at a time (each clip's frames are solved together, vectorised):

1. joint torques from `biomotion.analysis.chain.analyze` on the generic Rajagopal 2016 model
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

The Rajagopal model's muscles are ``Millard2012EquilibriumMuscle``: forces per unit activation come from their own
Millard 2012 active force-length and force-velocity curves (`biomotion.muscles.millard`, each muscle's curve
properties from the .osim), as in OpenSim's static optimization. The muscle type is recorded in the labels file
(``muscle_curves``). Activations are not low-pass filtered afterwards (PG-BIG filters theirs at 6 Hz;
ours come from 6 Hz-filtered kinematics already).

    biomotion train labels --cache build/dataset --data-root ../shared/data

writes ``<cache>/surrogate_labels.safetensors`` (activations of the 80 muscles, convergence, COM position, velocity
and acceleration per frame) and ``bounds_muscle_activations.json``; each clip's result is kept in
``surrogate_labels.safetensors.parts/`` until the whole cache is done, so an interrupted run resumes.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from biomotion.analysis.activation_labels import MODEL_FILE, Labeler, LabelSettings
from biomotion.errors import BiomotionError, DataFormatError
from biomotion.io.atomic import atomic_write
from biomotion.muscles.surrogate import COM_COLUMNS

FORMAT = "biomotion-surrogate-labels/1"
DEFAULT_NAME = "surrogate_labels.safetensors"
BOUNDS_NAME = "bounds_muscle_activations.json"


@dataclass(frozen=True)
class SurrogateLabels:
    """Activation labels aligned with a cache's frames (``values`` rows)."""

    activations: np.ndarray  # [N_frames_total, M] float32
    converged: np.ndarray  # [N_frames_total] bool: the frame's torque balance met the tolerance
    muscle_names: tuple[str, ...]
    info: dict  # settings, balanced coordinates, curves, cache fingerprint, timings
    com: np.ndarray | None = None  # [N_frames_total, 9] COM position, velocity, acceleration (COM_COLUMNS)

    def save(self, path: str | Path, metadata: dict[str, str] | None = None) -> None:
        """safetensors (atomic) with muscle names and ``info`` in the metadata."""
        from safetensors.numpy import save

        arrays = {
            "activations": np.ascontiguousarray(self.activations, dtype=np.float32),
            "converged": self.converged.astype(np.uint8),
        }
        if self.com is not None:
            arrays["com"] = np.ascontiguousarray(self.com, dtype=np.float32)
        blob = save(
            arrays,
            metadata={
                "format": FORMAT,
                "muscles": json.dumps(list(self.muscle_names)),
                "info": json.dumps(self.info),
                **(metadata or {}),
            },
        )
        with atomic_write(path, "wb") as handle:
            handle.write(blob)

    @classmethod
    def load(cls, path: str | Path) -> SurrogateLabels:
        from biomotion.io.tensors import read_metadata, read_tensors

        meta = read_metadata(path, "surrogate labels")
        if meta.get("format") != FORMAT:
            raise DataFormatError(
                Path(path), f"not a surrogate-labels file (format {meta.get('format')!r})", field="format"
            )
        arrays = read_tensors(path, "surrogate labels", numpy=True)
        return cls(
            arrays["activations"],
            arrays["converged"].astype(bool),
            tuple(json.loads(meta["muscles"])),
            json.loads(meta["info"]),
            arrays.get("com"),
        )


def cache_fingerprint(cache) -> str:
    """SHA-256 of a cache's coordinate array: labels belong to exactly that cache."""
    return hashlib.sha256(np.ascontiguousarray(cache.values).tobytes()).hexdigest()


#: Columns of `SurrogateLabels.com`.


def compute_labels(
    cache,
    data_root: str | Path,
    settings: LabelSettings = LabelSettings(),
    *,
    progress: bool = True,
    parts: str | Path | None = None,
) -> SurrogateLabels:
    """Labels of every clip of ``cache`` (a `biomotion.data.registry.DatasetCache`, all splits).

    With ``parts`` (a folder), each clip's result is written there as it is done (``<index>.npz``, atomically,
    tagged with the cache fingerprint and settings) and clips already there are read back instead of solved,
    so an interrupted run resumes where it stopped."""
    labeler = Labeler.from_data_root(data_root, settings)
    n_total = len(cache.values)
    activations = np.zeros((n_total, len(labeler.muscle_names)), dtype=np.float32)
    com = np.zeros((n_total, len(COM_COLUMNS)), dtype=np.float32)
    converged = np.zeros(n_total, dtype=bool)
    covered = np.zeros(n_total, dtype=bool)
    reserve_sq, started = 0.0, time.perf_counter()
    so_seconds, resumed = 0.0, 0
    tag = json.dumps(
        {"cache_sha256": cache_fingerprint(cache), "settings": asdict(settings), "muscles": list(labeler.muscle_names)},
        sort_keys=True,
    )
    folder = Path(parts) if parts is not None else None
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
    for i in tqdm(range(len(cache)), desc="muscle labels", unit="clip", disable=not progress):
        record = cache.records[i]
        rows = slice(record["offset"], record["offset"] + record["n_frames"])
        part = folder / f"{i:06d}.npz" if folder is not None else None
        stored = _read_part(part, tag) if part is not None else None
        if stored is None:
            tic = time.perf_counter()
            result, clip_com = labeler.label(cache.motion(i))
            so_seconds += time.perf_counter() - tic
            stored = {
                "activations": result.activations.numpy().astype(np.float32),
                "com": clip_com,
                "converged": result.converged.numpy(),
                "reserve_sq": np.array(float(result.reserve_torques.pow(2).sum())),
            }
            if part is not None:
                with atomic_write(part, "wb") as handle:
                    np.savez(handle, tag=np.array(tag), **stored)
        else:
            resumed += 1
        activations[rows] = stored["activations"]
        com[rows] = stored["com"]
        converged[rows] = stored["converged"]
        covered[rows] = True
        reserve_sq += float(stored["reserve_sq"])
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
        "com_columns": list(COM_COLUMNS),
        "cache": str(cache.folder),
        "cache_sha256": cache_fingerprint(cache),
        "clips": len(cache),
        "clips_resumed": resumed,
        "frames": n_total,
        "converged_share": float(converged.mean()),
        "reserve_rms_nm": float(np.sqrt(reserve_sq / (n_total * len(labeler.coordinates)))),
        "seconds": round(seconds, 1),
        "so_seconds": round(so_seconds, 1),
    }
    return SurrogateLabels(activations, converged, labeler.muscle_names, info, com)


def _read_part(path: Path, tag: str) -> dict | None:
    """A clip's stored result, or None when absent, unreadable or made for another cache or settings."""
    if not path.exists():
        return None
    try:
        with np.load(path) as stored:
            if str(stored["tag"]) != tag:
                return None
            return {k: stored[k] for k in ("activations", "com", "converged", "reserve_sq")}
    except (OSError, KeyError, ValueError):
        return None


def labels_for_cache(
    cache, data_root: str | Path, path: str | Path | None = None, *, progress: bool = True
) -> SurrogateLabels:
    """Labels of ``cache`` from ``path`` (default ``<cache>/surrogate_labels.safetensors``) when that file
    exists and was made from this very cache; otherwise computed and written there. The muscle-activation
    bounds (`activation_bounds`) are written beside it either way."""
    path = Path(path) if path else Path(cache.folder) / DEFAULT_NAME
    labels = SurrogateLabels.load(path) if path.exists() else None
    if (
        labels is None
        or labels.info.get("cache_sha256") != cache_fingerprint(cache)
        or len(labels.activations) != len(cache.values)
    ):
        parts = path.with_name(path.name + ".parts")
        labels = compute_labels(cache, data_root, progress=progress, parts=parts)
        labels.save(path)
        shutil.rmtree(parts, ignore_errors=True)
    activation_bounds(cache, labels).save(path.parent / BOUNDS_NAME)
    return labels


def activation_bounds(cache, labels: SurrogateLabels):
    """5th/95th percentile of each muscle's activation over the training split's converged frames (PG-BIG Table 1
    activation bounds), as `biomotion.metrics.bounds.PercentileBounds`: written beside the cache's other bounds."""
    from biomotion.metrics.bounds import PercentileBounds

    rows = np.zeros(len(cache.values), dtype=bool)
    for i in cache.indices(split="train"):
        record = cache.records[i]
        rows[record["offset"] : record["offset"] + record["n_frames"]] = True
    keep = rows & labels.converged
    return PercentileBounds.from_samples(
        labels.activations[keep], labels.muscle_names, quantity="muscle_activations", unit="1"
    )
