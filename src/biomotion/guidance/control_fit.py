"""The last stage of controlled generation: the guided clip's coordinates moved, smoothly and as little as
needed, until the control targets are met.

PG-BIG's guidance (Sec. 3.3) refines the sampled *latents*; a latent can only reach the motions the decoder makes,
so a target that asks for a phase or a place the sample does not already come near (a running foot at a given
spot at a given time) is approached but not reached. OmniControl (Xie et al. 2024, Sec. 3.3) meets spatial
targets by also correcting the motion itself after each denoising step ("spatial guidance"); here, with a
generator that is not a diffusion model, the correction is one stage after guidance and foot planting
(`biomotion.guidance.planting`), on the coordinates:

    minimise over d:  control(q0 + d) + w_proximity * mean(d^2) + w_smooth * mean((d'')^2)
                      + w_feet * mean over planted foot points |p(q0 + d) - p(q0)|^2

with ``control`` the spec's own weighted loss over its targets of kind ``path`` and ``value``
(`biomotion.guidance.control.Control.loss`: body paths and positions, angles, COM height or vertical GRF at given
times): the targets that ask for a place or a value at a time. Muscle activation targets, of any kind, are left out
(``UNFITTED_QUANTITIES``): this stage has no muscle surrogate, and moving the coordinates for an activation the
guidance estimated would not be checked by anything after it; they are met by the latent guidance alone. Bounds
(``max``, ``min``) are left to the latent guidance, which meets them from inside the decoder's motions; pushed
further here, a bound on the guidance's own estimate (Newton's vertical force from the unfiltered COM, inverse
dynamics of unfiltered coordinates) is not the bound the analysis measures after its 6 Hz filter, and the correction
can make that one worse. d is a correction of every coordinate, represented by its values at knots about every
``knot_frames`` frames (the first and last frames among them) and interpolated between them by cubic convolution:
continuous in velocity, so a correction adds neither jitter nor acceleration spikes; only the coordinates that can
move what a target names are corrected (`free_coordinates`: a hand path leaves the legs alone). Rotations are kept
inside their ranges, the foot points that planting put on the floor are held where they are (the last term), and the
COM is recomputed from the corrected coordinates. Adam on the knot values for ``iterations`` steps; without a path or
value target the clip is returned as it is.

Contract: q [B, T, n] canonical coordinates on the floor at ``rate`` Hz in, the same shape out; the input is not
changed; coupled coordinates (the knee ``_beta``) are recomputed from their independent ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from biomotion.body.kinematics import apply_couplers, center_of_mass, forward_kinematics, points_in_ground
from biomotion.guidance.control import Control

FITTED_KINDS = ("path", "value")
"""The kinds of target this stage corrects the coordinates for (module docstring)."""
UNFITTED_QUANTITIES = ("muscle_activation",)
"""Quantities this stage leaves alone whatever their kind: it computes no activations (module docstring)."""


@dataclass(frozen=True)
class ControlFitConfig:
    """Settings of the stage (module docstring): Adam ``iterations`` at learning rate ``lr`` (rad or m per step),
    knots every ``knot_frames`` frames, and the weights of the proximity, smoothness and planted-feet terms (rad^2,
    (rad/frame^2)^2 and m^2 in their means)."""

    iterations: int = 60
    lr: float = 0.01
    knot_frames: int = 3
    w_proximity: float = 10.0
    w_smooth: float = 100.0
    w_feet: float = 1000.0
    contact_height: float = 0.02  # m: a foot point this low after planting is held (planting puts stance on y = 0)


def free_coordinates(body, control: Control) -> torch.Tensor:
    """[n] bool: the coordinates the stage may change, those that can move what the targets name: a body's
    position, the coordinates of the joints between it and the ground; a joint angle, that coordinate; the COM and
    the vertical GRF, every coordinate. A hand path leaves the legs as they were."""
    free = torch.zeros(len(body.coordinate_names), dtype=torch.bool)
    joint_of_child = {joint.child: joint for joint in body.joints}
    for target in control.targets:
        if target.quantity == "joint_position":
            b = body.body_index(target.body)
            while b >= 0 and b in joint_of_child:
                joint = joint_of_child[b]
                free[list(joint.coordinates)] = True
                b = joint.parent
        elif target.quantity == "joint_angle":
            free[body.coordinate_names.index(target.coordinate)] = True
        else:
            free[:] = True
    return free


def fit_control(
    body,
    q: torch.Tensor,
    control: Control,
    rate: float,
    feet_bodies: torch.Tensor,
    feet_offsets: torch.Tensor,
    lower: torch.Tensor,
    upper: torch.Tensor,
    rotational: torch.Tensor,
    frames: int | None = None,
    config: ControlFitConfig = ControlFitConfig(),
) -> torch.Tensor:
    """Coordinates q [B, T, n] corrected to meet ``control`` (module docstring); ``feet_bodies``/``feet_offsets``
    the foot contact points (`biomotion.body.contact.foot_points`), ``lower``/``upper`` [n] the coordinate ranges
    applied to the ``rotational`` [n] ones, ``frames`` the clip's length (T when None)."""
    q0 = q.detach()
    fitted = tuple(t for t in control.targets if t.kind in FITTED_KINDS and t.quantity not in UNFITTED_QUANTITIES)
    control = Control(fitted, control.source)
    if not control.targets:
        return q0
    free = free_coordinates(body, control).to(q0.dtype)  # [n]
    count, length, n = q0.shape
    dtype = q0.dtype
    with torch.no_grad():
        feet0 = points_in_ground(forward_kinematics(body, q0.reshape(-1, n)), feet_bodies, feet_offsets)
        feet0 = feet0.view(count, length, -1, 3)
        planted = (feet0[..., 1] < config.contact_height).to(dtype)  # [B, T, K]
    knot_count = max(2, -(-(length - 1) // config.knot_frames) + 1)  # evenly spread, the first and last frames
    knots = torch.zeros(count, n, knot_count, dtype=dtype, requires_grad=True)
    optimiser = torch.optim.Adam([knots], lr=config.lr)
    held = planted.sum().clamp(min=1.0)

    def corrected() -> torch.Tensor:
        d = torch.nn.functional.interpolate(knots[:, :, None], size=(1, length), mode="bicubic", align_corners=True)
        x = q0 + d[:, :, 0].transpose(1, 2) * free
        return torch.where(rotational, torch.minimum(torch.maximum(x, lower), upper), x)

    for _ in range(config.iterations):
        optimiser.zero_grad()
        x = corrected()
        flat = x.reshape(-1, n)
        poses = forward_kinematics(body, flat)
        com = center_of_mass(body, flat, poses).view(count, length, 3)
        feet = points_in_ground(poses, feet_bodies, feet_offsets).view(count, length, -1, 3)
        d = x - q0
        loss = (
            control.loss(x, com, rate, frames, body).sum()
            + config.w_proximity * d.pow(2).mean()
            + config.w_smooth * (d[:, 2:] - 2 * d[:, 1:-1] + d[:, :-2]).pow(2).mean()
            + config.w_feet * ((feet - feet0).pow(2).sum(-1) * planted).sum() / held
        )
        loss.backward()
        optimiser.step()
    with torch.no_grad():
        return apply_couplers(body, corrected().reshape(-1, n)).view_as(q0)
