"""Caps on the vertical ground reaction and on joint-moment magnitudes, met in coordinate space and checked the way
the outputs are measured.

A generator's own means of meeting a bound (PG-BIG's latent guidance, FlexMotion's control module) can leave it
missed in what the analysis recomputes from the final coordinates (`biomotion.guidance.measured_bounds`). This
stage is the last resort, one lever for every such cap: the vertical excursion of the pelvis. The vertical ground
reaction is Newton's m (g + a_COM,y), and in stance the knee and hip moments grow with it and with how deep the
body sinks, so damping the pelvis height about its mean, pelvis_ty(t) = mean + k (pelvis_ty(t) - mean), lowers the
peak force, the flight, and the moments together; k = 1 is the clip as given, k = 0 a pelvis that neither rises nor
sinks. The feet stay where the clip had them: the stance targets are taken from the clip before damping
(`biomotion.guidance.planting.plant_targets`) and the legs reach them after (`reach_targets`), so the change shows
in the knees and hips and not as feet sinking into or floating above the floor.

k is found by bisection on the measured bounds: the largest k (the least change) at which the analysis finds every
cap of the clip met; where none is met within ``steps`` halvings, the k that misses least (summed over the caps,
k = 1 included). Only caps on magnitudes are taken, the bounds a calmer body can meet: a GRF ``max`` at or above one
body weight or ``min`` at or below it, a moment ``max`` at or above 0 or ``min`` at or below 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from biomotion.guidance.control import Control
from biomotion.guidance.measured_bounds import measured_bounds, measured_excess
from biomotion.guidance.planting import PlantingConfig, plant_targets, reach_targets


@dataclass(frozen=True)
class BoundFitConfig:
    """Bisection halvings on the damping factor k, and the planting settings the legs reach their targets with."""

    steps: int = 6
    planting: PlantingConfig = PlantingConfig()


def magnitude_caps(control: Control) -> list[int]:
    """Indices of the measured bounds (`measured_bounds`) that cap a magnitude (module docstring)."""
    caps = []
    for i in measured_bounds(control):
        t = control.targets[i]
        neutral = 1.0 if t.quantity == "grf_vertical" else 0.0
        if (t.kind == "max" and t.value >= neutral) or (t.kind == "min" and t.value <= neutral):
            caps.append(i)
    return caps


def damped(q: torch.Tensor, k: float, column: int) -> torch.Tensor:
    """q [T, n] with coordinate ``column`` (pelvis_ty) moved towards its mean by 1 - k of its excursion."""
    out = q.clone()
    mean = q[:, column].mean()
    out[:, column] = mean + k * (q[:, column] - mean)
    return out


def fit_bounds(
    body,
    q: torch.Tensor,
    control: Control,
    rate: float,
    bodies: torch.Tensor,
    offsets: torch.Tensor,
    feet: tuple[str, ...],
    lower: torch.Tensor,
    upper: torch.Tensor,
    frames: int | None = None,
    config: BoundFitConfig = BoundFitConfig(),
) -> tuple[torch.Tensor, list[float]]:
    """Clips q [B, T, n] (canonical coordinates, on the floor, at ``rate`` Hz) with the magnitude caps of
    ``control`` met where pelvis damping can meet them (module docstring), and the damping factor k of each clip
    (1: unchanged). ``bodies``/``offsets``/``feet``: the foot contact points; ``lower``/``upper``: coordinate
    ranges; ``frames``: the clip's length (the rest of T is left as it is)."""
    from biomotion.body.kinematics import forward_kinematics, points_in_ground

    caps = magnitude_caps(control)
    frames = q.shape[1] if frames is None else min(frames, q.shape[1])
    factors = [1.0] * q.shape[0]
    if not caps:
        return q, factors
    column = list(body.coordinate_names).index("pelvis_ty")
    out = q.clone()
    for b in range(q.shape[0]):
        clip = q[b, :frames]
        excess = measured_excess(body, clip[None], rate, control, caps)[0]
        if (excess <= 0).all():
            continue
        with torch.no_grad():
            points = points_in_ground(forward_kinematics(body, clip), bodies, offsets)
        target, weight = plant_targets(points[None].double().numpy(), feet, config.planting)

        def candidate(k: float, clip: torch.Tensor = clip, target=target, weight=weight) -> torch.Tensor:
            moved = damped(clip, k, column)[None]
            return reach_targets(body, moved, bodies, offsets, target, weight, lower, upper, config.planting)[0]

        least = (float(np.clip(excess, 0, None).sum()), 1.0, clip)
        met = None
        low, high = 0.0, 1.0
        for _ in range(config.steps):
            k = 0.5 * (low + high)
            trial = candidate(k)
            miss = float(np.clip(measured_excess(body, trial[None], rate, control, caps)[0], 0, None).sum())
            if miss == 0:
                met, low = (k, trial), k
            else:
                high = k
                if miss < least[0]:
                    least = (miss, k, trial)
        k, chosen = met if met is not None else least[1:]
        out[b, :frames] = chosen
        factors[b] = k
    return out, factors
