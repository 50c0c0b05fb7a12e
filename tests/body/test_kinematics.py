"""Forward kinematics against OpenSim 4.6 on every model in the data, plus markers, joint centres, COM,
couplers, Jacobians, dtypes, batching and autograd."""

from __future__ import annotations

import zlib

import numpy as np
import pytest
import torch

from biomotion.body.kinematics import (
    apply_couplers,
    body_coms,
    center_of_mass,
    forward_kinematics,
    joint_centers,
    marker_jacobians,
    marker_positions,
)
from biomotion.body.model import BodyModel
from tests.body.oracle import Oracle, model_paths, random_poses
from tests.conftest import data_path

RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
RUNNER = "fukuchi-running/RBDS001/RBDS001_simple.osim"
TOLERANCE = 1e-5  # m, and for rotation-matrix entries (float64); measured errors are about 1e-15


@pytest.mark.parametrize("relative", model_paths())
def test_fk_matches_opensim(relative: str) -> None:
    path = data_path(relative)
    model = BodyModel.from_osim(path)
    oracle = Oracle(path)
    assert list(model.coordinate_names) == oracle.coordinate_names
    count = 2 if relative.startswith("fukuchi-running/RBDS") else 3
    q = random_poses(model, np.random.default_rng(zlib.crc32(relative.encode())), count)
    poses = forward_kinematics(model, torch.tensor(q))
    markers = marker_positions(model, torch.tensor(q), poses)
    centers = joint_centers(model, torch.tensor(q), poses)
    for k in range(count):
        oracle.set(q[k])
        rotations, positions = oracle.body_poses()
        assert np.abs(poses.positions[k].numpy() - positions).max() <= TOLERANCE
        assert np.abs(poses.rotations[k].numpy() - rotations).max() <= TOLERANCE
        if model.marker_names:
            assert np.abs(markers[k].numpy() - oracle.markers()).max() <= TOLERANCE
        assert np.abs(centers[k].numpy() - oracle.joint_centers()).max() <= TOLERANCE


def test_center_of_mass_matches_opensim() -> None:
    path = data_path(RAJAGOPAL)
    model, oracle = BodyModel.from_osim(path), Oracle(path)
    q = random_poses(model, np.random.default_rng(1), 2)
    com = center_of_mass(model, torch.tensor(q))
    coms = body_coms(model, torch.tensor(q))
    for k in range(2):
        oracle.set(q[k])
        expected = np.array([oracle.model.calcMassCenterPosition(oracle.state).get(i) for i in range(3)])
        assert np.abs(com[k].numpy() - expected).max() <= 1e-9
        femur = oracle.model.getBodySet().get("femur_r")
        station = femur.findStationLocationInGround(oracle.state, femur.getMassCenter())
        assert (
            np.abs(coms[k, model.body_index("femur_r")].numpy() - np.array([station.get(i) for i in range(3)])).max()
            <= 1e-9
        )


def test_couplers_match_opensim_assembly() -> None:
    path = data_path(RAJAGOPAL)
    model, oracle = BodyModel.from_osim(path), Oracle(path)
    q = torch.zeros(3, model.n_q, dtype=torch.float64)
    knee, beta = model.coordinate_index("knee_angle_r"), model.coordinate_index("knee_angle_r_beta")
    q[:, knee] = torch.tensor([0.1, 0.9, 1.7], dtype=torch.float64)
    coupled = apply_couplers(model, q)
    assert coupled is not q and torch.equal(q[:, beta], torch.zeros(3, dtype=torch.float64))
    for k in range(3):
        oracle.set(np.zeros(model.n_q))
        oracle.coords.get("knee_angle_r").setValue(oracle.state, float(q[k, knee]), True)  # assembles couplers
        assert abs(float(coupled[k, beta]) - oracle.coords.get("knee_angle_r_beta").getValue(oracle.state)) <= 1e-6


def test_float32_and_batch_dims() -> None:
    model = BodyModel.from_osim(data_path(RAJAGOPAL))
    q = torch.tensor(random_poses(model, np.random.default_rng(2), 6)).reshape(2, 3, model.n_q)
    poses64 = forward_kinematics(model, q)
    poses32 = forward_kinematics(model.to(torch.float32), q.float())
    assert poses32.positions.dtype == torch.float32 and poses64.positions.shape == (2, 3, model.n_bodies, 3)
    assert (poses32.positions.double() - poses64.positions).abs().max() <= 1e-5
    single = forward_kinematics(model, q[1, 2])
    assert torch.allclose(single.rotations, poses64.rotations[1, 2], atol=1e-14, rtol=0)


def test_marker_jacobians_match_central_differences() -> None:
    model = BodyModel.from_osim(data_path(RAJAGOPAL))
    q = torch.tensor(random_poses(model, np.random.default_rng(3), 1)[0])
    analytic = marker_jacobians(model, q)
    h = 1e-6
    steps = h * torch.eye(model.n_q, dtype=torch.float64)
    numeric = (marker_positions(model, q + steps) - marker_positions(model, q - steps)) / (2 * h)  # [n_q, M, 3]
    assert analytic.shape == (len(model.marker_names), 3, model.n_q)
    assert (analytic - numeric.permute(1, 2, 0)).abs().max() <= 1e-8


def test_fk_gradcheck() -> None:
    model = BodyModel.from_osim(data_path(RUNNER))
    q = torch.tensor(random_poses(model, np.random.default_rng(4), 1), requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda x: (marker_positions(model, x), forward_kinematics(model, x).rotations), (q,)
    )


def test_wrong_coordinate_count_is_rejected() -> None:
    from biomotion.errors import ModelError

    model = BodyModel.from_osim(data_path(RUNNER))
    with pytest.raises(ModelError, match="coordinates"):
        forward_kinematics(model, torch.zeros(model.n_q + 1, dtype=torch.float64))
