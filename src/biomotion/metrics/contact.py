"""Foot-ground contact metrics: penetration, floating, foot contact velocity, skate ratio, PhysPT's FS and GP.

Inputs are contact points ``points`` [..., T, K, 3] in metres in the y-up ground frame (ground plane y = 0), e.g.
heel/toe/metatarsal points of both feet; ``rate`` in Hz; optional ``valid`` [..., T]. Points should lie on the
sole: joint centres (ankle, toe joint) sit several cm above the floor and must be lowered by their height above
the sole first (see docs/metrics.md).

Ground. The main definition is the **absolute ground y = 0** (PG-BIG Sec. 4.2, PhysPT Sec. 4, HUMOS Sec. 3.3).
``ground="clip_median"`` gives the variant of PG-BIG's public evaluator: the ground of a clip is the median over
its frames of the per-frame lowest point (pg-big-reference-notes.md, "Evaluation in code"), so any clip gets some
penetration and some floating around its own median.

Contact detection (`contact_mask`): a point is in contact at frame t when its height above the ground is below
``height`` (default 0.05 m, the foot-height threshold of GMD/OmniControl's skate ratio), and, if ``speed`` is given,
its horizontal speed is below it (PhysPT Supp. F quotes 3 cm and 1 m/s as the usual heuristic). The sliding metrics
use the height test only, since a speed test would hide the sliding they measure. A contact model's forces can be
used instead through `contact_from_force` (vertical force above 20 N, the usual force-plate stance threshold).
"""

from __future__ import annotations

import torch

from biomotion.errors import DataFormatError
from biomotion.metrics.base import Metric, Tensor, as_mask, as_tensor, difference, frame_mask, masked_mean, pair_mask

GROUND_MODES = ("absolute", "clip_median")
CONTACT_HEIGHT = 0.05
"""m: contact height threshold (GMD / OmniControl skate ratio ``thresh_height``)."""
SKATE_SPEED = 0.5
"""m/s: horizontal speed above which a foot in contact skates (GMD / OmniControl ``thresh_vel``; 2.5 cm/frame at
20 fps)."""
SKATE_WINDOW = 0.25
"""s: centred window of the speed average in the skate test (5 frames at 20 fps in GMD / OmniControl)."""
STANCE_SPEED = 0.5
"""m/s: a point slower than this horizontally is planted (stance) for the floating metric."""
FORCE_THRESHOLD = 20.0
"""N: vertical force above which a contact point is loaded (usual force-plate stance threshold)."""


def _points(points) -> Tensor:
    return as_tensor(points, "points", min_dims=3, last=3)


def ground_height(points, valid=None, ground: str = "absolute") -> Tensor:
    """Ground height [...] of each sequence: 0 (``"absolute"``) or the median over valid frames of the per-frame
    lowest point (``"clip_median"``, PG-BIG public evaluator)."""
    points = _points(points)
    if ground not in GROUND_MODES:
        raise DataFormatError(None, f"ground must be one of {GROUND_MODES}, got {ground!r}", field="ground")
    if ground == "absolute":
        return points.new_zeros(points.shape[:-3])
    valid = frame_mask(valid, points.shape[:-2], points.device)
    lowest = points[..., 1].amin(-1)
    return torch.nanquantile(torch.where(valid, lowest, torch.full_like(lowest, float("nan"))), 0.5, dim=-1)


def heights(points, valid=None, ground: str = "absolute") -> Tensor:
    """[..., T, K] height of every point above the ground of its sequence."""
    points = _points(points)
    return points[..., 1] - ground_height(points, valid, ground)[..., None, None]


def horizontal_speed(points, rate: float) -> Tensor:
    """[..., T - 1, K] horizontal speed (m/s) between frames t and t + 1 (pair it with ``pair_mask(valid)``)."""
    points = _points(points)
    return torch.linalg.vector_norm(difference(points[..., [0, 2]], rate, dim=-3), dim=-1)


