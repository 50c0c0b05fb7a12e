"""Rigid-body dynamics of a `BodyModel`, batched over frames: mass matrix, bias forces, inverse dynamics.

Spatial (6D) vectors follow Featherstone, "Rigid Body Dynamics Algorithms" (2008; RBDA): motion vectors are
(angular, linear) at the origin of the frame they are expressed in, force vectors (moment, force); each body's
quantities are in its own frame. Inverse dynamics is the recursive Newton-Euler algorithm (RBDA Table 5.1), the
mass matrix the composite-rigid-body algorithm (RBDA Table 6.2). An OpenSim CustomJoint's mobility is a general
function of its coordinates, so each joint's motion subspace S(q) and velocity-product term c_J = S̊(q) q̇ are
obtained by differentiating the joint transform X_PB(q) analytically through the axis functions' first and
second derivatives, as Simbody's function-based mobilizer defines them (generalized speeds = coordinate
rates); the derivatives of the whole result with respect to q, q̇, q̈ come from autograd.

Both algorithms run on every joint at once (`KinematicTree`): with all spatial quantities expressed in ground
orientation about one point per frame (the root body's origin, which keeps lever arms short), the recursions of
RBDA Table 5.1 become sums over each body's ancestors (velocities, accelerations) and over its descendants
(forces, composite inertias), i.e. products with the tree's constant ancestor matrix (RBDA Sec. 5.3, the
algorithm in ground coordinates), and the number of tensor operations does not grow with the number of bodies.
`joint_velocity` is the same velocity-product term one joint at a time, in the child body frame.

The spatial operators (transforms, cross products, inertia; both layouts) are those of `biomotion.body.spatial`,
and every pose, axis and subspace column comes from the one kinematics engine, `KinematicTree`.

The generalized forces are the quantity OpenSim's ``InverseDynamicsSolver`` returns: the mobility forces that
produce the given accelerations with gravity and external loads, ignoring constraints (couplers and locks).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from biomotion.body.kinematics import (
    JointTerms,
    KinematicTree,
    TreePoses,
    _over,
    joint_terms,
    motion_to_child,
    to_frames_first,
    to_frames_last,
)
from biomotion.body.model import BodyModel, JointModel
from biomotion.body.spatial import cross_frames_last as _cross
from biomotion.body.spatial import cross_motion_frames_last, spatial_inertia_frames_last
from biomotion.body.spatial import matmul_frames_last as _mm
from biomotion.body.spatial import matvec_frames_last as _mv
from biomotion.body.spatial import tmatvec_frames_last as _mtv
from biomotion.errors import ModelError


@dataclass(frozen=True)
class ExternalLoad:
    """A load on one body, all in ground: ``force`` [..., 3] (N) applied at ``point`` [..., 3] (m), plus a free
    ``moment`` [..., 3] (N·m), as an OpenSim ExternalForce with force, point and torque expressed in ground."""

    body: str
    force: torch.Tensor
    point: torch.Tensor
    moment: torch.Tensor | None = None


# ---- joint velocity terms ------------------------------------------------------------------------------------


def joint_velocity(
    joint: JointModel, q: torch.Tensor, qd: torch.Tensor, hdot: str = "opensim", terms: JointTerms | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(v_J = S q̇, c_J = S̊ q̇) [..., 6] in the child body frame.

    With rotation angles theta_k = f_k(q) about axes W_k (axis k after rotations 1..k-1, in F) and translations
    d_m = g_m(q) along b_m (in F), the relative angular velocity is w = sum W_k theta_k' and the velocity of M's
    origin p' = sum b_m d_m'; at zero coordinate acceleration their rates are
    w' = sum (Omega_k x W_k theta_k' + W_k theta_k''), Omega_k = sum_{l<k} W_l theta_l', and p'' = sum b_m d_m'',
    and c_J = (w', p'' - w x p') carried to the child frame.

    ``hdot="exact"`` uses that Omega_k. ``hdot="opensim"`` reproduces Simbody's function-based mobilizer
    (``MobilizedBody::FunctionBased``, which every CustomJoint uses), whose H-dot takes Omega for rotation2 from
    the joint's first coordinate alone and Omega for rotation3 from all but its third coordinate; the two agree
    unless rotation k is not driven by coordinate k alone (e.g. the Rajagopal walker knee, where all three
    rotations follow the knee angle).
    """
    if hdot not in ("opensim", "exact"):
        raise ModelError(f"hdot must be 'opensim' or 'exact', not {hdot!r}")
    terms = joint_terms(joint, q) if terms is None else terms
    zero = q.new_zeros(*q.shape[:-1], 3)

    def rate(k: int | None) -> torch.Tensor:
        return qd[..., k] if k is not None else q.new_zeros(q.shape[:-1])

    rates = [d1 * rate(k) for (d1, _), k in zip(terms.rotation_derivatives, terms.rotation_coordinates)]
    omega = sum((w * r[..., None] for w, r in zip(terms.rotation_axes, rates)), zero)
    simbody = hdot == "opensim" and joint.type == "CustomJoint" and bool(joint.coordinates)
    if simbody:
        first, third = joint.coordinates[0], (joint.coordinates[2] if len(joint.coordinates) > 2 else None)
        omega_first = sum(
            (w * r[..., None] for w, r, k in zip(terms.rotation_axes, rates, terms.rotation_coordinates) if k == first),
            zero,
        )
        omega_no_third = sum(
            (
                w * r[..., None]
                for w, r, k in zip(terms.rotation_axes, rates, terms.rotation_coordinates)
                if third is None or k != third
            ),
            zero,
        )
    omega_dot = zero
    preceding = zero
    for w, r, (_, d2), k, slot in zip(
        terms.rotation_axes, rates, terms.rotation_derivatives, terms.rotation_coordinates, terms.rotation_slots
    ):
        frame_rate = preceding
        if simbody:
            frame_rate = (zero, omega_first, omega_no_third)[slot]
        omega_dot = omega_dot + torch.linalg.cross(frame_rate, w) * r[..., None] + w * (d2 * rate(k) ** 2)[..., None]
        preceding = preceding + w * r[..., None]
    velocity, acceleration = zero, zero
    for b, (d1, d2), k in zip(terms.translation_axes, terms.translation_derivatives, terms.translation_coordinates):
        velocity = velocity + b * (d1 * rate(k))[..., None]
        acceleration = acceleration + b * (d2 * rate(k) ** 2)[..., None]
    v_j = motion_to_child(joint, terms, omega, velocity)
    c_j = motion_to_child(joint, terms, omega_dot, acceleration - torch.linalg.cross(omega, velocity))
    return v_j, c_j


