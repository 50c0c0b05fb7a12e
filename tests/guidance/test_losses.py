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


def test_locomotion_pace_holds_the_speed_in_every_window_not_only_on_average():
    """Two 2 s clips at 30 Hz with the same mean speed, 3 m/s: one steady, one at 2 m/s then 4 m/s. The clip-mean
    speed term cannot tell them apart; over 1 s windows the surging clip is 1 m/s off at both ends."""
    t = torch.arange(61, dtype=torch.float32) / 30.0
    q = torch.zeros(2, 61, 39)
    q[0, :, 3] = 3.0 * t
    q[1, :, 3] = torch.where(t <= 1.0, 2.0 * t, 2.0 + 4.0 * (t - 1.0))
    target = torch.tensor([3.0, 3.0])
    torch.testing.assert_close(losses.locomotion_speed(q, 30.0, target), torch.zeros(2), atol=1e-6, rtol=0)
    pace = losses.locomotion_pace(q, 30.0, target, 30)
    assert float(pace[0]) < 1e-8
    speeds = losses.window_speeds(q, 30.0, 30)[1]
    torch.testing.assert_close(speeds[[0, -1]], torch.tensor([2.0, 4.0]), atol=1e-5, rtol=0)
    assert float(pace[1]) > 0.2  # windows from 2 to 4 m/s, mean square deviation about 1/3 (m/s)^2


def test_amplitude_is_the_squared_distance_of_each_coordinate_std_to_the_target():
    q = torch.zeros(1, 40, 39)
    q[0, :, 9] = torch.sin(torch.arange(40) * 2 * torch.pi / 20)  # std 1/sqrt(2) over whole periods
    q[0, :, 11] = 7.0  # constant: std 0, no target
    target = torch.full((39,), float("nan"))
    target[9] = 0.5
    expected = (q[0, :, 9].std(correction=0) - 0.5) ** 2
    torch.testing.assert_close(losses.amplitude(q, target), expected[None])
    q.requires_grad_(True)
    losses.amplitude(q, target).sum().backward()
    assert q.grad[0, :, 11].abs().sum() == 0 and q.grad[0, :, 9].abs().sum() > 0


def test_com_energy_bounds_the_fluctuation_of_the_com_energy_per_kg():
    """A COM moving at a steady 3 m/s at a constant height has a constant energy (no penalty); one whose speed
    swings between 2 and 4 m/s fluctuates by about 3 J/kg, above a 1 J/kg bound."""
    t = torch.arange(91, dtype=torch.float64) / 30.0
    steady = torch.stack([3.0 * t, torch.full_like(t, 1.0), torch.zeros_like(t)], -1)
    surging = torch.stack([3.0 * t - torch.cos(2 * torch.pi * t) / (2 * torch.pi), torch.full_like(t, 1.0), 0 * t], -1)
    com = torch.stack([steady, surging]).requires_grad_(True)
    penalty = losses.com_energy(com, 30.0, 1.0)
    assert float(penalty[0].detach()) == 0.0 and float(penalty[1].detach()) > 1.0
    penalty.sum().backward()
    assert com.grad[0].abs().sum() == 0 and com.grad[1].abs().sum() > 0
