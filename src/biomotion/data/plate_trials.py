"""Trials with force plates under a data root, analysed once into the arrays a learned ground-reaction model is
trained and scored on (`biomotion.models.ground_forces`), cached on disk.

Sources (whatever subjects a data root holds; nothing depends on which are present):

- ``fukuchi-running``: every runner's treadmill trials at 2.5, 3.5 and 4.5 m/s (``c3d/<r>runT25|35|45.c3d``, one
  plate carrying both feet), on ``<r>/<r>_simple.osim`` with the shipped IK ``ik/<speed>/<r>_<speed>_ik_simple.mot``
  or, for a runner with only captures, the C3D solved by the source's own chain (`biomotion.data.fukuchi_chain`,
  as `biomotion validate dynamics` does). Category ``running``.
- development trials, never trained on nor scored by the evaluation (`development_trials`): gait2392 subject01's
  walk (``opensim-models/Pipelines/Gait2392_Simbody``, head, arms and trunk one body) and Hamner 2013 subject01
  running at 5 m/s (a full-body model with arms), the two trials the contact model's settings were chosen on
  (`biomotion.body.contact.ContactSettings`). Design choices of the learned model that concern other models and
  activities than the Fukuchi runners are checked on them (docs/decisions/learned-grf.md).
- ``opencap/<subject>``: every trial with ``IK/<trial>_ik.mot`` and ``ID/<trial>_grf.mot`` on
  ``Models/optimized_scale_and_markers.osim`` (static trials left out), one plate per foot. Categories
  ``walking``, ``drop jump``, ``squat``, ``sit-to-stand`` from the trial name.

`trial_samples` runs `biomotion.analysis.chain.analyze` with the plates (coordinates low-passed at 10 Hz, as the
GRF check of ``validate dynamics``), then `biomotion.analysis.ground_features.ground_features`, and keeps, on the
motion's frames: the features, the plates assigned to the feet (`assign_to_feet`; on the treadmill one foot at a
time, since running has no double support), the frames fit for comparison (`plate_frames`) and the physics-only
contact solve. The result is cached under ``~/.cache/biomotion/ground_forces/`` (``$XDG_CACHE_HOME`` respected),
keyed by the input files' paths, sizes and modification times and `SAMPLES_VERSION`.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from biomotion.analysis.chain import analyze, plate_frames
from biomotion.analysis.ground_features import GroundFeatures, ground_features
from biomotion.body.model import BodyModel
from biomotion.data.fukuchi_chain import FUKUCHI, runner_files
from biomotion.data.sources import OPENCAP_MODEL_FILE
from biomotion.io.atomic import atomic_write
from biomotion.io.c3d import read_c3d_forces
from biomotion.io.mot import read_ground_reaction, read_motion
from biomotion.motion import GroundReaction, Motion

SPEEDS = ("T25", "T35", "T45")
OPENCAP = "opencap"
#: the low-pass of the coordinates before differentiation, as ``validate dynamics`` compares GRF at
CUTOFF_HZ = 10.0
#: bump when the features or the stored arrays change: old cache entries are then not read
SAMPLES_VERSION = 2
#: OpenCap trial-name prefixes and their category (first match wins)
CATEGORIES = (("walking", "walking"), ("DJ", "drop jump"), ("squats", "squat"), ("STS", "sit-to-stand"))


@dataclass(frozen=True)
class PlateTrial:
    """One trial with plates: ``name`` (``fukuchi/RBDS001/T35``), source, subject, category, the model file, the
    files it is read from (for the cache key) and loaders of its motion and plates."""

    name: str
    source: str
    subject: str
    category: str
    model: Path
    files: tuple[Path, ...]
    load_motion: Callable[[], Motion]
    load_forces: Callable[[], GroundReaction]


def cache_folder() -> Path:
    """``~/.cache/biomotion/ground_forces`` (or under ``$XDG_CACHE_HOME``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "biomotion" / "ground_forces"


def _fukuchi_chain_motion(base: Path, runner: str, speed: str) -> Motion:
    from biomotion.data.fukuchi_chain import as_simple, solve_trial

    result, _ = solve_trial(base, runner, speed)
    return as_simple(result.motion)


def fukuchi_trials(data_root: Path, speeds: tuple[str, ...] = SPEEDS) -> tuple[list[PlateTrial], list[str]]:
    """Every Fukuchi running trial with a plate (C3D) and a motion (shipped IK or the source chain), and what was
    skipped and why."""
    base = Path(data_root) / FUKUCHI
    trials, skipped = [], []
    for speed in speeds:
        for c3d in sorted(base.glob(f"c3d/*run{speed}.c3d")):
            runner = c3d.name.removesuffix(f"run{speed}.c3d")
            files = runner_files(base, runner, speed)
            model = base / runner / f"{runner}_simple.osim"
            ik = files["reference"]
            chain = [k for k in ("generic", "scale_setup", "ik_setup", "static") if not files[k].exists()]
            name = f"fukuchi/{runner}/{speed}"
            if not model.exists():
                skipped.append(f"{name}: no {model.relative_to(base)}")
                continue
            if ik.exists():
                load_motion = lambda p=ik: read_motion(p)
                inputs = (model, ik, c3d)
            elif not chain:
                load_motion = lambda r=runner, s=speed: _fukuchi_chain_motion(base, r, s)
                inputs = (model, c3d, *(files[k] for k in ("generic", "scale_setup", "ik_setup", "static")))
                name += " (C3D, source chain)"
            else:
                skipped.append(f"{name}: no {ik.relative_to(base)}, and the chain lacks {', '.join(chain)}")
                continue
            trials.append(
                PlateTrial(
                    name, "fukuchi", runner, "running", model, inputs, load_motion, lambda c=c3d: read_c3d_forces(c)
                )
            )
    return trials, skipped


#: (name, category, model, motion, plates) of the development trials, relative to the data root
DEVELOPMENT = (
    (
        "gait2392/subject01/walk1",
        "walking",
        "opensim-models/Pipelines/Gait2392_Simbody/OutputReference/subject01_simbody.osim",
        "opensim-models/Pipelines/Gait2392_Simbody/subject01_walk1_ik.mot",
        "opensim-models/Pipelines/Gait2392_Simbody/subject01_walk1_grf.mot",
    ),
    (
        "hamner/subject01/Run_5",
        "running",
        "Hamner2013/subject01/subject01_adjusted_scaled.osim",
        "Hamner2013/subject01/Run_5.mot",
        "Hamner2013/subject01/Run_5_grf.mot",
    ),
)


def development_trials(data_root: Path) -> list[PlateTrial]:
    """The development trials (module docstring) present under ``data_root``."""
    trials = []
    for name, category, *relative in DEVELOPMENT:
        model, motion, plates = (Path(data_root) / r for r in relative)
        if model.exists() and motion.exists() and plates.exists():
            source, subject, _ = name.split("/")
            trials.append(
                PlateTrial(
                    name,
                    source,
                    subject,
                    category,
                    model,
                    (model, motion, plates),
                    lambda p=motion: read_motion(p),
                    lambda g=plates: read_ground_reaction(g),
                )
            )
    return trials


def opencap_category(trial: str) -> str | None:
    """``walking``, ``drop jump``, ``squat``, ``sit-to-stand`` from an OpenCap trial name; None for others."""
    return next((category for prefix, category in CATEGORIES if trial.startswith(prefix)), None)


def opencap_trials(data_root: Path) -> tuple[list[PlateTrial], list[str]]:
    """Every OpenCap trial with IK and plates, of every subject folder under ``opencap/`` with the scaled model;
    static and unknown activities are listed as skipped."""
    trials, skipped = [], []
    for folder in sorted(p for p in (Path(data_root) / OPENCAP).glob("*") if (p / OPENCAP_MODEL_FILE).is_file()):
        for grf in sorted((folder / "ID").glob("*_grf.mot")):
            trial = grf.name.removesuffix("_grf.mot")
            ik = folder / "IK" / f"{trial}_ik.mot"
            category = opencap_category(trial)
            name = f"{OPENCAP}/{folder.name}/{trial}"
            if not ik.exists() or category is None:
                if not trial.startswith("static"):
                    skipped.append(f"{name}: {'no IK' if not ik.exists() else 'activity not known'}")
                continue
            model = folder / OPENCAP_MODEL_FILE
            trials.append(
                PlateTrial(
                    name,
                    OPENCAP,
                    folder.name,
                    category,
                    model,
                    (model, ik, grf),
                    lambda p=ik: read_motion(p),
                    lambda g=grf: read_ground_reaction(g),
                )
            )
    return trials, skipped


@dataclass(frozen=True)
class TrialSamples:
    """A trial's arrays on its motion frames (SI unless said).

    Attributes:
        times: [T] s. features: [T, F] (`biomotion.analysis.ground_features.FEATURE_NAMES`). forward: [T, 3]
        heading. baseline: [T, 3] m(g + a_COM) in BW, (forward, up, right). heel, toe: [T, 2, 3] foot axis ends.
        measured: [T, 2, 3] N, plates per foot (right, left). measured_cop: [T, 2, 3] m (NaN unloaded).
        inferred: [T, 2, 3] N, the physics-only contact solve per foot. keep: [T] bool, `plate_frames`.
        leg_length: m. body_weight: N. mass: kg.
    """

    times: np.ndarray
    features: np.ndarray
    forward: np.ndarray
    baseline: np.ndarray
    heel: np.ndarray
    toe: np.ndarray
    measured: np.ndarray
    measured_cop: np.ndarray
    inferred: np.ndarray
    keep: np.ndarray
    leg_length: float
    body_weight: float
    mass: float

    @property
    def ground(self) -> GroundFeatures:
        """The features as `GroundFeatures` (what a predictor takes)."""
        return GroundFeatures(
            self.times,
            self.features,
            self.forward,
            self.baseline,
            self.heel,
            self.toe,
            self.leg_length,
            self.body_weight,
        )


def samples_key(trial: PlateTrial, cutoff_hz: float = CUTOFF_HZ) -> str:
    """The cache key of a trial's samples: its files' paths, sizes and modification times, the cutoff and
    `SAMPLES_VERSION`."""
    stamp = [(str(p.resolve()), p.stat().st_size, p.stat().st_mtime_ns) for p in trial.files]
    text = json.dumps({"files": stamp, "cutoff": cutoff_hz, "version": SAMPLES_VERSION})
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def trial_samples(trial: PlateTrial, cutoff_hz: float = CUTOFF_HZ, cache: bool = True) -> TrialSamples:
    """`TrialSamples` of ``trial`` (module docstring), from the cache when it holds them."""
    path = cache_folder() / f"{samples_key(trial, cutoff_hz)}.npz"
    if cache and path.is_file():
        with np.load(path) as stored:
            arrays = {f.name: stored[f.name] for f in fields(TrialSamples)}
        return TrialSamples(**{k: (float(v) if v.ndim == 0 else v) for k, v in arrays.items()})
    model = BodyModel.from_osim(trial.model)
    motion = trial.load_motion()
    forces = trial.load_forces().slice(motion.times[0] - 0.1, motion.times[-1] + 0.1)
    result = analyze(motion, model, forces, cutoff_hz=cutoff_hz)
    features = ground_features(result)
    samples = TrialSamples(
        times=features.times,
        features=features.values.astype(np.float32),
        forward=features.forward,
        baseline=features.baseline,
        heel=features.heel,
        toe=features.toe,
        measured=result.measured.force,
        measured_cop=result.measured.cop,
        inferred=result.inferred.force,
        keep=plate_frames(result),
        leg_length=features.leg_length,
        body_weight=features.body_weight,
        mass=float(model.total_mass),
    )
    if cache:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(path, "wb") as handle:
            np.savez_compressed(handle, **{f.name: np.asarray(getattr(samples, f.name)) for f in fields(samples)})
    return samples
