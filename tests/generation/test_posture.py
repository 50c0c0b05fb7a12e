"""A person's posture offset (biomotion.generation.posture) and the population postures it is measured against."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.generation.posture import POSTURE_COORDINATES, centring_shift, nearest_action, posture_offset
from biomotion.models.actions import ActionVocabulary
from biomotion.models.bundle import ALL_ACTIONS, GeneratorBundle, GuidanceBounds, population_posture

N = len(CANONICAL_COORDINATES)
KNEE, ROTATION = CANONICAL_COORDINATES.index("knee_angle_r"), CANONICAL_COORDINATES.index("pelvis_rotation")
RUN = np.full(N, 0.1)
SQUAT = np.full(N, 0.8)
SLOPE = np.zeros(N)
SLOPE[KNEE] = 0.08  # rad per m/s


def _bounds(posture, slope=(), speed=math.nan) -> GuidanceBounds:
    return GuidanceBounds(
        tuple([1.0] * N), (0.5, 4.0), (1.0, 20.0), 1000, tuple([100.0] * N), tuple(posture), tuple(slope), speed
    )


def _bundle(with_postures: bool = True) -> GeneratorBundle:
    vocabulary = ActionVocabulary.from_labels(
        [
            {"action": "run", "style": None, "speed": 3.5, "text": "run"},
            {"action": "squat", "style": None, "speed": None, "text": "squat"},
        ]
    )
    if not with_postures:
        bounds = {ALL_ACTIONS: _bounds(())}
    else:
        bounds = {
            ALL_ACTIONS: _bounds((RUN + SQUAT) / 2),
            "run": _bounds(RUN, SLOPE, 3.5),
            "squat": _bounds(SQUAT, np.zeros(N)),
        }
    return GeneratorBundle(None, vocabulary, bounds)


def _clip(mean: np.ndarray, frames: int = 40) -> tuple[torch.Tensor, torch.Tensor]:
    wiggle = 0.05 * np.sin(np.linspace(0, 2 * np.pi, frames, endpoint=False))[:, None]  # zero mean
    return torch.tensor(mean[None] + wiggle), torch.ones(N, dtype=torch.bool)


def test_population_posture_is_a_line_in_speed_through_the_clip_means():
    speeds = np.array([2.5, 3.5, 4.5, 2.5])
    means = np.stack([RUN + SLOPE * (v - 3.25) for v in speeds])
    means[0, 0] = np.nan  # a clip without the first coordinate
    posture, slope, centre = population_posture(means, speeds)
    assert centre == pytest.approx(3.25)
    np.testing.assert_allclose(posture, RUN, atol=1e-12)
    np.testing.assert_allclose(slope, SLOPE, atol=1e-12)
    plain, no_slope, no_centre = population_posture(means, np.array([2.5, np.nan, 4.5, 2.5]))
    assert math.isnan(no_centre) and not any(no_slope)
    np.testing.assert_allclose(plain[1:], np.nanmean(means, 0)[1:], atol=1e-12)


def test_bounds_keep_their_postures_through_a_save_and_old_ones_load_without():
    bounds = _bounds(RUN, SLOPE, 3.5)
    again = GuidanceBounds.from_dict(bounds.to_dict())
    assert again.posture == bounds.posture and again.posture_slope == bounds.posture_slope
    assert again.posture_speed == 3.5
    old = {k: v for k, v in bounds.to_dict().items() if not k.startswith("posture")}
    assert GuidanceBounds.from_dict(old).posture == ()
    assert _bundle(with_postures=False).posture("run") is None


def test_the_offset_is_the_references_deviation_from_the_population_at_their_speed():
    bundle = _bundle()
    person = np.where(POSTURE_COORDINATES.numpy(), 0.03 * np.arange(N) / N, 0.0)
    references = [_clip(RUN + SLOPE * (v - 3.5) + person) for v in (2.5, 4.5)]
    offset = posture_offset(references, bundle, ["run", "run"], [2.5, 4.5])
    posture = POSTURE_COORDINATES.numpy()
    np.testing.assert_allclose(offset.numpy()[posture], person[posture], atol=1e-12)
    assert torch.isnan(offset[~POSTURE_COORDINATES]).all()  # pelvis_rotation and translations are not posture
    # the knee's speed effect would otherwise be counted as the person's: 0.08 rad per m/s
    blind = posture_offset(references, bundle, ["run", "run"])
    assert float(blind[KNEE]) == pytest.approx(person[KNEE], abs=1e-12)  # 2.5 and 4.5 average to 3.5
    one = posture_offset(references[:1], bundle, ["run"])
    assert float(one[KNEE]) == pytest.approx(person[KNEE] - 0.08, abs=1e-12)


def test_an_unlabelled_reference_is_read_as_the_nearest_action_and_absent_coordinates_stay_unknown():
    bundle = _bundle()
    q, mask = _clip(SQUAT + 0.02)
    mask = mask.clone()
    mask[KNEE] = False
    assert nearest_action(q.mean(0), mask, bundle) == "squat"
    offset = posture_offset([(q, mask)], bundle)
    known = POSTURE_COORDINATES & mask
    torch.testing.assert_close(offset[known], torch.full((int(known.sum()),), 0.02, dtype=torch.float64))
    assert torch.isnan(offset[KNEE])


def test_the_centring_shift_moves_each_clip_mean_to_the_target_where_it_is_known():
    q = torch.randn(3, 20, N)
    target = torch.full((N,), float("nan"))
    target[KNEE] = 0.7
    shifted = q + centring_shift(q, target)[:, None]
    torch.testing.assert_close(shifted[..., KNEE].mean(1), torch.full((3,), 0.7))
    torch.testing.assert_close(shifted[..., ROTATION], q[..., ROTATION])
