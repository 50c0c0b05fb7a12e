"""Balance: is the ZMP (HUMOS) or the COM's ground projection (PhysPT's BOS) inside the base of support?

The base of support of a frame is the convex hull, in the ground plane (x, z), of the contact points in contact at
that frame (points [..., T, K, 3], contact [..., T, K] from `biomotion.metrics.contact.contact_mask` unless given).
``margin`` (m) dilates it by a disc, i.e. treats each contact point as a disc of that radius: useful when the
points are joint centres along the foot's axis (two points per foot span no area). The query point is a ZMP or
COM given as [..., T, 3] (y up; x and z are used) or [..., T, 2] (x, z).

Frames without any contact (flight) have no support and are left out of every average here, as are frames whose
query is NaN (the body model's ZMP, `biomotion.body.balance.zero_moment_point`, is NaN in flight: where the
kinematics ask the ground for less than `biomotion.body.balance.MIN_VERTICAL_LOAD_BW` body weights).
"""

from __future__ import annotations

import torch

from biomotion.errors import DataFormatError
from biomotion.metrics.base import Metric, Tensor, as_mask, as_tensor, frame_mask, ground_plane, masked_mean
from biomotion.metrics.contact import CONTACT_HEIGHT, contact_mask

TOLERANCE = 1e-10
"""m^2: cross products below this count as collinear (coordinates in metres)."""


def _cross(a: Tensor, b: Tensor) -> Tensor:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def signed_distance_to_hull(support, active, query) -> Tensor:
    """Signed distance (m) from ``query`` [..., 2] to the boundary of the convex hull of the ``active`` [..., P]
    points of ``support`` [..., P, 2]: positive inside, negative outside, NaN where no point is active.

    Vectorised without building the hull: (i, j) is a hull edge when every other active point lies left of i -> j
    or on the segment (so collinear boundary points give one edge, and of coincident points only the first
    counts); the query is inside when it lies left of every hull edge and the hull has area. The distance is the
    smallest distance to a hull edge, which also covers degenerate (segment) hulls; with a single distinct point
    it is the distance to that point. Costs O(P^3) per frame, meant for a few contact points.
    """
    support = as_tensor(support, "support", min_dims=2, last=2)
    query = as_tensor(query, "query", min_dims=1, last=2).to(support.dtype)
    active = as_mask(active, support.shape[:-1], "active", support.device)
    p = support
    n = p.shape[-2]
    edge = p[..., None, :, :] - p[..., :, None, :]  # [..., i, j, 2] = p_j - p_i
    rel = edge  # [..., i, k, 2] = p_k - p_i
    cross = _cross(edge[..., :, :, None, :], rel[..., :, None, :, :])  # [..., i, j, k]
    along = (edge[..., :, :, None, :] * rel[..., :, None, :, :]).sum(-1)  # [..., i, j, k]
    length2 = edge.square().sum(-1)  # [..., i, j]
    on_segment = (cross.abs() <= TOLERANCE) & (along >= -TOLERANCE) & (along <= length2[..., None] + TOLERANCE)
    left = (cross > TOLERANCE) | on_segment | ~active[..., None, None, :]
    earlier = torch.ones(n, n, dtype=torch.bool, device=p.device).tril(-1)  # [i, k]: k < i
    duplicate = ((length2 <= TOLERANCE) & active[..., None, :] & earlier).any(-1)
    first = active & ~duplicate
    hull_edge = left.all(-1) & first[..., :, None] & first[..., None, :] & (length2 > TOLERANCE)
    area = 0.5 * torch.where(hull_edge, _cross(p[..., :, None, :], p[..., None, :, :]), 0.0).sum((-2, -1))

    to_query = query[..., None, :] - p  # [..., i, 2]
    side = _cross(edge, to_query[..., :, None, :])  # [..., i, j]
    inside = (torch.where(hull_edge, side >= -TOLERANCE, True).all((-2, -1))) & (area > TOLERANCE)
    t = ((to_query[..., :, None, :] * edge).sum(-1) / length2.clamp(min=TOLERANCE)).clamp(0.0, 1.0)
    gap = torch.linalg.vector_norm(to_query[..., :, None, :] - t[..., None] * edge, dim=-1)
    inf = torch.full((), float("inf"), dtype=p.dtype, device=p.device)
    edge_distance = torch.where(hull_edge, gap, inf).amin((-2, -1))
    point_distance = torch.where(active, torch.linalg.vector_norm(to_query, dim=-1), inf).amin(-1)
    distance = torch.where(hull_edge.any((-2, -1)), edge_distance, point_distance)
    signed = torch.where(inside, distance, -distance)
    return torch.where(active.any(-1), signed, torch.full_like(signed, float("nan")))


