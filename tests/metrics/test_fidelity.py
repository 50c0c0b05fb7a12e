"""Fidelity after temporal alignment, the Gaussian W2 variant, motion entropy and diversity."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from biomotion.errors import DataFormatError
from biomotion.metrics import fidelity as F
from biomotion.metrics.fidelity import Diversity, Fidelity, GaussianFidelity, MotionEntropy
from tests.conftest import data_path

F64 = torch.float64


def brute_force_dtw(cost: np.ndarray) -> tuple[float, int]:
    """Textbook O(NM) double loop, the reference for `dtw`."""
    rows, cols = cost.shape
    total = np.full((rows + 1, cols + 1), np.inf)
    steps = np.zeros((rows + 1, cols + 1))
    total[0, 0] = 0.0
    for i in range(1, rows + 1):
        for j in range(1, cols + 1):
            options = [
                (total[i - 1, j - 1], steps[i - 1, j - 1]),
                (total[i - 1, j], steps[i - 1, j]),
                (total[i, j - 1], steps[i, j - 1]),
            ]
            k = int(np.argmin([o[0] for o in options]))
            total[i, j] = cost[i - 1, j - 1] + options[k][0]
            steps[i, j] = options[k][1] + 1
    return total[rows, cols], int(steps[rows, cols])


def test_dtw_by_hand_and_against_the_double_loop():
    cost = torch.tensor([[[0.0, 1.0, 2.0], [1.0, 0.0, 1.0]]], dtype=F64)
    # best path (0,0) -> (1,1) -> (1,2): 0 + 0 + 1 over 3 cells
    total, steps = F.dtw(cost, torch.tensor([2]), torch.tensor([3]))
    assert total.item() == 1.0 and steps.item() == 3
    rng = np.random.default_rng(0)
    costs = rng.random((4, 7, 9))
    n, m = torch.tensor([7, 3, 5, 1]), torch.tensor([9, 9, 2, 4])
    total, steps = F.dtw(torch.from_numpy(costs), n, m)
    for b in range(4):
        expected_total, expected_steps = brute_force_dtw(costs[b, : n[b], : m[b]])
        assert total[b].item() == pytest.approx(expected_total, abs=1e-12) and steps[b].item() == expected_steps


def wave(frames: int, phase: float = 0.0) -> torch.Tensor:
    """[T, 2, 3] two joints tracing one period of a circle of radius 0.3 m."""
    t = torch.linspace(0, 2 * math.pi, frames, dtype=F64) + phase
    joint = torch.stack([0.3 * torch.cos(t), 0.3 * torch.sin(t), torch.zeros_like(t)], -1)
    return torch.stack([joint, joint + torch.tensor([0.0, 0.0, 1.0], dtype=F64)], 1)


def test_fidelity_undoes_a_change_of_pace():
    ref = wave(40)
    slow_start = torch.cat([ref[:1].expand(15, 2, 3), ref])  # holds the first pose for 15 frames
    assert F.aligned_joint_error(slow_start, ref).item() == pytest.approx(0.0, abs=1e-12)
    linear = F.aligned_joint_error(slow_start, ref, align="linear").item()
    assert linear > 0.05
    stretched = wave(70)  # same path, other length
    assert F.aligned_joint_error(stretched, ref, align="linear").item() < 0.005
    assert F.aligned_joint_error(ref + 0.02, ref).item() == pytest.approx(0.02 * math.sqrt(3), abs=1e-12)


def test_fidelity_batches_with_padding_and_joint_masks():
    ref = wave(40)
    pred_a, pred_b = wave(30, 0.3), wave(50)
    pred = torch.zeros(2, 50, 2, 3, dtype=F64)
    pred[0, :30], pred[1] = pred_a, pred_b
    pred[0, 30:] = 100.0
    valid = torch.ones(2, 50, dtype=torch.bool)
    valid[0, 30:] = False
    metric = Fidelity()
    batched = metric.update(pred, ref, valid)
    single = torch.stack([F.aligned_joint_error(pred_a, ref), F.aligned_joint_error(pred_b, ref)])
    torch.testing.assert_close(batched, single, rtol=0, atol=1e-12)
    off = ref.clone()
    off[:, 1] += 1.0
    assert F.aligned_joint_error(off, ref, joints=torch.tensor([True, False])).item() == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(DataFormatError, match="prefix"):
        F.aligned_joint_error(pred, ref, pred_valid=torch.tensor([False] + [True] * 49))
    with pytest.raises(DataFormatError, match="align"):
        Fidelity(align="soft")


def test_gaussian_w2_per_feature():
    pred = torch.tensor([[0.0, 10.0], [2.0, 10.0]], dtype=F64)  # feature 0: mean 1, std 1; feature 1: 10, 0
    ref = torch.tensor([[3.0, 10.0], [7.0, 10.0], [3.0, 10.0], [7.0, 10.0]], dtype=F64)  # 5, 2 and 10, 0
    assert F.gaussian_w2(pred, ref).item() == pytest.approx(math.sqrt(17) / 2)
    assert GaussianFidelity().score(pred, ref, mask=torch.tensor([True, False])).item() == pytest.approx(math.sqrt(17))


def test_entropy_of_known_histograms():
    uniform = torch.arange(50, dtype=F64)[:, None]  # one value per bin
    assert F.motion_entropy(uniform).item() == pytest.approx(math.log(50))
    two = torch.tensor([[0.0, 1.0], [0.0, 1.0]], dtype=F64)  # two equally likely values
    assert F.motion_entropy(two).item() == pytest.approx(math.log(2))
    assert F.motion_entropy(torch.full((5, 3), 0.7, dtype=F64)).item() == 0.0
    padded = torch.cat([two, torch.tensor([[5.0, 9.0]], dtype=F64)])
    assert MotionEntropy().score(padded, torch.tensor([True, True, False])).item() == pytest.approx(math.log(2))
    assert MotionEntropy(bins=1).score(uniform).item() == 0.0


def test_diversity_of_three_motions():
    diversity = Diversity()
    diversity.update(torch.tensor([[0.0, 0.0], [3.0, 0.0]]))
    diversity.update(torch.tensor([0.0, 4.0]))
    result = diversity.compute()
    assert result.mean == pytest.approx(4.0) and result.count == 3  # pairs 3, 4, 5
    assert result.std == pytest.approx(math.sqrt(2 / 3))


def facing_frame(joints: torch.Tensor, names: tuple[str, ...]) -> torch.Tensor:
    """Joints relative to the hips joint, turned about y so that the clip's mean right-to-left hip axis is +x
    (clips are captured walking either way along z)."""
    left_right = (joints[:, names.index("UpperLeg_L")] - joints[:, names.index("UpperLeg_R")]).mean(0)
    angle = torch.atan2(left_right[2], left_right[0])
    c, s = torch.cos(angle), torch.sin(angle)
    turn = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=F64)  # rotation by +angle about y
    relative = joints - joints[:, names.index("Hips")][:, None]
    return relative @ turn.T


def test_bandai_fidelity_entropy_and_diversity(walks):
    """Real clips in a common facing frame: another take of the same walk is closer (a few cm after DTW) than an
    elderly walk and than a different action; a clip is at 0 from itself. Entropy of all joint heights in 50 bins
    is near PG-BIG's reference (3.47 nats)."""
    from biomotion.io.bvh import read_bvh

    folder = data_path("bandai-namco/dataset-2")
    others = {}
    for label, pattern in (
        ("elderly walk", "dataset-2_walk_elderly_*.bvh.gz"),
        ("raise both hands", "dataset-2_raise-up-both-hands_normal_*.bvh.gz"),
    ):
        files = sorted(folder.glob(pattern))
        if not files:
            pytest.skip(f"real data not available: no {pattern} in {folder}")
        others[label] = facing_frame(torch.from_numpy(read_bvh(files[0]).global_positions()), walks[0].names)
    reference = facing_frame(walks[0].joints, walks[0].names)
    same_action = [F.aligned_joint_error(facing_frame(w.joints, w.names), reference).item() for w in walks[1:4]]
    other = {k: F.aligned_joint_error(v, reference).item() for k, v in others.items()}
    entropy = [F.motion_entropy(w.joints[..., 1]).item() for w in walks]
    features = lambda pose: torch.cat([pose.mean(0).reshape(-1), pose.std(0).reshape(-1)])  # noqa: E731
    walking, diversity = Diversity(), Diversity()
    for pose in [facing_frame(w.joints, w.names) for w in walks[:4]]:
        walking.update(features(pose))
        diversity.update(features(pose))
    for pose in others.values():
        diversity.update(features(pose))
    print(
        f"Bandai fidelity (facing frame, DTW): same walk {np.mean(same_action) * 100:.2f} cm, "
        + ", ".join(f"{k} {v * 100:.2f} cm" for k, v in other.items())
        + f"; entropy {np.mean(entropy):.3f} nats; diversity {diversity.compute().mean:.3f} m"
    )
    assert F.aligned_joint_error(walks[0].joints, walks[0].joints, root=1).item() == 0.0
    assert 0.005 < np.mean(same_action) < 0.08
    assert max(same_action) < min(other.values())
    assert 2.5 < np.mean(entropy) < math.log(50)
    assert walking.compute().mean < diversity.compute().mean  # other styles and actions add diversity
    flat = lambda pose: pose.reshape(pose.shape[0], -1)  # noqa: E731
    w2_same = F.gaussian_w2(flat(facing_frame(walks[1].joints, walks[1].names)), flat(reference)).item()
    w2_other = {k: F.gaussian_w2(flat(v), flat(reference)).item() for k, v in others.items()}
    print(f"Gaussian W2 (m): same walk {w2_same:.4f}, " + ", ".join(f"{k} {v:.4f}" for k, v in w2_other.items()))
    assert 0.0 < w2_same < min(w2_other.values())
