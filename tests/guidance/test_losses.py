"""Guidance terms with known values (biomotion.guidance.losses)."""

import torch

from biomotion.guidance import losses


def test_posture_is_the_squared_distance_of_each_clip_mean_to_the_target_where_one_is_set():
    q = torch.zeros(2, 10, 39)
    q[0, :, 7] = 0.3
    q[1, :5, 7], q[1, 5:, 7] = 0.0, 0.2  # mean 0.1
    q[:, :, 8] = 5.0  # no target for this coordinate: ignored
    target = torch.full((39,), float("nan"))
    target[7] = 0.1
    torch.testing.assert_close(losses.posture(q, target), torch.tensor([0.04, 0.0]))
    q.requires_grad_(True)
    losses.posture(q, target).sum().backward()
    assert float(q.grad[0, :, 7].sum()) > 0 and float(q.grad[..., 8].abs().sum()) == 0


def test_zmp_support_is_the_mean_distance_outside_the_stance_hull_over_supported_frames():
    """A 20 x 10 cm sole in contact; the ZMP inside it (frame 0), 5 cm in front of it (frame 1), unloaded
    (frame 2, ignored) and with no foot in contact (frame 3, ignored): (0 + 0.05) / 2 supported frames."""
    sole = torch.tensor([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.2, 0.0, 0.1], [0.0, 0.0, 0.1]])
    feet = sole.expand(1, 4, 4, 3).clone()
    contact = torch.ones(1, 4, 4, dtype=torch.bool)
    contact[0, 3] = False
    loaded = torch.tensor([[True, True, False, True]])
    zmp = torch.tensor([[[0.1, 0.0, 0.05], [0.25, 0.0, 0.05], [5.0, 0.0, 5.0], [5.0, 0.0, 5.0]]], requires_grad=True)
    penalty = losses.zmp_support(zmp, loaded, feet, contact)
    assert torch.allclose(penalty, torch.tensor([0.025]))
    penalty.sum().backward()
    assert torch.isfinite(zmp.grad).all()
    assert zmp.grad[0, 1, 0] > 0 and zmp.grad[0, [0, 2, 3]].abs().sum() == 0  # only the outside frame pulls


def test_foot_skim_weighs_horizontal_speed_by_nearness_to_the_floor():
    """Three points at 30 Hz: one 1 cm up moving 2 m/s forward (weight 1 - 0.01 / 0.05 = 0.8, speed^2 4), one
    moving the same 10 cm up (above the 5 cm height: weight 0) and one still on the floor (speed 0). Over the two
    steps of three frames: sum over points 3.2 per step, mean over steps 3.2."""
    t = torch.arange(3, dtype=torch.float32)[:, None] / 30.0
    feet = torch.zeros(1, 3, 3, 3)
    feet[0, :, 0, 0], feet[0, :, 0, 1] = 2.0 * t[:, 0], 0.01
    feet[0, :, 1, 0], feet[0, :, 1, 1] = 2.0 * t[:, 0], 0.10
    feet.requires_grad_(True)
    skim = losses.foot_skim(feet, 30.0, 0.05)
    torch.testing.assert_close(skim, torch.tensor([3.2]))
    skim.sum().backward()
    assert feet.grad[0, :, 0, 1].sum() < 0  # lifting the fast low point lowers the term ...
    assert feet.grad[0, :, 1].abs().sum() == 0 and feet.grad[0, :, 2].abs().sum() == 0  # ... the others are free
