"""Placement of cached clips (biomotion.data.placement) on real treadmill and overground data."""

from __future__ import annotations

import numpy as np
import pytest

from biomotion.body.contact import lowest_foot_heights
from biomotion.body.model import BodyModel
from biomotion.data.placement import GENERIC_HEIGHT, place_clip
from biomotion.data.sources import FUKUCHI, HAMNER, discover_all
from tests.conftest import DATA_ROOT, data_path


@pytest.fixture(scope="module")
def model():
    return BodyModel.from_osim(data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim"))


def _stance_foot_speed(model, motion) -> float:
    """Mean forward (x) speed of the lowest foot point over the frames where it is within 1 cm of its minimum."""
    import torch

    from biomotion.body.contact import foot_points
    from biomotion.body.kinematics import forward_kinematics, points_in_ground

    full = np.where(motion.mask[None], motion.values, model.defaults.numpy()[None])
    feet = foot_points(model)
    points = points_in_ground(
        forward_kinematics(model, torch.from_numpy(full.astype(np.float64))), feet.bodies, feet.offsets
    ).numpy()
    lowest = points[..., 1].argmin(-1)
    x = points[np.arange(len(points)), lowest, 0]
    height = points[..., 1].min(-1)
    stance = height < height.min() + 0.01
    return float(np.mean(np.gradient(x, 1 / motion.rate)[stance]))


@pytest.mark.parametrize("source", [FUKUCHI, HAMNER], ids=["fukuchi", "hamner"])
def test_treadmill_clip_becomes_overground_on_the_floor(model, source):
    data_path(source.folder)
    spec = next(s for s in discover_all(DATA_ROOT, [source.name])[0] if s.labels.speed == 3.5 or s.labels.speed == 3.0)
    raw = source.load_motion(spec).resample(30.0)
    placed = place_clip(raw, model, height=spec.profile.height, treadmill_speed=spec.labels.speed)
    speed = spec.labels.speed
    # on the belt the planted foot moves backwards at about the belt speed; placed, it rests (within 0.5 m/s)
    assert _stance_foot_speed(model, raw) < -0.7 * speed
    assert abs(_stance_foot_speed(model, placed)) < 0.5
    assert placed["pelvis_tx"][0] == 0 and placed["pelvis_tz"][0] == 0
    full = np.where(placed.mask[None], placed.values, model.defaults.numpy()[None]).astype(np.float64)
    assert abs(np.percentile(lowest_foot_heights(model, full), 5)) < 1e-6
    scale = GENERIC_HEIGHT / spec.profile.height if spec.profile.height else 1.0
    np.testing.assert_allclose(np.diff(placed["pelvis_ty"]), scale * np.diff(raw["pelvis_ty"]), atol=1e-6)
    # the belt is scaled with the body: the placed speed is the belt's at the generic size
    assert (placed["pelvis_tx"][-1] - placed["pelvis_tx"][0]) / (raw.times[-1] - raw.times[0]) == pytest.approx(
        scale * speed, abs=0.05 * speed
    )
    rotations = [n for n in raw.names if not n.startswith("pelvis_t")]
    np.testing.assert_array_equal(placed.select(rotations).values, raw.select(rotations).values)
