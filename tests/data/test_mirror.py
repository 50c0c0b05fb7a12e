"""The mirror image of a canonical pose is the reflection of the pose, body by body (forward kinematics)."""

from __future__ import annotations

import numpy as np
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.body.kinematics import forward_kinematics
from biomotion.body.mirror import mirror_coordinates, mirror_labels, other_side
from biomotion.body.model import BodyModel
from tests.conftest import data_path


def test_mirrored_pose_is_the_reflection_of_the_pose():
    model = BodyModel.from_osim(data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim"))
    assert model.coordinate_names == CANONICAL_COORDINATES
    rng = np.random.default_rng(0)
    ranges = model.ranges.numpy()
    low, high = np.maximum(ranges[:, 0], -1.0), np.minimum(ranges[:, 1], 1.0)
    q = rng.uniform(low, high, size=(20, len(low)))
    q[:, 3:6] = rng.normal(0.0, 0.5, size=(20, 3))
    mirrored, _ = mirror_coordinates(q)
    poses = forward_kinematics(model, torch.from_numpy(q))
    poses_m = forward_kinematics(model, torch.from_numpy(mirrored))
    names = model.body_names
    reflect = torch.tensor([1.0, 1.0, -1.0], dtype=torch.float64)
    for i, name in enumerate(names):
        j = names.index(other_side(name)) if other_side(name) in names else i
        # body origins: the mirrored pose's body j sits at the reflection of the pose's body i (to 1e-9 m)
        torch.testing.assert_close(poses_m.positions[:, j], poses.positions[:, i] * reflect, atol=1e-9, rtol=0)


def test_mirror_is_an_involution_and_swaps_labels():
    q = np.random.default_rng(1).normal(size=(5, len(CANONICAL_COORDINATES)))
    mask = np.zeros(len(CANONICAL_COORDINATES), bool)
    mask[CANONICAL_COORDINATES.index("arm_flex_r")] = True
    twice, mask_twice = mirror_coordinates(*mirror_coordinates(q, mask))
    np.testing.assert_array_equal(twice, q)
    np.testing.assert_array_equal(mask_twice, mask)
    assert mirror_coordinates(q, mask)[1][CANONICAL_COORDINATES.index("arm_flex_l")]
    labels = np.array([[0.1, 0.2, 0.3]])
    np.testing.assert_array_equal(mirror_labels(labels, ("soleus_r", "soleus_l", "x")), [[0.2, 0.1, 0.3]])
