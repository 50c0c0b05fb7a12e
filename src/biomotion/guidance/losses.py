"""The biomechanical guidance losses of PG-BIG Table 1, plus a ground term and the proximity term.

All take batched kinematics of generated clips at ``rate`` Hz: coordinates q [B, T, 39] (canonical, SI), foot
contact points [B, T, K, 3] and COM [B, T, 3] (m, y up, ground y = 0), activations [B, T, M]. Each returns [B]
(a mean over time, the paper's 1/T sum_t), differentiable in its inputs. Velocities are forward differences.

- `angular_velocity`: L_omega = 1/T sum_t sum_j max(0, |q_dot_tj| - q_dot_j^high) (95th percentile bounds).
- `foot_contact`: L_foot = 1/T sum_t ||v_t^foot (.) m_t||^2 with the binary contact mask m_t.
- `com_velocity`, `com_acceleration`: L_v, L_a = 1/T sum_t max(0, ||c'_t|| - high, low - ||c'_t||) (5-95th).
- `activation`: L_act = 1/T sum_t sum_m max(0, a_tm - a_m^high, a_m^low - a_tm).
- `foot_skim`: not in Table 1; L_foot without the binary mask: every foot point's horizontal speed^2, weighted by
  how near the floor it is (1 at the floor, 0 at the contact height). L_foot holds still the points the stance mask
  calls planted; a foot that skims the floor fast at touch-down or toe-off is in no stance, yet slides along it
  (what foot contact velocity and skate count).
- `ground`: not in Table 1; it carries Table 4's penetration term into guidance: penetration squared for every
  point plus height squared for points in contact, so planted feet neither sink nor hover (the contact metrics).
- `angular_jerk`: not in Table 1; L_omega's form one derivative up, 1/T sum_t sum_j max(0, |d3q_tj/dt3| - high_j)
  with 95th percentile bounds. It turns A.1's "refine motion smoothness" into a term, so guided motion is no
  jerkier than the data (the generation bar: jerk within 2x the reference).
- `locomotion_speed`: not in the paper; (||mean horizontal pelvis velocity|| - target)^2, the requested speed.
  Without it guidance found the cheapest way to stop a sliding stance foot: slowing the whole body down (guided
  runs asked for 3.5 m/s came out at 1.7-2.5 m/s).
- `locomotion_pace`: not in the paper; `locomotion_speed` held in every window of W frames, 1/N sum_n (s_n -
  target)^2 with s_n the horizontal pelvis speed over window n. The clip-mean form is met as well by a clip that
  runs 2.5 m/s for three seconds and 4.5 m/s for three more as by a steady 3.5 m/s, and guidance found such surges:
  the COM's kinetic energy then swings with them (PG-BIG Sec. 4.2's energy consistency).
- `posture`: not in the paper; sum_j (mean_t q_tj - target_j)^2 over the coordinates with a target, the person's
  posture (`biomotion.generation.posture`), so guidance does not pull the clip back to the population's.
- `amplitude`: not in the paper; sum_j (std_t q_tj - target_j)^2, each coordinate's amplitude held at the
  person's, the other half of the person's coordinate statistics with `posture` (the identity term:
  docs/decisions/generation-unseen-people.md).
- `com_energy`: not in Table 1; PG-BIG Sec. 4.2's energy consistency E_var as a guidance term: the std over the
  clip of the COM's mechanical energy per kg, above the population's for the action and speed, squared.
- `zmp_support`: not in PG-BIG; HUMOS Sec. 3.4's dynamic stability as a hinge: the distance (m) by which the
  zero-moment point lies outside the support of the stance points, mean over the frames the ground carries.
- `proximity`: mean squared distance of the latents to the unguided sample's (Sec. 3.3, A.1 schedule).
"""

from __future__ import annotations

import torch

from biomotion.metrics.bounds import bound_excess
from biomotion.metrics.stability import signed_distance_to_hull
from biomotion.models.bundle import com_energy_per_kg
from biomotion.models.foot_contact import mean_horizontal_speed


def _speed(x: torch.Tensor, rate: float) -> torch.Tensor:
    return torch.diff(x, dim=1) * rate


def angular_velocity(q: torch.Tensor, rate: float, high: torch.Tensor) -> torch.Tensor:
    """PG-BIG Table 1, L_omega; ``high`` [39] (inf where unbounded)."""
    return torch.relu(_speed(q, rate).abs() - high).sum(-1).mean(-1)


def angular_jerk(q: torch.Tensor, rate: float, high: torch.Tensor) -> torch.Tensor:
    """Coordinate jerk above its 95th percentile bound ``high`` [39], summed over coordinates, mean over time."""
    jerk = torch.diff(q, 3, dim=1).abs() * rate**3
    return torch.relu(jerk - high).sum(-1).mean(-1)


def foot_contact(feet: torch.Tensor, rate: float, contact: torch.Tensor) -> torch.Tensor:
    """PG-BIG Table 1, L_foot; ``contact`` [B, T, K] bool, applied to the velocity between frames t and t + 1
    when the point is in contact at both."""
    velocity = _speed(feet, rate)
    both = (contact[:, 1:] & contact[:, :-1]).to(feet.dtype)
    return (velocity.pow(2).sum(-1) * both).sum(-1).mean(-1)


