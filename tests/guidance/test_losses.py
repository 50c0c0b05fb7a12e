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
