"""Batched forward kinematics of a `BodyModel`: body poses, markers, joint centres, centres of mass, Jacobians.

Every function takes coordinates ``q`` of shape [..., n_q] (any leading batch dims, CoordinateSet order, SI:
rad and m) and is differentiable with autograd in float32 or float64. Poses follow OpenSim/Simbody: the pose of
body B in ground is X_GB = X_GP X_PF X_FM(q) X_MB, with X_FM the joint's spatial transform (model.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from biomotion.body.model import BodyModel, JointModel, axis_angle
from biomotion.errors import ModelError


@dataclass(frozen=True)
class BodyPoses:
    """Orientation [..., B, 3, 3] and origin [..., B, 3] of every body in ground, in BodySet order."""
    rotations: torch.Tensor
    positions: torch.Tensor


def joint_motion(joint: JointModel, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """X_FM(q): (R [..., 3, 3], p [..., 3]) of the child frame M in the parent frame F.

    Rotations are applied in axis order as body-fixed rotations; translations add up along axes fixed in F.
    """
    batch = q.shape[:-1]
    rotation = torch.eye(3, dtype=q.dtype).expand(*batch, 3, 3)
    translation = q.new_zeros(*batch, 3)
    for axis in joint.axes:
        amount = axis.amount(q)
        if axis.rotation:
            rotation = rotation @ axis_angle(axis.axis, amount)
        else:
            translation = translation + amount[..., None] * axis.axis
    return rotation, translation


def joint_transform(joint: JointModel, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """X_PB(q) = X_PF X_FM(q) X_MB: (R [..., 3, 3], p [..., 3]) of the child body in its parent body."""
    r_fm, p_fm = joint_motion(joint, q)
    r_pf, p_pf = joint.parent_rotation, joint.parent_translation
    r_bm, p_bm = joint.child_rotation, joint.child_translation
    r_mb = r_bm.transpose(-1, -2)
    p_mb = -(r_mb @ p_bm)
    rotation = r_pf @ r_fm @ r_mb
    translation = p_pf + (r_pf @ (p_fm + (r_fm @ p_mb[..., None]).squeeze(-1))[..., None]).squeeze(-1)
    return rotation, translation


def forward_kinematics(model: BodyModel, q: torch.Tensor) -> BodyPoses:
    """Poses of all bodies in ground at coordinates ``q`` [..., n_q]."""
    _check(model, q)
    rotations: list[torch.Tensor | None] = [None] * model.n_bodies
    positions: list[torch.Tensor | None] = [None] * model.n_bodies
    for j in model.joint_order:
        joint = model.joints[j]
        r_pb, p_pb = joint_transform(joint, q)
        if joint.parent < 0:
            rotations[joint.child], positions[joint.child] = r_pb, p_pb
        else:
            r_gp, p_gp = rotations[joint.parent], positions[joint.parent]
            rotations[joint.child] = r_gp @ r_pb
            positions[joint.child] = p_gp + (r_gp @ p_pb[..., None]).squeeze(-1)
    return BodyPoses(torch.stack(rotations, dim=-3), torch.stack(positions, dim=-2))


def points_in_ground(poses: BodyPoses, bodies: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
    """[..., P, 3] ground positions of points fixed at ``offsets`` [P, 3] in ``bodies`` [P] (-1 = ground)."""
    index = bodies.clamp(min=0)
    rotation = poses.rotations[..., index, :, :]
    origin = poses.positions[..., index, :]
    moved = origin + (rotation @ offsets.to(origin.dtype)[..., None]).squeeze(-1)
    return torch.where((bodies < 0)[:, None], offsets.to(origin.dtype).expand_as(moved), moved)


def marker_positions(model: BodyModel, q: torch.Tensor, poses: BodyPoses | None = None) -> torch.Tensor:
    """[..., M, 3] model markers in ground, in MarkerSet order (``model.marker_names``)."""
    poses = forward_kinematics(model, q) if poses is None else poses
    return points_in_ground(poses, model.marker_bodies, model.marker_offsets)


def joint_centers(model: BodyModel, q: torch.Tensor, poses: BodyPoses | None = None) -> torch.Tensor:
    """[..., J, 3] origin of each joint's child frame M in ground, in JointSet order."""
    poses = forward_kinematics(model, q) if poses is None else poses
    bodies = torch.tensor([j.child for j in model.joints], dtype=torch.long)
    offsets = torch.stack([j.child_translation for j in model.joints])
    return points_in_ground(poses, bodies, offsets)


