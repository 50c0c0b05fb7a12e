"""Muscles: path geometry (lengths, moment arms), muscle parameters and curves, batched static optimization.

Nothing here needs OpenSim at run time; `biomotion.muscles.fit_paths` (a build step) and
`biomotion.muscles.validation` use it as the oracle.
"""

from pathlib import Path

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


def validate_muscles(data_root: str | Path, poses: int = 200) -> dict:
    """Moment-arm and static-optimization figures against OpenSim (see `biomotion.muscles.validation`)."""
    from biomotion.muscles.validation import validate_muscles as run

    return run(data_root, poses)


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
    "validate_muscles",
]