def contact_mask(
    points,
    rate: float | None = None,
    *,
    height: float | Tensor = CONTACT_HEIGHT,
    speed: float | None = None,
    valid=None,
    ground: str = "absolute",
) -> Tensor:
    """[..., T, K] True where a point is in contact: height below ``height`` (m; a float or one per point [K]) and,
    if ``speed`` (m/s) is given, horizontal speed (mean of the adjacent frame differences) below ``speed``."""
    points = _points(points)
    valid = frame_mask(valid, points.shape[:-2], points.device)
    height = torch.as_tensor(height, dtype=points.dtype, device=points.device)
    contact = (heights(points, valid, ground) < height) & valid[..., None]
    if speed is None:
        return contact
    if rate is None:
        raise DataFormatError(None, "a speed threshold needs the rate", field="rate")
    pair_speed = horizontal_speed(points, rate)
    pairs = pair_mask(valid)[..., None].expand_as(pair_speed)
    zero = pair_speed.new_zeros(pair_speed.shape[:-2] + (1,) + pair_speed.shape[-1:])
    speed_sum = torch.cat([zero, torch.where(pairs, pair_speed, 0.0)], -2) + torch.cat(
        [torch.where(pairs, pair_speed, 0.0), zero], -2
    )
    count = torch.cat([zero, pairs.to(points.dtype)], -2) + torch.cat([pairs.to(points.dtype), zero], -2)
    return contact & (count > 0) & (speed_sum < speed * count)


def contact_from_force(forces, threshold: float = FORCE_THRESHOLD, *, vectors: bool = False) -> Tensor:
    """[..., T, K] True where a contact point carries a vertical force above ``threshold`` (N).

    ``forces`` is [..., T, K] vertical forces, or with ``vectors=True`` [..., T, K, 3] force vectors whose y
    component is used; e.g. the spring-damper forces of a contact model (PhysPT Sec. 3.2.3).
    """
    forces = as_tensor(forces, "forces", min_dims=3 if vectors else 2, last=3 if vectors else None)
    return (forces[..., 1] if vectors else forces) > threshold


def _contact(points: Tensor, contact, valid: Tensor, ground: str, height) -> Tensor:
    if contact is None:
        return contact_mask(points, height=height, valid=valid, ground=ground)
    return as_mask(contact, points.shape[:-1], "contact", points.device) & valid[..., None]


def penetration(points, valid=None, *, ground: str = "absolute") -> Tensor:
    """PG-BIG Sec. 4.2 "Floor Penetration": mean over valid frames of ``max(0, -z_t)``, z_t the height of the lowest
    point at frame t above the ground (m). With ``ground="clip_median"`` it is the public evaluator's variant."""
    points = _points(points)
    valid = frame_mask(valid, points.shape[:-2], points.device)
    lowest = heights(points, valid, ground).amin(-1)
    return masked_mean(torch.relu(-lowest), valid, -1)


def floating(
    points,
    rate: float,
    valid=None,
    *,
    ground: str = "absolute",
    tolerance: float = 0.0,
    stance_speed: float | None = STANCE_SPEED,
) -> Tensor:
    """PG-BIG Sec. 4.2 "Floor Floating": ``max(0, z_t - eps)`` averaged over stance frames (m).

    Stance is decided without heights, so that a hovering planted foot counts: z_t is the height of the lowest
    point whose horizontal speed is below ``stance_speed`` (m/s), and frames without such a point (swing of both
    feet, flight) are left out. ``stance_speed=None`` uses the lowest point of every frame: with
    ``ground="clip_median"`` and ``tolerance=0`` that is PG-BIG's public evaluator ("no contact mask").
    """
    points = _points(points)
    valid = frame_mask(valid, points.shape[:-2], points.device)
    height = heights(points, valid, ground)
    if stance_speed is None:
        lowest, keep = height.amin(-1), valid
    else:
        planted = contact_mask(points, rate, height=float("inf"), speed=stance_speed, valid=valid, ground=ground)
        lowest = torch.where(planted, height, torch.full_like(height, float("inf"))).amin(-1)
        keep = planted.any(-1)
        lowest = torch.where(keep, lowest, torch.zeros_like(lowest))
    return masked_mean(torch.relu(lowest - tolerance), keep, -1)


