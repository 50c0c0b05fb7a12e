"""Static-optimization activations of canonical clips on the generic Rajagopal 2016 model: the muscle surrogate's
labels (PG-BIG Sec. 3.3, App. A.3, A.8) and the EMG check's predictions.

One clip at a time: absent coordinates filled, the lab chain (`biomotion.analysis.chain.analyze`, inferred ground
reaction) for the inverse-dynamics torques, then static optimization of every frame at once with reserves
(`biomotion.muscles.static_optimization`), plus the whole-body COM position, velocity and acceleration.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.errors import BiomotionError, ModelError
from biomotion.motion import Motion
from biomotion.muscles.geometry import MusclePaths, balanced_coordinates, shipped_paths
from biomotion.muscles.properties import MuscleParameters, read_muscles
from biomotion.muscles.static_optimization import StaticOptimizationResult, optimize_activations

MODEL_FILE = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"


@dataclass(frozen=True)
class LabelSettings:
    """Static-optimization settings of the labels (squared activations as OpenSim's default)."""

    cutoff_hz: float = 6.0
    exponent: float = 2.0
    reserve_optimal_force: float = 10.0  # N·m per unit control
    reserve_bound: float = 100.0  # |control| <= 100: up to 1000 N·m
    tolerance: float = 1e-6  # N·m on the torque balance
    max_iterations: int = 200
    # the contact gate's width of the inferred ground reaction the torques come from, pinned at the value the
    # shipped surrogate's labels were made with (`ContactSettings.height_scale` is 0.01; docs/decisions/inferred-grf.md)
    contact_height_scale: float = 0.02


@dataclass(frozen=True)
class Labeler:
    """Everything needed to label one clip: the Rajagopal body model, muscle paths and parameters, settings."""

    model: object  # biomotion.body.model.BodyModel
    paths: MusclePaths
    muscles: MuscleParameters
    coordinates: tuple[str, ...]  # balanced coordinates
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
        muscles = read_muscles(path).select(paths.muscle_names)
        coordinates = balanced_coordinates(paths, model)
        return cls(model, paths, muscles, coordinates, muscles.kind, settings)

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
        q, qd, torques, _ = self._prepare(motion)
        return q, qd, torques

    def label(self, motion: Motion) -> tuple[StaticOptimizationResult, np.ndarray]:
        """Static optimization of one clip and its whole-body COM position, velocity and acceleration [T, 9]
        (m, m/s, m/s², ground frame of the generic model, from the same filtered coordinates)."""
        q, qd, torques, com = self._prepare(motion)
        return self.solve(q, qd, torques), com

    def _prepare(self, motion: Motion) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, np.ndarray]:
        from biomotion.analysis.chain import analyze, model_motion
        from biomotion.body.contact import ContactSettings

        motion = self.prepare(motion)
        cutoff = self.settings.cutoff_hz
        result = analyze(
            motion,
            self.model,
            cutoff_hz=cutoff,
            contact=ContactSettings(height_scale=self.settings.contact_height_scale),
        )
        coordinates = model_motion(motion, self.model)  # the same preparation analyze did, for qdot
        if cutoff and coordinates.n_frames > 15:
            coordinates, qd, _ = coordinates.smoothed(cutoff)
        else:
            qd, _ = coordinates.derivatives()
        q = torch.tensor(result.motion.values, dtype=torch.float64)
        qd = torch.tensor(np.ascontiguousarray(qd), dtype=torch.float64)
        torques = torch.tensor(result.torques, dtype=torch.float64)[:, self.paths.select(self.coordinates)]
        com = np.concatenate([result.com, result.com_velocity, result.com_acceleration], axis=1)
        return q, qd, torques, com

    def solve(self, q: torch.Tensor, qd: torch.Tensor, torques: torch.Tensor) -> StaticOptimizationResult:
        """Static optimization of every frame at once."""
        s = self.settings
        return optimize_activations(
            self.paths,
            self.muscles,
            q,
            qd,
            torques,
            self.coordinates,
            s.reserve_optimal_force,
            exponent=s.exponent,
            reserve_bound=s.reserve_bound,
            tolerance=s.tolerance,
            max_iterations=s.max_iterations,
        )

    def __call__(self, motion: Motion) -> StaticOptimizationResult:
        """Labels of one clip (canonical coordinates, any frame count >= 2)."""
        return self.solve(*self.kinematics_and_torques(motion))