def support_margin(
    query, points, valid=None, *, contact=None, margin: float = 0.0, height: float | Tensor = CONTACT_HEIGHT
) -> Tensor:
    """[..., T] signed distance (m) of ``query`` to the boundary of the support of each frame, dilated by
    ``margin``: positive inside. NaN on invalid frames and frames without contact."""
    points = as_tensor(points, "points", min_dims=3, last=3)
    query = as_tensor(query, "query", min_dims=2, last=(2, 3)).to(points.dtype)
    if query.shape[-2] != points.shape[-3]:
        raise DataFormatError(None, f"query has {query.shape[-2]} frames, points {points.shape[-3]}", field="query")
    valid = frame_mask(valid, points.shape[:-2], points.device)
    if contact is None:
        contact = contact_mask(points, height=height, valid=valid)
    else:
        contact = as_mask(contact, points.shape[:-1], "contact", points.device) & valid[..., None]
    signed = signed_distance_to_hull(ground_plane(points), contact, ground_plane(query)) + margin
    return torch.where(valid, signed, torch.full_like(signed, float("nan")))


def share_inside_support(
    query, points, valid=None, *, contact=None, margin: float = 0.0, height: float | Tensor = CONTACT_HEIGHT
) -> Tensor:
    """Share of supported frames whose ``query`` point lies inside the (dilated) support.

    For the ZMP it is HUMOS's "dynamic stability" (Sec. 3.4; 71.9 % for HUMOS), for the COM's ground projection
    PhysPT's "BOS" (Supp. D, Table 5, after IPMAN). NaN for a sequence without any supported frame."""
    signed = support_margin(query, points, valid, contact=contact, margin=margin, height=height)
    supported = torch.isfinite(signed)
    return masked_mean((signed >= 0).to(signed.dtype), supported, -1)


def mean_support_margin(
    query, points, valid=None, *, contact=None, margin: float = 0.0, height: float | Tensor = CONTACT_HEIGHT
) -> Tensor:
    """Mean over supported frames of the signed distance (m) of ``query`` to the support boundary, positive
    inside (HUMOS Sec. 3.4: distance of the ZMP to the base of support)."""
    signed = support_margin(query, points, valid, contact=contact, margin=margin, height=height)
    return masked_mean(signed, torch.isfinite(signed), -1)


class _SupportMetric(Metric):
    def __init__(self, margin: float = 0.0, height: float | Tensor = CONTACT_HEIGHT) -> None:
        super().__init__()
        self.margin, self.height = margin, height


class ZMPInsideSupport(_SupportMetric):
    """Share of supported frames with the ZMP inside the support (HUMOS "dynamic stability", printed in %)."""

    name, label, unit, display_unit, display_scale = "zmp_in_support", "ZMP in support", "1", "%", 100.0
    higher_is_better = True
    paper = 'HUMOS Sec. 3.4 "dynamic stability"'
    equation = "share of supported frames whose ZMP lies in the convex hull of the contact points in contact"

    def score(self, zmp, points, valid=None, contact=None) -> Tensor:
        return share_inside_support(zmp, points, valid, contact=contact, margin=self.margin, height=self.height)


class BaseOfSupport(_SupportMetric):
    """Share of supported frames with the COM's ground projection inside the support (PhysPT Table 5 "BOS",
    after IPMAN; printed in %)."""

    name, label, unit, display_unit, display_scale = "base_of_support", "BOS", "1", "%", 100.0
    higher_is_better = True
    paper = 'PhysPT Supp. D, Table 5 "BOS" (after IPMAN)'
    equation = (
        "share of supported frames whose COM ground projection lies in the convex hull of the contact points in contact"
    )

    def score(self, com, points, valid=None, contact=None) -> Tensor:
        return share_inside_support(com, points, valid, contact=contact, margin=self.margin, height=self.height)


class SupportDistance(_SupportMetric):
    """Mean signed distance (m) of a point (ZMP or COM projection) to the support boundary, positive inside
    (HUMOS Sec. 3.4)."""

    name, label, unit, display_unit, display_scale = "support_distance", "Support distance", "m", "cm", 100.0
    higher_is_better = True
    paper = "HUMOS Sec. 3.4 (distance of the ZMP to the base of support)"
    equation = "mean over supported frames of the signed distance to the support boundary, positive inside"

    def score(self, query, points, valid=None, contact=None) -> Tensor:
        return mean_support_margin(query, points, valid, contact=contact, margin=self.margin, height=self.height)