def body_coms(model: BodyModel, q: torch.Tensor, poses: BodyPoses | None = None) -> torch.Tensor:
    """[..., B, 3] centre of mass of each body in ground."""
    poses = forward_kinematics(model, q) if poses is None else poses
    return points_in_ground(poses, torch.arange(model.n_bodies), model.coms)


def center_of_mass(model: BodyModel, q: torch.Tensor, poses: BodyPoses | None = None) -> torch.Tensor:
    """[..., 3] whole-body centre of mass in ground."""
    coms = body_coms(model, q, poses)
    return (model.masses[:, None] * coms).sum(-2) / model.total_mass


def apply_couplers(model: BodyModel, q: torch.Tensor) -> torch.Tensor:
    """``q`` with every coupler's dependent coordinate set from its independent one (out of place)."""
    if not model.couplers:
        return q
    columns = list(q.unbind(-1))
    for coupler in model.couplers:
        columns[coupler.dependent] = coupler.scale_factor * coupler.function(columns[coupler.independent])
    return torch.stack(columns, dim=-1)


def point_jacobians(model: BodyModel, q: torch.Tensor, bodies: torch.Tensor, offsets: torch.Tensor,
                    poses: BodyPoses | None = None) -> torch.Tensor:
    """[..., P, 3, n_q] d(point in ground)/dq for points fixed at ``offsets`` [P, 3] in ``bodies`` [P].

    Column k is v_k + w_k x (p - o_k), with (w_k, v_k) coordinate k's motion subspace column in ground at the
    origin o_k of the body its joint moves, for points on that body's subtree (zero elsewhere).
    """
    poses = forward_kinematics(model, q) if poses is None else poses
    points = points_in_ground(poses, bodies, offsets)
    batch = q.shape[:-1]
    angular = q.new_zeros(*batch, model.n_q, 3)
    linear = q.new_zeros(*batch, model.n_q, 3)
    origin = q.new_zeros(*batch, model.n_q, 3)
    for joint in model.joints:
        if not joint.coordinates:
            continue
        s = motion_subspace(joint, q)  # child frame
        rotation = poses.rotations[..., joint.child, :, :]
        cols = list(joint.coordinates)
        angular[..., cols, :] = (rotation @ s[..., :3, :]).transpose(-1, -2)
        linear[..., cols, :] = (rotation @ s[..., 3:, :]).transpose(-1, -2)
        origin[..., cols, :] = poses.positions[..., joint.child, None, :].expand(*batch, len(cols), 3)
    moves = _subtree_mask(model)[bodies.clamp(min=0)] & (bodies >= 0)[:, None]  # [P, n_q]
    lever = points[..., :, None, :] - origin[..., None, :, :]                   # [..., P, n_q, 3]
    columns = linear[..., None, :, :] + torch.linalg.cross(angular[..., None, :, :].expand_as(lever), lever)
    return (columns * moves[..., None].to(q.dtype)).transpose(-1, -2)


def marker_jacobians(model: BodyModel, q: torch.Tensor) -> torch.Tensor:
    """[..., M, 3, n_q] d(marker positions)/dq."""
    return point_jacobians(model, q, model.marker_bodies, model.marker_offsets)


def _subtree_mask(model: BodyModel) -> torch.Tensor:
    """[B, n_q] True where coordinate k moves body b (k belongs to a joint on b's path to ground)."""
    mask = torch.zeros(model.n_bodies, model.n_q, dtype=torch.bool)
    joint_of_child = {j.child: j for j in model.joints}
    for b in range(model.n_bodies):
        body = b
        while body >= 0:
            joint = joint_of_child[body]
            mask[b, list(joint.coordinates)] = True
            body = joint.parent
    return mask


