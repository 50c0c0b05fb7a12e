"""A `Motion` of a `BodyModel` as a BVH clip: one BVH joint per body, exact body origins and orientations.

The BVH format (Biovision; Meredith & Maddock 2001, "Motion capture file formats explained", University of
Sheffield, section 2.2; `biomotion.io.bvh`) places each joint at its parent's origin plus the parent's rotation
applied to the joint's OFFSET (or to its position channels where it has them), and turns it by intrinsic Euler
rotations in channel order. The skeleton built here is the model's body tree:

- joints: the model's bodies, depth first from the root body (the one body jointed to ground, pelvis in the
  Rajagopal 2016 model), children in BodySet order; a joint's position is its body's origin;
- ``OFFSET``: the child body's origin in its parent body's frame with every coordinate at zero. OpenSim joint
  frames may sit away from the body origins (X_PB = X_PF X_FM(q) X_MB, Seth et al. 2018), so this is taken from
  forward kinematics (origin positions in ground expressed in the parent's frame), not from the joint frames;
- channels: the root has ``Xposition Yposition Zposition Zrotation Xrotation Yrotation``; a body whose origin
  moves in its parent's frame when the coordinates change (its joint translates along a coordinate-driven axis,
  e.g. Rajagopal's ``walker_knee`` and ``patellofemoral`` joints, or its joint rotates about a child frame offset
  from the body origin) gets the same six channels, so its origin is exact; every other body has ``Zrotation
  Xrotation Yrotation``. With ``joint_translations=False`` only the root has position channels (what some BVH
  tools expect); those bodies then keep their zero-pose offset and their origins are off by the joint's
  translation: in cached runs, walks, squats and drop jumps, up to 1.0 cm for the tibia (and the foot below it)
  and 7.3 cm for the patella;
- rotations: each body's orientation relative to its parent's, R_rel = R_GP^T R_GB from batched forward
  kinematics, as Z-X-Y Euler angles in degrees: R_rel = Rz(z) Rx(x) Ry(y), the order of OpenSim's hip and
  shoulder joints (flexion about z, adduction about x, rotation about y), so the middle angle -- the one that
  locks at +-90 degrees -- is the usually small adduction. Angles are unwrapped over time (no 360-degree jumps);
- positions: metres in the `BVHMotion` (``units="m"``); `biomotion.io.bvh.write_bvh` converts to the file's
  unit (``units="cm"`` by default). Axes are OpenSim's ground frame: y up, x forward, z to the right.

Dependent coordinates of coordinate couplers (Rajagopal's ``knee_angle_r_beta`` ...) are recomputed from their
independent ones before forward kinematics (``couplers=True``), as OpenSim enforces those constraints and the
dataset holds placeholders there.
"""

from __future__ import annotations

import numpy as np
import torch

from biomotion.body.canonical import DEFAULT_RATE
from biomotion.body.kinematics import apply_couplers, forward_kinematics
from biomotion.body.model import BodyModel
from biomotion.errors import DataFormatError, ModelError
from biomotion.io.bvh import BVHMotion, Skeleton
from biomotion.motion import Motion

ROTATION_CHANNELS: tuple[str, ...] = ("Zrotation", "Xrotation", "Yrotation")
"""Rotation channel order of every exported joint: R = Rz(z) Rx(x) Ry(y) (intrinsic, degrees)."""
POSITION_CHANNELS: tuple[str, ...] = ("Xposition", "Yposition", "Zposition")
_GIMBAL = 1e-9  # |cos(x)| below this: z and y turn about the same axis; y is set to 0


