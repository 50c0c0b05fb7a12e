"""Spatial algebra, in one place: cross-product matrices, rotations, and the 6D motion/force operators of
Featherstone, "Rigid Body Dynamics Algorithms" (2008; RBDA, ch. 2).

Forward kinematics, Jacobians, dynamics, balance and IK all rest on these few formulas; defining them once keeps
one sign convention and one layout for the whole physics core (DESIGN.md, "Layers": body holds the spatial algebra).

Conventions. ``skew(v) @ u = v x u``. Rotations map child-frame coordinates to parent-frame coordinates. Spatial
motion vectors are (angular; linear) and force vectors (moment; force), each about the origin of the frame they are
expressed in (RBDA ch. 2). Every function is batched over leading dims, differentiable with autograd, and
keeps its inputs' dtype.

Two layouts. Frames first ([..., 3], [..., 3, 3], [..., 6, 6]) is the public one. Frames last ([..., 3, N],
[..., 3, 3, N]; N = all frames flattened, last and contiguous) is the layout of `KinematicTree` and the batched
dynamics: there a 3x3 product is a few element-wise operations along contiguous frames, several times faster than
batched ``matmul`` or ``torch.linalg.cross`` on small matrices; the ``*_frames_last`` functions are the same
formulas in that layout.
"""

from __future__ import annotations

import torch

# ---- 3-vectors and rotations (frames first) -------------------------------------------------------------------


def skew(v: torch.Tensor) -> torch.Tensor:
    """[..., 3, 3] the cross-product matrix [v]x of ``v`` [..., 3]: ``skew(v) @ u == v x u`` (RBDA
    ch. 2's 3D cross operator)."""
    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack(
        [torch.stack([zero, -z, y], -1), torch.stack([z, zero, -x], -1), torch.stack([-y, x, zero], -1)], -2
    )


def vee(m: torch.Tensor) -> torch.Tensor:
    """[..., 3] the vector of the skew-symmetric part of ``m`` [..., 3, 3]: the inverse of `skew` on skew
    matrices, ``vee(skew(v)) == v``. Used for angular velocity from a rotation's rate, [w]x = dR/dt R^T."""
    return 0.5 * torch.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], dim=-1
    )


