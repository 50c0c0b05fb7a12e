"""Foot contact points and ground reaction forces inferred from kinematics alone (PhysPT Sec. 3.2.3, Eq. 4-5).

The pelvis (the free-floating root) has no actuator, so whatever generalized force its six coordinates need to
follow the motion must come from the ground. `infer_ground_reaction` finds, for every frame at once, non-negative
friction-bounded forces at a few points under each foot that best produce that root force, while a soft contact
prior — PhysPT's gate s = σ(−d/δd)·σ(−|v|/δv) on the point's height d and speed |v| (Eq. 4; here the
vertical speed, see `ContactSettings`) — makes forces at points that are high or moving expensive. The joint torques then follow by inverse dynamics with those loads
(the Euler-Lagrange equations, PhysPT Eq. 2), and the part of the root force left unexplained is reported as
the per-frame residual.

Rules (documented in README; none is fitted on force-plate data):
- contact points: 5 per foot, placed from the model's own foot geometry (heel medial/lateral, first and fifth
  metatarsal heads, toe tip), spaced in proportion to the calcaneus→MTP distance;
- ground level per point: its 2nd percentile height over the trial (feet rest on the ground in every trial we
  analyse), so the height that matters is the point's height above where it rests;
- friction: linearised cone, 4 edges, μ = 0.8;
- the solve is a batched non-negative least squares (accelerated projected gradient, FISTA: Beck & Teboulle
  2009) over all frames in one tensor program: no per-frame loop, no external QP solver.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from biomotion.body.dynamics import ExternalLoad, inverse_dynamics
from biomotion.body.kinematics import forward_kinematics, point_jacobians, points_in_ground
from biomotion.body.model import BodyModel
from biomotion.errors import ModelError


@dataclass(frozen=True)
class FootPoints:
    """Contact points: body index [K], offset in that body [K, 3], foot label per point ("r"/"l"), names."""

    bodies: torch.Tensor
    offsets: torch.Tensor
    feet: tuple[str, ...]
    names: tuple[str, ...]


def _joint_to(model: BodyModel, child: str):
    index = model.body_index(child)
    return next(j for j in model.joints if j.child == index)


def foot_points(model: BodyModel) -> FootPoints:
    """Five contact points per foot from the model's foot geometry (calcaneus and, when present, toes bodies)."""
    bodies, offsets, feet, names = [], [], [], []
    for side in ("r", "l"):
        calcn = f"calcn_{side}"
        if calcn not in model.body_names:
            raise ModelError(f"model {model.name!r} has no {calcn} body: cannot place foot contact points")
        lateral = 1.0 if side == "r" else -1.0  # +z is lateral on the right foot, medial on the left
        toes = f"toes_{side}"
        if toes in model.body_names:
            mtp = _joint_to(model, toes).parent_translation
        else:
            mtp = torch.tensor([0.18, -0.002, 0.0], dtype=model.dtype)
        length = float(torch.linalg.norm(mtp))
        heel_x = 0.10 * length
        points = {
            "heel_med": (calcn, [heel_x, 0.0, -lateral * 0.12 * length]),
            "heel_lat": (calcn, [heel_x, 0.0, lateral * 0.12 * length]),
            "met1": (calcn, [float(mtp[0]), 0.0, float(mtp[2]) - lateral * 0.15 * length]),
            "met5": (calcn, [float(mtp[0]) - 0.15 * length, 0.0, float(mtp[2]) + lateral * 0.22 * length]),
        }
        if toes in model.body_names:
            points["toe"] = (toes, [0.30 * length, 0.0, -lateral * 0.05 * length])
        else:
            points["toe"] = (calcn, [float(mtp[0]) + 0.30 * length, 0.0, float(mtp[2])])
        for name, (body, offset) in points.items():
            bodies.append(model.body_index(body))
            offsets.append(offset)
            feet.append(side)
            names.append(f"{name}_{side}")
    return FootPoints(torch.tensor(bodies), torch.tensor(offsets, dtype=model.dtype), tuple(feet), tuple(names))


