"""Real-data fixtures for the metric tests: Bandai-Namco walking joint centres and the Fukuchi dataset cache."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import torch

from biomotion.data.clips import TRUNK_FRACTION, WINTER_SEGMENTS
from tests.conftest import data_path

WALKS = "bandai-namco/dataset-2"
N_WALKS = 10
FOOT_JOINTS = ("Toes_L", "Toes_R", "Foot_L", "Foot_R")


@dataclass(frozen=True)
class Walk:
    """One Bandai-Namco walking clip as tensors (float64, metres, y up)."""

    name: str
    rate: float
    joints: torch.Tensor  # [T, J, 3]
    names: tuple[str, ...]

    def joint(self, name: str) -> torch.Tensor:
        return self.joints[:, self.names.index(name)]

    def feet(self) -> torch.Tensor:
        """[T, 4, 3] Toes_L, Toes_R, Foot_L, Foot_R joint centres."""
        return self.joints[:, [self.names.index(n) for n in FOOT_JOINTS]]

    def com(self) -> torch.Tensor:
        """[T, 3] whole-body COM from Winter's segment table."""
        com = sum(w * (self.joint(a) + c * (self.joint(b) - self.joint(a))) for a, b, w, c in WINTER_SEGMENTS)
        hips = 0.5 * (self.joint("UpperLeg_L") + self.joint("UpperLeg_R"))
        shoulders = 0.5 * (self.joint("UpperArm_L") + self.joint("UpperArm_R"))
        return com + TRUNK_FRACTION * (hips + 0.5 * (shoulders - hips))


@pytest.fixture(scope="session")
def walks() -> list[Walk]:
    """The first ten dataset-2 ``walk_normal`` takes (30 fps)."""
    from biomotion.io.bvh import read_bvh

    folder = data_path(WALKS)
    files = sorted(folder.glob("dataset-2_walk_normal_*.bvh.gz"))[:N_WALKS]
    if len(files) < N_WALKS:
        pytest.skip(f"real data not available: fewer than {N_WALKS} walk_normal clips in {folder}")
    clips = []
    for path in files:
        motion = read_bvh(path)
        clips.append(
            Walk(
                path.name.split(".")[0], motion.rate, torch.from_numpy(motion.global_positions()), motion.skeleton.names
            )
        )
    return clips


@pytest.fixture(scope="session")
def sole_offsets(walks) -> torch.Tensor:
    """[4] height of the toe and ankle joint centres above the sole when the foot is flat: their lowest height over
    all ten clips (a property of the one proportion-aligned skeleton, about 4.2 cm and 11.7 cm)."""
    return torch.stack([w.feet()[..., 1].amin(0) for w in walks]).amin(0)


def point_mass_zmp(com: torch.Tensor, rate: float) -> torch.Tensor:
    """[T, 3] ZMP of a point mass at ``com`` [T, 3] (Kajita's cart-table model, ground y = 0):
    ``p = c - c_y * c_ddot / (c_ddot_y + g)`` with central differences (one-sided at the ends, ``numpy.gradient``)."""
    c = com.numpy()
    accel = np.gradient(np.gradient(c, axis=0), axis=0) * rate**2
    zmp = c - c[:, [1]] * accel / (accel[:, [1]] + 9.80665)
    zmp[:, 1] = 0.0
    return torch.from_numpy(zmp)


@pytest.fixture(scope="session")
def fukuchi_cache(tmp_path_factory):
    """Dataset cache of the Fukuchi running clips only (23 runners x 3 speeds, 30 Hz)."""
    from biomotion.data.registry import DatasetCache, build_cache

    data_path("fukuchi-running/ik")
    out = tmp_path_factory.mktemp("fukuchi-cache")
    build_cache(data_path(""), out, sources=["fukuchi"], progress=False)
    return DatasetCache(out)