# ---- algorithms -----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Motion:
    """One kinematics pass for the dynamics, frames last and in ground orientation about the reference point
    ``origin`` [3, N]: poses, coordinate subspace columns [n_q, 6, N] and, given rates, joint velocities v_J
    and velocity-product terms c_J [B, 6, N]."""

    tree: KinematicTree
    poses: TreePoses
    origin: torch.Tensor
    subspace: torch.Tensor
    joint_velocity: torch.Tensor | None = None
    joint_bias: torch.Tensor | None = None


def _tree_motion(model: BodyModel, q: torch.Tensor, qd: torch.Tensor | None = None, hdot: str = "opensim") -> _Motion:
    """`motion_subspace`'s S and `joint_velocity`'s v_J and c_J of every joint at once (q, qd [n_q, N]), in
    ground orientation and shifted from each joint centre M to the reference point O (v_O = v_M + (M - O) x w)."""
    tree = KinematicTree.of(model, q.dtype)
    values, slopes, curvatures = tree.axis_values(q)
    frames = tree.joint_frames(values)
    poses = tree.poses(frames)
    axes = tree.ground_axes(poses, frames)
    origin = poses.positions[tree.reference]
    arm = axes.centers - origin  # M - O  [B, 3, N]
    angular, linear = tree.subspace(axes, slopes)
    subspace = torch.cat([angular, linear + _cross(arm[tree.coordinate_body], angular)], 1)
    if qd is None:
        return _Motion(tree, poses, origin, subspace)
    rates = torch.cat([qd, qd.new_zeros(1, qd.shape[-1])])  # axes without coordinate: 0
    rotation_rate = rates[tree.rotation_coordinate]
    turn = axes.rotation * (slopes[tree.rotation] * rotation_rate)[:, None]  # W_k theta_k'  [A_r, 3, N]
    omega = _over(tree.rotation_joint, turn)
    omega_dot = _over(
        tree.rotation_joint,
        _cross(_over(tree.frame_rates[hdot], turn), turn)
        + axes.rotation * (curvatures[tree.rotation] * rotation_rate**2)[:, None],
    )
    translation_rate = rates[tree.translation_coordinate]
    velocity = _over(tree.translation_joint, axes.translation * (slopes[tree.translation] * translation_rate)[:, None])
    acceleration = _over(
        tree.translation_joint, axes.translation * (curvatures[tree.translation] * translation_rate**2)[:, None]
    )
    joint_velocity = torch.cat([omega, velocity + _cross(arm, omega)], 1)
    joint_bias = torch.cat([omega_dot, acceleration - _cross(omega, velocity) + _cross(arm, omega_dot)], 1)
    return _Motion(tree, poses, origin, subspace, joint_velocity, joint_bias)