def foot_contact_velocity(
    points, rate: float, valid=None, *, contact=None, ground: str = "absolute", height: float | Tensor = CONTACT_HEIGHT
) -> Tensor:
    """PG-BIG Sec. 4.2 "Foot Contact Velocity": mean horizontal speed ``||p_dot_xz||`` (m/s) of the points in
    contact at both frames t and t + 1. NaN for a sequence without contact."""
    points = _points(points)
    valid = frame_mask(valid, points.shape[:-2], points.device)
    contact = _contact(points, contact, valid, ground, height)
    both = contact[..., :-1, :] & contact[..., 1:, :]
    return masked_mean(horizontal_speed(points, rate), both, (-2, -1))


def foot_sliding(
    points, valid=None, *, contact=None, ground: str = "absolute", height: float | Tensor = CONTACT_HEIGHT
) -> Tensor:
    """PhysPT Sec. 4 "FS": mean displacement ``||p_{t+1} - p_t||`` (m per frame, 3-D) of the points in contact at
    frames t and t + 1. Per frame, as in the paper, so it scales with 1/rate. NaN without contact."""
    points = _points(points)
    valid = frame_mask(valid, points.shape[:-2], points.device)
    contact = _contact(points, contact, valid, ground, height)
    both = contact[..., :-1, :] & contact[..., 1:, :]
    step = torch.linalg.vector_norm(torch.diff(points, dim=-3), dim=-1)
    return masked_mean(step, both, (-2, -1))


def ground_penetration(points, valid=None, *, ground: str = "absolute") -> Tensor:
    """PhysPT Sec. 4 "GP": mean depth ``-z`` (m) of the points below the ground, over those points only (0 when no
    point is below; NaN for a sequence without valid frames)."""
    points = _points(points)
    valid = frame_mask(valid, points.shape[:-2], points.device)
    height = heights(points, valid, ground)
    below = (height < 0) & valid[..., None]
    depth = torch.nan_to_num(masked_mean(-height, below, (-2, -1)), nan=0.0)
    return torch.where(valid.any(-1), depth, torch.full_like(depth, float("nan")))


def skate_ratio(
    points,
    rate: float,
    valid=None,
    *,
    height: float | Tensor = CONTACT_HEIGHT,
    speed: float = SKATE_SPEED,
    window: float = SKATE_WINDOW,
    ground: str = "absolute",
) -> Tensor:
    """Share of frame pairs in which a foot skates (GMD / OmniControl skating ratio; HUMOS "skate").

    A point skates between frames t and t + 1 when it is below ``height`` at both frames, and both its horizontal
    speed and the mean of that speed over a centred window of ``window`` seconds exceed ``speed`` (m/s). A pair
    counts once if any point skates (the reference code: either foot). Denominator: all valid frame pairs. The
    window holds 2 round(window rate / 2) + 1 pairs (5 at 20 fps, as in the reference code) and averages valid
    pairs only (the reference code zero-pads at the clip ends).
    """
    points = _points(points)
    valid = frame_mask(valid, points.shape[:-2], points.device)
    h = torch.as_tensor(height, dtype=points.dtype, device=points.device)
    low = (heights(points, valid, ground) < h) & valid[..., None]
    both = low[..., :-1, :] & low[..., 1:, :]
    pairs = pair_mask(valid)
    pair_speed = horizontal_speed(points, rate)
    half = max(0, round(window * rate / 2))
    averaged = _window_mean(pair_speed, pairs[..., None].expand_as(pair_speed), half)
    skating = (both & (pair_speed > speed) & (averaged > speed)).any(-1)
    return masked_mean(skating.to(points.dtype), pairs, -1)


