"""Muscles: path geometry (lengths, moment arms), muscle parameters and curves, batched static optimization.

Nothing here needs OpenSim at run time; `biomotion.training.fit_paths` (a build step) and
`biomotion.validation.muscles` use it as the oracle (through `biomotion.muscles.opensim_paths`).
"""

from biomotion.muscles.geometry import MusclePaths, PathGroup, shipped_paths
from biomotion.muscles.properties import (
    MuscleParameters,
    max_active_force,
    passive_force,
    read_muscles,
)
from biomotion.muscles.static_optimization import (
    StaticOptimizationResult,
    optimize_activations,
    solve_static_optimization,
)

__all__ = [
    "MuscleParameters",
    "MusclePaths",
    "PathGroup",
    "StaticOptimizationResult",
    "max_active_force",
    "optimize_activations",
    "passive_force",
    "read_muscles",
    "shipped_paths",
    "solve_static_optimization",
]
