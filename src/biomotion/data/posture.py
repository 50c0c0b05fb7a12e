"""Marker-placement posture offsets: the same movement as another lab's markers would have reported it.

Marker IK reports the pelvis' orientation from markers on the pelvis and each thigh's from markers on the thigh,
so a few millimetres of marker placement tilt the pelvis by several degrees while the thighs keep their place:
across the 23 Fukuchi runners at 3.5 m/s (their shipped IK in the dataset cache) the per-runner mean pelvis tilt
spans -13.4 to +4.5 deg (standard deviation 3.8), while mean tilt plus hip flexion (the thigh's angle in the
ground) varies half as much (4.6 to 12 deg, s.d. 1.8). The hip's mean axial rotation, set by the knee-axis
markers, spans -17.8 to -1.8 deg (s.d. 4.0). A new subject brings a new such offset.

`posture_offset` gives a clip such an offset: the pelvis turned by (tilt, list, rotation), the hips and the lumbar
joint turned back so that each thigh and the trunk keep their orientation in the ground (exactly: R_joint' =
R_pelvis'ᵀ R_pelvis R_joint, decomposed again in the joint's own axis order), the pelvis origin moved so the
midpoint of the hip centres stays where it was, and each hip's axial rotation offset. The legs below the hips and
the trunk above the lumbar joint then turn as before and move as before but for a few millimetres (a list or
rotation turns the hip centres about their midpoint: 7.7 cm x sin 3 deg = 4 mm); what changes is what differs
between labs: the pelvis segment and the hip angles (hence muscle lengths and moment arms). A masked (absent)
lumbar joint stays absent: the trunk then turns with the pelvis, as in the source's data.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from biomotion.body.model import BodyModel
from biomotion.errors import ModelError
from biomotion.motion import Motion

PELVIS = "ground_pelvis"
TURNED_BACK = ("hip_r", "hip_l", "back")  # the joints whose child keeps its ground orientation
AXIAL = ("hip_rotation_r", "hip_rotation_l")  # offset about each femur's own long axis
#: half-widths (deg) of the uniform offsets `random_offsets` draws: about twice the standard deviation of the
#: Fukuchi runners' per-runner means (module docstring); list and rotation about the same share of their ranges
SPREAD_DEG = {
    "pelvis_tilt": 8.0,
    "pelvis_list": 2.0,
    "pelvis_rotation": 3.0,
    "hip_rotation_r": 6.0,
    "hip_rotation_l": 6.0,
}


def _joint(model: BodyModel, name: str):
    for joint in model.joints:
        if joint.name == name:
            return joint
    raise ModelError(f"model {model.name!r} has no joint {name!r}")


def _rotation_axes(model: BodyModel, name: str) -> tuple[list[int], np.ndarray, np.ndarray, str]:
    """(coordinates, slopes, intercepts, scipy axis sequence) of a joint whose three rotations are each a linear
    function of one coordinate about a coordinate axis, with no frame rotations (the Rajagopal hips, back and
    pelvis)."""
    joint = _joint(model, name)
    rotations = [axis for axis in joint.axes if axis.rotation]
    if len(rotations) != 3 or any(not hasattr(a.function, "slope") for a in rotations):
        raise ModelError(f"joint {name!r} is not three linear rotations: no posture offset for it")
    if not (
        np.allclose(joint.parent_rotation.numpy(), np.eye(3)) and np.allclose(joint.child_rotation.numpy(), np.eye(3))
    ):
        raise ModelError(f"joint {name!r} has rotated frames: no posture offset for it")
    letters = []
    for axis in rotations:
        direction = axis.axis.numpy()
        k = int(np.argmax(np.abs(direction)))
        if not np.isclose(abs(direction[k]), 1.0) or direction[k] < 0:
            raise ModelError(f"joint {name!r} turns about {direction}, not a positive coordinate axis")
        letters.append("XYZ"[k])
    return (
        [a.coordinate for a in rotations],
        np.array([a.function.slope for a in rotations]),
        np.array([a.function.intercept for a in rotations]),
        "".join(letters),
    )


def _amounts(values: np.ndarray, axes) -> np.ndarray:
    columns, slopes, intercepts, _ = axes
    return values[:, columns] * slopes + intercepts


def posture_offset(motion: Motion, model: BodyModel, offsets_deg: Mapping[str, float]) -> Motion:
    """``motion`` (the model's coordinates, with its mask) with the pelvis turned by ``offsets_deg``'s
    pelvis_tilt / pelvis_list / pelvis_rotation and the hips and lumbar joint turned back (module docstring),
    then each hip's axial rotation offset by ``offsets_deg``'s hip_rotation_r / hip_rotation_l (deg; absent
    keys are 0)."""
    if tuple(motion.names) != tuple(model.coordinate_names):
        raise ModelError(f"posture offsets need the model's coordinates in its order, got {motion.names[:3]}...")
    values = motion.values.copy()
    pelvis = _rotation_axes(model, PELVIS)
    old = Rotation.from_euler(pelvis[3], _amounts(values, pelvis))
    turned = _amounts(values, pelvis) + np.radians([offsets_deg.get(model.coordinate_names[c], 0.0) for c in pelvis[0]])
    new = Rotation.from_euler(pelvis[3], turned)
    values[:, pelvis[0]] = (turned - pelvis[2]) / pelvis[1]
    change = new.inv() * old  # R_pelvis'ᵀ R_pelvis
    for name in TURNED_BACK:
        axes = _rotation_axes(model, name)
        if not motion.mask[axes[0]].all():
            continue
        joint = Rotation.from_euler(axes[3], _amounts(values, axes))
        amounts = (change * joint).as_euler(axes[3])
        values[:, axes[0]] = (amounts - axes[2]) / axes[1]
    hips = 0.5 * (_joint(model, "hip_r").parent_translation + _joint(model, "hip_l").parent_translation).numpy()
    translations = [model.coordinate_index(f"pelvis_t{k}") for k in "xyz"]
    values[:, translations] += old.apply(hips) - new.apply(hips)
    for name in AXIAL:
        values[:, model.coordinate_index(name)] += np.radians(offsets_deg.get(name, 0.0))
    return motion.with_values(values)


def random_offsets(rng: np.random.Generator, spread_deg: Mapping[str, float] = SPREAD_DEG) -> dict[str, float]:
    """Offsets (deg) drawn uniformly within ± each coordinate's ``spread_deg``."""
    return {name: float(rng.uniform(-half, half)) for name, half in spread_deg.items()}


def keeps_ranges(original: Motion, offset: Motion, model: BodyModel) -> bool:
    """Whether the offset copy puts no clamped coordinate outside the model's range at a frame where the
    original had it inside (the sources' own data leave ranges here and there: that is not the offset's doing)."""
    check = original.mask & model.clamped.numpy()
    low, high = model.ranges.numpy()[check].T

    def outside(motion: Motion) -> np.ndarray:
        part = motion.values[:, check]
        return (part < low - 1e-9) | (part > high + 1e-9)

    return not bool(np.any(outside(offset) & ~outside(original)))