def _window_mean(x: Tensor, mask: Tensor, half: int) -> Tensor:
    """Mean of ``x`` [..., N, K] over the centred window [n - half, n + half] along -2, valid entries only."""
    if half == 0:
        return x
    weights = mask.to(x.dtype)
    cum_x = torch.nn.functional.pad(torch.cumsum(torch.where(mask, x, 0.0), -2), (0, 0, 1, 0))
    cum_w = torch.nn.functional.pad(torch.cumsum(weights, -2), (0, 0, 1, 0))
    n = x.shape[-2]
    index = torch.arange(n, device=x.device)
    hi = (index + half + 1).clamp(max=n)
    lo = (index - half).clamp(min=0)
    total = cum_x.index_select(-2, hi) - cum_x.index_select(-2, lo)
    count = cum_w.index_select(-2, hi) - cum_w.index_select(-2, lo)
    return total / count.clamp(min=1.0)


def lowest_point_sliding(points, valid=None) -> Tensor:
    """PG-BIG public evaluator's "sliding": mean 3-D displacement between consecutive frames of the per-frame lowest
    point (m per frame; no contact mask, not divided by time, so it depends on the rate)."""
    points = _points(points)
    valid = frame_mask(valid, points.shape[:-2], points.device)
    index = points[..., 1].argmin(-1)
    lowest = torch.gather(points, -2, index[..., None, None].expand(*index.shape, 1, 3)).squeeze(-2)
    step = torch.linalg.vector_norm(torch.diff(lowest, dim=-2), dim=-1)
    return masked_mean(step, pair_mask(valid), -1)


def _ground_variant(metric: Metric, ground: str) -> None:
    """Name and label of the ``ground`` variant: the clip-median ground (PG-BIG's public evaluator) appends
    ``_median`` to the name and "(clip median)" to the label, and cites the evaluator."""
    if ground not in GROUND_MODES:
        raise DataFormatError(None, f"ground must be one of {GROUND_MODES}, got {ground!r}", field="ground")
    if ground == "clip_median":
        metric.name, metric.label = f"{metric.name}_median", f"{metric.label} (clip median)"
        metric.paper = f"{metric.paper}; clip-median ground: PG-BIG public evaluator (pg-big-reference-notes.md)"


class Penetration(Metric):
    """`penetration` per sequence (m). PG-BIG Sec. 4.2 / Table 2 "Penetration" (printed in cm)."""

    name, label, unit, display_unit, display_scale = "penetration", "Penetration", "m", "cm", 100.0
    higher_is_better = False
    paper = 'PG-BIG Sec. 4.2 "Floor Penetration", Table 2'
    equation = "mean_t max(0, -z_t), z_t the height of the lowest point at frame t"

    def __init__(self, ground: str = "absolute") -> None:
        super().__init__()
        self.ground = ground
        _ground_variant(self, ground)

    def score(self, points, valid=None) -> Tensor:
        return penetration(points, valid, ground=self.ground)


class Floating(Metric):
    """`floating` per sequence (m). PG-BIG Sec. 4.2 / Table 2 "Floating" (printed in cm)."""

    name, label, unit, display_unit, display_scale = "floating", "Floating", "m", "cm", 100.0
    higher_is_better = False
    paper = 'PG-BIG Sec. 4.2 "Floor Floating", Table 2'
    equation = (
        "mean over stance frames of max(0, z_t - eps), z_t the height of the lowest planted point "
        "(horizontal speed below stance_speed)"
    )

    def __init__(
        self, ground: str = "absolute", tolerance: float = 0.0, stance_speed: float | None = STANCE_SPEED
    ) -> None:
        super().__init__()
        self.ground, self.tolerance, self.stance_speed = ground, tolerance, stance_speed
        _ground_variant(self, ground)

    def score(self, points, rate: float, valid=None) -> Tensor:
        return floating(
            points, rate, valid, ground=self.ground, tolerance=self.tolerance, stance_speed=self.stance_speed
        )


