"""Foot planting: the last stage of guidance, in coordinate space.

Latent guidance (`biomotion.guidance.refine`) moves the motion only through the decoder, which cannot hold a stance
foot exactly still on the floor: after it, stance feet still hover a centimetre or two and slide a few centimetres
(``docs/results/guidance_weights.md``). This stage removes that residue the way motion-capture editing does
(Kovar, Schreiner & Gleicher 2002, "Footskate cleanup for motion capture editing", Proc. ACM SIGGRAPH/Eurographics
SCA, 97-104): find where each foot is planted, give the planted points fixed targets on the floor, and move the
legs the least that reaches them, per frame, by inverse kinematics.

1. **Stance** (per foot and frame): the foot's lowest contact point is below ``stance_height`` above the floor.
2. **Planted points**: during stance, the foot's points within ``band`` of its lowest point (the heel at strike,
   the whole sole at foot-flat, the forefoot at push-off). Each run of frames in which a point stays planted is
   one plant; its target is the point's mean horizontal position over the plant, at height 0.
3. **Fades**: for ``ramp`` frames before and after a plant the point is pulled by a linearly fading share of the
   correction it needs at the plant's edge (Kovar et al. Sec. 4 blend the adjustment in and out the same way), so
   the corrected motion has no step.
4. **Solve**: per frame, damped Gauss-Newton on the leg coordinates (hip, knee, ankle and subtalar of both legs;
   the pelvis, trunk, arms and toe joints are kept) minimising the weighted distance of the planted points to
   their targets, plus ``floor_weight`` times the height of any contact point that went below the floor (held at
   0 from then on, so the active set cannot flip-flop between iterations), plus ``damping`` times the squared
   change of the leg coordinates; coordinates stay in their ranges (one at a bound that the step would push out
   is held there and left out of that step's system). All frames of all clips are one batch of small (12 x 12)
   solves.

Everything happens on the canonical body (clips placed on the floor, `biomotion.data.placement`). The stage is part
of guidance: ``--no-guidance`` skips it, and `biomotion eval generation` reports the motion before it as its own
variant (``no_planting``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy import ndimage

from biomotion.body.kinematics import apply_couplers, forward_kinematics, point_jacobians, points_in_ground

#: Leg coordinates of the canonical model (Rajagopal 2016) that planting may change (knee ``_beta`` is coupled).
#: Not the toe joint: the solver finds bending the toes the cheapest way to move a toe point, and every such bend
#: puts toe-muscle activations outside their training band (muscle-limit violations 24.6 % of frames x muscles
#: on the example profile without ``mtp_angle``, 31.3 % with it, the same contact figures:
#: ``benchmarks/guidance_weights.py``, docs/results/guidance_weights.md).
LEG_COORDINATES = ("hip_flexion", "hip_adduction", "hip_rotation", "knee_angle", "ankle_angle", "subtalar_angle")


@dataclass(frozen=True)
class PlantingConfig:
    """Thresholds (m), fade length (frames at the clip's rate) and solver settings of foot planting.

    ``stance_height`` 3 cm rather than the metrics' 5 cm contact height: at 5 cm, on the example profile, foot
    contact velocity is 0.24 against 0.21 m/s and jerk 314 against 263 m/s^3 (``benchmarks/guidance_weights.py``,
    docs/results/guidance_weights.md; docs/decisions/foot-planting.md)."""

    stance_height: float = 0.03
    band: float = 0.015
    ramp: int = 3
    iterations: int = 6
    damping: float = 1e-2
    floor_weight: float = 10.0
    max_step: float = 0.05  # rad: largest change of a leg coordinate per iteration (a trust region)
    coordinates: tuple[str, ...] = LEG_COORDINATES


def leg_columns(coordinate_names: tuple[str, ...], leg: tuple[str, ...] = LEG_COORDINATES) -> list[int]:
    """Indices of the leg coordinates ``leg`` (both sides) among ``coordinate_names``."""
    wanted = {f"{name}_{side}" for name in leg for side in ("r", "l")}
    return [i for i, name in enumerate(coordinate_names) if name in wanted]


def plant_targets(points: np.ndarray, feet: tuple[str, ...], config: PlantingConfig) -> tuple[np.ndarray, np.ndarray]:
    """Targets [B, T, K, 3] and weights [B, T, K] in [0, 1] for contact points ``points`` [B, T, K, 3] (m, y up,
    floor y = 0) of the feet labelled ``feet`` [K] ("r"/"l"); weight 0 where a point is free."""
    b, t, k, _ = points.shape
    height = points[..., 1]
    planted = np.zeros((b, t, k), dtype=bool)
    for side in sorted(set(feet)):
        own = np.array([f == side for f in feet])
        lowest = height[..., own].min(-1, keepdims=True)
        planted[..., own] = (lowest < config.stance_height) & (height[..., own] < lowest + config.band)
    # one label per run of planted frames of one point of one clip: label along time only
    runs = planted.transpose(0, 2, 1).reshape(b * k, t)
    labels, count = ndimage.label(runs, structure=[[0, 0, 0], [1, 1, 1], [0, 0, 0]])
    flat = points.transpose(0, 2, 1, 3).reshape(b * k, t, 3)
    target = np.full((b * k, t, 3), np.nan)
    weight = np.zeros((b * k, t))
    if count:
        sizes = np.bincount(labels.ravel(), minlength=count + 1)
        anchors = (
            np.stack([np.bincount(labels.ravel(), flat[..., a].ravel(), minlength=count + 1) for a in range(3)], -1)
            / np.maximum(sizes, 1)[:, None]
        )
        anchors[:, 1] = 0.0
        inside = (labels > 0) & (sizes[labels] >= 2)  # a single frame is no plant
        target[inside] = anchors[labels[inside]]
        weight[inside] = 1.0
        correction = np.where(inside[..., None], target - flat, 0.0)
        for d in range(1, config.ramp + 1):
            share = 1.0 - d / (config.ramp + 1)
            for shift in (d, -d):  # after a plant's end, before its start
                source = np.roll(inside, shift, axis=1)
                edge = np.roll(correction, shift, axis=1)
                if shift > 0:
                    source[:, :shift] = False
                else:
                    source[:, shift:] = False
                use = source & ~inside & (weight < share)
                target[use] = flat[use] + share * edge[use]
                weight[use] = share
    back = lambda x: x.reshape(b, k, t, *x.shape[2:]).swapaxes(1, 2)  # noqa: E731
    return back(target), back(weight)


def plant_feet(
    body,
    q: torch.Tensor,
    bodies: torch.Tensor,
    offsets: torch.Tensor,
    feet: tuple[str, ...],
    lower: torch.Tensor,
    upper: torch.Tensor,
    config: PlantingConfig = PlantingConfig(),
) -> torch.Tensor:
    """Coordinates q [B, T, n] with planted feet (see the module docstring); ``bodies``/``offsets``/``feet`` the
    contact points (`biomotion.body.contact.foot_points`), ``lower``/``upper`` [n] the coordinate ranges (only the
    leg coordinates are changed and clamped)."""
    with torch.no_grad():
        x = q.detach().reshape(-1, q.shape[-1])
        points = points_in_ground(forward_kinematics(body, x), bodies, offsets)
        target, weight = plant_targets(points.view(*q.shape[:2], -1, 3).double().numpy(), feet, config)
    return reach_targets(body, q, bodies, offsets, target, weight, lower, upper, config)


def reach_targets(
    body,
    q: torch.Tensor,
    bodies: torch.Tensor,
    offsets: torch.Tensor,
    target: np.ndarray,
    weight: np.ndarray,
    lower: torch.Tensor,
    upper: torch.Tensor,
    config: PlantingConfig = PlantingConfig(),
) -> torch.Tensor:
    """Coordinates q [B, T, n] whose contact points (``bodies``/``offsets``, floor y = 0) reach ``target``
    [B, T, K, 3] with ``weight`` [B, T, K] (0: free; NaN targets of free points are ignored): step 4 of the module
    docstring, the solve `plant_feet` runs on `plant_targets`' targets, open to callers with targets of their own
    (`biomotion.generation.adapt`). Only ``config.coordinates`` change, within ``lower``/``upper`` [n]."""
    with torch.no_grad():
        x = q.detach().reshape(-1, q.shape[-1]).clone()
        target = torch.as_tensor(np.nan_to_num(target), dtype=x.dtype).reshape(len(x), -1, 3)
        weight = torch.as_tensor(weight, dtype=x.dtype).reshape(len(x), -1)
        legs = leg_columns(tuple(body.coordinate_names), config.coordinates)
        start = x[:, legs].clone()
        low, high = lower[legs].to(x.dtype), upper[legs].to(x.dtype)
        eye = config.damping * torch.eye(len(legs), dtype=x.dtype)
        floor = torch.zeros_like(weight, dtype=torch.bool)
        for _ in range(config.iterations):
            poses = forward_kinematics(body, x)
            p = points_in_ground(poses, bodies, offsets)
            jacobian = point_jacobians(body, x, bodies, offsets, poses)[..., legs]  # [N, K, 3, L]
            floor |= p[..., 1] < 0  # once under the floor, held on it: no flip-flop of the active set
            below = floor.to(x.dtype) * config.floor_weight
            residual = torch.cat([((p - target) * weight[..., None]).flatten(1), p[..., 1] * below], 1)
            rows = torch.cat(
                [(jacobian * weight[..., None, None]).flatten(1, 2), jacobian[..., 1, :] * below[..., None]], 1
            )
            current = x[:, legs]
            gradient = (rows.transpose(1, 2) @ residual[..., None]).squeeze(-1) + config.damping * (current - start)
            # a coordinate at a bound that descent would push outward is held there (projected Gauss-Newton): its
            # row and column leave the system, so the other coordinates take up its share
            held = ((current <= low) & (gradient > 0)) | ((current >= high) & (gradient < 0))
            keep = (~held).to(x.dtype)
            normal = (rows.transpose(1, 2) @ rows) * keep[:, :, None] * keep[:, None, :] + eye
            step = torch.linalg.solve(normal, -gradient * keep).clamp(-config.max_step, config.max_step)
            x[:, legs] = torch.minimum(torch.maximum(current + step, low), high)
        return apply_couplers(body, x).view_as(q)
