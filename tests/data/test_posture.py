"""Marker-placement posture offsets (`biomotion.data.posture`): the pelvis turns, the thighs, shanks, feet and
trunk keep their place in the ground, the ranges are checked."""

import numpy as np
import pytest
import torch

from biomotion.body.kinematics import forward_kinematics
from biomotion.data.clips import body_model
from biomotion.data.posture import keeps_ranges, posture_offset, random_offsets
from biomotion.errors import ModelError
from biomotion.motion import Motion

KEPT = ("femur_r", "femur_l", "tibia_r", "tibia_l", "calcn_r", "toes_l")


@pytest.fixture(scope="module")
def model(data_root):
    return body_model(data_root)


def running_like(model, frames: int = 40, seed: int = 0) -> Motion:
    """Defaults plus smooth random swings of the pelvis, hips, knees and trunk, moving forward."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / 30.0
    values = np.repeat(model.defaults.numpy()[None], frames, 0)
    for name, amplitude in (
        ("pelvis_tilt", 0.1),
        ("pelvis_list", 0.05),
        ("pelvis_rotation", 0.1),
        ("hip_flexion_r", 0.6),
        ("hip_adduction_r", 0.1),
        ("hip_rotation_r", 0.2),
        ("hip_flexion_l", 0.6),
        ("hip_adduction_l", 0.1),
        ("hip_rotation_l", 0.2),
        ("knee_angle_r", 0.5),
        ("knee_angle_l", 0.5),
        ("lumbar_extension", 0.2),
        ("lumbar_bending", 0.1),
        ("lumbar_rotation", 0.1),
    ):
        c = model.coordinate_index(name)
        values[:, c] += amplitude * np.sin(2 * np.pi * 1.4 * t + rng.uniform(0, 2 * np.pi))
    values[:, model.coordinate_index("knee_angle_r")] += 0.6
    values[:, model.coordinate_index("knee_angle_l")] += 0.6
    values[:, model.coordinate_index("pelvis_tx")] = 3.5 * t
    values[:, model.coordinate_index("pelvis_ty")] = 0.95
    return Motion(times=t, names=model.coordinate_names, values=values)


def poses(model, motion):
    return forward_kinematics(model, torch.as_tensor(motion.values))


def test_pelvis_turns_and_the_rest_of_the_body_stays(model):
    motion = running_like(model)
    offsets = {"pelvis_tilt": 8.0, "pelvis_list": -2.0, "pelvis_rotation": 3.0}
    moved = posture_offset(motion, model, offsets)
    before, after = poses(model, motion), poses(model, moved)
    for body in KEPT + ("torso",):
        k = model.body_index(body)
        assert torch.allclose(before.rotations[:, k], after.rotations[:, k], atol=1e-12), body
    hips = [model.body_index("femur_r"), model.body_index("femur_l")]  # their origins are the hip centres
    assert torch.allclose(before.positions[:, hips].mean(1), after.positions[:, hips].mean(1), atol=1e-12)
    for body in KEPT:  # list and rotation move each hip centre about the midpoint: 7.7 cm x sin(3 deg) = 4 mm
        k = model.body_index(body)
        assert torch.allclose(before.positions[:, k], after.positions[:, k], atol=5e-3), body
    pelvis = model.body_index("pelvis")
    turn = before.rotations[:, pelvis].transpose(-1, -2) @ after.rotations[:, pelvis]
    angle = np.degrees(np.arccos(np.clip((turn.diagonal(dim1=-2, dim2=-1).sum(-1).numpy() - 1) / 2, -1, 1)))
    assert angle.min() > 7.0 and angle.max() < 10.0  # |(8, -2, 3)| = 8.8 deg
    np.testing.assert_allclose(moved["pelvis_tilt"] - motion["pelvis_tilt"], np.radians(8.0), atol=1e-12)


def test_hip_axial_offsets_and_an_absent_trunk(model):
    motion = running_like(model, seed=1)
    mask = motion.mask.copy()
    lumbar = [model.coordinate_index(f"lumbar_{k}") for k in ("extension", "bending", "rotation")]
    mask[lumbar] = False  # as in the Fukuchi data: no trunk coordinates
    absent = Motion(times=motion.times, names=motion.names, values=motion.values, mask=mask)
    moved = posture_offset(absent, model, {"pelvis_tilt": -5.0, "hip_rotation_l": 4.0})
    np.testing.assert_array_equal(moved.values[:, lumbar], motion.values[:, lumbar])  # the trunk turns along
    before, after = poses(model, absent), poses(model, moved)
    torso, femur_r = model.body_index("torso"), model.body_index("femur_r")
    assert not torch.allclose(before.rotations[:, torso], after.rotations[:, torso], atol=1e-3)
    assert torch.allclose(before.rotations[:, femur_r], after.rotations[:, femur_r], atol=1e-12)
    femur_l = model.body_index("femur_l")
    axis = before.rotations[:, femur_l][..., :, 1]  # the femur's long axis (y) is kept ...
    assert torch.allclose(axis, after.rotations[:, femur_l][..., :, 1], atol=1e-12)
    assert not torch.allclose(before.rotations[:, femur_l], after.rotations[:, femur_l], atol=1e-3)  # ... it spins


def test_ranges_and_draws(model):
    motion = running_like(model, seed=2)
    assert keeps_ranges(motion, posture_offset(motion, model, {"hip_rotation_r": 5.0}), model)
    over = motion.values.copy()
    over[:, model.coordinate_index("hip_rotation_r")] = model.ranges[model.coordinate_index("hip_rotation_r"), 1]
    edge = motion.with_values(over)
    assert not keeps_ranges(edge, posture_offset(edge, model, {"hip_rotation_r": 5.0}), model)
    draws = [random_offsets(np.random.default_rng(0)) for _ in range(2)]
    assert draws[0] == draws[1] and abs(draws[0]["pelvis_tilt"]) <= 8.0
    with pytest.raises(ModelError, match="in its order"):
        posture_offset(motion.select(list(reversed(motion.names))), model, {})
