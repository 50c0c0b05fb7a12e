"""Bound violations (PG-BIG Table 1, FlexMotion muscle limits, ranges of motion): hand cases and Fukuchi running."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from biomotion.errors import DataFormatError
from biomotion.metrics import plausibility as P
from biomotion.metrics.bounds import PercentileBounds
from biomotion.metrics.plausibility import (
    ActivationViolation,
    AngularVelocityViolation,
    ComAccelerationViolation,
    ComVelocityViolation,
    JointRangeViolation,
)
from tests.conftest import data_path

F64 = torch.float64


def test_angular_velocity_above_the_95th_percentile_bound():
    rate = 10.0
    t = torch.arange(11, dtype=F64) / rate
    q = torch.stack([2.0 * t, 0.5 * t, -4.0 * t], -1)  # |dq/dt| = 2, 0.5, 4 rad/s
    bounds = PercentileBounds(("a", "b", "c"), [0.0, 0.0, 0.0], [1.0, 1.0, 5.0])
    assert P.angular_velocity_violation(q, rate, bounds=bounds).item() == pytest.approx(1 / 3)
    # Table 1 L_omega: (1/T) sum_t sum_j max(0, |q_dot| - high) = 1 rad/s per frame
    assert AngularVelocityViolation(bounds, statistic="excess").score(q, rate).item() == pytest.approx(1.0)
    # coordinate "a" masked out (per clip), then per frame from frame 5 on
    assert (
        P.angular_velocity_violation(
            q, rate, high=torch.tensor([1.0, 1.0, 5.0]), mask=torch.tensor([False, True, True])
        ).item()
        == 0.0
    )
    per_frame = torch.ones(11, 3, dtype=torch.bool)
    per_frame[5:, 0] = False
    # pair t uses frames t and t + 1, so "a" keeps pairs 0..3: 4 violations among 4 + 10 + 10 entries
    assert P.angular_velocity_violation(q, rate, bounds=bounds, mask=per_frame).item() == pytest.approx(4 / 24)
    with pytest.raises(DataFormatError, match="bounds"):
        P.angular_velocity_violation(q, rate, bounds=bounds.select(["a", "b"]))


def test_com_speed_and_acceleration_bounds():
    rate = 20.0
    t = torch.arange(21, dtype=F64) / rate
    com = torch.stack([2.0 * t, torch.ones_like(t), torch.zeros_like(t)], -1)  # 2 m/s, no acceleration
    speed_bounds = PercentileBounds(("com_speed",), [0.5], [1.5])
    assert ComVelocityViolation(speed_bounds).score(com, rate).item() == 1.0
    assert ComVelocityViolation(speed_bounds, statistic="excess").score(com, rate).item() == pytest.approx(0.5)
    slow = com * 0.1  # 0.2 m/s: below the low bound
    assert P.com_velocity_violation(slow, rate, bounds=speed_bounds, statistic="excess").item() == pytest.approx(0.3)
    accel = torch.stack([3.0 * t**2, torch.ones_like(t), torch.zeros_like(t)], -1)  # |c_ddot| = 6 m/s^2
    assert ComAccelerationViolation(low=1.0, high=4.0, statistic="excess").score(accel, rate).item() == pytest.approx(
        2.0
    )
    valid = torch.ones(21, dtype=torch.bool)
    valid[10:] = False
    assert P.com_acceleration_violation(accel, rate, low=1.0, high=7.0, valid=valid).item() == 0.0


def test_activation_limits_and_joint_ranges():
    activations = torch.tensor([[0.1, 0.9, 1.2], [0.0, -0.1, 0.5]], dtype=F64)  # two entries outside [0, 1]
    assert ActivationViolation().score(activations).item() == pytest.approx(2 / 6)
    assert ActivationViolation(statistic="excess").score(activations).item() == pytest.approx((0.2 + 0.1) / 2)
    muscle_bounds = PercentileBounds(("m1", "m2", "m3"), [0.05, 0.2, 0.1], [0.3, 0.8, 0.6])
    assert P.activation_violation(activations, bounds=muscle_bounds).item() == pytest.approx(4 / 6)
    q = torch.tensor([[0.0, 2.5], [0.2, -0.1], [math.radians(130), 0.0]], dtype=F64)
    low, high = torch.tensor([0.0, -0.5]), torch.tensor([math.radians(120), 2.0])
    assert JointRangeViolation(low=low, high=high).score(q).item() == pytest.approx(2 / 6)
    assert JointRangeViolation(low=low, high=high, statistic="excess").score(q).item() == pytest.approx(
        (0.5 + math.radians(10)) / 3
    )
    with pytest.raises(DataFormatError, match="statistic"):
        JointRangeViolation(statistic="max")


def test_fukuchi_running_against_training_bounds(fukuchi_cache):
    """Bounds of |dq/dt| learnt on the training runners (5th/95th percentile, PG-BIG Table 1) flag about 5 % of
    the held-out runners' frames; the Rajagopal model's ranges of motion are almost never left."""
    from biomotion.io.osim import read_osim

    cache = fukuchi_cache
    names = cache.coordinates
    clips = {split: [cache.motion(i) for i in cache.indices(split=split)] for split in ("train", "val", "test")}
    speeds = torch.cat([P.coordinate_speed(torch.from_numpy(m.values), cache.rate) for m in clips["train"]])
    mask = torch.from_numpy(np.stack([m.mask for m in clips["train"]])).repeat_interleave(
        torch.tensor([m.n_frames - 1 for m in clips["train"]]), dim=0
    )
    bounds = PercentileBounds.from_samples(speeds, names, mask=mask, quantity="|dq/dt|", unit="rad/s or m/s")
    assert np.isnan(bounds.high[names.index("lumbar_extension")])  # not in the Fukuchi model
    knee = bounds.high[names.index("knee_angle_r")]
    assert 10.0 < knee < 25.0  # rad/s, running knee swing
    train_rate = np.mean(
        [
            P.angular_velocity_violation(
                torch.from_numpy(m.values), cache.rate, bounds=bounds, mask=torch.from_numpy(m.mask)
            ).item()
            for m in clips["train"]
        ]
    )
    held_out = [
        P.angular_velocity_violation(
            torch.from_numpy(m.values), cache.rate, bounds=bounds, mask=torch.from_numpy(m.mask)
        ).item()
        for m in clips["val"] + clips["test"]
    ]
    assert train_rate == pytest.approx(0.05, abs=0.01)
    assert 0.01 < np.mean(held_out) < 0.15
    model = read_osim(data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim"))
    ranges = {c.name: c.range for c in model.coordinates}
    low = torch.tensor([ranges[n][0] for n in names], dtype=F64)
    high = torch.tensor([ranges[n][1] for n in names], dtype=F64)
    # translations are left out, as `biomotion eval` does: placed overground runs travel past pelvis_tx's +-5 m
    rotations = torch.tensor([not n.startswith("pelvis_t") for n in names])
    range_rates = [
        JointRangeViolation(low=low, high=high)
        .score(torch.from_numpy(m.values), torch.from_numpy(m.mask) & rotations)
        .item()
        for m in clips["train"] + clips["val"] + clips["test"]
    ]
    print(
        f"Fukuchi: knee speed bound {knee:.1f} rad/s; angular-velocity violations train {train_rate:.3f}, "
        f"held out {np.mean(held_out):.3f}; range-of-motion violations {np.mean(range_rates):.4f}"
    )
    assert np.mean(range_rates) < 0.01


def test_bandai_com_bounds_from_other_takes(walks):
    """COM speed and acceleration bounds (5th/95th percentiles) from five walks flag roughly 10 % of the frames of
    five other takes of the same walk (5 % on each side)."""
    rate = walks[0].rate
    coms = [w.com() for w in walks]
    speed = PercentileBounds.from_samples(
        torch.cat([P.com_speed(c, rate) for c in coms[:5]]), ("com_speed",), unit="m/s"
    )
    accel = PercentileBounds.from_samples(
        torch.cat([P.com_acceleration(c, rate) for c in coms[:5]]), ("com_acceleration",), unit="m/s^2"
    )
    speed_rates = [ComVelocityViolation(speed).score(c, rate).item() for c in coms[5:]]
    accel_rates = [ComAccelerationViolation(accel).score(c, rate).item() for c in coms[5:]]
    print(
        f"Bandai COM: speed bounds {speed.low[0]:.2f}-{speed.high[0]:.2f} m/s, acceleration bounds "
        f"{accel.low[0]:.2f}-{accel.high[0]:.2f} m/s^2; held-out violations {np.mean(speed_rates):.3f}, "
        f"{np.mean(accel_rates):.3f}"
    )
    assert 0.8 < speed.low[0] < speed.high[0] < 2.5  # walking speed, m/s
    assert 0.03 < np.mean(speed_rates) < 0.3 and 0.03 < np.mean(accel_rates) < 0.3
