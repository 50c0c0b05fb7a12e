"""Balance and energy from coordinates: body velocities and accelerations, whole-body COM and its derivatives,
zero-moment point, kinetic and potential energy.

All functions take coordinates ``q``, velocities ``qd`` and accelerations ``qdd`` of shape [..., n_q] (SI) and are
batched and differentiable. Body velocities are exact time derivatives of the forward kinematics, obtained by
forward-mode autograd (``torch.func.jvp``) along (qd, qdd), never by finite differences of positions. The one
exception is `sampled_body_motion`, for trajectories already posed frame by frame (guidance's decoded clips): central
differences of the posed bodies, at a fraction of the nested forward-mode cost, for a loss rather than a report.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch.func import jvp

from biomotion.body.kinematics import body_coms, forward_kinematics
from biomotion.body.model import BodyModel
from biomotion.body.spatial import vee


@dataclass(frozen=True)
class BodyMotion:
    """Per-body COM position/velocity/acceleration [..., B, 3] and angular velocity/acceleration [..., B, 3]
    in ground, plus orientations [..., B, 3, 3]."""

    com: torch.Tensor
    com_velocity: torch.Tensor
    com_acceleration: torch.Tensor
    rotations: torch.Tensor
    angular_velocity: torch.Tensor
    angular_acceleration: torch.Tensor


def body_motion(model: BodyModel, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor) -> BodyMotion:
    """Velocities and accelerations of every body's COM and frame (Featherstone 2008, Sec. 2.7: v = J(q) q̇,
    a = J q̈ + J̇ q̇), from nested forward-mode derivatives of the forward kinematics."""

    def pose(qq: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        poses = forward_kinematics(model, qq)
        return body_coms(model, qq, poses), poses.rotations

    def rates(qq: torch.Tensor, vv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        (_, rotation), (velocity, rotation_rate) = jvp(pose, (qq,), (vv,))
        return velocity, vee(rotation_rate @ rotation.transpose(-1, -2))

    com, rotations = pose(q)
    (velocity, omega), (acceleration, omega_dot) = jvp(rates, (q, qd), (qd, qdd))
    return BodyMotion(com, velocity, acceleration, rotations, omega, omega_dot)


def sampled_body_motion(coms: torch.Tensor, rotations: torch.Tensor, rate: float) -> BodyMotion:
    """`BodyMotion` of body trajectories sampled at ``rate`` Hz, COMs [..., T, B, 3] and orientations
    [..., T, B, 3, 3], by second-order central differences along T (one-sided at the ends, ``torch.gradient``):
    v and a of each COM, and ω = vee(Ṙ Rᵀ) with its own difference for ω̇ (Featherstone 2008, Sec. 2.7)."""
    step = 1.0 / rate
    velocity = torch.gradient(coms, spacing=step, dim=-3)[0]
    acceleration = torch.gradient(velocity, spacing=step, dim=-3)[0]
    rate_of_rotation = torch.gradient(rotations, spacing=step, dim=-4)[0]
    omega = vee(rate_of_rotation @ rotations.transpose(-1, -2))
    omega_dot = torch.gradient(omega, spacing=step, dim=-3)[0]
    return BodyMotion(coms, velocity, acceleration, rotations, omega, omega_dot)


@dataclass(frozen=True)
class CenterOfMass:
    """Whole-body COM position, velocity and acceleration [..., 3] in ground (m, m/s, m/s²)."""

    position: torch.Tensor
    velocity: torch.Tensor
    acceleration: torch.Tensor


def center_of_mass_motion(
    model: BodyModel, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor, bodies: BodyMotion | None = None
) -> CenterOfMass:
    """Mass-weighted mean of the body COM kinematics (Winter 2009, ch. 4)."""
    bodies = body_motion(model, q, qd, qdd) if bodies is None else bodies
    weights = (model.masses / model.total_mass)[:, None]
    return CenterOfMass(
        (weights * bodies.com).sum(-2),
        (weights * bodies.com_velocity).sum(-2),
        (weights * bodies.com_acceleration).sum(-2),
    )


def _world_inertia(model: BodyModel, rotations: torch.Tensor) -> torch.Tensor:
    return rotations @ model.inertias @ rotations.transpose(-1, -2)


MIN_VERTICAL_LOAD_BW = 0.2
"""Body weights the ground must carry, by the kinematics (m (g + a_COM,y)), for a frame to have a zero-moment
point. Below it the body is close to free fall (running's flight, a jump, the instants of touch-down and
lift-off): the ZMP, a horizontal moment over that small vertical force, then lies metres from the body (-15 to
47 m on a generated 3 s run before this rule) and says nothing about balance. The ZMP-to-plate comparison asks the
same load of the plates (`biomotion.analysis.chain.zmp_to_plate_cop`)."""


def zero_moment_point(
    model: BodyModel,
    q: torch.Tensor,
    qd: torch.Tensor,
    qdd: torch.Tensor,
    ground_height: float = 0.0,
    bodies: BodyMotion | None = None,
    min_load_bw: float = MIN_VERTICAL_LOAD_BW,
) -> torch.Tensor:
    """[..., 3] zero-moment point on the horizontal ground plane y = ``ground_height`` (y up).

    The point where the gravito-inertial wrench of all bodies has no horizontal moment (Vukobratović & Borovac
    2004; HUMOS uses it as its stability criterion): with F = Σ mᵢ(g − aᵢ) and
    M_O = Σ rᵢ × mᵢ(g − aᵢ) − Σ Ḣᵢ, where Ḣᵢ = Iᵢω̇ᵢ + ωᵢ × Iᵢωᵢ about each body's COM, the contact wrench
    (−F, −M_O) has zero horizontal moment about p = (M_z / F_y, h, −M_x / F_y) taken relative to the plane.
    NaN where the vertical contact force this asks for is below ``min_load_bw`` body weights (flight; see
    `MIN_VERTICAL_LOAD_BW`).
    """
    bodies = body_motion(model, q, qd, qdd) if bodies is None else bodies
    contact_force, contact_moment = _ground_wrench(model, bodies, ground_height)
    fy = contact_force[..., 1]
    weight = model.total_mass * torch.linalg.vector_norm(model.gravity.to(fy.dtype))
    fy = torch.where(fy >= max(min_load_bw, 1e-12) * weight, fy, torch.full_like(fy, float("nan")))
    x = contact_moment[..., 2] / fy
    z = -contact_moment[..., 0] / fy
    return torch.stack([x, torch.full_like(x, ground_height), z], dim=-1)


def loaded_zero_moment_point(
    model: BodyModel, bodies: BodyMotion, ground_height: float = 0.0, min_load_bw: float = MIN_VERTICAL_LOAD_BW
) -> tuple[torch.Tensor, torch.Tensor]:
    """(ZMP [..., 3], loaded [...] bool): `zero_moment_point` of given body motion, for a loss. Where the ground
    carries less than ``min_load_bw`` body weights the moment is divided by that load instead, so the result and
    its gradient stay finite everywhere (NaN there would poison the gradients of every frame); ``loaded`` marks the
    frames whose ZMP is the real one."""
    contact_force, contact_moment = _ground_wrench(model, bodies, ground_height)
    fy = contact_force[..., 1]
    floor = max(min_load_bw, 1e-12) * model.total_mass * torch.linalg.vector_norm(model.gravity.to(fy.dtype))
    loaded = fy >= floor
    load = torch.where(loaded, fy, torch.full_like(fy, float(floor)))
    x = contact_moment[..., 2] / load
    z = -contact_moment[..., 0] / load
    return torch.stack([x, torch.full_like(x, ground_height), z], dim=-1), loaded


def _ground_wrench(model: BodyModel, bodies: BodyMotion, ground_height: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(force, moment about (0, ground_height, 0)) [..., 3] the ground must apply for the bodies' motion: minus the
    gravito-inertial wrench Σ mᵢ(g − aᵢ), Σ rᵢ × mᵢ(g − aᵢ) − Σ Ḣᵢ (see `zero_moment_point`)."""
    masses = model.masses[:, None].to(bodies.com.dtype)
    gravity = model.gravity.to(bodies.com.dtype)
    force_each = masses * (gravity - bodies.com_acceleration)
    inertia = _world_inertia(model, bodies.rotations).to(bodies.com.dtype)
    omega = bodies.angular_velocity
    spin = (inertia @ bodies.angular_acceleration[..., None]).squeeze(-1) + torch.cross(
        omega, (inertia @ omega[..., None]).squeeze(-1), dim=-1
    )
    arm = bodies.com - bodies.com.new_tensor([0.0, ground_height, 0.0])
    force = force_each.sum(-2)
    moment = torch.cross(arm, force_each, dim=-1).sum(-2) - spin.sum(-2)
    return -force, -moment


def mechanical_energy(model: BodyModel, q: torch.Tensor, qd: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(kinetic, potential) energy [...] in J: Σ ½ mᵢ|vᵢ|² + ½ ωᵢᵀ Iᵢ ωᵢ and Σ −mᵢ g·rᵢ (zero at the ground).

    PG-BIG's energy-consistency metric is the variance of their sum over a clip.
    """
    bodies = body_motion(model, q, qd, torch.zeros_like(qd))
    inertia = _world_inertia(model, bodies.rotations)
    omega = bodies.angular_velocity
    rotational = 0.5 * (omega * (inertia @ omega[..., None]).squeeze(-1)).sum(-1)
    translational = 0.5 * model.masses * (bodies.com_velocity**2).sum(-1)
    kinetic = (translational + rotational).sum(-1)
    potential = -(model.masses[:, None] * model.gravity.to(q.dtype) * bodies.com).sum((-1, -2))
    return kinetic, potential
