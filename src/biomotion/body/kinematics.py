"""Batched forward kinematics of a `BodyModel`: body poses, markers, joint centres, centres of mass, Jacobians.

Every function takes coordinates ``q`` of shape [..., n_q] (any leading batch dims, CoordinateSet order, SI:
rad and m) and is differentiable with autograd in float32 or float64. Poses follow OpenSim/Simbody: the pose of
body B in ground is X_GB = X_GP X_PF X_FM(q) X_MB, with X_FM the joint's spatial transform (model.py).

The whole-model functions run on a `KinematicTree`, the model's constants stacked once: every transform axis of
every joint is evaluated in one pass (`FunctionStack`), every joint transform in one batched product, and the
tree is composed one depth level at a time, so the number of tensor operations does not grow with the number of
bodies. The tree is the package's one forward-kinematics and Jacobian engine: marker IK (ik/markers.py), the
dynamics, balance, contact, scaling, retargeting and the viewer pose a `BodyModel` through it (or through the
functions here that wrap it). The per-joint functions (`joint_motion`, `joint_terms`, `motion_subspace`) are the
same formulas one joint at a time, the reference the tree is tested against. Rotations, cross products and the
frames-last 3x3 algebra come from `biomotion.body.spatial`.

These are many small tensor operations: on a loaded or small machine torch's intra-op threads cost more than they
give (up to 100x slower at 2 threads than at 1 on a busy 2-core machine, docs/results/dynamics.md); run them
inside `torch_threads(1)` there, and parallelise over trials instead.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import torch

from biomotion.body.functions import Constant, FunctionStack, Linear, PiecewiseCubic, Polynomial
from biomotion.body.model import BodyModel, JointModel
from biomotion.body.spatial import axis_angle, skew
from biomotion.body.spatial import cross_frames_last as _cross
from biomotion.body.spatial import matmul_frames_last as _mm
from biomotion.body.spatial import matvec_frames_last as _mv
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
    tree = KinematicTree.of(model, q.dtype)
    return tree.poses(tree.joint_frames(tree.axis_values(to_frames_last(q, 1), order=0)[0])).public(q.shape[:-1])


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


def point_jacobians(
    model: BodyModel, q: torch.Tensor, bodies: torch.Tensor, offsets: torch.Tensor, poses: BodyPoses | None = None
) -> torch.Tensor:
    """[..., P, 3, n_q] d(point in ground)/dq for points fixed at ``offsets`` [P, 3] in ``bodies`` [P].

    Column k is v_k + w_k x (p - o_k), with (w_k, v_k) coordinate k's motion subspace column in ground at the
    origin o_k of its joint's child frame M, for points on the subtree that joint moves (zero elsewhere).
    """
    _check(model, q)
    tree = KinematicTree.of(model, q.dtype)
    values, slopes = tree.axis_values(to_frames_last(q, 1), order=1)
    frames = tree.joint_frames(values)
    tree_poses = (
        tree.poses(frames)
        if poses is None
        else TreePoses(to_frames_last(poses.rotations, 3), to_frames_last(poses.positions, 2))
    )
    axes = tree.ground_axes(tree_poses, frames)
    angular, linear = tree.subspace(axes, slopes)  # [n_q, 3, N] at M
    index = bodies.clamp(min=0)
    points = tree.points(tree_poses, bodies, offsets.to(q.dtype))  # [P, 3, N]
    lever = points[:, None] - axes.centers[tree.coordinate_body][None]  # [P, n_q, 3, N]
    columns = linear + _cross(angular, lever)
    moves = tree.moves[index] & (bodies >= 0)[:, None]  # [P, n_q]
    columns = columns * moves[..., None, None].to(q.dtype)
    return to_frames_first(columns.transpose(1, 2), q.shape[:-1])


def marker_jacobians(model: BodyModel, q: torch.Tensor) -> torch.Tensor:
    """[..., M, 3, n_q] d(marker positions)/dq."""
    return point_jacobians(model, q, model.marker_bodies, model.marker_offsets)


# ---- joint motion subspace -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class JointTerms:
    """Each moving axis of a joint at ``q``: amounts and their derivatives, and the rotation axes W_k in F
    (axis k after rotations 1..k-1), which give the relative angular velocity sum_k W_k dtheta_k/dt."""

    rotation: torch.Tensor  # R_FM [..., 3, 3]
    rotation_axes: tuple[torch.Tensor, ...]  # W_k [..., 3] in F
    rotation_derivatives: tuple[tuple[torch.Tensor, torch.Tensor], ...]  # (theta', theta'')
    translation_axes: tuple[torch.Tensor, ...]  # b_m [3] in F
    translation_derivatives: tuple[tuple[torch.Tensor, torch.Tensor], ...]  # (d', d'')
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


def motion_to_child(
    joint: JointModel, terms: JointTerms, angular_f: torch.Tensor, linear_f: torch.Tensor
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
        for axis, (d1, _), k in zip(
            terms.translation_axes, terms.translation_derivatives, terms.translation_coordinates
        ):
            if k == c:
                linear = linear + axis * d1[..., None]
        columns.append(motion_to_child(joint, terms, angular, linear))
    return torch.stack(columns, -1) if columns else q.new_zeros(*q.shape[:-1], 6, 0)


# ---- the whole tree at once ------------------------------------------------------------------------------------
# Layout: frames last. The tree's tensors are [K, ..., N] (K bodies, axes or coordinates; N = all leading batch
# dims of q flattened), so every 3x3 product is a few element-wise operations along contiguous frames and every
# sum over the tree is one matrix product; `to_frames_last` and `to_frames_first` convert at the public boundary.


def to_frames_last(x: torch.Tensor, dims: int) -> torch.Tensor:
    """[..., *item] (``dims`` trailing item dims) -> [*item, N] with N the flattened leading dims."""
    item = x.shape[x.dim() - dims :]
    return x.reshape(-1, *item).movedim(0, -1)


def to_frames_first(x: torch.Tensor, batch: torch.Size) -> torch.Tensor:
    """[*item, N] -> [*batch, *item] (contiguous)."""
    return x.movedim(-1, 0).reshape(*batch, *x.shape[:-1])


def _over(matrix: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``matrix`` [R, K] applied along the first dim of ``x`` [K, ...]: one matrix product."""
    return (matrix @ x.reshape(x.shape[0], -1)).reshape(matrix.shape[0], *x.shape[1:])


