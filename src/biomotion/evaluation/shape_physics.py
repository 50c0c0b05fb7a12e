"""HUMOS's physics metrics (penetrate, float, skate) and dynamic stability of a gait clip on a body model: what
`biomotion.evaluation.shape` scores for a motion adapted onto body B, for the copy baseline and for B's own motion.

HUMOS (``humos.md``, "Why This Works", Mechanisms 2 and 3; its Sec. 3.3-3.4) judges a motion moved onto another
body by intuitive physics (ground penetration, floating, foot skating) and by dynamic stability: the share of frames
whose zero-moment point (ZMP) lies inside the base of support, the convex hull of the contact points that are both
low and slow; frames in flight have no base of support and are **not counted stable** (they stay in the
denominator), unlike `biomotion.metrics.stability.share_inside_support`, which leaves them out.

A clip is prepared the way every evaluated clip of this project is (`clip_physics`):

1. its coordinates are put in the model's order (`biomotion.analysis.chain.model_motion`: couplers applied);
2. placed (`biomotion.data.placement.place_clip`, no size normalisation): a treadmill clip is made overground by
   adding the belt speed times time along +x, so a planted foot rests instead of moving with the belt, and the
   clip is put on the floor (5th percentile over frames of its lowest foot contact point at y = 0). Penetrate and
   float therefore measure how consistently the feet meet one floor, not the height offset a pelvis translation
   carried over from another body would leave;
3. resampled to `RATE` (low-pass first) with quintic-spline derivatives, the foot contact points of the model
   (`biomotion.body.contact.foot_points`, five per foot) by forward kinematics
   (`biomotion.data.clips.coordinate_set`, as ``biomotion eval`` does);
4. scored with the project's metric objects on the absolute ground y = 0: `Penetration` ("penetrate"),
   `Floating` ("float", stance frames by speed), `SkateRatio` ("skate"); and `dynamic_stability` with the body
   model's whole-body ZMP (`biomotion.body.balance.zero_moment_point`, NaN where the kinematics ask the ground for
   less than `biomotion.body.balance.MIN_VERTICAL_LOAD_BW` body weights: flight).

Contact for the base of support: height below `biomotion.metrics.contact.CONTACT_HEIGHT` (0.05 m) and horizontal
speed below `biomotion.metrics.contact.STANCE_SPEED` (0.5 m/s), the project's thresholds for a low and a planted
point (`biomotion.metrics.contact.contact_mask`).
"""

from __future__ import annotations

import torch

from biomotion.analysis.chain import model_motion
from biomotion.body.balance import zero_moment_point
from biomotion.body.kinematics import torch_threads
from biomotion.body.model import BodyModel
from biomotion.data.clips import CoordinateClip, coordinate_set
from biomotion.data.placement import place_clip
from biomotion.metrics.base import Tensor, as_tensor, frame_mask, masked_mean
from biomotion.metrics.contact import CONTACT_HEIGHT, STANCE_SPEED, Floating, Penetration, SkateRatio, contact_mask
from biomotion.metrics.stability import support_margin
from biomotion.motion import Motion

RATE = 30.0  # Hz: the rate of every evaluated clip (`biomotion.body.canonical.DEFAULT_RATE`)
PHYSICS = ("penetrate", "float", "skate")
"""HUMOS's intuitive-physics metrics, in report order (lower is better)."""
STABILITY = "dyn_stability"
"""Key of the dynamic stability share (higher is better)."""


def dynamic_stability(
    zmp,
    points,
    rate: float,
    valid=None,
    *,
    height: float | Tensor = CONTACT_HEIGHT,
    speed: float = STANCE_SPEED,
) -> Tensor:
    """HUMOS Sec. 3.4 dynamic stability per sequence [...]: the share of valid frames whose ``zmp`` [..., T, 3]
    (or [..., T, 2] as x, z) lies inside the base of support, the convex hull in the ground plane of the contact
    ``points`` [..., T, K, 3] (y up, m) that are below ``height`` and slower than ``speed`` horizontally (m/s,
    ``rate`` Hz). A frame without such a point (flight) or without a ZMP (NaN) is not stable and still counts in
    the denominator; the hull's boundary counts as inside. NaN for a sequence without valid frames."""
    points = as_tensor(points, "points", min_dims=3, last=3)
    valid = frame_mask(valid, points.shape[:-2], points.device)
    contact = contact_mask(points, rate, height=height, speed=speed, valid=valid)
    signed = support_margin(zmp, points, valid, contact=contact)
    stable = torch.isfinite(signed) & (signed >= 0.0)
    return masked_mean(stable.to(points.dtype), valid, -1)


def clip_physics(model: BodyModel, motion: Motion, treadmill_speed: float | None = None) -> dict[str, float]:
    """Penetrate (m), float (m), skate (share of frame pairs) and dynamic stability (share of frames) of
    ``motion`` on ``model`` (module docstring); ``treadmill_speed`` (m/s) for a clip run on a treadmill, None
    overground. A motion lacking a coordinate of the model raises `biomotion.errors.ModelError` naming it."""
    placed = place_clip(model_motion(motion, model), model, height=None, treadmill_speed=treadmill_speed)
    clips = coordinate_set([CoordinateClip("clip", "clip", placed)], model, RATE, derivatives=True)
    feet, valid = clips.feet, clips.valid
    with torch_threads(1), torch.no_grad():
        zmp = clips.q.new_full((*valid.shape, 3), float("nan"))
        zmp[valid] = zero_moment_point(model, clips.q[valid], clips.qd[valid], clips.qdd[valid])
    values = {
        "penetrate": Penetration().score(feet, valid),
        "float": Floating().score(feet, clips.rate, valid),
        "skate": SkateRatio().score(feet, clips.rate, valid),
        STABILITY: dynamic_stability(zmp, feet, clips.rate, valid),
    }
    return {key: float(value[0]) for key, value in values.items()}
