"""Foot contact points and ground reaction forces inferred from kinematics alone (PhysPT Sec. 3.2.3, Eq. 4-5).

The pelvis (the free-floating root) has no actuator, so whatever generalized force its six coordinates need to
follow the motion must come from the ground. `infer_ground_reaction` finds, for every frame at once, non-negative
friction-bounded forces at a few points under each foot that best produce that root force, while a soft contact
prior — PhysPT's gate s = σ(−d/δd)·σ(−|v|/δv) on the point's height d and speed |v| (Eq. 4; here the
vertical speed, see `ContactSettings`) — makes forces at points that are high or moving expensive. The joint torques
then follow by inverse dynamics with those loads (the Euler-Lagrange equations, PhysPT Eq. 2), and the part of the root
force left unexplained is reported as the per-frame residual.

Rules (documented in README; none is fitted on force-plate data):
- contact points: 5 per foot, placed from the model's own foot geometry (heel medial/lateral, first and fifth
  metatarsal heads, toe tip), spaced in proportion to the calcaneus→MTP distance;
- ground level per point: its 2nd percentile height over the trial (feet rest on the ground in every trial we
  analyse), so the height that matters is the point's height above where it rests;
- friction: linearised cone, 4 edges, μ = 0.8;
- the solve is a batched non-negative least squares over all frames in one tensor program: Newton's method on
  its 6-dimensional Lagrange dual (see `_nonnegative_least_squares`), no per-frame loop, no external QP solver.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
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
        raise ModelError(
            f"model {model.name!r} has {len(roots)} root coordinates; force inference needs a "
            "6-degree-of-freedom floating base"
        )
    return roots


@dataclass(frozen=True)
class ContactSettings:
    """Contact prior and solver settings (heights in m, speeds in m/s).

    The gate's values were chosen on two trials kept out of every evaluation of the inferred forces — Hamner
    subject01 running at 5 m/s and gait2392 subject01 walking — by a small grid search, repeatable with
    ``python benchmarks/grf_settings.py`` (docs/results/grf.md: each setting varied alone at the evaluation's
    10 Hz; a default moves only where another value lowers the tuning trials' mean RMSE by more than 2 %;
    docs/decisions/inferred-grf.md). The speed gate uses the vertical speed because a treadmill belt carries the
    stance foot horizontally.
    """

    height_scale: float = 0.01  # δd (m)
    height_offset: float = 0.02  # gate centre: 2 cm above the point's resting height
    speed_scale: float = 0.1  # δv (m/s), on the vertical speed
    speed_offset: float = 0.3  # gate centre: 0.3 m/s vertical speed
    friction: float = 0.8
    prior_weight: float = 1e-3  # weight of the "not in contact" penalty (1/s − 1)·|β|² relative to the fit
    moment_length: float = 1.0  # m: root moments are divided by this to weigh them against root forces
    iterations: int = 50  # most Newton steps of the force solve (it stops exactly, after 5-7 on OpenCap)
    rest_percentile: float = 2.0


@dataclass(frozen=True)
class InferredForces:
    """Result of `infer_ground_reaction` (all tensors batched over frames)."""

    point_forces: torch.Tensor  # [T, K, 3] N, in ground
    point_positions: torch.Tensor  # [T, K, 3] m
    gate: torch.Tensor  # [T, K] contact prior s in (0, 1)
    foot_force: torch.Tensor  # [T, 2, 3] N, right then left
    foot_cop: torch.Tensor  # [T, 2, 3] m (NaN when the foot carries < 1 N)
    foot_moment: torch.Tensor  # [T, 2, 3] N·m free moment about the CoP (vertical part)
    torques: torch.Tensor  # [T, n_q] generalized forces with the inferred loads
    root_residual: torch.Tensor  # [T, 6] root generalized force left unexplained (N·m, N)
    points: FootPoints


def _point_kinematics(
    model: BodyModel, q: torch.Tensor, qd: torch.Tensor, points: FootPoints, directions: list[int]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Positions [T, K, 3], velocities [T, K, 3] and Jacobian columns [T, K, 3, D] for ``directions``."""
    poses = forward_kinematics(model, q)
    positions = points_in_ground(poses, points.bodies, points.offsets)
    jacobian = point_jacobians(model, q, points.bodies, points.offsets, poses)
    velocities = (jacobian @ qd[..., None, :, None]).squeeze(-1)
    return positions, velocities, jacobian[..., directions]