@dataclass(frozen=True)
class JointFrames:
    """Every joint at once, indexed by its child body, frames last: X_PB(q) = X_PF X_FM(q) X_MB as one [B, 3, 4, N]
    tensor (R_PB | p_PB), and every rotation axis k after the rotations before it, R_PF W_k [A_r, 3, N]
    (`JointTerms.rotation_axes`, in the parent body's orientation)."""

    x_pb: torch.Tensor
    rotation_axes: torch.Tensor

    @property
    def r_pb(self) -> torch.Tensor:
        """R_PB [B, 3, 3, N] (a view of ``x_pb``)."""
        return self.x_pb[:, :, :3]

    @property
    def p_pb(self) -> torch.Tensor:
        """p_PB [B, 3, N] (a view of ``x_pb``)."""
        return self.x_pb[:, :, 3]


@dataclass(frozen=True)
class TreePoses:
    """Body orientations [B, 3, 3, N] and origins [B, 3, N] in ground, frames last (`KinematicTree.poses` gives
    them as views of one [B, 3, 4, N] tensor)."""

    rotations: torch.Tensor
    positions: torch.Tensor

    def public(self, batch: torch.Size) -> BodyPoses:
        return BodyPoses(to_frames_first(self.rotations, batch), to_frames_first(self.positions, batch))


@dataclass(frozen=True)
class GroundAxes:
    """The moving axes in ground orientation, frames last: rotation axes W_k [A_r, 3, N], translation axes b_m
    [A_t, 3, N], and the joint centres (origin of each joint's frame M) [B, 3, N]."""

    rotation: torch.Tensor
    translation: torch.Tensor
    centers: torch.Tensor


