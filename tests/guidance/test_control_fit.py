"""The coordinate-space control stage (`biomotion.guidance.control_fit`) on the canonical model: it puts a body on
its path, changes only the coordinates that move that body, and leaves a clip without path or value targets as it
is."""

from __future__ import annotations

import pytest
import torch

from biomotion.guidance.control import Control, body_origins
from biomotion.guidance.control_fit import fit_control, free_coordinates
from tests.conftest import data_path

RATE = 30.0
FRAMES = [5, 10, 15, 20, 25]


@pytest.fixture(scope="module")
def standing():
    """The canonical body standing still for 1 s (30 frames, its default pose) and its foot points."""
    from biomotion.body.contact import foot_points
    from biomotion.data.clips import body_model

    body = body_model(data_path(".")).to(torch.float32)
    q = body.defaults.to(torch.float32).expand(1, 30, -1).clone()
    return body, q, foot_points(body)


def _fit(body, q, feet, control):
    ranges = body.ranges.to(torch.float32)
    rotational = torch.tensor([not n.startswith("pelvis_t") for n in body.coordinate_names])
    return fit_control(
        body, q, control, RATE, feet.bodies, feet.offsets.to(torch.float32), ranges[:, 0], ranges[:, 1], rotational
    )


def test_a_hand_path_is_met_and_the_legs_stay(standing):
    body, q, feet = standing
    hand = body_origins(body, q)[0, :, body.body_index("hand_r")]
    path = [[f / RATE, x + 0.05, y + 0.05, z] for f, (x, y, z) in zip(FRAMES, hand[FRAMES].tolist())]
    spec = {"quantity": "joint_position", "body": "hand_r", "kind": "path", "path": path, "weight": 1e5}
    control = Control.from_dict({"targets": [spec]})
    fitted = _fit(body, q, feet, control)
    after = body_origins(body, fitted)[0, FRAMES, body.body_index("hand_r")]
    error = (after - torch.tensor([p[1:] for p in path])).norm(dim=-1)
    assert error.max() < 0.005  # 7 cm asked for, within 5 mm reached
    legs = [body.coordinate_names.index(n) for n in ("hip_flexion_r", "knee_angle_r", "ankle_angle_l")]
    assert torch.equal(fitted[..., legs], q[..., legs])  # not on the hand's chain: untouched
    assert free_coordinates(body, control)[body.coordinate_names.index("arm_flex_r")]
    step = (fitted - q)[0]
    assert (step[2:] - 2 * step[1:-1] + step[:-2]).abs().max() < 0.02  # smooth: no frame-to-frame jitter


def test_bounds_alone_leave_the_clip_as_it_is(standing):
    body, q, feet = standing
    spec = {"quantity": "joint_angle", "coordinate": "knee_angle_r", "kind": "max", "value": 10}
    assert torch.equal(_fit(body, q, feet, Control.from_dict({"targets": [spec]})), q)


def test_muscle_targets_of_any_kind_leave_the_clip_as_it_is(standing):
    """The stage computes no activations: a muscle ``value`` target (a fitted kind) is skipped, not evaluated."""
    body, q, feet = standing
    spec = {"quantity": "muscle_activation", "muscle": "glmed1_r", "kind": "value", "times": [0.5], "value": 0.2}
    assert torch.equal(_fit(body, q, feet, Control.from_dict({"targets": [spec]})), q)
