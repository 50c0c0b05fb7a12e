"""Rigid-body dynamics of a `BodyModel`, batched over frames: mass matrix, bias forces, inverse dynamics.

Spatial (6D) vectors follow Featherstone, "Rigid Body Dynamics Algorithms" (2008; RBDA): motion vectors are
(angular, linear) at the origin of the frame they are expressed in, force vectors (moment, force); each body's
quantities are in its own frame. Inverse dynamics is the recursive Newton-Euler algorithm (RBDA Table 5.1), the
mass matrix the composite-rigid-body algorithm (RBDA Table 6.2). An OpenSim CustomJoint's mobility is a general
function of its coordinates, so each joint's motion subspace S(q) and velocity-product term c_J = S̊(q) q̇ are
obtained by differentiating the joint transform X_PB(q) analytically through the axis functions' first and
second derivatives, as Simbody's function-based mobilizer defines them (generalized speeds = coordinate
rates); the derivatives of the whole result with respect to q, q̇, q̈ come from autograd.

The generalized forces are the quantity OpenSim's ``InverseDynamicsSolver`` returns: the mobility forces that
produce the given accelerations with gravity and external loads, ignoring constraints (couplers and locks).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from biomotion.body.kinematics import JointTerms, joint_terms, joint_transform, motion_subspace, motion_to_child
from biomotion.body.model import BodyModel, JointModel
from biomotion.errors import ModelError


@dataclass(frozen=True)
class ExternalLoad:
    """A load on one body, all in ground: ``force`` [..., 3] (N) applied at ``point`` [..., 3] (m), plus a free
    ``moment`` [..., 3] (N·m), as an OpenSim ExternalForce with force, point and torque expressed in ground."""
    body: str
    force: torch.Tensor
    point: torch.Tensor
    moment: torch.Tensor | None = None


# ---- spatial algebra ------------------------------------------------------------------------------------------

def _skew(v: torch.Tensor) -> torch.Tensor:
    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack([torch.stack([zero, -z, y], -1), torch.stack([z, zero, -x], -1),
                        torch.stack([-y, x, zero], -1)], -2)


def _blocks(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    return torch.cat([torch.cat([a, b], -1), torch.cat([c, d], -1)], -2)


def motion_transform(rotation: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
    """[..., 6, 6] ^B X_A for frame B at ``rotation``, ``translation`` in A (RBDA eq. 2.24)."""
    rt = rotation.transpose(-1, -2)
    return _blocks(rt, torch.zeros_like(rt), -rt @ _skew(translation), rt)


def cross_motion(v: torch.Tensor) -> torch.Tensor:
    """[..., 6, 6] the operator v×  on motion vectors (RBDA eq. 2.31)."""
    w, u = _skew(v[..., :3]), _skew(v[..., 3:])
    return _blocks(w, torch.zeros_like(w), u, w)


def spatial_inertia(mass: torch.Tensor, com: torch.Tensor, inertia: torch.Tensor) -> torch.Tensor:
    """[..., 6, 6] inertia about the frame origin of a body with ``inertia`` [..., 3, 3] about its COM."""
    c = _skew(com)
    m = mass[..., None, None]
    eye = torch.eye(3, dtype=com.dtype).expand_as(c)
    return _blocks(inertia + m * (c @ c.transpose(-1, -2)), m * c, m * c.transpose(-1, -2), m * eye)


def _mv(matrix: torch.Tensor, vector: torch.Tensor) -> torch.Tensor:
    return (matrix @ vector[..., None]).squeeze(-1)


# ---- joint velocity terms ------------------------------------------------------------------------------------

def joint_velocity(joint: JointModel, q: torch.Tensor, qd: torch.Tensor, hdot: str = "opensim",
                   terms: JointTerms | None = None) -> tuple[torch.Tensor, torch.Tensor]:
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
        omega_first = sum((w * r[..., None] for w, r, k in zip(terms.rotation_axes, rates, terms.rotation_coordinates)
                           if k == first), zero)
        omega_no_third = sum((w * r[..., None] for w, r, k in zip(terms.rotation_axes, rates,
                                                                   terms.rotation_coordinates)
                              if third is None or k != third), zero)
    omega_dot = zero
    preceding = zero
    for w, r, (_, d2), k, slot in zip(terms.rotation_axes, rates, terms.rotation_derivatives,
                                      terms.rotation_coordinates, terms.rotation_slots):
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

def _body_inertias(model: BodyModel) -> torch.Tensor:
    return spatial_inertia(model.masses, model.coms, model.inertias)


def inverse_dynamics(model: BodyModel, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor,
                     loads: tuple[ExternalLoad, ...] | list[ExternalLoad] = (), gravity: bool = True,
                     hdot: str = "opensim") -> torch.Tensor:
    """[..., n_q] generalized forces (N·m or N) that produce ``qdd`` at (``q``, ``qd``) under gravity and
    ``loads``: tau = M(q) qdd + C(q, qd) - G(q) - J^T f_ext (recursive Newton-Euler, RBDA Table 5.1).

    ``hdot`` selects the velocity-product term of CustomJoints (see `joint_velocity`): "opensim" matches
    OpenSim/Simbody, "exact" is the exact derivative; they differ only for joints whose rotations share a
    coordinate (about 1e-4 N·m at 2 rad/s knee speed in the Rajagopal knee)."""
    if not (q.shape[-1] == qd.shape[-1] == qdd.shape[-1] == model.n_q):
        raise ModelError(f"q, qd, qdd must have {model.n_q} coordinates for model {model.name!r}")
    q, qd, qdd = torch.broadcast_tensors(q, qd, qdd)
    batch = q.shape[:-1]
    inertias = _body_inertias(model)
    g = model.gravity.to(q.dtype) if gravity else q.new_zeros(3)
    ground_acc = torch.cat([q.new_zeros(3), -g]).expand(*batch, 6)
    n = model.n_bodies
    vel: list[torch.Tensor | None] = [None] * n
    acc: list[torch.Tensor | None] = [None] * n
    rot: list[torch.Tensor | None] = [None] * n
    pos: list[torch.Tensor | None] = [None] * n
    force: list[torch.Tensor | None] = [None] * n
    subspace: dict[int, torch.Tensor] = {}
    transform: dict[int, torch.Tensor] = {}
    for j in model.joint_order:
        joint = model.joints[j]
        b, p = joint.child, joint.parent
        r_pb, p_pb = joint_transform(joint, q)
        x = motion_transform(r_pb, p_pb)
        terms = joint_terms(joint, q)
        s = motion_subspace(joint, q, terms)
        v_j, c_j = joint_velocity(joint, q, qd, hdot, terms)
        v_parent = q.new_zeros(*batch, 6) if p < 0 else vel[p]
        a_parent = ground_acc if p < 0 else acc[p]
        vel[b] = _mv(x, v_parent) + v_j
        a = _mv(x, a_parent) + c_j + _mv(cross_motion(vel[b]), v_j)
        if joint.coordinates:
            a = a + _mv(s, qdd[..., list(joint.coordinates)])
        acc[b] = a
        if p < 0:
            rot[b], pos[b] = r_pb, p_pb
        else:
            rot[b], pos[b] = rot[p] @ r_pb, pos[p] + _mv(rot[p], p_pb)
        momentum = _mv(inertias[b], vel[b])
        force[b] = _mv(inertias[b], a) - _mv(cross_motion(vel[b]).transpose(-1, -2), momentum)
        subspace[j], transform[j] = s, x
    for load in loads:
        b = model.body_index(load.body)
        applied = torch.broadcast_to(load.force.to(q.dtype), (*batch, 3))
        moment = torch.linalg.cross(torch.broadcast_to(load.point.to(q.dtype), (*batch, 3)) - pos[b], applied)
        if load.moment is not None:
            moment = moment + load.moment.to(q.dtype)
        rt = rot[b].transpose(-1, -2)
        force[b] = force[b] - torch.cat([_mv(rt, moment), _mv(rt, applied)], -1)
    tau = q.new_zeros(*batch, model.n_q)
    for j in reversed(model.joint_order):
        joint = model.joints[j]
        f = force[joint.child]
        if joint.coordinates:
            tau[..., list(joint.coordinates)] = _mv(subspace[j].transpose(-1, -2), f)
        if joint.parent >= 0:
            force[joint.parent] = force[joint.parent] + _mv(transform[j].transpose(-1, -2), f)
    return tau


def bias_forces(model: BodyModel, q: torch.Tensor, qd: torch.Tensor, gravity: bool = True,
                hdot: str = "opensim") -> torch.Tensor:
    """[..., n_q] C(q, qd) - G(q): inverse dynamics at zero acceleration without external loads."""
    return inverse_dynamics(model, q, qd, torch.zeros_like(q), gravity=gravity, hdot=hdot)


def mass_matrix(model: BodyModel, q: torch.Tensor) -> torch.Tensor:
    """[..., n_q, n_q] joint-space inertia matrix (composite-rigid-body algorithm, RBDA Table 6.2)."""
    if q.shape[-1] != model.n_q:
        raise ModelError(f"q must have {model.n_q} coordinates for model {model.name!r}")
    batch = q.shape[:-1]
    inertias = _body_inertias(model)
    composite = [inertias[b].expand(*batch, 6, 6) for b in range(model.n_bodies)]
    subspace, transform = {}, {}
    for j in model.joint_order:
        joint = model.joints[j]
        r_pb, p_pb = joint_transform(joint, q)
        transform[j] = motion_transform(r_pb, p_pb)
        subspace[j] = motion_subspace(joint, q)
    joint_of_body = {joint.child: j for j, joint in enumerate(model.joints)}
    for j in reversed(model.joint_order):
        joint = model.joints[j]
        if joint.parent >= 0:
            x = transform[j]
            composite[joint.parent] = composite[joint.parent] + x.transpose(-1, -2) @ composite[joint.child] @ x
    out = q.new_zeros(*batch, model.n_q, model.n_q)
    for i, joint in enumerate(model.joints):
        if not joint.coordinates:
            continue
        rows = list(joint.coordinates)
        f = composite[joint.child] @ subspace[i]
        out[..., torch.tensor(rows)[:, None], torch.tensor(rows)[None, :]] = subspace[i].transpose(-1, -2) @ f
        k = i
        while model.joints[k].parent >= 0:
            f = transform[k].transpose(-1, -2) @ f
            k = joint_of_body[model.joints[k].parent]
            cols = list(model.joints[k].coordinates)
            if cols:
                block = subspace[k].transpose(-1, -2) @ f  # [..., n_k, n_i]
                out[..., torch.tensor(cols)[:, None], torch.tensor(rows)[None, :]] = block
                out[..., torch.tensor(rows)[:, None], torch.tensor(cols)[None, :]] = block.transpose(-1, -2)
    return out
