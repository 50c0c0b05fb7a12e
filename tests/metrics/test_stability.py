"""Support polygons, ZMP / COM inside the base of support: hand cases, scipy's convex hull, Bandai-Namco walking."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial import ConvexHull

from biomotion.metrics import stability as S
from biomotion.metrics.stability import BaseOfSupport, SupportDistance, ZMPInsideSupport
from tests.metrics.conftest import point_mass_zmp

F64 = torch.float64


def square_feet(frames: int, side: float = 0.2) -> torch.Tensor:
    """[T, 4, 3] corners of a square support of ``side`` on the ground, centred on the origin."""
    h = side / 2
    corners = torch.tensor([[-h, 0.0, -h], [h, 0.0, -h], [h, 0.0, h], [-h, 0.0, h]], dtype=F64)
    return corners.expand(frames, 4, 3).clone()


def test_zmp_inside_and_outside_a_square_support():
    feet = square_feet(4)
    zmp = torch.tensor(
        [
            [0.0, 0.0, 0.0],  # centre: 0.1 m from every edge
            [0.05, 0.0, 0.0],  # 0.05 m from the +x edge
            [0.25, 0.0, 0.0],  # 0.15 m outside the +x edge
            [0.13, 0.0, 0.14],
        ],
        dtype=F64,
    )  # outside the corner (0.1, 0.1) by (0.03, 0.04)
    margins = S.support_margin(zmp, feet)
    assert margins.tolist() == pytest.approx([0.1, 0.05, -0.15, -0.05], abs=1e-12)
    assert S.share_inside_support(zmp, feet).item() == pytest.approx(0.5)
    assert ZMPInsideSupport(margin=0.06).score(zmp, feet).item() == pytest.approx(0.75)  # dilated by 6 cm
    assert SupportDistance().score(zmp, feet).item() == pytest.approx((0.1 + 0.05 - 0.15 - 0.05) / 4)
    assert S.support_margin(zmp[:, [0, 2]], feet).tolist() == pytest.approx(margins.tolist())  # (x, z) queries


def test_contact_decides_the_support_and_flight_is_left_out():
    feet = square_feet(3)
    feet[1, 2:, 1] = 0.2  # frame 1: two corners lifted -> support is the segment z = -0.1
    feet[2, :, 1] = 0.3  # frame 2: flight
    com = torch.tensor([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]], dtype=F64)
    margins = S.support_margin(com, feet)
    assert margins[:2].tolist() == pytest.approx([0.1, -0.1], abs=1e-12) and math.isnan(margins[2].item())
    assert BaseOfSupport().score(com, feet).item() == pytest.approx(0.5)
    assert BaseOfSupport(margin=0.1).score(com, feet).item() == pytest.approx(1.0)  # a 2-point foot with width
    explicit = torch.tensor([[True, True, True, True], [True] * 4, [False] * 4])
    assert S.share_inside_support(com, feet, contact=explicit).item() == pytest.approx(1.0)


def test_degenerate_supports():
    origin = torch.zeros(2, dtype=F64)
    one = torch.tensor([[0.3, 0.4]], dtype=F64)
    assert S.signed_distance_to_hull(one, torch.tensor([True]), origin).item() == pytest.approx(-0.5)
    line = torch.tensor([[-1.0, 0.0], [0.0, 0.0], [1.0, 0.0], [1.0, 0.0]], dtype=F64)  # collinear + duplicate
    assert S.signed_distance_to_hull(line, torch.ones(4, dtype=torch.bool), origin).item() == 0.0
    assert S.signed_distance_to_hull(
        line, torch.ones(4, dtype=torch.bool), torch.tensor([2.0, 0.0], dtype=F64)
    ).item() == pytest.approx(-1.0)
    square = torch.tensor(
        [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.0], [0.5, 0.5], [1.0, 0.0]], dtype=F64
    )  # interior point, point on an edge, duplicated corner
    assert S.signed_distance_to_hull(
        square, torch.ones(7, dtype=torch.bool), torch.tensor([0.5, 0.5], dtype=F64)
    ).item() == pytest.approx(0.5)
    assert math.isnan(S.signed_distance_to_hull(square, torch.zeros(7, dtype=torch.bool), origin).item())


def test_signed_distance_matches_scipy_convex_hull():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(500, 6, 2))
    active = rng.random((500, 6)) < 0.8
    queries = rng.normal(size=(500, 2)) * 0.8
    ours = S.signed_distance_to_hull(
        torch.from_numpy(points), torch.from_numpy(active), torch.from_numpy(queries)
    ).numpy()
    checked = 0
    for n in range(500):
        hull_points = points[n][active[n]]
        if len(hull_points) < 3:
            continue
        hull = ConvexHull(hull_points)
        inside_by_facet = -(hull.equations[:, :2] @ queries[n] + hull.equations[:, 2])
        if (inside_by_facet >= 0).all():
            reference = inside_by_facet.min()
        else:
            a = hull_points[hull.vertices]
            edge = np.roll(a, -1, 0) - a
            t = np.clip(((queries[n] - a) * edge).sum(1) / (edge * edge).sum(1), 0, 1)
            reference = -np.linalg.norm(queries[n] - a - t[:, None] * edge, axis=1).min()
        assert ours[n] == pytest.approx(reference, abs=1e-9)
        checked += 1
    assert checked > 400


def test_bandai_walking_balance(walks, sole_offsets):
    """Point-mass ZMP (cart-table) and Winter COM of ten walks; support from the toe and ankle joints lowered to
    the sole, each a disc of 5 cm (half a foot's width). Real walking is not always 'stable' by these tests: the
    point-mass ZMP ignores angular momentum and the joint-centre support misses heel and toe tip."""
    zmp_share, com_share, zmp_margin = [], [], []
    lower = torch.cat([torch.zeros(4, 1, dtype=F64), sole_offsets[:, None], torch.zeros(4, 1, dtype=F64)], 1)
    for walk in walks:
        soles = walk.feet() - lower
        com = walk.com()
        zmp = point_mass_zmp(com, walk.rate)
        zmp_share.append(ZMPInsideSupport(margin=0.05).score(zmp, soles).item())
        com_share.append(BaseOfSupport(margin=0.05).score(com, soles).item())
        zmp_margin.append(SupportDistance(margin=0.05).score(zmp, soles).item())
    mean = lambda v: sum(v) / len(v)
    print(
        f"Bandai walks: ZMP inside support {mean(zmp_share):.3f}, COM inside (BOS) {mean(com_share):.3f}, "
        f"ZMP margin {mean(zmp_margin) * 100:.2f} cm"
    )
    assert 0.4 < mean(zmp_share) < 0.95
    assert 0.5 < mean(com_share) < 0.98
    assert -0.05 < mean(zmp_margin) < 0.05