def inverse_dynamics(
    model: BodyModel,
    q: torch.Tensor,
    qd: torch.Tensor,
    qdd: torch.Tensor,
    loads: tuple[ExternalLoad, ...] | list[ExternalLoad] = (),
    gravity: bool = True,
    hdot: str = "opensim",
) -> torch.Tensor:
    """[..., n_q] generalized forces (N·m or N) that produce ``qdd`` at (``q``, ``qd``) under gravity and
    ``loads``: tau = M(q) qdd + C(q, qd) - G(q) - J^T f_ext (recursive Newton-Euler, RBDA Table 5.1).

    ``hdot`` selects the velocity-product term of CustomJoints (see `joint_velocity`): "opensim" matches
    OpenSim/Simbody, "exact" is the exact derivative; they differ only for joints whose rotations share a
    coordinate (about 1e-4 N·m at 2 rad/s knee speed in the Rajagopal knee)."""
    if not (q.shape[-1] == qd.shape[-1] == qdd.shape[-1] == model.n_q):
        raise ModelError(f"q, qd, qdd must have {model.n_q} coordinates for model {model.name!r}")
    if hdot not in ("opensim", "exact"):
        raise ModelError(f"hdot must be 'opensim' or 'exact', not {hdot!r}")
    q, qd, qdd = torch.broadcast_tensors(q, qd, qdd)
    batch = q.shape[:-1]
    motion = _tree_motion(model, to_frames_last(q, 1), to_frames_last(qd, 1), hdot)
    tree, poses, origin = motion.tree, motion.poses, motion.origin
    # forward: a body's velocity and acceleration are sums over the body and its ancestors
    velocity = _over(tree.ancestors, motion.joint_velocity)  # [B, 6, N]
    local = (
        motion.joint_bias
        + _over(tree.owned, motion.subspace * to_frames_last(qdd, 1)[:, None])
        + cross_motion_frames_last(velocity, motion.joint_velocity)
    )
    acceleration = _over(tree.ancestors, local)
    if gravity:  # the ground's fictitious upward acceleration (RBDA Sec. 5.3)
        acceleration = acceleration - torch.cat([torch.zeros_like(tree.gravity), tree.gravity])
    # Newton-Euler at each body's centre of mass, inertia in the body frame
    rotations = poses.rotations
    com = poses.positions + _mv(rotations, tree.coms) - origin
    omega, alpha = velocity[:, :3], acceleration[:, :3]
    com_velocity = velocity[:, 3:] + _cross(omega, com)
    force = tree.masses * (acceleration[:, 3:] + _cross(alpha, com) + _cross(omega, com_velocity))
    omega_body, alpha_body = _mtv(rotations, omega), _mtv(rotations, alpha)
    moment = _mv(rotations, _mv(tree.inertias, alpha_body) + _cross(omega_body, _mv(tree.inertias, omega_body)))
    wrench = torch.cat([moment + _cross(com, force), force], 1)
    if loads:
        wrench = wrench - _load_wrenches(model, loads, origin, batch)
    # backward: each joint carries the wrenches of its subtree
    carried = _over(tree.ancestors.T, wrench)
    return to_frames_first((motion.subspace * carried[tree.coordinate_body]).sum(1), batch)