def _friction_edges(mu: float, dtype: torch.dtype) -> torch.Tensor:
    """[4, 3] unit-free edge directions of the linearised friction cone around +y (n ± μ t)."""
    return torch.tensor([[mu, 1.0, 0.0], [-mu, 1.0, 0.0], [0.0, 1.0, mu], [0.0, 1.0, -mu]], dtype=dtype)


def _nonnegative_least_squares(
    a: torch.Tensor, r: torch.Tensor, d: torch.Tensor, iterations: int, tolerance: float = 1e-9
) -> torch.Tensor:
    """argmin_{x ≥ 0} ½|Ax − r|² + ½Σᵢ dᵢxᵢ² for a batch of A [T, m, n], r [T, m], d [T, n] > 0 (m ≪ n).

    Lagrange dual (Boyd & Vandenberghe 2004, Convex Optimization, Sec. 5.2; λ = r − Ax the residual): the
    unconstrained, strictly convex, continuously differentiable piecewise quadratic in m variables (6 here)

        min_λ f(λ) = ½|λ|² − rᵀλ + ½Σᵢ max(0, aᵢᵀλ)²/dᵢ,    x*ᵢ = max(0, aᵢᵀλ*)/dᵢ,

    with ∇f = λ − r + A x(λ) and generalized Hessian H = I + Σ_{aᵢᵀλ>0} aᵢaᵢᵀ/dᵢ (m×m), so every Newton point
    is λ − H⁻¹∇f = H⁻¹r: one batched m×m Cholesky solve, whatever n. This is the generalized-Newton method for
    squared plus functions (Mangasarian 2002, "A finite Newton method for classification", Optim. Methods
    Softw. 17:913-929) with an exact line search in place of Armijo's: along λ + tδ, f′ is piecewise linear
    and increasing with kinks at tᵢ = −aᵢᵀλ/aᵢᵀδ, so sorting the kinks and accumulating the slopes gives its
    root. A Newton step that crosses no kink lands on the minimiser of the quadratic piece it lies in, which
    is f's minimiser: that frame is exact and leaves the batch (on such functions nonsmooth Newton converges
    globally and finitely: Sun 1997, "On piecewise quadratic Newton and trust region problems", Math.
    Program. 76:451-467; 5-7 steps on the OpenCap trials). A crossing by a term whose force xᵢ stays
    below ``tolerance``·(1 + |r|∞) on both sides is rounding and does not count; after ``iterations`` steps
    the frames still moving keep their last line-search point.
    """
    eye = torch.eye(a.shape[-2], dtype=a.dtype)
    solution = r.clone()
    # the frames still iterating ("live"): their index, A, r, 1/d, rounding floor, λ and s = Aᵀλ
    live, a_live, r_live, inv_d = torch.arange(r.shape[0]), a, r, 1.0 / d
    floor = tolerance * (1.0 + r.abs().amax(-1, keepdim=True))
    lam, s = r, (a * r[..., None]).sum(-2)  # start at x = 0
    for _ in range(iterations):
        active = s > 0
        h = torch.baddbmm(eye, a_live * (active * inv_d)[..., None, :], a_live.transpose(-1, -2))
        target = torch.cholesky_solve(r_live[..., None], torch.linalg.cholesky_ex(h).L).squeeze(-1)
        delta = target - lam
        c = (a_live * delta[..., None]).sum(-2)  # Aᵀδ
        moved = s + c
        crossing = ((active != (moved > 0)) & (torch.maximum(s.abs(), moved.abs()) * inv_d > floor)).any(-1)
        exact = ~crossing
        solution[live[exact]] = target[exact]
        if not bool(crossing.any()):
            break
        live, a_live, r_live = live[crossing], a_live[crossing], r_live[crossing]
        inv_d, floor = inv_d[crossing], floor[crossing]
        lam, s, c, delta, active = lam[crossing], s[crossing], c[crossing], delta[crossing], active[crossing]
        # f′(λ + tδ) = α_j + β_j t between the j-th and (j+1)-th kink (piece 0 starts at t = 0)
        w = c * inv_d
        ws, wc = w * s, w * c
        alpha = (delta * (lam - r_live)).sum(-1, keepdim=True) + (ws * active).sum(-1, keepdim=True)
        beta = (delta * delta).sum(-1, keepdim=True) + (wc * active).sum(-1, keepdim=True)
        kink = -s / c
        ahead = kink > 0
        kink, order = torch.sort(torch.where(ahead, kink, torch.inf), dim=-1)
        enters = torch.where(ahead, torch.sign(c), 0.0)  # +1: a term switches on, −1: off
        alphas = torch.cat([alpha, alpha + (enters * ws).gather(-1, order).cumsum(-1)], -1)
        betas = torch.cat([beta, beta + (enters * wc).gather(-1, order).cumsum(-1)], -1)
        ends = torch.cat([kink, torch.full_like(alpha, torch.inf)], -1)
        j = (alphas + betas * ends < 0).sum(-1, keepdim=True).clamp(max=ends.shape[-1] - 1)  # root's piece
        slope = betas.gather(-1, j)
        step = torch.where(slope > 0, -alphas.gather(-1, j) / slope, 0.0).clamp(min=0.0)
        lam, s = lam + step * delta, s + step * c
    else:
        solution[live] = lam
    return (a * solution[..., None]).sum(-2).clamp(min=0.0) / d


