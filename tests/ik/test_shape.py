"""`shape_from_bvh`: a Bandai-Namco actor's skeleton as a `Shape` of Rajagopal 2016 (the HUMOS identity from a
BVH). Truth: the factors the skeleton retargeting fits for the same clip, and the skeleton's own bone lengths."""

import numpy as np
import pytest
import torch

from biomotion.body.model import BodyModel
from biomotion.body.shape import segment_lengths
from biomotion.ik.shape import shape_from_bvh
from biomotion.ik.skeleton import BANDAI_NAMCO, face_forward, joint_positions, segment_scales
from biomotion.io.bvh import read_bvh
from tests.conftest import data_path

torch.set_num_threads(1)

RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
WALK = "bandai-namco/dataset-2/dataset-2_walk_normal_016.bvh.gz"


def test_bvh_shape_is_the_retargeting_scale():
    generic = BodyModel.from_osim(data_path(RAJAGOPAL))
    shape = shape_from_bvh(data_path(WALK), generic, mass=70.0, height=1.75)
    source = joint_positions(read_bvh(data_path(WALK)))
    source = face_forward(source.select(BANDAI_NAMCO.source_joints()), BANDAI_NAMCO)
    fitted = segment_scales(generic.to(torch.float64), source, BANDAI_NAMCO)
    for body in generic.body_names:
        np.testing.assert_allclose(shape.scales[body], fitted[body], rtol=1e-12)
    assert shape.mass == 70.0 and shape.height == 1.75 and shape.reference == generic.name
    model = shape.to_model(generic)
    assert float(model.total_mass) == pytest.approx(70.0, rel=1e-12)
    # the scaled thigh is the skeleton's hip-knee bone (median over frames), within 1 mm
    hip, knee = source["UpperLeg_R"], source["LowerLeg_R"]
    bone = float(np.median(np.linalg.norm(hip - knee, axis=-1)))
    assert shape.lengths["femur_r"] == pytest.approx(segment_lengths(model)["femur_r"], rel=1e-12)
    hip_to_knee = next(j for j in model.joints if j.name == "walker_knee_r").parent_translation
    assert float(torch.linalg.vector_norm(hip_to_knee)) == pytest.approx(bone, abs=1e-3)