def _load_wrenches(
    model: BodyModel, loads: tuple[ExternalLoad, ...] | list[ExternalLoad], origin: torch.Tensor, batch: torch.Size
) -> torch.Tensor:
    """[B, 6, N] the loads as wrenches about the reference point, summed per body."""
    dtype = origin.dtype

    def frames_last(x: torch.Tensor) -> torch.Tensor:
        return to_frames_last(torch.broadcast_to(x.to(dtype), (*batch, 3)), 1)

    wrenches = []
    for load in loads:
        force = frames_last(load.force)
        moment = _cross(frames_last(load.point) - origin, force)
        if load.moment is not None:
            moment = moment + frames_last(load.moment)
        wrenches.append(torch.cat([moment, force]))
    on_body = torch.zeros(model.n_bodies, len(loads), dtype=dtype)
    on_body[[model.body_index(load.body) for load in loads], torch.arange(len(loads))] = 1.0
    return _over(on_body, torch.stack(wrenches))


def bias_forces(
    model: BodyModel, q: torch.Tensor, qd: torch.Tensor, gravity: bool = True, hdot: str = "opensim"
) -> torch.Tensor:
    """[..., n_q] C(q, qd) - G(q): inverse dynamics at zero acceleration without external loads."""
    return inverse_dynamics(model, q, qd, torch.zeros_like(q), gravity=gravity, hdot=hdot)


def mass_matrix(model: BodyModel, q: torch.Tensor) -> torch.Tensor:
    """[..., n_q, n_q] joint-space inertia matrix (composite-rigid-body algorithm, RBDA Table 6.2): entry
    (i, j) with i's joint an ancestor of (or the same as) j's is S_i^T I^c_j S_j, I^c_j the composite inertia
    of the subtree below j's joint; zero where neither joint is above the other."""
    if q.shape[-1] != model.n_q:
        raise ModelError(f"q must have {model.n_q} coordinates for model {model.name!r}")
    motion = _tree_motion(model, to_frames_last(q, 1))
    tree, rotations = motion.tree, motion.poses.rotations
    com = motion.poses.positions + _mv(rotations, tree.coms) - motion.origin  # [B, 3, N]
    inertia = _mm(_mm(rotations, tree.inertias), rotations.transpose(1, 2))
    body = spatial_inertia_frames_last(tree.masses[:, 0], com, inertia)  # [B, 6, 6, N]
    composite = _over(tree.ancestors.T, body)
    s = motion.subspace  # [n_q, 6, N]
    moved = (composite[tree.coordinate_body] * s[:, None]).sum(2)  # I^c_j S_j  [n_q, 6, N]
    products = (s[:, None] * moved[None]).sum(2)  # S_i . I^c_j S_j
    weights = tree.ancestor_joint.to(s.dtype)[..., None]
    upper = products * weights
    full = upper + upper.transpose(0, 1) + products * tree.same_joint.to(s.dtype)[..., None]
    return to_frames_first(full, q.shape[:-1])