def root_coordinates(model: BodyModel) -> list[int]:
    """Coordinates of the joint(s) attached to ground: the unactuated floating base."""
    roots = [c for j in model.joints if j.parent < 0 for c in j.coordinates]
    if len(roots) != 6:
        raise ModelError(f"model {model.name!r} has {len(roots)} root coordinates; force inference needs a "
                         "6-degree-of-freedom floating base")
    return roots


@dataclass(frozen=True)
class ContactSettings:
    """Contact prior and solver settings (heights in m, speeds in m/s).

    The gate's values were chosen on two trials kept out of every evaluation of the inferred forces — Hamner
    subject01 running at 5 m/s and gait2392 subject01 walking — by a small grid search (docs/results/grf.md);
    the speed gate uses the vertical speed because a treadmill belt carries the stance foot horizontally.
    """

    height_scale: float = 0.02      # δd (m)
    height_offset: float = 0.02     # gate centre: 2 cm above the point's resting height
    speed_scale: float = 0.1        # δv (m/s), on the vertical speed
    speed_offset: float = 0.3       # gate centre: 0.3 m/s vertical speed
    friction: float = 0.8
    prior_weight: float = 1e-3      # weight of the "not in contact" penalty (1/s − 1)·|β|² relative to the fit
    moment_length: float = 1.0      # m: root moments are divided by this to weigh them against root forces
    iterations: int = 400
    rest_percentile: float = 2.0


@dataclass(frozen=True)
class InferredForces:
    """Result of `infer_ground_reaction` (all tensors batched over frames)."""

    point_forces: torch.Tensor      # [T, K, 3] N, in ground
    point_positions: torch.Tensor   # [T, K, 3] m
    gate: torch.Tensor              # [T, K] contact prior s in (0, 1)
    foot_force: torch.Tensor        # [T, 2, 3] N, right then left
    foot_cop: torch.Tensor          # [T, 2, 3] m (NaN when the foot carries < 1 N)
    foot_moment: torch.Tensor       # [T, 2, 3] N·m free moment about the CoP (vertical part)
    torques: torch.Tensor           # [T, n_q] generalized forces with the inferred loads
    root_residual: torch.Tensor     # [T, 6] root generalized force left unexplained (N·m, N)
    points: FootPoints


