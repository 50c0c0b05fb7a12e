"""Foot contact of canonical clips: the stance mask, the tokenizer's four contact channels, floor penetration.

PG-BIG's tokenizer carries foot-contact channels and is trained with a penetration term (Sec. 3.1, Table 4), and its
foot guidance term L_foot uses a binary contact mask m_t (Table 1) that the paper does not define. Here:

- `stance_mask` says which foot points of a clip are in stance (low and slow: the rule guidance uses;
  docs/decisions/stance-mask.md has the evidence that chose it);
- `FootKinematics.labels` reduces it to four channels, heel and forefoot of each foot (HumanML3D's layout: Guo
  et al. 2022 store heel and toe contact of both feet), the targets of the tokenizer's contact channels, and
  `points_in_contact` takes decoded channels back to foot points (guidance's m_t);
- `FootKinematics` places the foot points of canonical coordinates (masked coordinates at the model's defaults,
  as `biomotion.data.placement` does) for the labels and for the penetration term.
"""

from __future__ import annotations

import torch

#: The tokenizer's contact channels and the foot points (`biomotion.body.contact.foot_points` names, without the
#: side) each one covers.
CONTACT_GROUPS = (
    ("heel_r", ("heel_med", "heel_lat")),
    ("forefoot_r", ("met1", "met5", "toe")),
    ("heel_l", ("heel_med", "heel_lat")),
    ("forefoot_l", ("met1", "met5", "toe")),
)
N_CONTACT = len(CONTACT_GROUPS)


def mean_horizontal_speed(q: torch.Tensor, rate: float) -> torch.Tensor:
    """[B] ||mean horizontal pelvis velocity|| (m/s) of clips q [B, T, 39] (pelvis_tx, pelvis_tz: columns 3, 5)."""
    horizontal = q[..., [3, 5]]
    return ((horizontal[:, -1] - horizontal[:, 0]) * rate / max(q.shape[1] - 1, 1)).norm(dim=-1)


def stance_mask(
    feet: torch.Tensor,
    q: torch.Tensor,
    rate: float,
    height: float = 0.05,
    ratio: float | None = 1.5,
    floor: float = 0.5,
) -> torch.Tensor:
    """[B, T, K] which foot points [B, T, K, 3] of clips q [B, T, 39] are in stance (PG-BIG Table 1's contact
    mask m_t; L_foot "enforces zero velocity during stance phases"): below ``height`` (m) and, unless ``ratio`` is
    None, moving horizontally slower than ``ratio`` times the clip's mean horizontal speed (pelvis displacement
    over the clip, `mean_horizontal_speed`) or slower than ``floor`` (m/s, the metrics' skate speed), whichever
    is faster.

    A stance foot sliding in a sample is slower than the body it carries (the example runner's unguided stance
    feet: about 1.3 m/s against 3.5), so the speed test still catches it; a swing foot is faster than the body,
    and height alone takes the low swing of a slow walk for stance, where the foot and ground terms then stop it
    (the strides of "walk, elderly" shrink: docs/results/walking_styles.md, `python benchmarks/walking_styles.py`).
    Ratio 1.5 was chosen on the generator's dev subjects (training subjects set aside; never evaluation subjects;
    docs/decisions/stance-mask.md)."""
    feet = feet.detach()
    low = feet[..., 1] < height
    if ratio is None:
        return low
    speed = torch.gradient(feet[..., [0, 2]], spacing=1.0 / rate, dim=1)[0].norm(dim=-1)  # [B, T, K]
    limit = torch.clamp(ratio * mean_horizontal_speed(q.detach(), rate), min=floor)  # [B]
    return low & (speed < limit[:, None, None])


def group_members(point_names: tuple[str, ...]) -> torch.Tensor:
    """[N_CONTACT, K] bool: which of the foot points (names like ``heel_med_r``) each contact channel covers."""
    members = torch.zeros(N_CONTACT, len(point_names), dtype=torch.bool)
    for g, (group, points) in enumerate(CONTACT_GROUPS):
        side = group[-1]
        for k, name in enumerate(point_names):
            members[g, k] = name.endswith(f"_{side}") and name[:-2] in points
    return members


def points_in_contact(channels: torch.Tensor, members: torch.Tensor) -> torch.Tensor:
    """[..., K] bool per foot point from channel decisions [..., N_CONTACT] bool and `group_members` [N_CONTACT, K]:
    a point is in contact when its channel is."""
    return (channels[..., :, None] & members).any(-2)


class FootKinematics:
    """Foot points of canonical coordinates on a body model (the canonical Rajagopal 2016 one), differentiable.

    Coordinates a clip lacks (``mask`` False) take the model's defaults, so a source without, say, subtalar
    angles is judged on a neutral subtalar joint rather than on whatever fills the gap."""

    def __init__(self, body) -> None:
        from biomotion.body.contact import foot_points

        self.body = body.to(torch.float32)
        feet = foot_points(self.body)
        self.bodies, self.offsets = feet.bodies, feet.offsets.to(torch.float32)
        self.members = group_members(feet.names)
        self.defaults = self.body.defaults.to(torch.float32)

    def points(self, q: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """[B, T, K, 3] foot points (y up, the clips' floor at y = 0) of coordinates q [B, T, 39], mask [B, 39]."""
        from biomotion.body.kinematics import forward_kinematics, points_in_ground

        if mask is not None:
            q = torch.where(mask[:, None, :], q, self.defaults)
        poses = forward_kinematics(self.body, q.reshape(-1, q.shape[-1]))
        return points_in_ground(poses, self.bodies, self.offsets).view(*q.shape[:2], -1, 3)

    def labels(self, q: torch.Tensor, mask: torch.Tensor, rate: float) -> torch.Tensor:
        """[B, T, N_CONTACT] float 0/1: a channel is in contact when any of its points is in stance (`stance_mask`
        with its defaults) in clips q [B, T, 39] (on the floor, as the dataset cache holds them)."""
        with torch.no_grad():
            q = torch.where(mask[:, None, :], q, self.defaults)
            stance = stance_mask(self.points(q), q, rate)  # [B, T, K]
            return (stance[..., None, :] & self.members).any(-1).to(torch.float32)

    def penetration_cm(self, q: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Mean over frames and foot points of max(0, -height) in cm (PG-BIG Sec. 4.2's penetration, the
        tokenizer's penetration term of Table 4)."""
        return 100.0 * torch.relu(-self.points(q, mask)[..., 1]).mean()
