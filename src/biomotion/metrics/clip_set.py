"""`ClipSet`: the padded kinematics of a set of clips that the set-level metrics score.

Every clip is, at one common rate, the points the metrics need (`biomotion.data.clips` builds it from coordinate
files, a dataset cache or BVH clips):
- ``points`` [N, T, J, 3]: body points (joint centres) for jerk, entropy, reconstruction and fidelity;
- ``feet`` [N, T, K, 3]: foot contact points on the sole for the contact family and the support;
- ``com`` [N, T, 3] and ``total_mass``: the whole-body COM for the point-mass energy;
- ``q`` [N, T, n] with ``mask`` [N, n] (and ``qd``, ``qdd``): coordinates, for joint ranges and full-body physics.
Clips are padded to the longest one; ``valid`` [N, T] marks real frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class ClipSet:
    """Padded kinematics of a set of clips (see the module docstring); ``kind`` is "coordinates" or "bvh";
    ``root`` is the index of the pelvis among ``points`` (ground_pelvis for the model, Hips for a BVH)."""

    kind: str
    names: tuple[str, ...]
    groups: tuple[str, ...]
    rate: float
    valid: torch.Tensor
    points: torch.Tensor
    feet: torch.Tensor
    com: torch.Tensor
    total_mass: float
    q: torch.Tensor | None = None
    mask: torch.Tensor | None = None
    qd: torch.Tensor | None = None
    qdd: torch.Tensor | None = None
    root: int = 0

    def __len__(self) -> int:
        return len(self.names)
