"""The physics core: an OpenSim model as tensors, batched forward kinematics, scaling and rigid-body dynamics.

All torch, batched over leading dimensions, differentiable; validated against OpenSim 4.6 (see tests/body).
"""

from biomotion.body.dynamics import ExternalLoad, bias_forces, inverse_dynamics, mass_matrix
from biomotion.body.kinematics import (
    BodyPoses,
    apply_couplers,
    body_coms,
    center_of_mass,
    forward_kinematics,
    joint_centers,
    marker_jacobians,
    marker_positions,
    point_jacobians,
    points_in_ground,
)
from biomotion.body.model import BodyModel
from biomotion.body.scaling.bodies import scale_factors, scale_model, scale_model_from_file

__all__ = [
    "BodyModel",
    "BodyPoses",
    "ExternalLoad",
    "forward_kinematics",
    "marker_positions",
    "joint_centers",
    "body_coms",
    "center_of_mass",
    "points_in_ground",
    "point_jacobians",
    "marker_jacobians",
    "apply_couplers",
    "mass_matrix",
    "bias_forces",
    "inverse_dynamics",
    "scale_factors",
    "scale_model",
    "scale_model_from_file",
]