def motion_to_bvh(
    model: BodyModel,
    motion: Motion,
    *,
    couplers: bool = True,
    joint_translations: bool = True,
    frame_time: float | None = None,
) -> BVHMotion:
    """The BVH clip of ``motion`` on ``model`` (see the module docstring for the skeleton and channels).

    Args:
        model: the body model whose coordinates ``motion`` holds (e.g. Rajagopal 2016 for canonical motions).
        motion: coordinates over time, SI units (rad, m); every model coordinate must be a column (extra columns
            are ignored); uniformly sampled.
        couplers: recompute coupled (dependent) coordinates from their independent ones first.
        joint_translations: give position channels to bodies whose origin moves in their parent's frame (exact
            origins); False: position channels on the root only.
        frame_time: seconds per frame; default 1 / the motion's rate (1 / 30 s for a one-frame motion).

    Returns:
        A `BVHMotion` in metres whose `global_positions` are the body origins of the model's forward kinematics
        (joints named after the bodies, depth-first order).
    """
    model64 = model.to(torch.float64)
    q = _coordinates(model64, motion)
    zero = torch.zeros(model64.n_q, dtype=torch.float64)
    if couplers:
        q, zero = apply_couplers(model64, q), apply_couplers(model64, zero)
    order, parents = _depth_first(model64)
    index = torch.tensor(order)
    parent_body = torch.tensor([model64.parent[b] for b in order])

    rest = forward_kinematics(model64, zero)
    offsets = _in_parent(rest.rotations[index], rest.positions[index], rest.rotations, rest.positions, parent_body)

    poses = forward_kinematics(model64, q)  # [T, B, ...]
    rotations, positions = poses.rotations[:, index], poses.positions[:, index]
    relative = _in_parent(rotations, positions, poses.rotations, poses.positions, parent_body, rotate_too=True)
    local_rotation, local_position = relative
    angles = np.degrees(zxy_euler(local_rotation).numpy())  # [T, J, 3]
    angles = np.unwrap(angles, period=360.0, axis=0)
    local_position = local_position.numpy()

    translating = [model64.parent[b] < 0 or (joint_translations and _translates(model64, b)) for b in order]
    channels = tuple((*POSITION_CHANNELS, *ROTATION_CHANNELS) if moves else ROTATION_CHANNELS for moves in translating)
    columns = [
        np.concatenate([local_position[:, j], angles[:, j]], axis=1) if moves else angles[:, j]
        for j, moves in enumerate(translating)
    ]
    skeleton = Skeleton(
        names=tuple(model64.body_names[b] for b in order), parents=parents, offsets=offsets.numpy(), channels=channels
    )
    return BVHMotion(skeleton, np.concatenate(columns, axis=1), _frame_time(motion, frame_time), units="m")


def zxy_euler(rotation: torch.Tensor) -> torch.Tensor:
    """[..., 3] angles (z, x, y) in radians with ``rotation`` [..., 3, 3] = Rz(z) Rx(x) Ry(y).

    From R = Rz Rx Ry: R[2, 1] = sin x, R[0, 1] = -sin z cos x, R[1, 1] = cos z cos x, R[2, 0] = -cos x sin y,
    R[2, 2] = cos x cos y. x lies in [-90, 90] degrees; where cos x vanishes (gimbal lock) y is 0 and z takes
    the whole turn about the shared axis, z = atan2(R[1, 0], R[0, 0]).
    """
    r = rotation
    cos_x = torch.sqrt(r[..., 0, 1] ** 2 + r[..., 1, 1] ** 2)
    x = torch.atan2(r[..., 2, 1], cos_x)
    locked = cos_x < _GIMBAL
    z = torch.where(locked, torch.atan2(r[..., 1, 0], r[..., 0, 0]), torch.atan2(-r[..., 0, 1], r[..., 1, 1]))
    y = torch.where(locked, torch.zeros_like(x), torch.atan2(-r[..., 2, 0], r[..., 2, 2]))
    return torch.stack([z, x, y], dim=-1)


