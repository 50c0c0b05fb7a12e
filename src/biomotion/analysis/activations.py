"""Muscle activations of one analysed trial on its own model: ``biomotion analyze --muscles PATHS``.

The inverse-dynamics torques of `biomotion.analysis.chain.analyze` (measured plates when given, the inferred ground
reaction otherwise) are balanced by the model's muscles with the batched static optimization of
`biomotion.muscles.static_optimization` (Crowninshield & Brand 1981; OpenSim's ``StaticOptimization``): squared
activations, muscle forces from the model's own force-length-velocity curves and pennation (Thelen 2003 or
Millard 2012, read from the .osim), on every unlocked, independent coordinate some muscle spans, each with a reserve
actuator that is penalised like a muscle (`TrialSettings`) so the muscles carry what they can. Coordinates no muscle
spans (pelvis, arms) are not balanced; their torques stay in ``torques.sto``.

Muscle geometry comes from path functions fitted to the model's own OpenSim geometry
(`biomotion.training.fit_paths`, minutes per model, once): a scaled model's moment arms differ from the generic
model's, so paths fitted on another model file are used only with a warning, which `PathCheck` records. The shipped
files are the generic Rajagopal 2016 model (``rajagopal2016``) and OpenSim's gait2392 ``subject01_simbody.osim``
(``gait2392_subject01``); against OpenSim 4.6 the whole chain on that gait2392 walk agrees to a mean activation R²
of 0.994 (``benchmarks/analysis_chain.py``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.analysis.chain import Analysis
from biomotion.errors import ModelError
from biomotion.io.mot import write_storage
from biomotion.muscles.geometry import MusclePaths, balanced_coordinates, shipped_paths
from biomotion.muscles.properties import read_muscles
from biomotion.muscles.static_optimization import StaticOptimizationResult, optimize_activations


@dataclass(frozen=True)
class TrialSettings:
    """Static-optimization settings of a trial: squared activations, and on each balanced coordinate a weak reserve
    actuator (1 N·m per unit control, as OpenSim's reserve actuators are usually set up) penalised like a muscle, so
    it takes only what the muscles cannot give; its control bound lets it reach 1000 N·m where they cannot.
    (The surrogate labels use 10 N·m reserves, `LabelSettings`; on the gait2392 walk those take visible shares of
    the small muscles' torques, and the activations then drift from OpenSim's, which has no joint reserves there.)"""

    exponent: float = 2.0
    reserve_optimal_force: float = 1.0  # N·m (or N) per unit control
    reserve_bound: float = 1000.0  # |control|


@dataclass(frozen=True)
class PathCheck:
    """Whether the path functions were fitted on this very model file: ``verified`` (same SHA-256), or a
    ``warning`` saying why not (fitted on another file, or the file does not record its source)."""

    paths: str
    fitted_on: str
    verified: bool
    warning: str | None


def load_paths(spec: str | Path) -> tuple[MusclePaths, str]:
    """Path functions from a ``.safetensors`` file written by `biomotion.training.fit_paths`, or a shipped name."""
    path = Path(spec)
    if path.suffix == ".safetensors" or path.exists():
        if not path.exists():
            raise ModelError(f"muscle path file not found: {path}")
        return MusclePaths.load(path), str(path)
    return shipped_paths(str(spec)), f"shipped:{spec}"


def check_paths(paths: MusclePaths, label: str, model_path: str | Path, coordinate_names: tuple[str, ...]) -> PathCheck:
    """Refuse paths made for other coordinates; say whether they were fitted on ``model_path`` itself."""
    if tuple(paths.coordinate_names) != tuple(coordinate_names):
        missing = sorted(set(paths.coordinate_names) ^ set(coordinate_names))
        raise ModelError(
            f"{label}: its coordinates are not those of {model_path} (differing: {', '.join(missing) or 'the order'})"
        )
    source = paths.info.get("source", "an unnamed model")
    recorded = paths.info.get("source_sha256")
    if recorded is None:
        return PathCheck(label, source, False, f"{label} does not record which model file it was fitted on")
    if recorded != hashlib.sha256(Path(model_path).read_bytes()).hexdigest():
        return PathCheck(
            label,
            source,
            False,
            f"{label} was fitted on another model file ({source}); a differently scaled model has other "
            f"moment arms: fit paths for this one with `biomotion train paths --model "
            f"{model_path} --out PATHS.safetensors`",
        )
    return PathCheck(label, source, True, None)


def trial_activations(
    result: Analysis, model_path: str | Path, paths: MusclePaths, settings: TrialSettings = TrialSettings()
) -> StaticOptimizationResult:
    """Static optimization of every frame of ``result`` at once (see the module docstring)."""
    muscles = read_muscles(model_path).select(paths.muscle_names)
    coordinates = balanced_coordinates(paths, result.model)
    names = result.model.coordinate_names
    q = torch.from_numpy(np.ascontiguousarray(result.motion.values, dtype=np.float64))
    qd = torch.from_numpy(np.ascontiguousarray(result.velocities, dtype=np.float64))
    torques = torch.from_numpy(
        np.ascontiguousarray(result.torques[:, [names.index(c) for c in coordinates]], dtype=np.float64)
    )
    return optimize_activations(
        paths,
        muscles,
        q,
        qd,
        torques,
        coordinates,
        settings.reserve_optimal_force,
        exponent=settings.exponent,
        reserve_bound=settings.reserve_bound,
    )


def write_activations(path: str | Path, result: Analysis, solution: StaticOptimizationResult) -> Path:
    """OpenSim's StaticOptimization activation layout: time, one column per muscle, then one per reserve
    (``<coordinate>_reserve``, its control)."""
    labels = [*solution.muscle_names, *(f"{c}_reserve" for c in solution.coordinate_names)]
    values = torch.cat([solution.activations, solution.reserve_controls], -1).numpy()
    return write_storage(path, labels, result.motion.times, values, name="Static Optimization activations")


def activation_summary(solution: StaticOptimizationResult, check: PathCheck, settings: TrialSettings) -> dict:
    """What summary.json says about the muscles: paths used, balanced frames, reserve use per coordinate."""
    return {
        "paths": check.paths,
        "paths_fitted_on": check.fitted_on,
        "paths_verified_for_model": check.verified,
        "paths_warning": check.warning,
        "muscles": len(solution.muscle_names),
        "balanced_coordinates": list(solution.coordinate_names),
        "frames_balanced": int(solution.converged.sum()),
        "frames": int(solution.converged.numel()),
        "settings": {
            "exponent": settings.exponent,
            "reserve_optimal_force": settings.reserve_optimal_force,
            "reserve_bound": settings.reserve_bound,
        },
        "reserve_usage": solution.reserve_usage(),
    }
