"""Left-right mirror images of canonical motion and of muscle-activation labels (training-data augmentation).

Reflecting a motion through the sagittal plane (z -> -z in the OpenSim ground frame: x forward, y up, z right)
gives another plausible motion of the same person, with left and right exchanged. In the Rajagopal 2016 model the
left limbs' joint axes are the mirror images of the right ones, so a limb coordinate keeps its value and moves to
the other side (hip_flexion_r <-> hip_flexion_l, ...); the coordinates about the x and y axes of the midline
(pelvis_list, pelvis_rotation, lumbar_bending, lumbar_rotation) and the lateral translation pelvis_tz change sign.
``tests/data/test_mirror.py`` checks the result by forward kinematics: every body of the mirrored pose is the
reflection of its counterpart.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from biomotion.body.canonical import CANONICAL_COORDINATES

NEGATED = ("pelvis_list", "pelvis_rotation", "pelvis_tz", "lumbar_bending", "lumbar_rotation")


def other_side(name: str) -> str:
    """``x_r`` <-> ``x_l`` (also ``knee_angle_r_beta``); names of neither side are returned unchanged."""
    for a, b in (("_r", "_l"), ("_l", "_r")):
        if name.endswith(a):
            return name[: -len(a)] + b
        if f"{a}_" in name:
            return name.replace(f"{a}_", f"{b}_", 1)
    return name


def mirror_permutation(names: Sequence[str]) -> np.ndarray:
    """Index array p with ``mirrored[..., i] = values[..., p[i]]`` (names without a counterpart map to themselves)."""
    index = {n: i for i, n in enumerate(names)}
    return np.array([index.get(other_side(n), i) for i, n in enumerate(names)])


def mirror_coordinates(
    values: np.ndarray, mask: np.ndarray | None = None, names: Sequence[str] = CANONICAL_COORDINATES
) -> tuple[np.ndarray, np.ndarray | None]:
    """Mirror image of coordinates [..., n] (and of the per-coordinate mask [..., n])."""
    p = mirror_permutation(names)
    sign = np.array([-1.0 if n in NEGATED else 1.0 for n in names], dtype=values.dtype)
    return values[..., p] * sign, None if mask is None else mask[..., p]


def mirror_labels(values: np.ndarray, names: Sequence[str]) -> np.ndarray:
    """Per-muscle values [..., M] of the mirrored motion: each muscle takes its counterpart's."""
    return values[..., mirror_permutation(names)]


def mirror_ground_vectors(values: np.ndarray) -> np.ndarray:
    """Ground-frame vectors [..., 3k] (consecutive x, y, z triples, e.g. COM velocity then acceleration) of the
    mirror image: every z component changes sign."""
    if values.shape[-1] % 3:
        raise ValueError(f"expected x, y, z triples in the last axis; got {values.shape[-1]} values")
    return values * np.tile(np.array([1, 1, -1], dtype=values.dtype), values.shape[-1] // 3)