def infer_ground_reaction(
    model: BodyModel,
    q: torch.Tensor,
    qd: torch.Tensor,
    qdd: torch.Tensor,
    settings: ContactSettings = ContactSettings(),
) -> InferredForces:
    """Ground reaction per foot and joint torques from kinematics only (q, qd, qdd [T, n_q], SI)."""
    points = foot_points(model)
    roots = root_coordinates(model)
    with torch.no_grad():
        free = inverse_dynamics(model, q, qd, qdd)[..., roots]  # [T, 6] what the ground must supply
        positions, velocities, jacobian = _point_kinematics(model, q, qd, points, roots)
        rest = torch.quantile(positions[..., 1], settings.rest_percentile / 100.0, dim=0)
        height = positions[..., 1] - rest
        speed = velocities[..., 1].abs()  # vertical only: on a treadmill the stance foot moves with the belt
        gate = torch.sigmoid(-(height - settings.height_offset) / settings.height_scale) * torch.sigmoid(
            -(speed - settings.speed_offset) / settings.speed_scale
        )
        edges = _friction_edges(settings.friction, q.dtype)  # [4, 3]
        # generalized root force of edge e at point k: J_kᵀ e  -> [T, 6, K*4]
        per_edge = torch.einsum("tkcd,ec->tdke", jacobian, edges)
        a = per_edge.reshape(*per_edge.shape[:2], -1)
        scale = torch.ones(6, dtype=q.dtype)
        rotational = [i for i, c in enumerate(roots) if model.motion_types[c] == "rotational"]
        scale[rotational] = 1.0 / settings.moment_length
        a_w, r_w = a * scale[:, None], free * scale
        penalty = settings.prior_weight * (1.0 / gate.clamp(min=1e-6) - 1.0)  # [T, K]
        # ½|A x − r|² + ½xᵀ diag(penalty per edge + 1e-9) x, x ≥ 0: N along each cone edge
        coefficients = _nonnegative_least_squares(
            a_w.contiguous(), r_w, penalty.repeat_interleave(4, dim=-1) + 1e-9, settings.iterations
        )
        beta = coefficients.reshape(*coefficients.shape[:-1], len(points.names), 4)
        point_forces = torch.einsum("tke,ec->tkc", beta, edges)
        residual = free - (a @ coefficients[..., None]).squeeze(-1)
        loads = [
            ExternalLoad(model.body_names[int(points.bodies[k])], point_forces[:, k], positions[:, k])
            for k in range(len(points.names))
        ]
        torques = inverse_dynamics(model, q, qd, qdd, loads)
    return InferredForces(
        point_forces, positions, gate, *_per_foot(point_forces, positions, points), torques, residual, points
    )


def _per_foot(
    point_forces: torch.Tensor, positions: torch.Tensor, points: FootPoints
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


#: Percentile over frames of the lowest foot contact point taken as the floor of a clip (robust to a few frames
#: of foot-skimming or noise below the floor).
GROUND_PERCENTILE = 5.0


def lowest_foot_heights(model: BodyModel, q: np.ndarray) -> np.ndarray:
    """[T] height of the lowest foot contact point per frame for canonical coordinates q [T, n] (all present)."""
    feet = foot_points(model)
    with torch.no_grad():
        poses = forward_kinematics(model, torch.from_numpy(q).to(model.dtype))
        return points_in_ground(poses, feet.bodies, feet.offsets)[..., 1].amin(-1).numpy()