def axis_angle(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """[..., 3, 3] rotation by ``angle`` [...] (rad, right-handed) about the unit ``axis`` [3]:
    R = I + sin(a) K + (1 - cos(a)) K^2 with K = [axis]x (Rodrigues' formula). The rotation of each CustomJoint
    transform axis (model.py's conventions); `KinematicTree.joint_frames` evaluates the same formula for every
    axis of a model at once."""
    k = skew(axis)
    eye = torch.eye(3, dtype=axis.dtype)
    s, c = torch.sin(angle)[..., None, None], torch.cos(angle)[..., None, None]
    return eye + s * k + (1.0 - c) * (k @ k)


def body_fixed_xyz(angles: torch.Tensor) -> torch.Tensor:
    """[..., 3, 3] R = Rx(a) Ry(b) Rz(c) of ``angles`` [..., 3] (rad): body-fixed X-Y-Z Euler angles, OpenSim's
    orientation convention for offset frames (PhysicalOffsetFrame ``orientation``)."""
    eye = torch.eye(3, dtype=angles.dtype)
    return axis_angle(eye[0], angles[..., 0]) @ axis_angle(eye[1], angles[..., 1]) @ axis_angle(eye[2], angles[..., 2])


# ---- 6D operators (frames first) -------------------------------------------------------------------------------


def _blocks(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    return torch.cat([torch.cat([a, b], -1), torch.cat([c, d], -1)], -2)


def motion_transform(rotation: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
    """[..., 6, 6] the Plücker transform ^B X_A of motion vectors from frame A to frame B, for B at ``rotation``
    [..., 3, 3] and ``translation`` [..., 3] in A: [E 0; -E [r]x E] with E = rotation^T, r = translation
    (RBDA eq. 2.24). Forces transform with its inverse transpose, ^B X_A^* = (^B X_A)^-T."""
    rt = rotation.transpose(-1, -2)
    return _blocks(rt, torch.zeros_like(rt), -rt @ skew(translation), rt)


def cross_motion(v: torch.Tensor) -> torch.Tensor:
    """[..., 6, 6] the spatial cross operator v x on motion vectors, [[w]x 0; [u]x [w]x] for v = (w; u)
    [..., 6] (RBDA eq. 2.31); its dual on forces is -(v x)^T (eq. 2.32)."""
    w, u = skew(v[..., :3]), skew(v[..., 3:])
    return _blocks(w, torch.zeros_like(w), u, w)


def spatial_inertia(mass: torch.Tensor, com: torch.Tensor, inertia: torch.Tensor) -> torch.Tensor:
    """[..., 6, 6] spatial inertia about the frame origin of a rigid body of ``mass`` [...], centre of mass ``com``
    [..., 3] and rotational ``inertia`` [..., 3, 3] about the COM, all in that frame:
    [I_c + m [c]x [c]x^T, m [c]x; m [c]x^T, m 1] (RBDA Sec. 2.13)."""
    c = skew(com)
    m = mass[..., None, None]
    eye = torch.eye(3, dtype=com.dtype).expand_as(c)
    return _blocks(inertia + m * (c @ c.transpose(-1, -2)), m * c, m * c.transpose(-1, -2), m * eye)


# ---- the same formulas, frames last ----------------------------------------------------------------------------


def skew_frames_last(v: torch.Tensor) -> torch.Tensor:
    """[..., 3, 3, N] `skew` of ``v`` [..., 3, N]."""
    x, y, z = v.unbind(-2)
    zero = torch.zeros_like(x)
    return torch.stack(
        [torch.stack([zero, -z, y], -2), torch.stack([z, zero, -x], -2), torch.stack([-y, x, zero], -2)], -3
    )


def cross_frames_last(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """[..., 3, N] a x b of [..., 3, N] (by components: several times faster than ``torch.linalg.cross`` here)."""
    a0, a1, a2 = a.unbind(-2)
    b0, b1, b2 = b.unbind(-2)
    return torch.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], -2)


#: Elements of an operand from which the frames-last products are summed term by term (three products, one
#: temporary the size of the result) rather than as one broadcast product summed over a middle dim (one call, a
#: temporary three times the result): 1.4-1.7x faster at a thousand frames of a dozen bodies, slower at a hundred.
_UNROLLED = 32768


def matmul_frames_last(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """[..., 3, 3, N] products a b of [..., 3, 3, N] (either may be a constant [..., 3, 3, 1])."""
    if max(a.numel(), b.numel()) < _UNROLLED:
        return (a[..., :, :, None, :] * b[..., None, :, :, :]).sum(-3)
    out = a[..., :, 0, None, :] * b[..., None, 0, :, :]
    out.addcmul_(a[..., :, 1, None, :], b[..., None, 1, :, :])
    return out.addcmul_(a[..., :, 2, None, :], b[..., None, 2, :, :])


def matvec_frames_last(a: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """[..., 3, N] a v of [..., 3, 3, N] and [..., 3, N]."""
    if max(a.numel(), v.numel()) < _UNROLLED:
        return (a * v[..., None, :, :]).sum(-2)
    out = a[..., :, 0, :] * v[..., None, 0, :]
    out.addcmul_(a[..., :, 1, :], v[..., None, 1, :])
    return out.addcmul_(a[..., :, 2, :], v[..., None, 2, :])


def tmatvec_frames_last(a: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """[..., 3, N] a^T v of [..., 3, 3, N] and [..., 3, N] (a rotation's inverse applied)."""
    return (a * v[..., :, None, :]).sum(-3)


def cross_motion_frames_last(v: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """[..., 6, N] v x m of motion vectors [..., 6, N], `cross_motion` (RBDA eq. 2.31) applied without forming the
    6x6 operator: (w x m_w; w x m_u + u x m_w) for v = (w; u)."""
    w = v[..., :3, :]
    return torch.cat(
        [
            cross_frames_last(w, m[..., :3, :]),
            cross_frames_last(w, m[..., 3:, :]) + cross_frames_last(v[..., 3:, :], m[..., :3, :]),
        ],
        -2,
    )


def spatial_inertia_frames_last(mass: torch.Tensor, com: torch.Tensor, inertia: torch.Tensor) -> torch.Tensor:
    """[..., 6, 6, N] `spatial_inertia` (RBDA Sec. 2.13) of ``mass`` [..., N] (or [..., 1]), ``com`` [..., 3, N]
    and ``inertia`` [..., 3, 3, N] about the COM, all in the frame whose origin it is taken about."""
    c = skew_frames_last(com)
    m = mass[..., None, None, :]
    eye = torch.eye(3, dtype=com.dtype)[..., None].expand_as(c)
    return torch.cat(
        [
            torch.cat([inertia + m * matmul_frames_last(c, c.transpose(-3, -2)), m * c], -2),
            torch.cat([m * c.transpose(-3, -2), m * eye], -2),
        ],
        -3,
    )
