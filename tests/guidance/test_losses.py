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


def test_stance_is_low_and_slower_than_the_body_so_a_low_swing_is_not_stance():
    """A walk at 1 m/s (pelvis 1 m/s): a stance point sliding at 0.3 m/s and a swing point skimming 2 cm above
    the floor at 2.5 m/s; both below 5 cm. Height alone calls both stance; the speed test keeps only the first
    (limit 1.5 m/s); a standing clip keeps the 0.5 m/s floor."""
    from biomotion.guidance.refine import stance_mask

    rate, t = 30.0, torch.arange(30) / 30.0
    q = torch.zeros(1, 30, 39)
    q[0, :, 3] = t                                        # pelvis_tx: 1 m/s
    feet = torch.zeros(1, 30, 2, 3)
    feet[0, :, 0, 0], feet[0, :, 0, 1] = 0.3 * t, 0.01    # sliding stance point
    feet[0, :, 1, 0], feet[0, :, 1, 1] = 2.5 * t, 0.02    # low swing point
    assert stance_mask(feet, q, rate, ratio=None).all()
    mask = stance_mask(feet, q, rate, ratio=1.5)
    assert mask[0, :, 0].all() and not mask[0, :, 1].any()
    standing = torch.zeros_like(q)
    mask = stance_mask(feet, standing, rate, ratio=1.5)    # limit: the 0.5 m/s floor
    assert mask[0, :, 0].all() and not mask[0, :, 1].any()
    feet[0, :, 0, 1] = 0.08                                # above 5 cm: never stance
    assert not stance_mask(feet, q, rate, ratio=1.5)[0, :, 0].any()