class FootContactVelocity(Metric):
    """`foot_contact_velocity` per sequence (m/s). PG-BIG Sec. 4.2 "Foot Contact Velocity"."""

    name, label, unit = "foot_contact_velocity", "Foot contact vel.", "m/s"
    higher_is_better = False
    paper = 'PG-BIG Sec. 4.2 "Foot Contact Velocity"'
    equation = "mean ||p_dot_xz|| over the points in contact at frames t and t + 1"

    def __init__(self, height: float | Tensor = CONTACT_HEIGHT, ground: str = "absolute") -> None:
        super().__init__()
        self.height, self.ground = height, ground
        _ground_variant(self, ground)

    def score(self, points, rate: float, valid=None, contact=None) -> Tensor:
        return foot_contact_velocity(points, rate, valid, contact=contact, ground=self.ground, height=self.height)


class FootSliding(Metric):
    """`foot_sliding` per sequence (m/frame). PhysPT Sec. 4 / Table 1 "FS" (printed in mm)."""

    name, label, unit, display_unit, display_scale = "foot_sliding", "FS", "m/frame", "mm/frame", 1000.0
    higher_is_better = False
    paper = 'PhysPT Sec. 4 "FS", Table 1'
    equation = "mean ||p_{t+1} - p_t|| over the points in contact at frames t and t + 1"

    def __init__(self, height: float | Tensor = CONTACT_HEIGHT, ground: str = "absolute") -> None:
        super().__init__()
        self.height, self.ground = height, ground
        _ground_variant(self, ground)

    def score(self, points, valid=None, contact=None) -> Tensor:
        return foot_sliding(points, valid, contact=contact, ground=self.ground, height=self.height)


class GroundPenetration(Metric):
    """`ground_penetration` per sequence (m). PhysPT Sec. 4 / Table 1 "GP" (printed in mm)."""

    name, label, unit, display_unit, display_scale = "ground_penetration", "GP", "m", "mm", 1000.0
    higher_is_better = False
    paper = 'PhysPT Sec. 4 "GP", Table 1'
    equation = "mean depth -z of the points below the ground, over those points only (0 when none)"

    def __init__(self, ground: str = "absolute") -> None:
        super().__init__()
        self.ground = ground
        _ground_variant(self, ground)

    def score(self, points, valid=None) -> Tensor:
        return ground_penetration(points, valid, ground=self.ground)


class SkateRatio(Metric):
    """`skate_ratio` per sequence (share of frame pairs). GMD / OmniControl skating ratio, HUMOS "skate"."""

    name, label, unit, display_unit, display_scale = "skate_ratio", "Skate", "1", "%", 100.0
    higher_is_better = False
    paper = 'GMD / OmniControl skating ratio (thresh_height 0.05 m, thresh_vel 0.5 m/s); HUMOS "skate"'
    equation = (
        "share of frame pairs in which a point below height at both frames moves horizontally faster than "
        "speed, also on average over a centred window"
    )

    def __init__(
        self,
        height: float | Tensor = CONTACT_HEIGHT,
        speed: float = SKATE_SPEED,
        window: float = SKATE_WINDOW,
        ground: str = "absolute",
    ) -> None:
        super().__init__()
        self.height, self.speed, self.window, self.ground = height, speed, window, ground
        _ground_variant(self, ground)

    def score(self, points, rate: float, valid=None) -> Tensor:
        return skate_ratio(
            points, rate, valid, height=self.height, speed=self.speed, window=self.window, ground=self.ground
        )


class LowestPointSliding(Metric):
    """`lowest_point_sliding` per sequence (m/frame): PG-BIG public evaluator's "Sliding"."""

    name, label, unit, display_unit, display_scale = (
        "lowest_point_sliding",
        "Sliding (lowest point)",
        "m/frame",
        "cm/frame",
        100.0,
    )
    higher_is_better = False
    paper = 'PG-BIG public evaluator "sliding" (pg-big-reference-notes.md), PG-BIG Table 2 "Sliding"'
    equation = "mean_t ||p_{t+1} - p_t||, p_t the lowest point at frame t (no contact mask, per frame)"

    def score(self, points, valid=None) -> Tensor:
        return lowest_point_sliding(points, valid)
