"""MJE, P-MJE and the global-trajectory error: exact cases and Bandai-Namco joints."""

from __future__ import annotations

import math

import pytest
import torch
from scipy.spatial.transform import Rotation

from biomotion.metrics import reconstruction as R
from biomotion.metrics.reconstruction import GlobalTrajectoryError, JointError, ProcrustesJointError

F64 = torch.float64


def test_constant_offset_and_root_relative_error():
    target = torch.randn(10, 5, 3, dtype=F64, generator=torch.Generator().manual_seed(0))
    shifted = target + torch.tensor([0.03, 0.0, 0.04], dtype=F64)
    assert R.joint_error(shifted, target).item() == pytest.approx(0.05, abs=1e-12)
    assert JointError(root=0).score(shifted, target).item() == pytest.approx(0.0, abs=1e-12)
    one_joint_off = target.clone()
    one_joint_off[:, 2] += torch.tensor([0.0, 0.1, 0.0], dtype=F64)
    assert R.joint_error(one_joint_off, target).item() == pytest.approx(0.02, abs=1e-12)
    assert R.joint_error(one_joint_off, target, joints=torch.tensor([1, 1, 0, 1, 1])).item() == 0.0


def test_procrustes_removes_a_similarity_transform():
    generator = torch.Generator().manual_seed(1)
    target = torch.randn(2, 6, 8, 3, dtype=F64, generator=generator)
    rotation = torch.from_numpy(Rotation.from_euler("zyx", [30, -50, 110], degrees=True).as_matrix())
    pred = 1.3 * target @ rotation.T + torch.tensor([0.5, -1.0, 2.0], dtype=F64)
    assert R.procrustes_joint_error(pred, target).abs().max().item() < 1e-12
    assert R.joint_error(pred, target).min().item() > 0.1
    # a reflection is not a rotation: a mirrored pose keeps an error
    mirrored = target * torch.tensor([-1.0, 1.0, 1.0], dtype=F64)
    assert R.procrustes_joint_error(mirrored, target).min().item() > 0.05
    # a masked joint neither drives the alignment nor counts
    broken = pred.clone()
    broken[..., 3, :] += 5.0
    joints = torch.ones(8, dtype=torch.bool)
    joints[3] = False
    assert ProcrustesJointError().score(broken, target, joints=joints).abs().max().item() < 1e-12


def test_global_trajectory_error_realigns_every_window():
    # 4 s at 10 Hz, root drifting at 0.1 m/s along x; 2 s windows: error at frame k of a window is 0.01 k m
    rate, frames = 10.0, 40
    target = torch.zeros(frames, 2, 3, dtype=F64)
    target[:, 1, 1] = 1.0
    drift = torch.zeros(frames, 1, 3, dtype=F64)
    drift[:, 0, 0] = 0.1 * torch.arange(frames, dtype=F64) / rate
    pred = target + drift + torch.tensor([5.0, 0.0, 0.0], dtype=F64)  # plus a constant offset, removed per window
    expected = 0.01 * sum(range(20)) / 20
    assert R.global_trajectory_error(pred, target, rate, window=2.0).item() == pytest.approx(expected, abs=1e-12)
    assert GlobalTrajectoryError(window=10.0).score(pred, target, rate).item() == pytest.approx(
        0.01 * sum(range(40)) / 40, abs=1e-12
    )


def test_bandai_joints_under_a_rigid_transform_and_noise(walks):
    """A rotated, scaled, moved copy of real poses has zero P-MJE but a large MJE; 1 cm of noise per axis gives
    an MJE of sqrt(2) * 2 / sqrt(pi) cm (mean of a chi_3 of scale 1 cm: 1.60 cm)."""
    rotation = torch.from_numpy(Rotation.from_euler("y", 90, degrees=True).as_matrix())
    generator = torch.Generator().manual_seed(2)
    errors = []
    for walk in walks[:3]:
        moved = 0.9 * walk.joints @ rotation.T + torch.tensor([1.0, 0.0, 0.0], dtype=F64)
        assert R.procrustes_joint_error(moved, walk.joints).item() < 1e-9
        assert R.joint_error(moved, walk.joints).item() > 0.5
        noisy = walk.joints + 0.01 * torch.randn(walk.joints.shape, dtype=F64, generator=generator)
        errors.append((R.joint_error(noisy, walk.joints).item(), R.procrustes_joint_error(noisy, walk.joints).item()))
    chi3 = 2 * math.sqrt(2 / math.pi)
    mje = sum(e[0] for e in errors) / len(errors)
    pmje = sum(e[1] for e in errors) / len(errors)
    print(f"Bandai joints + 1 cm noise: MJE {mje * 100:.3f} cm, P-MJE {pmje * 100:.3f} cm")
    assert mje == pytest.approx(0.01 * chi3, rel=0.02)
    assert 0.5 * mje < pmje < mje  # alignment absorbs part of the noise, never adds to it


def test_bandai_trajectory_against_a_straight_walk(walks):
    """The hips of real walks against a constant-velocity straight line between their first and last positions:
    the clips start and end at rest, so the real hips lag the line by decimetres in the middle (a mean of ~13 cm),
    plus a few cm of sway."""
    errors = []
    for walk in walks:
        hips = walk.joint("Hips")[:, None]
        line = hips[:1] + (hips[-1:] - hips[:1]) * torch.linspace(0, 1, hips.shape[0], dtype=F64)[:, None, None]
        errors.append(R.global_trajectory_error(line, hips, walk.rate).item())
    print(f"Bandai hips vs straight line: G-MPJPE {sum(errors) / len(errors) * 100:.2f} cm")
    assert 0.03 < sum(errors) / len(errors) < 0.3
