"""The coordinate-space stage for caps (`biomotion.guidance.bound_fit`): a body bobbing up and down on planted feet
bears a peak vertical force above a cap; damping its pelvis height meets the cap as the analysis measures it, and a
clip that already meets its caps is left as it is."""

from __future__ import annotations

import math

import pytest
import torch

from biomotion.guidance.bound_fit import fit_bounds, magnitude_caps
from biomotion.guidance.control import Control
from biomotion.guidance.measured_bounds import measured_excess
from tests.conftest import data_path

RATE = 30.0


@pytest.fixture(scope="module")
def bobbing():
    """The canonical body in its default pose, its pelvis bobbing 4 cm at 1.5 Hz for 2 s, knees flexed 30 degrees
    so that the legs can take up the bobbing; q [1, 60, 39], and its foot points."""
    from biomotion.body.contact import foot_points
    from biomotion.data.clips import body_model

    body = body_model(data_path(".")).to(torch.float32)
    q = body.defaults.to(torch.float32).expand(1, 60, -1).clone()
    names = list(body.coordinate_names)
    for side in ("r", "l"):
        q[..., names.index(f"knee_angle_{side}")] = math.radians(30)
    time = torch.arange(60) / RATE
    q[0, :, names.index("pelvis_ty")] += 0.04 * torch.sin(2 * math.pi * 1.5 * time)
    return body, q, foot_points(body)


def _fit(body, q, feet, spec):
    ranges = body.ranges.to(torch.float32)
    return fit_bounds(
        body, q, spec, RATE, feet.bodies, feet.offsets.to(torch.float32), feet.feet, ranges[:, 0], ranges[:, 1]
    )


def test_a_grf_cap_is_met_by_damping_the_pelvis(bobbing):
    body, q, feet = bobbing
    spec = Control.from_dict({"targets": [{"quantity": "grf_vertical", "kind": "max", "value": 1.2}]}, "test")
    (before,) = measured_excess(body, q, RATE, spec, [0])[0]
    assert before > 0.05  # 4 cm at 1.5 Hz: peak acceleration 3.6 m/s^2, about 1.36 BW
    fitted, (k,) = _fit(body, q, feet, spec)
    (after,) = measured_excess(body, fitted, RATE, spec, [0])[0]
    assert after <= 0 and 0 < k < 1
    names = list(body.coordinate_names)
    arms = [names.index(n) for n in ("arm_flex_r", "lumbar_extension")]
    assert torch.equal(fitted[..., arms], q[..., arms])  # only the pelvis height and the legs move


def test_a_met_cap_and_a_floor_above_one_body_weight_change_nothing(bobbing):
    body, q, feet = bobbing
    spec = Control.from_dict(
        {
            "targets": [
                {"quantity": "grf_vertical", "kind": "max", "value": 2.0},
                {"quantity": "joint_torque", "coordinate": "knee_angle_r", "kind": "max", "value": -3.0},
            ]
        },
        "test",
    )
    assert magnitude_caps(spec) == [0]  # a moment that must reach -3 is no cap on a magnitude
    fitted, factors = _fit(body, q, feet, spec)
    assert factors == [1.0] and torch.equal(fitted, q)