# ---- joint motion subspace -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class JointTerms:
    """Each moving axis of a joint at ``q``: amounts and their derivatives, and the rotation axes W_k in F
    (axis k after rotations 1..k-1), which give the relative angular velocity sum_k W_k dtheta_k/dt."""
    rotation: torch.Tensor                          # R_FM [..., 3, 3]
    rotation_axes: tuple[torch.Tensor, ...]         # W_k [..., 3] in F
    rotation_derivatives: tuple[tuple[torch.Tensor, torch.Tensor], ...]      # (theta', theta'')
    translation_axes: tuple[torch.Tensor, ...]      # b_m [3] in F
    translation_derivatives: tuple[tuple[torch.Tensor, torch.Tensor], ...]   # (d', d'')
    rotation_coordinates: tuple[int | None, ...]
    translation_coordinates: tuple[int | None, ...]
    rotation_slots: tuple[int, ...]


def joint_terms(joint: JointModel, q: torch.Tensor) -> JointTerms:
    batch = q.shape[:-1]
    rotation = torch.eye(3, dtype=q.dtype).expand(*batch, 3, 3)
    w, rd, rc, slots, b, td, tc = [], [], [], [], [], [], []
    for axis in joint.axes:
        value, d1, d2 = axis.derivatives(q)
        unit = axis.axis.to(q.dtype)
        if axis.rotation:
            w.append((rotation @ unit[:, None]).squeeze(-1))
            rotation = rotation @ axis_angle(unit, value)
            rd.append((d1, d2))
            rc.append(axis.coordinate)
            slots.append(axis.slot)
        else:
            b.append(unit)
            td.append((d1, d2))
            tc.append(axis.coordinate)
    return JointTerms(rotation, tuple(w), tuple(rd), tuple(b), tuple(td), tuple(rc), tuple(tc), tuple(slots))


def motion_to_child(joint: JointModel, terms: JointTerms, angular_f: torch.Tensor, linear_f: torch.Tensor
                    ) -> torch.Tensor:
    """[..., 6] a relative motion given in F about M's origin ([..., 3] each) as a spatial vector in the child
    body frame about its origin."""
    r_bm, p_bm = joint.child_rotation, joint.child_translation
    to_b = r_bm @ terms.rotation.transpose(-1, -2)
    angular = (to_b @ angular_f[..., None]).squeeze(-1)
    linear = (to_b @ linear_f[..., None]).squeeze(-1) + torch.linalg.cross(p_bm.expand_as(angular), angular)
    return torch.cat([angular, linear], -1)


def motion_subspace(joint: JointModel, q: torch.Tensor, terms: JointTerms | None = None) -> torch.Tensor:
    """[..., 6, n_joint_coordinates] the joint's motion subspace S(q) in the child body frame: column j is the
    relative spatial velocity of the child for a unit rate of the joint's j-th coordinate."""
    terms = joint_terms(joint, q) if terms is None else terms
    columns = []
    for c in joint.coordinates:
        angular, linear = q.new_zeros(*q.shape[:-1], 3), q.new_zeros(*q.shape[:-1], 3)
        for w, (d1, _), k in zip(terms.rotation_axes, terms.rotation_derivatives, terms.rotation_coordinates):
            if k == c:
                angular = angular + w * d1[..., None]
        for axis, (d1, _), k in zip(terms.translation_axes, terms.translation_derivatives,
                                    terms.translation_coordinates):
            if k == c:
                linear = linear + axis * d1[..., None]
        columns.append(motion_to_child(joint, terms, angular, linear))
    return torch.stack(columns, -1) if columns else q.new_zeros(*q.shape[:-1], 6, 0)


def _check(model: BodyModel, q: torch.Tensor) -> None:
    if q.shape[-1] != model.n_q:
        raise ModelError(f"q has {q.shape[-1]} coordinates, model {model.name!r} has {model.n_q}")