def _coordinates(model: BodyModel, motion: Motion) -> torch.Tensor:
    """[T, n_q] float64 model coordinates from the motion's columns (all must be present and finite)."""
    missing = [name for name in model.coordinate_names if name not in motion.names]
    if missing:
        raise ModelError(
            f"motion lacks {len(missing)} coordinate(s) of model {model.name!r}: "
            f"{', '.join(missing)}; select them (Motion.select fills absent ones) before export"
        )
    values = motion.select(model.coordinate_names).values
    bad = ~np.isfinite(values)
    if bad.any():
        frame, column = np.argwhere(bad)[0]
        raise DataFormatError(
            None,
            f"coordinate {model.coordinate_names[column]!r} is {values[frame, column]}; "
            f"BVH needs finite values in every frame",
            frame=int(frame),
        )
    return torch.as_tensor(values, dtype=torch.float64)


def _frame_time(motion: Motion, frame_time: float | None) -> float:
    if frame_time is not None:
        return float(frame_time)
    if motion.n_frames < 2:
        return 1.0 / DEFAULT_RATE
    steps = np.diff(motion.times)
    if np.ptp(steps) > 1e-6 * float(np.mean(steps)) + 1e-9:
        raise DataFormatError(
            None,
            f"motion is not uniformly sampled (steps {steps.min():.6g} to "
            f"{steps.max():.6g} s); resample it (Motion.resample) before BVH export",
        )
    return float(np.mean(steps))


def _depth_first(model: BodyModel) -> tuple[list[int], tuple[int, ...]]:
    """(bodies in depth-first order from the single root, parent position in that order or -1)."""
    roots = [b for b in range(model.n_bodies) if model.parent[b] < 0]
    if len(roots) != 1:
        names = ", ".join(model.body_names[b] for b in roots)
        raise ModelError(
            f"model {model.name!r} has {len(roots)} bodies jointed to ground ({names}); a BVH "
            f"skeleton needs exactly one root"
        )
    children: list[list[int]] = [[] for _ in range(model.n_bodies)]
    for b, parent in enumerate(model.parent):
        if parent >= 0:
            children[parent].append(b)
    order: list[int] = []
    stack = [roots[0]]
    while stack:
        body = stack.pop()
        order.append(body)
        stack.extend(reversed(children[body]))
    place = {b: i for i, b in enumerate(order)}
    return order, tuple(-1 if model.parent[b] < 0 else place[model.parent[b]] for b in order)


def _in_parent(
    rotations: torch.Tensor,
    positions: torch.Tensor,
    all_rotations: torch.Tensor,
    all_positions: torch.Tensor,
    parent_body: torch.Tensor,
    rotate_too: bool = False,
):
    """Pose of bodies ([..., J, 3, 3], [..., J, 3]) in their parent body's frame (ground for the root).

    ``all_*`` are the poses of every body (BodySet order) to look parents up in; returns the positions, and
    with ``rotate_too`` (relative rotations, positions).
    """
    has_parent = parent_body >= 0
    index = parent_body.clamp(min=0)
    eye = torch.eye(3, dtype=rotations.dtype)
    parent_rotation = torch.where(has_parent[:, None, None], all_rotations[..., index, :, :], eye)
    parent_position = torch.where(
        has_parent[:, None], all_positions[..., index, :], torch.zeros(3, dtype=positions.dtype)
    )
    local_position = (parent_rotation.transpose(-1, -2) @ (positions - parent_position)[..., None])[..., 0]
    if not rotate_too:
        return local_position
    return parent_rotation.transpose(-1, -2) @ rotations, local_position


def _translates(model: BodyModel, body: int) -> bool:
    """Whether the body's origin can move in its parent's frame: its joint has a coordinate-driven translation
    axis, or a coordinate-driven rotation about a child frame that is offset from the body origin."""
    joint = next(j for j in model.joints if j.child == body)
    driven = [axis for axis in joint.axes if axis.coordinate is not None]
    offset = bool(torch.any(joint.child_translation.abs() > 0))
    return any(not axis.rotation for axis in driven) or (offset and any(axis.rotation for axis in driven))
