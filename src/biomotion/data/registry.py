"""Build and read the cached training set: every registered source, one rate, canonical coordinates, splits.

Layout of a cache folder:
- ``clips.safetensors``: ``values`` [N_frames_total, 39] float32 (SI units, canonical coordinates, all clips
  concatenated) and ``masks`` [N_clips, 39] uint8.
- ``bounds_coordinates.json``, ``bounds_coordinate_speeds.json``: 5th/95th percentiles over the training split
  (`biomotion.metrics.bounds.PercentileBounds`), shared by the plausibility metrics and the generator's guidance.
- ``manifest.json``: rate, coordinate names, one record per clip (id, source, subject, split, labels, profile,
  offset and length into ``values``, start time, source file relative to the data root), counts per source,
  subject, action and split, sources skipped, and the build settings.

Splits are by subject, never by clip, so no person is in two splits (PG-BIG Sec. 4.1 evaluates on held-out
subjects): a subject's split is a stable hash of ``source/subject``, so adding subjects never moves others.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import time
from collections import Counter
from collections.abc import Collection, Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from biomotion.body.canonical import CANONICAL_COORDINATES, DEFAULT_RATE
from biomotion.data.placement import place_clip
from biomotion.data.sources import SOURCES, discover_all, forward_speed
from biomotion.errors import BiomotionError, DataFormatError
from biomotion.io.atomic import atomic_write
from biomotion.motion import Motion
from biomotion.profile import Profile
from biomotion.trial import Labels

SPLIT_FRACTIONS = (("train", 0.70), ("val", 0.15), ("test", 0.15))
MANIFEST = "manifest.json"
ARRAYS = "clips.safetensors"


def subject_split(source: str, subject: str, fractions=SPLIT_FRACTIONS) -> str:
    """Deterministic subject-level split from a hash of ``source/subject`` (uniform in [0, 1))."""
    digest = hashlib.sha256(f"{source}/{subject}".encode()).digest()
    u = int.from_bytes(digest[:8], "big") / 2**64
    edge = 0.0
    for name, fraction in fractions:
        edge += fraction
        if u < edge:
            return name
    return fractions[-1][0]


@dataclass(frozen=True)
class ClipRecord:
    """Manifest entry of one cached clip."""

    clip_id: str
    source: str
    subject: str
    split: str
    labels: dict
    profile: dict
    offset: int
    n_frames: int
    start_time: float
    file: str


def _relative(path: Path, root: Path) -> str:
    try:
        return str(path.resolve().relative_to(root.resolve()))
    except ValueError:
        return path.name


PLACEMENT_MODEL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"


def _placement_model(data_root: Path):
    """The canonical model used to put clips on the floor, or None when the data root lacks it."""
    from biomotion.body.model import BodyModel

    path = data_root / PLACEMENT_MODEL
    return BodyModel.from_osim(path) if path.exists() else None


def _load_motion(spec) -> Motion:
    return SOURCES[spec.source].load_motion(spec)


def _load_thread_limited(spec) -> Motion:
    import torch

    torch.set_num_threads(1)
    return _load_motion(spec)


def _motions(specs: list, workers: int, progress: bool) -> Iterable[Motion]:
    """Each clip's motion in order; when clips must be solved by IK (minutes for a few hundred BVH clips), by
    ``workers`` processes."""
    heavy = sum(spec.retargeted for spec in specs)
    bar = tqdm(total=len(specs), desc="building dataset cache", unit="clip", disable=not progress)
    if workers > 1 and heavy > workers:
        context = multiprocessing.get_context("spawn")  # torch's thread pools do not survive a fork
        with ProcessPoolExecutor(workers, mp_context=context) as pool:
            for motion in pool.map(_load_thread_limited, specs, chunksize=4):
                bar.update()
                yield motion
    else:
        for spec in specs:
            bar.update()
            yield _load_motion(spec)
    bar.close()


def build_cache(
    data_root: str | Path,
    out: str | Path,
    *,
    rate: float = DEFAULT_RATE,
    sources: Iterable[str] | None = None,
    progress: bool = True,
    workers: int | None = None,
    exclude_subjects: Collection[str] = (),
) -> dict:
    """Build the cache in ``out`` from every source present under ``data_root``; returns the manifest.

    ``exclude_subjects`` ("source/subject" keys) leaves those people's clips out unread (`biomotion eval
    generation` needs only the subjects a model never saw, and retargeting the others would cost minutes).

    A clip that fails to load stops the build with its file named (malformed data is an error, not a skip);
    sources absent from the data root are listed under ``skipped``. Files are written atomically, the manifest
    last, so a folder with a manifest always holds a complete cache. Retargeted clips are loaded by ``workers``
    processes (default: one per CPU).
    """
    data_root, out = Path(data_root), Path(out)
    started = time.perf_counter()
    specs, skipped = discover_all(data_root, sources)
    excluded = set(exclude_subjects)
    kept = [spec for spec in specs if f"{spec.source}/{spec.subject}" not in excluded]
    if specs and not kept:
        raise BiomotionError(f"every clip under {data_root} belongs to an excluded subject ({len(excluded)} excluded)")
    specs = kept
    if not specs:
        raise BiomotionError(f"no clips found under {data_root}; skipped: {'; '.join(skipped) or 'none'}")
    model = _placement_model(data_root)
    chunks: list[np.ndarray] = []
    masks: list[np.ndarray] = []
    records: list[ClipRecord] = []
    offset = 0
    for spec, motion in zip(specs, _motions(specs, workers or os.cpu_count() or 1, progress)):
        source = SOURCES[spec.source]
        labels = spec.labels
        if source.overground and labels.speed is None and labels.action in ("walk", "run"):
            labels = replace(labels, speed=round(forward_speed(motion), 3))
        clip = motion.resample(rate) if abs(motion.rate - rate) > 1e-6 else motion
        if model is not None:
            clip = place_clip(
                clip, model, height=spec.profile.height, treadmill_speed=labels.speed if source.treadmill else None
            )
        if not np.all(np.isfinite(clip.values[:, clip.mask])):
            raise DataFormatError(spec.path, "non-finite coordinate values after resampling")
        chunks.append(clip.values.astype(np.float32))
        masks.append(clip.mask.astype(np.uint8))
        records.append(
            ClipRecord(
                clip_id=spec.clip_id,
                source=spec.source,
                subject=spec.subject,
                split=subject_split(spec.source, spec.subject),
                labels=asdict(labels),
                profile=spec.profile.to_dict(),
                offset=offset,
                n_frames=clip.n_frames,
                start_time=float(clip.times[0]),
                file=_relative(spec.path, data_root),
            )
        )
        offset += clip.n_frames
    from safetensors.numpy import save_file

    out.mkdir(parents=True, exist_ok=True)
    arrays = {"values": np.concatenate(chunks, axis=0), "masks": np.stack(masks)}
    tmp = out / f".{ARRAYS}.tmp"
    save_file(arrays, str(tmp))
    tmp.replace(out / ARRAYS)
    bounds = _write_bounds(out, chunks, masks, records, rate, model)
    manifest = {
        "format": "biomotion-dataset-cache/1",
        "bounds": bounds,
        "rate_hz": rate,
        "coordinates": list(CANONICAL_COORDINATES),
        "units": "rad for rotations, m for pelvis_tx/ty/tz; OpenSim ground frame (y up)",
        "placement": (
            "pelvis translations at the generic 1.70 m size, treadmill made overground, start at the "
            "origin, feet on y = 0 (biomotion.data.placement)"
            if model is not None
            else f"none: {PLACEMENT_MODEL} absent from the data root, translations as recorded"
        ),
        "split_rule": "sha256(source/subject) -> train 70 %, val 15 %, test 15 %, by subject",
        "counts": _counts(records),
        "skipped_sources": skipped,
        "build_seconds": round(time.perf_counter() - started, 2),
        "clips": [asdict(r) for r in records],
    }
    with atomic_write(out / MANIFEST) as handle:
        json.dump(manifest, handle, indent=1)
    return manifest


def _write_bounds(
    out: Path, chunks: list[np.ndarray], masks: list[np.ndarray], records: list[ClipRecord], rate: float, model=None
) -> dict[str, str]:
    """5th/95th percentile bounds of coordinates and coordinate speeds over the training split's clips
    (PG-BIG Sec. 3.3, Table 1: the guidance and plausibility metrics share them), and with the canonical
    ``model`` those of COM speed and acceleration magnitude (forward differences, as
    `biomotion.metrics.plausibility`); written beside the cache. Muscle-activation bounds need static
    optimization and are written with its labels (`biomotion.training.surrogate_labels`)."""
    from biomotion.metrics.bounds import PercentileBounds

    train = [i for i, r in enumerate(records) if r.split == "train"] or list(range(len(records)))
    values = np.concatenate([chunks[i] for i in train])
    speeds = np.concatenate(
        [
            np.gradient(chunks[i], 1.0 / rate, axis=0) if len(chunks[i]) > 1 else np.full_like(chunks[i], np.nan)
            for i in train
        ]
    )
    mask = np.concatenate([np.broadcast_to(masks[i].astype(bool), chunks[i].shape) for i in train])
    files = {}
    for name, array, unit in (("coordinates", values, "rad or m"), ("coordinate_speeds", speeds, "rad/s or m/s")):
        bounds = PercentileBounds.from_samples(array, CANONICAL_COORDINATES, mask=mask, quantity=name, unit=unit)
        bounds.save(out / f"bounds_{name}.json")
        files[name] = f"bounds_{name}.json"
    if model is not None:
        values, keep = _com_terms(model, [chunks[i] for i in train], [masks[i] for i in train], rate)
        bounds = PercentileBounds.from_samples(
            values, ("com_speed", "com_acceleration"), mask=keep, quantity="com", unit="m/s and m/s^2"
        )
        bounds.save(out / "bounds_com.json")
        files["com"] = "bounds_com.json"
    return files


def _com_terms(model, chunks: list[np.ndarray], masks: list[np.ndarray], rate: float) -> tuple[np.ndarray, np.ndarray]:
    """[N, 2] COM speed and acceleration magnitude per frame pair / triple of every clip, and their mask (the
    acceleration column has one sample fewer per clip)."""
    import torch

    from biomotion.body.kinematics import center_of_mass
    from biomotion.metrics.plausibility import com_acceleration, com_speed

    defaults = model.defaults.numpy()
    rows, keep = [], []
    for chunk, mask in zip(chunks, masks):
        if len(chunk) < 3:
            continue
        full = np.where(mask.astype(bool)[None], chunk, defaults[None]).astype(np.float64)
        with torch.no_grad():
            com = center_of_mass(model, torch.from_numpy(full))
        speed = com_speed(com, rate)[:, 0].numpy()
        acceleration = np.append(com_acceleration(com, rate)[:, 0].numpy(), np.nan)
        rows.append(np.stack([speed, acceleration], -1))
        keep.append(np.stack([np.ones_like(speed, bool), np.isfinite(acceleration)], -1))
    values, mask = np.concatenate(rows), np.concatenate(keep)
    return np.nan_to_num(values), mask


def _counts(records: list[ClipRecord]) -> dict:
    per_subject = Counter(f"{r.source}/{r.subject}" for r in records)
    return {
        "clips": len(records),
        "frames": int(sum(r.n_frames for r in records)),
        "per_source": dict(Counter(r.source for r in records)),
        "subjects_per_source": dict(Counter(key.split("/")[0] for key in per_subject)),
        "per_subject": dict(per_subject),
        "per_action": dict(Counter(f"{r.source}/{r.labels['action']}" for r in records)),
        "per_split": dict(Counter(r.split for r in records)),
        "subjects_per_split": dict(Counter(subject_split(*key.split("/", 1)) for key in per_subject)),
    }


def manifest_markdown(manifest: dict, command: str) -> str:
    """Counts of a built cache as Markdown: per source, per action, per split."""
    counts = manifest["counts"]
    lines = [
        f"# Dataset cache: {counts['clips']} clips, {counts['frames']} frames at {manifest['rate_hz']:g} Hz",
        "",
        f"Produced by `{command}` in {manifest['build_seconds']} s. Split rule: {manifest['split_rule']}. "
        f"Skipped: {', '.join(manifest['skipped_sources']) or 'nothing'}.",
        "",
        "| source | clips | subjects |",
        "|---|---|---|",
    ]
    lines += [f"| {s} | {n} | {counts['subjects_per_source'][s]} |" for s, n in counts["per_source"].items()]
    lines += ["", "| source/action | clips |", "|---|---|"]
    lines += [f"| {a} | {n} |" for a, n in counts["per_action"].items()]
    lines += ["", "| split | clips | subjects |", "|---|---|---|"]
    lines += [f"| {s} | {n} | {counts['subjects_per_split'].get(s, 0)} |" for s, n in counts["per_split"].items()]
    return "\n".join(lines) + "\n"


class DatasetCache:
    """Read access to a built cache: clips as `Motion` (canonical coordinates, masks), filtered by split/source."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        manifest_path = self.folder / MANIFEST
        if not manifest_path.exists():
            raise BiomotionError(
                f"{self.folder} is not a dataset cache (no {MANIFEST}); build one with `biomotion data build`"
            )
        try:
            self.manifest = json.loads(manifest_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise DataFormatError(
                manifest_path,
                f"not valid JSON ({error}): a damaged cache; build it again with `biomotion data build`",
                line=getattr(error, "lineno", None),
            ) from None
        missing = [
            key
            for key in ("clips", "rate_hz", "coordinates")
            if not isinstance(self.manifest, dict) or key not in self.manifest
        ]
        if missing:
            raise DataFormatError(manifest_path, f"not a dataset-cache manifest: no {', '.join(missing)}")
        from biomotion.io.tensors import read_tensors

        arrays = read_tensors(self.folder / ARRAYS, "dataset cache arrays", numpy=True)
        absent = [key for key in ("values", "masks") if key not in arrays]
        if absent:
            raise DataFormatError(self.folder / ARRAYS, f"not dataset cache arrays: no {', '.join(absent)}")
        self.values = arrays["values"]
        self.masks = arrays["masks"].astype(bool)
        self.records = self.manifest["clips"]
        self.rate = float(self.manifest["rate_hz"])
        self.coordinates = tuple(self.manifest["coordinates"])

    def __len__(self) -> int:
        return len(self.records)

    def indices(self, split: str | None = None, source: str | None = None, action: str | None = None) -> list[int]:
        return [
            i
            for i, r in enumerate(self.records)
            if (split is None or r["split"] == split)
            and (source is None or r["source"] == source)
            and (action is None or r["labels"]["action"] == action)
        ]

    def motion(self, index: int) -> Motion:
        record = self.records[index]
        values = self.values[record["offset"] : record["offset"] + record["n_frames"]].astype(np.float64)
        times = record["start_time"] + np.arange(record["n_frames"]) / self.rate
        return Motion(times=times, names=self.coordinates, values=values, mask=self.masks[index])

    def labels(self, index: int) -> Labels:
        return Labels(**self.records[index]["labels"])

    def profile(self, index: int) -> Profile:
        return Profile.from_dict(self.records[index]["profile"])
