"""Foot planting (`biomotion.guidance.planting`): the plant rule on synthetic points, and the leg IK on the
canonical Rajagopal 2016 model holding sliding feet still on the floor."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from biomotion.body.contact import foot_points
from biomotion.body.kinematics import forward_kinematics, points_in_ground
from biomotion.body.model import BodyModel
from biomotion.guidance.planting import PlantingConfig, leg_columns, plant_feet, plant_targets
from tests.conftest import data_path


def test_plant_targets_anchor_at_the_mean_on_the_floor_and_fade_out():
    t = np.arange(20)
    points = np.zeros((1, 20, 2, 3))
    points[0, :, 0, 1] = np.where((t >= 5) & (t <= 14), 0.005, 0.2)  # right point: planted on frames 5-14
    points[0, :, 0, 0] = 0.01 * t  # ... sliding 1 cm per frame
    points[0, :, 1, 1] = 0.3  # left point: in the air throughout
    config = PlantingConfig(ramp=3)
    target, weight = plant_targets(points, ("r", "l"), config)
    anchor = 0.01 * np.arange(5, 15).mean()
    np.testing.assert_allclose(weight[0, 5:15, 0], 1.0)
    np.testing.assert_allclose(target[0, 5:15, 0], np.tile([anchor, 0.0, 0.0], (10, 1)))
    # fades: shares 3/4, 2/4, 1/4 of the correction at the plant's edge, then nothing
    np.testing.assert_allclose(weight[0, [4, 3, 2, 1], 0], [0.75, 0.5, 0.25, 0.0])
    np.testing.assert_allclose(weight[0, [15, 16, 17, 18], 0], [0.75, 0.5, 0.25, 0.0])
    edge = np.array([anchor, 0.0, 0.0]) - points[0, 5, 0]
    np.testing.assert_allclose(target[0, 3, 0], points[0, 3, 0] + 0.5 * edge)
    assert not weight[0, :, 1].any()
    assert np.isnan(target[0, 0, 0]).all()


def test_single_frame_touch_is_not_a_plant():
    points = np.full((1, 10, 1, 3), 0.2)
    points[0, 4, 0, 1] = 0.0
    _, weight = plant_targets(points, ("r",), PlantingConfig())
    assert not weight.any()


@pytest.fixture(scope="module")
def body():
    return BodyModel.from_osim(data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim")).to(torch.float32)


def _feet(body, q):
    points = foot_points(body)
    flat = q.reshape(-1, q.shape[-1])
    return points_in_ground(forward_kinematics(body, flat), points.bodies, points.offsets.float()).view(
        *q.shape[:2], -1, 3
    )


def test_plant_feet_holds_sliding_feet_still_on_the_floor(body):
    """Standing on slightly bent legs (hips 0.15 rad, knees 0.3, ankles 0.15: feet flat) locked while the pelvis
    glides 8 cm forward and sinks 5 mm: the feet slide 8 cm and sink into the floor. Planted, they stay within 5 mm
    of one place, on the floor to a millimetre, moved by the legs alone."""
    frames = 30
    q = body.defaults.clone().expand(1, frames, -1).clone()
    names = body.coordinate_names
    for side in ("r", "l"):
        for name, value in (("hip_flexion", 0.15), ("knee_angle", 0.3), ("ankle_angle", 0.15)):
            q[..., names.index(f"{name}_{side}")] = value
    lowest = _feet(body, q)[..., 1].min()
    q[..., 4] -= lowest - 0.002  # soles 2 mm above the floor
    q[..., 3] += torch.linspace(0.0, 0.08, frames)  # pelvis_tx glides 8 cm
    q[..., 4] -= torch.linspace(0.0, 0.005, frames)  # and sinks 5 mm
    before = _feet(body, q)
    assert float(before[0, -1, :, 0].sub(before[0, 0, :, 0]).abs().min()) > 0.079

    points = foot_points(body)
    ranges = body.ranges.to(torch.float32)
    planted = plant_feet(body, q, points.bodies, points.offsets.float(), points.feet, ranges[:, 0], ranges[:, 1])
    after = _feet(body, planted)
    drift = (after[0, :, :, [0, 2]] - after[0, :1, :, [0, 2]]).norm(dim=-1)
    assert float(drift.max()) < 0.005
    # before: 5 mm deep at the end; the damping (1e-2 per rad^2) trades about a millimetre of height for joint change
    assert float(before[..., 1].min()) < -0.0029
    assert float(after[..., 1].min()) > -0.0015
    assert float(after[..., 1].amin(-1).abs().max()) < 0.0015  # still standing on the floor, not lifted
    legs = leg_columns(tuple(body.coordinate_names))
    others = [i for i in range(body.n_q) if i not in legs and not body.coordinate_names[i].endswith("_beta")]
    torch.testing.assert_close(planted[..., others], q[..., others], rtol=0, atol=0)
    assert bool(((planted >= ranges[:, 0] - 1e-6) & (planted <= ranges[:, 1] + 1e-6)).all())