def foot_skim(feet: torch.Tensor, rate: float, height: float) -> torch.Tensor:
    """Horizontal speed^2 of every foot point between frames t and t + 1, weighted by how near the floor it stays
    (1 - max(y_t, y_t+1) / ``height``, 0 above ``height``), summed over points, mean over time."""
    velocity = _speed(feet[..., [0, 2]], rate)
    y = feet[..., 1]
    near = torch.relu(1.0 - torch.maximum(y[:, 1:], y[:, :-1]) / height)
    return (velocity.pow(2).sum(-1) * near).sum(-1).mean(-1)


def com_velocity(com: torch.Tensor, rate: float, low: float, high: float) -> torch.Tensor:
    """PG-BIG Table 1, L_v."""
    return bound_excess(_speed(com, rate).norm(dim=-1), torch.tensor(low), torch.tensor(high)).mean(-1)


def com_acceleration(com: torch.Tensor, rate: float, low: float, high: float) -> torch.Tensor:
    """PG-BIG Table 1, L_a."""
    return bound_excess(_speed(_speed(com, rate), rate).norm(dim=-1), torch.tensor(low), torch.tensor(high)).mean(-1)


def activation(activations: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """PG-BIG Table 1, L_act; ``low``/``high`` [M]."""
    return bound_excess(activations, low, high).sum(-1).mean(-1)


def ground(feet: torch.Tensor, contact: torch.Tensor) -> torch.Tensor:
    """Penetration^2 of every point plus height^2 of points in contact, summed over points, mean over time."""
    height = feet[..., 1]
    return (torch.relu(-height).pow(2) + contact.to(height.dtype) * height.pow(2)).sum(-1).mean(-1)


def locomotion_speed(q: torch.Tensor, rate: float, target: torch.Tensor) -> torch.Tensor:
    """(||mean horizontal pelvis velocity|| - target [B])^2 per clip."""
    return (mean_horizontal_speed(q, rate) - target).pow(2)


def window_speeds(q: torch.Tensor, rate: float, window: int) -> torch.Tensor:
    """[B, N] horizontal pelvis speed (m/s) over every window of ``window`` frames of clips q [B, T, 39] (start
    frames 0 .. T - window; the whole clip when it is shorter)."""
    horizontal = q[..., [3, 5]]
    window = min(window, q.shape[1] - 1)
    if window < 1:
        return torch.zeros(q.shape[0], 1, dtype=q.dtype)
    return (horizontal[:, window:] - horizontal[:, :-window]).norm(dim=-1) * rate / window


def locomotion_pace(q: torch.Tensor, rate: float, target: torch.Tensor, window: int) -> torch.Tensor:
    """1/N sum_n (s_n - target)^2 per clip: `window_speeds` against the target speed [B] (m/s)."""
    return (window_speeds(q, rate, window) - target[:, None]).pow(2).mean(-1)


def posture(q: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """sum_j (mean_t q_tj - target_j)^2 over the coordinates whose target [39] is finite."""
    known = torch.isfinite(target)
    return ((q[..., known].mean(1) - target[known]) ** 2).sum(-1)


def amplitude(q: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """sum_j (std_t q_tj - target_j)^2 over the coordinates whose target [39] is finite: each coordinate's amplitude
    (standard deviation over the clip) held at the person's (`biomotion.generation.posture.amplitude_ratio`)."""
    known = torch.isfinite(target)
    return ((q[..., known].std(1, correction=0) - target[known]) ** 2).sum(-1)


def com_energy(com: torch.Tensor, rate: float, high: float) -> torch.Tensor:
    """max(0, std_t e_t - high)^2 per clip, e_t the COM's mechanical energy per kg (J/kg,
    `biomotion.models.bundle.com_energy_per_kg`) of ``com`` [B, T, 3]: PG-BIG Sec. 4.2's energy consistency as a
    one-sided bound, ``high`` the population's fluctuation for the action and speed (`GeneratorBundle.energy`)."""
    return torch.relu(com_energy_per_kg(com, rate).std(-1, correction=0) - high).pow(2)


def zmp_support(zmp: torch.Tensor, loaded: torch.Tensor, feet: torch.Tensor, contact: torch.Tensor) -> torch.Tensor:
    """Mean over supported frames (``loaded`` [B, T] and some point of ``contact`` [B, T, K]) of how far (m) the ZMP
    [B, T, 3] lies outside the convex hull of the contact points ``feet`` [B, T, K, 3] in the ground plane, 0 inside
    (HUMOS Sec. 3.4: a stable motion keeps its ZMP in the base of support). The hull is held fixed: the term moves
    the ZMP, the foot terms place the feet."""
    active = contact & loaded[..., None]
    signed = signed_distance_to_hull(feet[..., [0, 2]].detach(), active, zmp[..., [0, 2]])
    supported = torch.isfinite(signed)
    outside = torch.relu(-torch.where(supported, signed, torch.zeros_like(signed)))
    return outside.sum(-1) / supported.sum(-1).clamp_min(1)


def proximity(z: torch.Tensor, z0: torch.Tensor) -> torch.Tensor:
    """Mean squared latent distance to the unguided sample, per clip."""
    return (z - z0).pow(2).mean((-2, -1))