def _point_kinematics(model: BodyModel, q: torch.Tensor, qd: torch.Tensor, points: FootPoints,
                      directions: list[int]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Positions [T, K, 3], velocities [T, K, 3] and Jacobian columns [T, K, 3, D] for ``directions``."""
    poses = forward_kinematics(model, q)
    positions = points_in_ground(poses, points.bodies, points.offsets)
    jacobian = point_jacobians(model, q, points.bodies, points.offsets, poses)
    velocities = (jacobian @ qd[..., None, :, None]).squeeze(-1)
    return positions, velocities, jacobian[..., directions]


def _friction_edges(mu: float, dtype: torch.dtype) -> torch.Tensor:
    """[4, 3] unit-free edge directions of the linearised friction cone around +y (n ± μ t)."""
    return torch.tensor([[mu, 1.0, 0.0], [-mu, 1.0, 0.0], [0.0, 1.0, mu], [0.0, 1.0, -mu]], dtype=dtype)


def _nonnegative_least_squares(p: torch.Tensor, b: torch.Tensor, iterations: int) -> torch.Tensor:
    """argmin_{x ≥ 0} ½xᵀPx − bᵀx for a batch of SPD ``p`` [T, n, n], by FISTA with step 1/λ_max(P)."""
    step = 1.0 / torch.linalg.eigvalsh(p)[..., -1:].clamp(min=1e-12)
    x = torch.zeros_like(b)
    y, t = x, 1.0
    for _ in range(iterations):
        gradient = (p @ y[..., None]).squeeze(-1) - b
        x_next = (y - step * gradient).clamp(min=0.0)
        t_next = 0.5 * (1.0 + (1.0 + 4.0 * t * t) ** 0.5)
        y = x_next + ((t - 1.0) / t_next) * (x_next - x)
        x, t = x_next, t_next
    return x


def infer_ground_reaction(model: BodyModel, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor,
                          settings: ContactSettings = ContactSettings()) -> InferredForces:
    """Ground reaction per foot and joint torques from kinematics only (q, qd, qdd [T, n_q], SI)."""
    points = foot_points(model)
    roots = root_coordinates(model)
    with torch.no_grad():
        free = inverse_dynamics(model, q, qd, qdd)[..., roots]             # [T, 6] what the ground must supply
        positions, velocities, jacobian = _point_kinematics(model, q, qd, points, roots)
        rest = torch.quantile(positions[..., 1], settings.rest_percentile / 100.0, dim=0)
        height = positions[..., 1] - rest
        speed = velocities[..., 1].abs()  # vertical only: on a treadmill the stance foot moves with the belt
        gate = torch.sigmoid(-(height - settings.height_offset) / settings.height_scale) * torch.sigmoid(
            -(speed - settings.speed_offset) / settings.speed_scale)
        edges = _friction_edges(settings.friction, q.dtype)                # [4, 3]
        # generalized root force of edge e at point k: J_kᵀ e  -> [T, 6, K*4]
        per_edge = torch.einsum("tkcd,ec->tdke", jacobian, edges)
        a = per_edge.reshape(*per_edge.shape[:2], -1)
        scale = torch.ones(6, dtype=q.dtype)
        rotational = [i for i, c in enumerate(roots) if model.motion_types[c] == "rotational"]
        scale[rotational] = 1.0 / settings.moment_length
        a_w, r_w = a * scale[:, None], free * scale
        weight = model.total_mass * 9.80665
        penalty = settings.prior_weight * (1.0 / gate.clamp(min=1e-6) - 1.0)   # [T, K]
        p = (a_w.transpose(-1, -2) @ a_w + torch.diag_embed(penalty.repeat_interleave(4, dim=-1) + 1e-9)
             ) / weight ** 2
        b = (a_w.transpose(-1, -2) @ r_w[..., None]).squeeze(-1) / weight ** 2
        coefficients = _nonnegative_least_squares(p, b, settings.iterations)  # N along each cone edge
        beta = coefficients.reshape(*coefficients.shape[:-1], len(points.names), 4)
        point_forces = torch.einsum("tke,ec->tkc", beta, edges)
        residual = free - (a @ coefficients[..., None]).squeeze(-1)
        loads = [ExternalLoad(model.body_names[int(points.bodies[k])], point_forces[:, k], positions[:, k])
                 for k in range(len(points.names))]
        torques = inverse_dynamics(model, q, qd, qdd, loads)
    return InferredForces(point_forces, positions, gate, *_per_foot(point_forces, positions, points), torques,
                          residual, points)


def _per_foot(point_forces: torch.Tensor, positions: torch.Tensor, points: FootPoints
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Sum point forces per foot; CoP on the ground from the vertical-force-weighted point positions and the
    free moment about it (vertical component of Σ (p_k − cop) × f_k)."""
    forces, cops, moments = [], [], []
    for side in ("r", "l"):
        mask = torch.tensor([f == side for f in points.feet])
        f_k, p_k = point_forces[:, mask], positions[:, mask]
        total = f_k.sum(1)
        vertical = f_k[..., 1].sum(1, keepdim=True)
        cop = (f_k[..., 1:2] * p_k).sum(1) / vertical.clamp(min=1e-9)
        cop = torch.cat([cop[:, :1], torch.zeros_like(cop[:, :1]), cop[:, 2:]], dim=-1)
        cop = torch.where(vertical > 1.0, cop, torch.full_like(cop, float("nan")))
        arm = p_k - torch.nan_to_num(cop)[:, None]
        arm = torch.cat([arm[..., :1], torch.zeros_like(arm[..., :1]), arm[..., 2:]], dim=-1)
        moment = torch.linalg.cross(arm, f_k).sum(1)
        moment = torch.stack([torch.zeros_like(moment[:, 0]), moment[:, 1], torch.zeros_like(moment[:, 0])], -1)
        forces.append(total)
        cops.append(cop)
        moments.append(moment)
    return torch.stack(forces, 1), torch.stack(cops, 1), torch.stack(moments, 1)
