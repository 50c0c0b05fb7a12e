"""Control bounds measured as the analysis measures the outputs (`biomotion.guidance.measured_bounds`): a body
standing still bears one body weight, so a GRF cap below it is missed by the difference and one above it is met;
tightening moves only the bounds it names, inwards."""

from __future__ import annotations

import pytest
import torch

from biomotion.guidance.control import Control
from biomotion.guidance.measured_bounds import measured_bounds, measured_excess, tightened
from tests.conftest import data_path

RATE = 30.0


@pytest.fixture(scope="module")
def standing():
    """The canonical body standing still for 2 s in its default pose: q [1, 60, 39]."""
    from biomotion.data.clips import body_model

    body = body_model(data_path("."))
    return body, body.defaults.to(torch.float32).expand(1, 60, -1).clone()


def _spec(*targets: dict) -> Control:
    return Control.from_dict({"targets": list(targets)}, "test")


def test_a_still_body_misses_a_cap_below_one_body_weight_by_the_difference(standing):
    body, q = standing
    caps = _spec(
        {"quantity": "grf_vertical", "kind": "max", "value": 0.9},
        {"quantity": "grf_vertical", "kind": "max", "value": 1.2},
    )
    floor = _spec({"quantity": "grf_vertical", "kind": "min", "value": 1.1, "window": [0.5, 1.5]})
    excess = measured_excess(body, q, RATE, caps, measured_bounds(caps))[0]
    assert excess[0] == pytest.approx(0.1, abs=0.01)  # 1 BW against a 0.9 cap
    assert excess[1] == pytest.approx(-0.2, abs=0.01)  # met, with 0.2 BW to spare
    (below,) = measured_excess(body, q, RATE, floor, [0])[0]
    assert below == pytest.approx(0.1, abs=0.01)  # 1 BW against a 1.1 floor


def test_a_still_body_has_no_knee_moment_to_speak_of(standing):
    body, q = standing
    spec = _spec({"quantity": "joint_torque", "coordinate": "knee_angle_r", "kind": "max", "value": 0.0})
    (excess,) = measured_excess(body, q, RATE, spec, [0])[0]
    assert abs(excess) < 0.3  # N·m/kg: the default pose is upright, the knee carries little moment


def test_only_grf_and_moment_bounds_are_measured_and_tightening_moves_them_inwards():
    spec = _spec(
        {"quantity": "grf_vertical", "kind": "max", "value": 2.2},
        {"quantity": "joint_angle", "coordinate": "knee_angle_r", "kind": "max", "value": 60},
        {"quantity": "joint_torque", "coordinate": "knee_angle_r", "kind": "min", "value": -1.5},
    )
    indices = measured_bounds(spec)
    assert indices == [0, 2]
    moved = tightened(spec, indices, [0.1, 0.2])
    assert moved.targets[0].value == pytest.approx(2.1)
    assert moved.targets[2].value == pytest.approx(-1.3)
    assert moved.targets[1] == spec.targets[1]