class KinematicTree:
    """A `BodyModel`'s constants stacked for joint-vectorised kinematics, frames last; bodies and joints share an
    index (joint ``b`` is the one whose child is body ``b``; model.py guarantees one per body).

    The one forward-kinematics and Jacobian engine of the package: `forward_kinematics`, `point_jacobians`, the
    dynamics, balance and marker IK all evaluate a model through it. A pass is `axis_values` -> `joint_frames` ->
    `poses`, then `points` for body-fixed points and `ground_axes` -> `subspace` / `twists` for derivatives.

    ``bodies`` restricts the tree to a subtree closed under parents (e.g. the root body alone, for IK's root
    multi-start); tree index k is then model body ``bodies[k]`` (`bodies`, in increasing order), coordinates keep
    their model index and those of joints outside the subtree move nothing. Built once per model and dtype and
    kept on the model (`of`, whole tree only); a model any of whose tensors requires grad (e.g. differentiable
    scale factors) gets a fresh one per call, so gradients reach its parameters.
    """

    def __init__(self, model: BodyModel, dtype: torch.dtype, bodies: Sequence[int] | None = None) -> None:
        kept = list(range(model.n_bodies)) if bodies is None else sorted({int(b) for b in bodies})
        local = {b: k for k, b in enumerate(kept)}
        n_b, n_q = len(kept), model.n_q
        joint_of = {j.child: j for j in model.joints}
        joints = [joint_of[b] for b in kept]
        missing = [model.body_names[j.parent] for j in joints if j.parent >= 0 and j.parent not in local]
        if missing:
            raise ModelError(f"a subtree must hold the parents of its bodies; missing {sorted(set(missing))}")
        parent_of = [local[j.parent] if j.parent >= 0 else -1 for j in joints]  # tree index, -1 ground
        self.bodies = torch.tensor(kept, dtype=torch.long)
        depth: dict[int, int] = {}
        for j in model.joint_order:
            joint = model.joints[j]
            if joint.child in local:
                b = local[joint.child]
                depth[b] = 0 if parent_of[b] < 0 else depth[parent_of[b]] + 1
        levels = [[b for b in range(n_b) if depth[b] == d] for d in range(max(depth.values(), default=-1) + 1)]
        place = {b: i for level in levels for i, b in enumerate(level)}
        self.levels = [
            (torch.tensor(level), torch.tensor([place[parent_of[b]] for b in level]) if d else None)
            for d, level in enumerate(levels)
        ]
        self.assemble = torch.argsort(torch.tensor([b for level in levels for b in level], dtype=torch.long))
        self.parent = torch.tensor([p if p >= 0 else n_b for p in parent_of], dtype=torch.long)  # n_b: ground
        self.reference = levels[0][0] if levels else 0  # a root body
        ancestors = torch.zeros(n_b, n_b, dtype=torch.bool)  # [b, a]: a is b or on its path to ground
        for b in range(n_b):
            a = b
            while a >= 0:
                ancestors[b, a] = True
                a = parent_of[a]
        coordinate_body = torch.zeros(n_q, dtype=torch.long)
        owned = torch.zeros(n_b, n_q, dtype=torch.bool)  # [b, c]: c is a coordinate of joint b
        for b, joint in enumerate(joints):
            coordinate_body[list(joint.coordinates)] = b
            owned[b, list(joint.coordinates)] = True
        self.coordinate_body = coordinate_body
        has_joint = owned.any(0)
        self.moves = ancestors[:, coordinate_body] & has_joint  # [B, n_q]
        both = has_joint[:, None] & has_joint[None, :]
        same = (coordinate_body[:, None] == coordinate_body[None, :]) & both
        above = ancestors[coordinate_body][:, coordinate_body].T & both
        self.same_joint, self.ancestor_joint = same, above & ~same  # [c, c']: c's joint is above c''s

        functions, scales, arguments, axis_body = [], [], [], []
        rotation, translation = [], []  # (axis index, body, rank, unit, coordinate, slot, joint)
        slots = [[None] * 3 for _ in range(n_b)]
        for b, joint in enumerate(joints):
            rank = 0
            for axis in joint.axes:
                coordinate = n_q if axis.coordinate is None else axis.coordinate
                entry = (len(functions), b, rank, axis.axis, coordinate, axis.slot, joint)
                if axis.rotation:
                    slots[b][rank] = len(rotation)
                    rotation.append(entry)
                    rank += 1
                else:
                    translation.append(entry)
                functions.append(axis.function)
                scales.append(axis.scale)
                arguments.append(coordinate)
                axis_body.append(b)
        self.functions = FunctionStack(functions, scales, dtype)
        self.argument = torch.tensor(arguments, dtype=torch.long)  # n_q: the axis has no coordinate
        self.axis_body = torch.tensor(axis_body, dtype=torch.long)  # every axis's joint, in joint axis order
        n_r = len(rotation)
        self.slots = torch.tensor([[n_r if s is None else s for s in row] for row in slots], dtype=torch.long)

        def columns(entries: list) -> tuple[torch.Tensor, ...]:
            index = torch.tensor([e[0] for e in entries], dtype=torch.long)
            body = torch.tensor([e[1] for e in entries], dtype=torch.long)
            coordinate = torch.tensor([e[4] for e in entries], dtype=torch.long)
            units = torch.stack([e[3].to(dtype) for e in entries]) if entries else torch.zeros(0, 3, dtype=dtype)
            by_joint = torch.zeros(n_b, len(entries), dtype=dtype)  # [b, a]: axis a moves joint b
            by_joint[body, torch.arange(len(entries))] = 1.0
            by_coordinate = torch.zeros(n_q, len(entries), dtype=dtype)  # [c, a]: axis a follows c of its joint
            for a, e in enumerate(entries):
                if e[4] in e[6].coordinates:
                    by_coordinate[e[4], a] = 1.0
            return index, body, coordinate, units[..., None], by_joint, by_coordinate

        (
            self.rotation,
            self.rotation_body,
            self.rotation_coordinate,
            self.rotation_units,
            self.rotation_joint,
            self.rotation_columns,
        ) = columns(rotation)
        (
            self.translation,
            self.translation_body,
            self.translation_coordinate,
            self.translation_units,
            self.translation_joint,
            self.translation_columns,
        ) = columns(translation)
        rank = torch.tensor([e[2] for e in rotation], dtype=torch.long)
        self.ranked = [torch.nonzero(rank == r).flatten() for r in range(3)]  # rotation axes by rank in joint
        self.unrank = torch.argsort(torch.cat(self.ranked))
        self.turns = [None] + [
            torch.tensor([b for b in range(n_b) if slots[b][r] is not None], dtype=torch.long) for r in (1, 2)
        ]  # joints with a 2nd, a 3rd rotation
        # which rotation rates carry axis k's frame (see dynamics.joint_velocity): the preceding axes of the
        # joint ("exact"), or Simbody's rule for CustomJoints ("opensim")
        exact = torch.zeros(n_r, n_r, dtype=dtype)
        opensim = torch.zeros(n_r, n_r, dtype=dtype)
        for k, (_, b, rank, _, _, slot, joint) in enumerate(rotation):
            simbody = joint.type == "CustomJoint" and bool(joint.coordinates)
            first = joint.coordinates[0] if joint.coordinates else None
            third = joint.coordinates[2] if len(joint.coordinates) > 2 else None
            for m, (_, b2, rank2, _, coordinate2, _, _) in enumerate(rotation):
                if b2 != b:
                    continue
                exact[k, m] = float(rank2 < rank)
                opensim[k, m] = (
                    float(rank2 < rank)
                    if not simbody
                    else float(
                        (slot == 1 and coordinate2 == first) or (slot == 2 and (third is None or coordinate2 != third))
                    )
                )
        self.frame_rates = {"exact": exact, "opensim": opensim}

        def stacked(name: str) -> torch.Tensor:
            return torch.stack([getattr(j, name).to(dtype) for j in joints])[..., None]

        self.r_pf, self.p_pf = stacked("parent_rotation"), stacked("parent_translation")
        self.p_bm = stacked("child_translation")
        self.r_mb = stacked("child_rotation").transpose(1, 2)
        # `joint_frames`'s constants. The joint's fixed rotations are folded into its axis rotations: rotation axis
        # a of joint b is the factor L (I + sin K + (1 - cos) K^2) R, K = [u_a]x, L = R_PF if a is the joint's first
        # rotation (else I), R = R_MB if its last (else I), so that a joint's factors multiply to R_PB directly;
        # a joint without rotation has the constant R_PF R_MB (factor n_r + b)
        count = [sum(s is not None for s in row) for row in slots]
        first = torch.tensor([e[2] == 0 for e in rotation], dtype=torch.bool)[:, None, None]
        last = torch.tensor([e[2] == count[e[1]] - 1 for e in rotation], dtype=torch.bool)[:, None, None]
        eye = torch.eye(3, dtype=dtype)
        left = torch.where(first, self.r_pf[self.rotation_body, ..., 0], eye)
        right = torch.where(last, self.r_mb[self.rotation_body, ..., 0], eye)
        units = skew(self.rotation_units[..., 0])
        self.factor_terms = [(left @ m @ right)[..., None] for m in (eye.expand_as(units), units, units @ units)]
        self.fixed = (self.r_pf[..., 0] @ self.r_mb[..., 0])[..., None]  # [B, 3, 3, 1]
        self.first_factor = torch.tensor([row[0] if row[0] is not None else n_r + b for b, row in enumerate(slots)])
        self.second_factor = self.slots[self.turns[1], 1]
        self.third_factor = self.slots[self.turns[2], 2]
        # R_PF W_k: constant for a joint's first rotation, its first factor (R_PF R_1) or the product of its first
        # two (R_PF R_1 R_2) applied to u_k for the second and third; R_PF b_m for the translations
        self.first_axes = _mv(self.r_pf[self.rotation_body[self.ranked[0]]], self.rotation_units[self.ranked[0]])
        self.second_axes = (self.rotation_body[self.ranked[1]], self.rotation_units[self.ranked[1]])
        self.third_axes = (self.rotation_body[self.ranked[2]], self.rotation_units[self.ranked[2]])
        self.translation_in_parent = _mv(self.r_pf[self.translation_body], self.translation_units)
        self.rotation_parent = self.parent[self.rotation_body]  # n_b: ground
        self.translation_parent = self.parent[self.translation_body]
        self.ancestors = ancestors.to(dtype)
        self.owned = owned.to(dtype)
        index = self.bodies if bodies is not None else slice(None)
        self.masses = model.masses[index].to(dtype)[:, None, None]
        self.coms = model.coms[index].to(dtype)[..., None]
        self.inertias = model.inertias[index].to(dtype)[..., None]
        self.gravity = model.gravity.to(dtype)[:, None]
        self.eye = torch.eye(3, dtype=dtype)[..., None]

    @classmethod
    def of(cls, model: BodyModel, dtype: torch.dtype) -> KinematicTree:
        """The model's tree in ``dtype``, cached on the (immutable) model unless it requires grad."""
        cache = model.__dict__.get("_kinematic_trees")
        if cache is not None and dtype in cache:
            return cache[dtype]
        tree = cls(model, dtype)
        if not _requires_grad(model):
            if cache is None:
                cache = {}
                object.__setattr__(model, "_kinematic_trees", cache)  # frozen dataclass: a cache, not a field
            cache[dtype] = tree
        return tree

    def axis_values(self, q: torch.Tensor, order: int = 2) -> tuple[torch.Tensor, ...]:
        """Amount of every transform axis and its first two derivatives in its coordinate, [A, N] each, from
        coordinates ``q`` [n_q, N]; only the first ``order + 1`` of them (`FunctionStack.derivatives`)."""
        padded = torch.cat([q, q.new_zeros(1, q.shape[-1])])
        return self.functions.derivatives(padded[self.argument], order)

    def joint_frames(self, values: torch.Tensor) -> JointFrames:
        """X_PB of every joint and the rotation axes from the axis amounts ``values`` [A, N]: each rotation axis
        one factor by Rodrigues' formula (`axis_angle`) with the joint's fixed rotations folded in, products only
        where a joint has a second or third rotation, and p_PB = p_PF + R_PF p_FM - R_PB p_BM."""
        n = values.shape[-1]
        angle = values[self.rotation, None, None, :]
        identity, k, k2 = self.factor_terms
        factors = identity + torch.sin(angle) * k + (1.0 - torch.cos(angle)) * k2
        factors = torch.cat([factors, self.fixed.expand(-1, 3, 3, n)])
        first = factors[self.first_factor]
        second, third = self.turns[1], self.turns[2]
        first_two = first.index_put((second,), _mm(first[second], factors[self.second_factor]))
        r_pb = first_two.index_put((third,), _mm(first_two[third], factors[self.third_factor]))
        shift = _over(self.translation_joint, values[self.translation, None, :] * self.translation_in_parent)
        p_pb = (self.p_pf + shift).sub_(_mv(r_pb, self.p_bm))
        (second_body, second_units), (third_body, third_units) = self.second_axes, self.third_axes
        axes = torch.cat(
            [
                self.first_axes.expand(-1, 3, n),
                _mv(first[second_body], second_units),
                _mv(first_two[third_body], third_units),
            ]
        )
        return JointFrames(torch.cat([r_pb, p_pb[:, :, None]], 2), axes[self.unrank])

    def poses(self, frames: JointFrames) -> TreePoses:
        """Compose X_GB = X_GP X_PB down the tree, one depth level at a time, on the 3x4 (R | p) of each transform:
        (R_GB | p_GB) = R_GP (R_PB | p_PB) + (0 | p_GP). The poses are views of one [B, 3, 4, N] tensor."""
        transforms: list[torch.Tensor] = []
        for bodies, parents in self.levels:
            x = frames.x_pb[bodies]
            if parents is not None:
                x_gp = transforms[-1][parents]
                x = _mm(x_gp[:, :, :3], x)
                x[:, :, 3].add_(x_gp[:, :, 3])
            transforms.append(x)
        x = torch.cat(transforms)[self.assemble]
        return TreePoses(x[:, :, :3], x[:, :, 3])

    def ground_axes(self, poses: TreePoses, frames: JointFrames) -> GroundAxes:
        """Every moving axis in ground orientation (R_GP R_PF W_k, R_GP R_PF b_m) and the joint centres."""
        ground = self.eye.expand(3, 3, poses.rotations.shape[-1])[None]
        r_gp = torch.cat([poses.rotations, ground])  # R_GP, indexed by parent (n_b: ground)
        rotation = _mv(r_gp[self.rotation_parent], frames.rotation_axes)
        translation = _mv(r_gp[self.translation_parent], self.translation_in_parent)
        centers = poses.positions + _mv(poses.rotations, self.p_bm)
        return GroundAxes(rotation, translation, centers)

    def subspace(self, axes: GroundAxes, slopes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Motion subspace column of every coordinate in ground orientation, about its joint centre: angular and
        linear parts [n_q, 3, N] (`motion_subspace`'s columns, rotated to ground and taken at M)."""
        angular = _over(self.rotation_columns, axes.rotation * slopes[self.rotation, None, :])
        linear = _over(self.translation_columns, axes.translation * slopes[self.translation, None, :])
        return angular, linear

    def twists(self, axes: GroundAxes, slopes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Ground twist of every coordinate, (w_k, v_k) [n_q, 3, N] each: the `subspace` column moved from its
        joint centre o_k to the ground origin, v_k = v_M + o_k x w_k, so that a point p fixed on a body the
        coordinate moves has dp/dq_k = w_k x p + v_k (the spatial Jacobian in ground coordinates,
        Featherstone 2008 RBDA ch. 4); zero for coordinates of no joint of the tree."""
        angular, linear = self.subspace(axes, slopes)
        return angular, linear + _cross(axes.centers[self.coordinate_body], angular)

    def points(self, poses: TreePoses, bodies: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
        """[P, 3, N] ground positions of points fixed at ``offsets`` [P, 3] in tree bodies ``bodies`` [P] (-1 =
        ground: the offset is the position)."""
        index = bodies.clamp(min=0)
        offsets = offsets.to(poses.positions.dtype)[..., None]
        moved = poses.positions[index] + _mv(poses.rotations[index], offsets)
        return torch.where((bodies < 0)[:, None, None], offsets, moved)

    def tree_bodies(self, bodies: torch.Tensor) -> torch.Tensor:
        """Tree indices of model body indices ``bodies`` [P] (-1 = ground stays -1); a `ModelError` for a body
        outside the tree."""
        position = {b: k for k, b in enumerate(self.bodies.tolist())}
        found = [-1 if b < 0 else position.get(b) for b in bodies.tolist()]
        if None in found:
            raise ModelError("a point sits on a body outside the kinematic tree")
        return torch.tensor(found, dtype=torch.long)

    def affine_axes(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Which axis amounts are affine in their coordinate, amount = s q + c: ([A] bool, s [A], c [A]), the
        axis scale folded in, s = c = 0 where not affine (`FunctionStack`'s own classification)."""
        stack = self.functions
        scale = stack.scale.detach()
        affine = torch.zeros(stack.size, dtype=torch.bool)
        affine[stack.affine] = True
        slope = torch.zeros(stack.size, dtype=scale.dtype)
        intercept = torch.zeros(stack.size, dtype=scale.dtype)
        slope[stack.affine] = scale[stack.affine] * stack.slope.to(scale.dtype)
        intercept[stack.affine] = scale[stack.affine] * stack.intercept.to(scale.dtype)
        return affine, slope, intercept


def _requires_grad(model: BodyModel) -> bool:
    """Whether any tensor of a model's kinematic and inertial data (joints, axes, functions) requires grad: the
    fields the tree is built from, read directly (a generic walk over the objects costs as much as a few IK
    iterations on a model loaded afresh)."""
    tensors = [model.masses, model.coms, model.inertias, model.gravity]
    for joint in model.joints:
        tensors += [joint.parent_rotation, joint.parent_translation, joint.child_rotation, joint.child_translation]
        for axis in joint.axes:
            tensors += [axis.axis, axis.scale]
            if _function_requires_grad(axis.function):
                return True
    return any(t.requires_grad for t in tensors if isinstance(t, torch.Tensor))


def _function_requires_grad(function, depth: int = 0) -> bool:
    """Whether a model function holds a tensor that requires grad (its attributes, nested functions included)."""
    if isinstance(function, torch.Tensor):
        return function.requires_grad
    if isinstance(function, (Constant, Linear, Polynomial)) or depth > 8:
        return False
    if isinstance(function, PiecewiseCubic):
        return any(t.requires_grad for t in (function.x, function.y, function.b, function.c, function.d))
    if isinstance(function, (tuple, list)):
        return any(_function_requires_grad(f, depth + 1) for f in function)
    if hasattr(function, "__dict__"):
        return any(_function_requires_grad(v, depth + 1) for v in vars(function).values())
    return False


@contextmanager
def torch_threads(count: int) -> Iterator[None]:
    """Run the enclosed code with ``count`` torch intra-op threads, restoring the previous number after.

    The batched kinematics and dynamics are many small operations; on a 2-core or busy machine one thread per
    process is fastest (docs/results/dynamics.md), and batches of trials scale over processes instead. Changes
    process-wide state while active: not for use from several Python threads at once.
    """
    previous = torch.get_num_threads()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _check(model: BodyModel, q: torch.Tensor) -> None:
    if q.shape[-1] != model.n_q:
        raise ModelError(f"q has {q.shape[-1]} coordinates, model {model.name!r} has {model.n_q}")
