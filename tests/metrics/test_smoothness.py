"""Jerk, energy consistency, ACCL and VEL: exact cases (polynomials, free fall) and Bandai-Namco walking."""

from __future__ import annotations

import math

import pytest
import torch

from biomotion.metrics import smoothness as S
from biomotion.metrics.smoothness import AccelerationError, EnergyConsistency, JerkIndex, VelocityError

F64 = torch.float64


def test_jerk_of_a_cubic_is_exact():
    # x(t) = a t^3 along x for joint 0, b t^3 along y for joint 1: third differences are exactly 6a, 6b
    rate, a, b = 50.0, 0.7, -0.2
    t = torch.arange(40, dtype=F64) / rate
    x = torch.zeros(40, 2, 3, dtype=F64)
    x[:, 0, 0] = a * t**3
    x[:, 1, 1] = b * t**3
    expected_squared = ((6 * a) ** 2 + (6 * b) ** 2) / 2
    assert S.jerk_index(x, rate).item() == pytest.approx(expected_squared, rel=1e-6)
    assert S.jerk_index(x, rate, squared=False).item() == pytest.approx(3 * (abs(a) + abs(b)), rel=1e-6)
    # joint 1 masked out; coordinates as [T, n, 1]
    assert S.jerk_index(x, rate, joints=torch.tensor([True, False])).item() == pytest.approx((6 * a) ** 2, rel=1e-6)
    q = (0.5 * t**3)[:, None, None]
    assert S.jerk_index(q, rate, squared=False).item() == pytest.approx(3.0, rel=1e-6)


def test_energy_of_free_fall_is_constant_and_of_a_lift_is_a_ramp():
    rate, mass, g = 100.0, 70.0, S.GRAVITY
    t = torch.arange(60, dtype=F64) / rate
    falling = torch.zeros(60, 1, 3, dtype=F64)
    falling[:, 0, 1] = 2.0 - 0.5 * g * t**2
    energy = S.mechanical_energy(falling, torch.tensor([mass], dtype=F64), rate)
    # forward-difference speed with mid-pair height is exact up to a constant -m g^2 dt^2 / 8
    torch.testing.assert_close(
        energy, torch.full_like(energy, mass * g * 2.0 - mass * g**2 / rate**2 / 8), rtol=0, atol=1e-9
    )
    assert S.energy_consistency(energy).item() == pytest.approx(0.0, abs=1e-12)
    # lifted at a constant 0.5 m/s: E = const + m g v t, variance (m g v)^2 (N^2 - 1) / (12 rate^2) over N samples
    lifted = torch.zeros(61, 1, 3, dtype=F64)
    lifted[:, 0, 1] = 1.0 + 0.5 * torch.arange(61, dtype=F64) / rate
    energy = S.mechanical_energy(lifted, torch.tensor([mass], dtype=F64), rate)
    n, slope = energy.shape[-1], mass * g * 0.5
    expected = slope**2 * (n**2 - 1) / (12 * rate**2)
    assert S.energy_consistency(energy).item() == pytest.approx(expected, rel=1e-9)
    assert EnergyConsistency(std=True).score(energy).item() == pytest.approx(math.sqrt(expected), rel=1e-9)


def test_acceleration_and_velocity_errors_of_known_offsets():
    rate = 30.0
    t = torch.arange(20, dtype=F64) / rate
    target = torch.randn(20, 3, 3, dtype=F64, generator=torch.Generator().manual_seed(0))
    drift = torch.zeros(20, 3, 3, dtype=F64)
    drift[..., 2] = (0.4 * t)[:, None]  # constant 0.4 m/s offset velocity, zero acceleration
    assert S.velocity_error(target + drift, target, rate).item() == pytest.approx(0.4, rel=1e-9)
    assert S.acceleration_error(target + drift, target, rate).item() == pytest.approx(0.0, abs=1e-9)
    bend = torch.zeros(20, 3, 3, dtype=F64)
    bend[..., 0] = (1.5 * t**2)[:, None]  # 3 m/s^2 offset acceleration
    assert S.acceleration_error(target + bend, target, rate).item() == pytest.approx(3.0, rel=1e-9)
    assert AccelerationError(per_frame=True).score(target + bend, target, rate).item() == pytest.approx(
        3.0 / rate**2, rel=1e-9
    )
    assert VelocityError(per_frame=True).score(target + drift, target, rate).item() == pytest.approx(
        0.4 / rate, rel=1e-9
    )


def test_masks_remove_frames_and_joints():
    rate = 10.0
    t = torch.arange(12, dtype=F64) / rate
    x = torch.zeros(2, 12, 2, 3, dtype=F64)
    x[0, :, :, 0] = (t**3)[:, None]
    x[1, :8, :, 0] = (2 * t[:8] ** 3)[:, None]
    x[1, 8:] = 1e3  # padding garbage
    valid = torch.ones(2, 12, dtype=torch.bool)
    valid[1, 8:] = False
    metric = JerkIndex(squared=False)
    values = metric.update(x, rate, valid)
    assert values.tolist() == pytest.approx([6.0, 12.0], rel=1e-9)
    per_frame_joints = torch.ones(2, 12, 2, dtype=torch.bool)
    per_frame_joints[0, 5, 1] = False  # joint 1 missing at frame 5: its jerks at t = 2..5 drop
    x[0, :, 1, 0] += torch.where(torch.arange(12) == 5, 9.0, 0.0).to(F64)
    assert S.jerk_index(x, rate, valid, joints=per_frame_joints, squared=False)[0].item() == pytest.approx(
        6.0, rel=1e-9
    )
    assert metric.compute().mean == pytest.approx(9.0)


def test_bandai_walking_smoothness(walks):
    """Clean 30 fps mocap: joint jerk of a few tens of m/s^3 and a COM energy that varies by tens of joules; 1 mm
    of white noise gives the ACCL / VEL of its statistics: E||n_{t+1} - n_t|| = sqrt(2) s E[chi_3] per frame."""
    rate = walks[0].rate
    jerks, energy_std = [], []
    noise_vel, noise_acc = [], []
    generator = torch.Generator().manual_seed(1)
    sigma = 0.001
    for walk in walks:
        jerks.append(S.jerk_index(walk.joints, rate, squared=False).item())
        com = walk.com()[:, None]
        energy = S.mechanical_energy(com, torch.tensor([70.0], dtype=F64), rate)
        energy_std.append(S.energy_consistency(energy, std=True).item())
        noisy = walk.joints + sigma * torch.randn(walk.joints.shape, dtype=F64, generator=generator)
        noise_vel.append(S.velocity_error(noisy, walk.joints, rate, per_frame=True).item())
        noise_acc.append(S.acceleration_error(noisy, walk.joints, rate, per_frame=True).item())
    mean = lambda v: sum(v) / len(v)
    chi3 = 2 * math.sqrt(2 / math.pi)  # E of a chi distribution with 3 degrees of freedom
    print(
        f"Bandai walks: jerk {mean(jerks):.1f} m/s^3, energy std {mean(energy_std):.1f} J (70 kg COM), "
        f"noise VEL {mean(noise_vel) * 1e3:.3f} mm/frame, ACCL {mean(noise_acc) * 1e3:.3f} mm/frame^2"
    )
    assert 5.0 < mean(jerks) < 200.0
    assert 1.0 < mean(energy_std) < 100.0
    assert mean(noise_vel) == pytest.approx(math.sqrt(2) * sigma * chi3, rel=0.02)
    assert mean(noise_acc) == pytest.approx(math.sqrt(6) * sigma * chi3, rel=0.02)
