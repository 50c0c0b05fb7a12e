"""Marker inverse kinematics and static calibration.

- `solve_ik`: OpenSim's IK objective (marker weights, coordinate tasks, clamped ranges, locked and coupled
  coordinates, occluded markers) solved for every frame at once with batched Levenberg-Marquardt in torch;
- `scale_static`: OpenSim's ScaleTool (measurement scale factors, marker placement on a static trial, or PG-BIG's
  percentile-trimmed registration) and `write_scaled_osim` for a scaled model OpenSim loads;
- `read_ik_setup` / `read_scale_setup`: the OpenSim setup files that configure both.

Nothing here needs OpenSim; `biomotion.validation.ik` checks it against OpenSim as the oracle.
"""

from biomotion.body.scaling.osim_file import ScaleResult, write_scale_set, write_scaled_osim
from biomotion.ik.markers import IKResult, evaluate_ik, free_coordinates, solve_ik, tracked_markers
from biomotion.ik.scaling import (
    Placement,
    average_frames,
    body_scale_factors,
    frame_range,
    measurement_factors,
    place_markers,
    register_markers,
    scale_static,
)
from biomotion.io.setup import (
    CoordinateTask,
    IKSetup,
    Measurement,
    ScaleSetup,
    TaskSet,
    read_ik_setup,
    read_scale_setup,
)

__all__ = [
    "IKResult",
    "solve_ik",
    "evaluate_ik",
    "free_coordinates",
    "tracked_markers",
    "Placement",
    "ScaleResult",
    "scale_static",
    "body_scale_factors",
    "measurement_factors",
    "frame_range",
    "place_markers",
    "register_markers",
    "average_frames",
    "write_scaled_osim",
    "write_scale_set",
    "CoordinateTask",
    "IKSetup",
    "Measurement",
    "ScaleSetup",
    "TaskSet",
    "read_ik_setup",
    "read_scale_setup",
]
