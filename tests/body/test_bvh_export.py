"""BVH export of model motions: written, read back with our BVH reader, its forward kinematics gives the model's
body origins (and orientations) in every frame.

Tolerance: 1e-4 m on positions (the export is exact up to the 10 significant digits `write_bvh` prints: errors
measured about 1e-9 m) and 1e-6 on rotation matrix entries.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from biomotion.body.bvh_export import ROTATION_CHANNELS, motion_to_bvh, zxy_euler
from biomotion.body.kinematics import apply_couplers, forward_kinematics
from biomotion.body.model import BodyModel
from biomotion.errors import ModelError
from biomotion.io.bvh import axis_rotation, read_bvh, write_bvh
from biomotion.motion import Motion
from tests.conftest import DATA_ROOT, data_path

RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
POSITION_TOLERANCE = 1e-4  # m
ROTATION_TOLERANCE = 1e-6

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def model() -> BodyModel:
    return BodyModel.from_osim(data_path(RAJAGOPAL))


def _synthetic(model: BodyModel, frames: int = 40) -> Motion:
    """Smooth motion through a wide part of every coordinate's range (2 s at 20 Hz, pelvis translating)."""
    t = np.arange(frames) / 20.0
    low, high = model.ranges[:, 0].numpy(), model.ranges[:, 1].numpy()
    phase = np.linspace(0, 2 * np.pi, model.n_q, endpoint=False)
    mid, half = (low + high) / 2, 0.45 * (high - low)
    values = mid + half * np.sin(2 * np.pi * 0.7 * t[:, None] + phase)
    for name, start, speed in (("pelvis_tx", 0.0, 1.5), ("pelvis_ty", 0.94, 0.0), ("pelvis_tz", 0.1, -0.2)):
        values[:, model.coordinate_index(name)] = start + speed * t
    return Motion(times=t, names=model.coordinate_names, values=values)


def _check_round_trip(model: BodyModel, motion: Motion, path, units: str) -> float:
    bvh = motion_to_bvh(model, motion)
    write_bvh(path, bvh, units=units)
    back = read_bvh(path)
    assert back.units == units and back.n_frames == motion.n_frames
    assert back.frame_time == pytest.approx(1.0 / motion.rate, rel=1e-8)
    rotations, positions = back.global_transforms()
    q = apply_couplers(model, torch.as_tensor(motion.select(model.coordinate_names).values))
    poses = forward_kinematics(model, q)
    order = [model.body_index(name) for name in back.skeleton.names]
    assert sorted(order) == list(range(model.n_bodies))
    error = float(np.abs(positions - poses.positions[:, order].numpy()).max())
    assert error < POSITION_TOLERANCE
    assert np.abs(rotations - poses.rotations[:, order].numpy()).max() < ROTATION_TOLERANCE
    return error


def test_skeleton_is_the_body_tree(model):
    bvh = motion_to_bvh(model, _synthetic(model, 3))
    skeleton = bvh.skeleton
    assert skeleton.names[0] == "pelvis" and skeleton.parents[0] == -1
    for j, name in enumerate(skeleton.names[1:], start=1):
        assert skeleton.names[skeleton.parents[j]] == model.body_names[model.parent[model.body_index(name)]]
    six = {name for name, chans in zip(skeleton.names, skeleton.channels) if len(chans) == 6}
    assert six == {"pelvis", "tibia_r", "tibia_l", "patella_r", "patella_l"}  # root and translating joints
    assert all(chans[-3:] == ROTATION_CHANNELS for chans in skeleton.channels)
    rest = forward_kinematics(model, torch.zeros(model.n_q, dtype=torch.float64))
    femur, tibia = model.body_index("femur_r"), model.body_index("tibia_r")
    expected = rest.rotations[femur].T @ (rest.positions[tibia] - rest.positions[femur])
    np.testing.assert_allclose(skeleton.offsets[skeleton.index("tibia_r")], expected.numpy(), atol=1e-12)
    only_root = motion_to_bvh(model, _synthetic(model, 3), joint_translations=False).skeleton
    assert [len(c) for c in only_root.channels] == [6] + [3] * (model.n_bodies - 1)


def test_synthetic_motion_round_trips_through_a_bvh_file(model, tmp_path):
    motion = _synthetic(model)
    for units in ("cm", "m", "mm"):
        assert _check_round_trip(model, motion, tmp_path / f"synthetic_{units}.bvh", units) < 1e-6


def test_cached_motions_round_trip_through_a_bvh_file(model, tmp_path):
    from biomotion.data.registry import DatasetCache, build_cache

    data_path("opencap")
    build_cache(DATA_ROOT, tmp_path / "cache", sources=["opencap", "fukuchi"], progress=False)
    cache = DatasetCache(tmp_path / "cache")
    for action in ("run", "squat", "drop jump", "walk"):
        found = cache.indices(action=action)
        if found:
            _check_round_trip(model, cache.motion(found[0]), tmp_path / f"{action}.bvh.gz", "cm")


def test_zxy_euler_inverts_bvh_rotations_including_gimbal_lock():
    rng = np.random.default_rng(0)
    angles = rng.uniform(-np.pi, np.pi, (200, 3))
    angles[:, 1] /= 2  # x in [-90, 90] degrees
    angles[:5, 1] = np.pi / 2  # gimbal lock
    angles[5:10, 1] = -np.pi / 2
    matrices = axis_rotation("Z", angles[:, 0]) @ axis_rotation("X", angles[:, 1]) @ axis_rotation("Y", angles[:, 2])
    recovered = zxy_euler(torch.as_tensor(matrices)).numpy()
    rebuilt = (
        axis_rotation("Z", recovered[:, 0]) @ axis_rotation("X", recovered[:, 1]) @ axis_rotation("Y", recovered[:, 2])
    )
    np.testing.assert_allclose(rebuilt, matrices, atol=1e-7)
    np.testing.assert_allclose(recovered[10:], angles[10:], atol=1e-9)


def test_missing_coordinates_are_named(model):
    motion = _synthetic(model, 3)
    partial = Motion(times=motion.times, names=motion.names[:-2], values=motion.values[:, :-2])
    with pytest.raises(ModelError, match="wrist_flex_l, wrist_dev_l"):
        motion_to_bvh(model, partial)
